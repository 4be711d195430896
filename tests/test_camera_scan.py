"""The camera scan: a rover-frame memory of what the camera has seen, checked
against the simulator's truth on seeded scenes and on a real daemon."""

from __future__ import annotations

import json
import logging
import math
import uuid
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers.daemon import Daemon

from fused_image import CHANNEL_DEPTH, CHANNEL_HEATMAP, DEPTH_MAX_M, depth_to_channel
from rover_env import RoverEnv
from rover_env.camera_scan import CameraScan, CameraScanConfig, sector_of
from rover_train.imitation.expert import PlannerExpert

DT = 0.05
SIZE = (96, 96)


def _truth_image(env: RoverEnv) -> np.ndarray:
    """The fused image a perfect daemon would make: true depth, the pedestrian mask as heat."""
    frame = env.sim.render_camera(depth=True, segmentation=True)
    fused = np.zeros((*SIZE, 3), dtype=np.float32)
    assert frame.depth is not None and frame.pedestrian_mask is not None
    fused[:, :, CHANNEL_DEPTH] = depth_to_channel(frame.depth)
    fused[:, :, CHANNEL_HEATMAP] = frame.pedestrian_mask
    return fused


def _pose(env: RoverEnv) -> tuple[float, float, float]:
    return float(env.position[0]), float(env.position[1]), float(env.orientation[2])


@pytest.fixture
def inspect_env() -> Iterator[RoverEnv]:
    env = RoverEnv(world_n="inspect", n_pedestrians=3, pedestrian_mode="pacing", size=SIZE)
    yield env
    env.close()


def _people_ahead(env: RoverEnv, spots: list[tuple[float, float]]) -> np.ndarray:
    """Pin pedestrians at (ahead, left) metres from the rover; their world positions."""
    x, y, yaw = _pose(env)
    for i, (a, left) in enumerate(spots):
        env.sim.place_pedestrian(i, x + a * math.cos(yaw) - left * math.sin(yaw),
                                 y + a * math.sin(yaw) + left * math.cos(yaw), 0.0)  # fmt: skip
    env.step(np.zeros(2, dtype=np.float32))
    return env.sim.pedestrian_positions.copy()


def test_true_depth_puts_scenery_on_the_lidars_ranges_and_people_on_their_spots(
    inspect_env: RoverEnv,
) -> None:
    env = inspect_env
    env.reset(seed=3)
    truth = _people_ahead(env, [(2.0, 0.5), (3.5, -1.0), (5.0, 0.0)])
    scan = CameraScan(SIZE, DT)
    scan.update(_truth_image(env), *_pose(env))
    obs = scan.observation
    lidar = env.sim.lidar(32, 12.0, pedestrians=False)
    seen = obs[2] == 0.0
    assert seen.sum() == 8  # 90° of 360° in sectors of 11.25°
    assert set(np.flatnonzero(seen)) == set(range(12, 20))  # straight ahead: the middle
    both = seen & (obs[0] < 10) & (lidar < 10)
    assert both.sum() >= 4
    assert np.abs(obs[0] - lidar)[both].max() < 0.1  # the same scenery at the same range
    assert (obs[2][~seen] == scan.config.memory_s).all()  # never seen: the memory's age
    points, ages = scan.points("person")
    assert len(points) == 3 and (ages == 0).all()
    for px, py in truth:  # each person found at its near side, within 0.4 m of its centre
        assert np.hypot(points[:, 0] - px, points[:, 1] - py).min() < 0.4
    x, y, yaw = _pose(env)
    near = np.hypot(truth[:, 0] - x, truth[:, 1] - y)
    k = sector_of(np.arctan2(truth[:, 1] - y, truth[:, 0] - x) - yaw, 32)
    assert np.all(obs[1][k] <= near) and np.all(obs[1][k] > near - 0.5)


def test_noisy_depth_reads_a_quantile_of_the_column_not_its_nearest_pixel(
    inspect_env: RoverEnv,
) -> None:
    """Per-pixel depth noise (5 %, independent; the network's is 12 % either way at the 10th
    / 90th percentile, but correlated): the nearest of a column's pixels reads the noise, not
    the wall, so the scan reads its obstacle at a quantile of the column's ranges."""
    env = inspect_env
    env.reset(seed=3)
    clean = _truth_image(env)
    metres = (1.0 - clean[:, :, CHANNEL_DEPTH]) * DEPTH_MAX_M
    rng = np.random.default_rng(0)
    noisy = clean.copy()
    noisy[:, :, CHANNEL_DEPTH] = depth_to_channel(metres * rng.normal(1.0, 0.05, metres.shape))
    lidar = env.sim.lidar(32, 12.0, pedestrians=False)
    errors = {}
    for quantile in (0.0, CameraScanConfig().obstacle_quantile):
        scan = CameraScan(SIZE, DT, CameraScanConfig(obstacle_quantile=quantile))
        scan.update(noisy, *_pose(env))
        obs = scan.observation
        both = (obs[2] == 0.0) & (obs[0] < 5) & (lidar < 5)
        assert both.sum() >= 4
        errors[quantile] = np.median((obs[0] - lidar)[both])
    nearest, default = errors.values()
    assert nearest < -0.25  # the nearest pixel: walls 2.4-2.9 m away read short by the noise
    assert abs(default) < 0.2 and abs(default) < abs(nearest) / 2
    with pytest.raises(ValueError, match="obstacle_quantile"):
        CameraScanConfig(obstacle_quantile=1.0)


def test_the_column_quantile_is_the_kth_smallest_to_within_a_bin() -> None:
    from rover_env.camera_scan_kernel import QUANTILE_BIN_M, QUANTILE_BINS, _quantile_index

    rng = np.random.default_rng(1)
    counts = np.empty(QUANTILE_BINS + 1, dtype=np.int64)
    for values in (rng.uniform(1.0, 1.5, 50),  # a wall: the histogram
                   np.r_[rng.uniform(0.5, 0.6, 3), rng.uniform(4.0, 6.0, 40)],  # beyond it
                   np.array([2.0, 2.0, 2.0, 1.0])):  # fmt: skip
        for k in range(len(values)):
            before = values.copy()
            got = values[_quantile_index(values, len(values), k, counts)]
            assert (values == before).all()
            assert abs(got - np.sort(values)[k]) <= QUANTILE_BIN_M


def test_the_memory_turns_with_the_rover_and_ages_out(inspect_env: RoverEnv) -> None:
    env = inspect_env
    env.reset(seed=3)
    _people_ahead(env, [(2.0, 0.3), (30.0, 30.0), (31.0, 30.0)])  # 8.5° left: sector 16
    scan = CameraScan(SIZE, DT, CameraScanConfig(person_memory_s=0.5))
    x, y, yaw = _pose(env)
    scan.update(_truth_image(env), x, y, yaw)
    ahead = sector_of(np.array(0.15), 32)
    assert scan.observation[1, ahead] < 2.0
    # the same image seen after the rover turned 90° left: the person now stands to the
    # right (bearing -90°), and the sectors ahead were last seen one step ago
    blind = np.zeros((*SIZE, 3), dtype=np.float32)  # a camera that sees nothing near
    scan.update(blind, x, y, yaw + math.pi / 2, pan=-math.pi)  # looking behind
    right = sector_of(np.array(0.15 - math.pi / 2), 32)
    assert scan.observation[1, right] < 2.0 and scan.observation[1, ahead] == 10.0
    assert scan.observation[2, right] == pytest.approx(DT)
    for _ in range(10):  # 0.5 s: the person's reading is gone, the scenery's stays
        scan.update(blind, x, y, yaw + math.pi / 2, pan=-math.pi)
    assert scan.observation[1].min() == 10.0
    assert scan.observation[0].min() < 10.0
    scan.reset()
    assert (scan.observation[:2] == 10.0).all() and (scan.observation[2] == 20.0).all()


def test_a_sector_seen_empty_is_emptied(inspect_env: RoverEnv) -> None:
    env = inspect_env
    env.reset(seed=3)
    _people_ahead(env, [(2.0, 0.0), (30.0, 30.0), (31.0, 30.0)])
    scan = CameraScan(SIZE, DT)
    x, y, yaw = _pose(env)
    scan.update(_truth_image(env), x, y, yaw)
    assert scan.observation[1].min() < 2.0
    scan.update(np.zeros((*SIZE, 3), dtype=np.float32), x, y, yaw)  # looked again: nobody
    assert scan.observation[1].min() == 10.0 and scan.observation[0].min() == 10.0


def test_non_finite_input_leaves_the_scan_unchanged_and_warns_once(
    inspect_env: RoverEnv, caplog: pytest.LogCaptureFixture
) -> None:
    env = inspect_env
    env.reset(seed=3)
    _people_ahead(env, [(2.0, 0.0), (30.0, 30.0), (31.0, 30.0)])
    scan = CameraScan(SIZE, DT)
    image = _truth_image(env)
    scan.update(image, *_pose(env))
    before = scan.observation.copy()
    bad = image.copy()
    bad[10, 10, CHANNEL_DEPTH] = np.nan
    caplog.set_level(logging.WARNING, logger="rover_env.camera_scan")
    scan.update(bad, *_pose(env))
    x, y, _ = _pose(env)
    scan.update(image, x, y, math.inf)
    assert np.array_equal(scan.observation[:2], before[:2])  # readings kept
    assert np.allclose(scan.observation[2][before[2] == 0], 2 * DT)  # time went on
    assert np.isfinite(scan.observation).all()
    assert caplog.text.count("non-finite") == 1
    with pytest.raises(ValueError, match="shape"):
        scan.update(np.zeros((64, 64, 3), dtype=np.float32), *_pose(env))


def test_the_scan_keyword_is_refused_where_there_is_no_fused_image() -> None:
    with pytest.raises(TypeError, match="takes no camera_scan.*RoverEnvFused-v0"):
        RoverEnv(camera_scan=True)
    with pytest.raises(ValueError, match="sectors must be >= 4"):
        CameraScanConfig(sectors=2)


# --- on a real daemon -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_scan_{uuid.uuid4().hex[:8]}", slots=1).start()
    yield d
    assert d.proc is not None and d.proc.poll() is None, "daemon died:\n" + "".join(d.log)
    d.stop()
    d.remove_leftovers()


@pytest.mark.parametrize("env_id", ["roverav/RoverEnvFused-v0", "roverav/RoverEnvFusedGaze-v0",
                                    "roverav/RoverEnvFusedDiscrete-v0",
                                    "roverav/RoverEnvFusedGazeDiscrete-v0"])  # fmt: skip
def test_every_fused_id_adds_the_scan_key_only_when_asked(daemon: Daemon, env_id: str) -> None:
    plain = gym.make(env_id, rl_obs_name=daemon.name, slot=0)
    try:
        assert "camera_scan" not in plain.observation_space.spaces  # the seed's spaces
    finally:
        plain.close()
    env = gym.make(env_id, rl_obs_name=daemon.name, slot=0, camera_scan=True)
    try:
        space = env.observation_space["camera_scan"]
        assert space.shape == (3, 32)
        obs, _ = env.reset(seed=1)
        assert space.contains(obs["camera_scan"])
        obs, *_ = env.step(env.action_space.sample())
        assert space.contains(obs["camera_scan"])
        assert (obs["camera_scan"][2] < 0.06).sum() >= 8  # the view was just seen
    finally:
        env.close()


def test_on_seeded_episodes_the_scan_agrees_with_the_truth(daemon: Daemon) -> None:
    """The daemon's own depth and heatmap, the planner expert driving among the crowd of 3:
    scenery within the bounds asserted below, people found, few false ones (the benchmark's
    table: benchmarks/camera_scan_accuracy.py)."""
    from rover_env import RoverEnvFused

    env = RoverEnvFused(world_n="inspect", rl_obs_name=daemon.name, slot=0, camera_scan=True,
                        goal_ends_episode=True)  # fmt: skip
    expert = PlannerExpert("inspect")
    errors: list[float] = []
    found = in_view = readings = false = 0
    try:
        for seed in (500_000, 500_001):
            env.reset(seed=seed)
            expert.reset()
            for _ in range(120):
                obs, _, terminated, truncated, _ = env.step(expert.act_env(env))
                scan = env.camera_scan
                assert scan is not None
                s = obs["camera_scan"]
                lidar = env.sim.lidar(32, 12.0, pedestrians=False)
                now = (s[2] == 0.0) & (s[0] < 10) & (lidar < 10)
                errors += np.abs(s[0] - lidar)[now].tolist()
                peds = env.sim.pedestrian_positions
                x, y = float(env.position[0]), float(env.position[1])
                view = env.sim.pedestrians_in_view() & (np.hypot(peds[:, 0] - x,
                                                                 peds[:, 1] - y) < 6.0)
                points, ages = scan.points("person")
                for px, py in peds[view]:
                    in_view += 1
                    found += bool(len(points)) and np.hypot(points[:, 0] - px,
                                                            points[:, 1] - py).min() < 0.5
                for qx, qy in points[ages == 0.0]:
                    readings += 1
                    false += np.hypot(peds[:, 0] - qx, peds[:, 1] - qy).min() >= 0.5
                if terminated or truncated:
                    break
    finally:
        env.close()
    assert len(errors) > 100
    assert float(np.median(errors)) < 0.8
    assert in_view > 20 and found / in_view > 0.5
    assert readings > 20 and false / readings < 0.35


def test_a_camera_agent_trains_on_the_scan_and_is_evaluated_with_it(
    daemon: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """rover-train --camera-scan stores the flag in the model's recipe; rover-eval makes the
    env with the scan itself, and an env without it is refused with the fix."""
    from rover_train import evaluate
    from rover_train.envs import make_env
    from rover_train.recipe import read_recipe
    from rover_train.train import parse_args, train

    args = ["--env", "fused", "--world", "maze", "--task", "nav", "--camera-scan",
            "--drop-image", "--relative-table", "--waypoint", "--name",
            daemon.name, "--slots", "1", "--n-steps", "32", "--batch-size", "32", "--n-epochs",
            "1", "--no-progress", "--checkpoint-every", "0", "--timesteps", "32", "--logdir",
            str(tmp_path)]  # fmt: skip
    assert train(parse_args(args))["status"] == "complete"
    model = tmp_path / "model.zip"
    recipe = read_recipe(model)
    assert recipe["camera_scan"] and recipe["drop_image"] and recipe["relative_table"]
    from rover_train.algos import ModelAgent, algo_class
    from rover_train.wrappers import agent_io

    trained = algo_class("ppo").load(model, device="cpu")
    assert "fused_image" not in trained.observation_space.spaces  # an MLP on scan and state
    assert trained.action_space.n == 60
    observe, act = agent_io(recipe)
    agent = ModelAgent(trained, observe=observe, act=act)  # what zoo.load makes of an rl entry
    plain = make_env("fused", world="maze", name=daemon.name, task="nav", camera_scan=True)
    try:
        obs, _ = plain.reset(seed=2)
        action = agent.act(obs)  # the plain env's observation in, its Box action out
        assert plain.action_space.contains(action)
        plain.step(action)
    finally:
        plain.close()
    code = evaluate.main([str(model), "--env", "fused", "--world", "maze", "--name", daemon.name,
                          "--episodes", "1", "--max-steps", "5", "--json"])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out.strip().splitlines()[-1]
    assert json.loads(out)["episodes"] == 1
    env = make_env("fused", world="maze", name=daemon.name, task="nav")
    try:
        with pytest.raises(evaluate.PolicyLoadError, match="camera_scan=True"):
            evaluate.load_policy(model, env, "ppo")
    finally:
        env.close()
    with pytest.raises(SystemExit):
        parse_args(["--env", "lidar", "--camera-scan"])
    assert "--camera-scan is built from the fused image" in capsys.readouterr().err


def test_a_camera_agent_trains_behind_the_shield_and_is_driven_behind_it(
    daemon: Daemon, tmp_path: Path
) -> None:
    """rover-train --shield trains MaskablePPO on the shield's masks, computed for each env's
    newest observation; rover-eval loads the model behind the same shield unless told not to."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from rover_train import evaluate
    from rover_train.envs import make_env
    from rover_train.shield import CollisionShield, shielded_vec_env
    from rover_train.train import parse_args, train
    from rover_train.wrappers import RelativeTable

    shield = CollisionShield()
    venv = shielded_vec_env(DummyVecEnv([lambda: RelativeTable(make_env(
        "fused", world="maze", name=daemon.name, task="nav", camera_scan=True))]), shield)
    try:
        assert venv.has_attr("action_masks")
        obs = venv.reset()
        for _ in range(3):
            (mask,) = venv.env_method("action_masks")
            assert mask.shape == (60,) and mask.dtype == bool
            assert np.array_equal(mask, shield.allowed(obs["camera_scan"][0]))
            obs, *_ = venv.step(np.array([int(np.flatnonzero(mask)[-1])]))
        assert venv.reset_infos is venv.venv.reset_infos  # the envs' own, for the checkpoints
    finally:
        venv.close()

    args = ["--env", "fused", "--world", "maze", "--task", "nav", "--camera-scan",
            "--drop-image", "--relative-table", "--waypoint", "--shield", "--name", daemon.name,
            "--slots", "1", "--n-steps", "32", "--batch-size", "32", "--n-epochs", "1",
            "--no-progress", "--checkpoint-every", "0", "--timesteps", "32", "--logdir",
            str(tmp_path)]  # fmt: skip
    assert train(parse_args(args))["status"] == "complete"
    model = tmp_path / "model.zip"
    env = make_env("fused", world="maze", name=daemon.name, task="nav", camera_scan=True)
    try:
        agent = evaluate.load_policy(model, env, deterministic=False)
        assert type(agent.model).__name__ == "MaskablePPO"
        assert isinstance(agent.shield, CollisionShield)  # as trained
        assert evaluate.load_policy(model, env, shield=False).shield is None
    finally:
        env.close()


def test_rover_eval_puts_a_box_student_behind_the_shield_on_the_scan_it_adds(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    """rover-eval STUDENT --shield makes the student's env with the camera scan (which the
    shield reads) and drives it behind the shield; the student alone needs no scan."""
    from rover_train import evaluate, zoo
    from rover_train.shield import ShieldedAgent

    argv = ["fused-inspect", "--episodes", "1", "--max-steps", "40", "--name", daemon.name,
            "--json"]  # fmt: skip
    assert evaluate.main([*argv, "--shield", "--person-margin", "0.6"]) == 0
    guarded = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert guarded["episodes"] == 1
    agent = zoo.load("fused-inspect", shield=True)
    assert isinstance(agent, ShieldedAgent)
    env = zoo.make_env("fused-inspect", rl_obs_name=daemon.name, camera_scan=True)
    try:
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        agent.reset()
        for _ in range(20):
            action = agent.act(obs)
            assert env.action_space.contains(action)
            command = np.clip(action[:2], env.action_space.low, env.action_space.high)
            assert agent.shield.allowed_commands(obs["camera_scan"], command[None])[0]
            obs, *_ = env.step(action)
    finally:
        env.close()


def test_the_shield_is_trained_with_ppo_over_the_relative_table_on_the_scan(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from rover_train.train import parse_args

    for bad in (["--env", "fused", "--camera-scan", "--shield"],
                ["--env", "fused", "--relative-table", "--shield"],
                ["--env", "fused", "--camera-scan", "--relative-table", "--algo", "dqn",
                 "--shield"]):  # fmt: skip
        with pytest.raises(SystemExit):
            parse_args(bad)
        assert "--shield masks the relative table's actions by the camera scan" in (
            capsys.readouterr().err)


def test_a_looking_agent_trains_with_a_drive_head_and_a_pan_head_behind_the_shield(
    daemon: Daemon, tmp_path: Path
) -> None:
    """rover-train --env fused-gaze --relative-table --pan-head: MultiDiscrete([60, 5]), the
    shield masking the drive head; the model drives the gaze env as trained."""
    from rover_train import evaluate
    from rover_train.envs import make_env
    from rover_train.shield import CollisionShield
    from rover_train.train import parse_args, train

    args = ["--env", "fused-gaze", "--world", "inspect", "--task", "nav", "--camera-scan",
            "--drop-image", "--relative-table", "--pan-head", "--waypoint", "--shield",
            "--name", daemon.name, "--slots", "1", "--n-steps", "32", "--batch-size", "32",
            "--n-epochs", "1", "--no-progress", "--checkpoint-every", "0", "--timesteps", "32",
            "--logdir", str(tmp_path)]  # fmt: skip
    assert train(parse_args(args))["status"] == "complete"
    env = make_env("fused-gaze", world="inspect", name=daemon.name, task="nav",
                   camera_scan=True)  # fmt: skip
    try:
        agent = evaluate.load_policy(tmp_path / "model.zip", env, deterministic=False)
        assert agent.model.action_space.nvec.tolist() == [60, 5]
        assert isinstance(agent.shield, CollisionShield) and agent.shield.pan_head
        obs, _ = env.reset(seed=3)
        for _ in range(5):
            action = agent.act(obs)
            assert env.action_space.contains(action) and action.shape == (3,)
            obs, *_ = env.step(action)
    finally:
        env.close()


def test_the_shipped_looking_entry_drives_its_env_and_turns_its_camera(daemon: Daemon) -> None:
    """zoo.load / zoo.make_env of rl-fused-gaze-inspect: the two heads become the gaze env's
    (speed, turn, pan) box, the drive behind the shield; the camera does not stay ahead."""
    from rover_train import zoo

    env = zoo.make_env("rl-fused-gaze-inspect", rl_obs_name=daemon.name, slot=0)
    agent = zoo.load("rl-fused-gaze-inspect")
    try:
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        agent.reset()
        pans = set()
        for _ in range(40):
            action = agent.act(obs)
            assert env.action_space.contains(action) and action.shape == (3,)
            pans.add(round(float(action[2]), 3))
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        assert len(pans) > 1  # it chose more than one pan window
    finally:
        env.close()


def test_the_pan_head_is_for_the_gaze_envs_table_and_on_policy_learners(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from rover_train.train import parse_args

    for bad, says in ((["--env", "fused", "--relative-table", "--pan-head"], "--env fused-gaze"),
                      (["--env", "fused-gaze", "--pan-head"], "no --relative-table"),
                      (["--env", "fused-gaze", "--relative-table", "--pan-head", "--algo",
                        "dqn"], "--algo ppo or recurrent-ppo")):  # fmt: skip
        with pytest.raises(SystemExit):
            parse_args(bad)
        err = capsys.readouterr().err
        assert "--pan-head" in err and says in err


def test_the_relative_table_is_rover_env_discretes_table() -> None:
    from rover_env.lidar_discrete_env import RoverEnvDiscrete
    from rover_train.wrappers import RelativeTable, relative_action

    discrete = RoverEnvDiscrete(world_n="maze")
    table = RelativeTable(RoverEnv(world_n="maze"))
    try:
        assert table.action_space == discrete.action_space
        for a in range(60):
            speed, heading = discrete._table_entry(a)  # relative to the yaw
            assert np.allclose(relative_action(a), [speed, heading])
            assert np.allclose(table.action(a), [speed, heading])
        assert np.allclose(relative_action(54), [1.0, 0.0])  # full speed straight on
        with pytest.raises(ValueError, match="outside 0..59"):
            relative_action(60)
    finally:
        discrete.close()
        table.close()


def test_scenery_seen_ahead_is_still_there_beside_the_rover_after_it_drove_on(
    inspect_env: RoverEnv,
) -> None:
    # The panel rows seen from the start are remembered in the world frame: 2.5 m on, with
    # the camera looking back (it frees only what it sees behind), every sector whose LIDAR
    # hit lies on scenery the first view saw reads that range from the new pose.
    env = inspect_env
    env.reset(seed=3)
    _people_ahead(env, [(30.0, 30.0), (31.0, 30.0), (32.0, 30.0)])
    scan = CameraScan(SIZE, DT)
    x0, y0, yaw0 = _pose(env)
    scan.update(_truth_image(env), x0, y0, yaw0)
    seen, _ = scan.points("obstacle")
    assert len(seen) >= 15  # the cells of the columns that show scenery, not a point a sector
    while math.hypot(env.position[0] - x0, env.position[1] - y0) < 2.5:
        env.step(np.array([0.5, 0.0], dtype=np.float32))
    x, y, yaw = _pose(env)
    scan.update(np.zeros((*SIZE, 3), dtype=np.float32), x, y, yaw, pan=math.pi)
    lidar = env.sim.lidar(32, 12.0, pedestrians=False)
    angles = -math.pi + (np.arange(32) + 0.5) * 2 * math.pi / 32 + yaw
    hits = np.stack([x + lidar * np.cos(angles), y + lidar * np.sin(angles)], axis=1)
    gap = np.hypot(hits[:, None, 0] - seen[None, :, 0], hits[:, None, 1] - seen[None, :, 1])
    covered = (lidar < 10.0) & (gap.min(axis=1) < 0.15)
    assert covered.sum() >= 5
    # a 0.1 m cell beside the rover spans more than a sector: it may read in a neighbour
    reading = scan.observation[0]
    error = np.min([np.abs(np.roll(reading, k) - lidar) for k in (-1, 0, 1)], axis=0)[covered]
    assert (error < 0.3).all(), (error, np.flatnonzero(covered))
