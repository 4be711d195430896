"""The policy zoo, its students and the planner expert they are distilled from."""

from __future__ import annotations

import io
import math
import subprocess
import uuid
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers.daemon import Daemon

from fused_image import FUSED_SIZE
from rover_env import FORWARD_CAMERA
from rover_train import zoo
from rover_train.agents import RandomAgent
from rover_train.evaluate import evaluate_agent
from rover_train.imitation.dagger import (
    DAggerConfig,
    Dataset,
    FusedView,
    WithFusedView,
    feature_spec,
    fit,
    make_training_env,
    run_dagger,
    sample_weight,
    stage2_config,
    teacher_config,
)
from rover_train.imitation.distill import RECIPES, DistillRun, read_recipe
from rover_train.imitation.expert import ExpertConfig, PlannerExpert, in_camera_view
from rover_train.progress import StatusLine
from rover_train.zoo.agent import (
    HEADING_BINS,
    HISTORY_STEPS,
    LIDAR_CLIP,
    FeatureSpec,
    ObsHistory,
    _scan_geometry,
    action_classes,
    decode_action,
    depth_scan,
    encode_action,
    state_features,
    unmapped_scan,
)
from rover_train.zoo.registry import ENTRY_DIR

REQUIRED = ("fused-inspect", "fused-maze", "lidar-inspect", "lidar-maze")


def test_the_zoo_ships_the_four_entries_in_a_few_megabytes() -> None:
    assert set(REQUIRED) <= set(zoo.names())
    total = sum(zoo.ENTRIES[n].path.stat().st_size for n in zoo.names())
    assert total < 12 * 2**20  # two-member ensembles of 0.4-0.5 MiB students included
    for name in zoo.names():
        if zoo.ENTRIES[name].trainer != zoo.DAGGER:  # RL models and fine-tunes: their own tests
            continue
        # the file's command remakes it from the recipe the file stores, which is the
        # recipe the lab's table makes the entry with
        assert zoo.command(name).endswith(
            f"python -m rover_train.imitation.distill --recipe rover_train/zoo/entries/{name}.pt"
        )
        agent = zoo.load(name)
        recipe = read_recipe(zoo.ENTRIES[name].path)
        assert recipe == RECIPES[name]
        net = agent.net
        assert len(getattr(net, "members", [net])) == recipe.members
        assert agent.spec.unmapped_scan == recipe.unmapped_scan


def test_an_unknown_entry_names_the_ones_there_are() -> None:
    with pytest.raises(zoo.UnknownEntryError, match="lidar-maze"):
        zoo.load("lidar-mars")


def test_a_retired_entry_says_it_was_retired_and_where_its_file_is() -> None:
    for name, retired in zoo.RETIRED.items():
        assert name not in zoo.ENTRIES and not (ENTRY_DIR / retired.file).exists()
        with pytest.raises(zoo.UnknownEntryError) as exc:
            zoo.load(name)
        assert "was retired" in str(exc.value)
        assert f"git show {retired.commit}:rover_train/zoo/entries/{retired.file}" in str(exc.value)
    root = Path(__file__).resolve().parents[1]

    def git(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                              check=False)  # fmt: skip

    if (root / ".git").exists() and git("rev-parse", "--is-shallow-repository").stdout.strip() \
            == "false":  # a clone with its whole history has each named file
        for retired in zoo.RETIRED.values():
            at = f"{retired.commit}:rover_train/zoo/entries/{retired.file}"
            found = git("cat-file", "-e", at)
            assert found.returncode == 0, found.stderr


@pytest.mark.parametrize("name", ["lidar-maze", "lidar-inspect"])
def test_lidar_entry_env_has_the_seed_spaces_and_the_agent_drives(name: str) -> None:
    env = zoo.make_env(name, length=150)
    try:
        space = env.observation_space
        assert space["lidar"].shape == (32,)
        assert {"pose", "imu", "target", "velocities"} <= set(space.spaces)
        np.testing.assert_allclose(env.action_space.low, [-1.0, -math.pi], rtol=1e-6)
        assert env.unwrapped.world_name == name.split("-")[1]
        assert env.unwrapped.length == 150  # the override reached the constructor
        agent = zoo.load(name)
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        agent.reset()
        first = agent.act(obs)
        np.testing.assert_array_equal(first, agent.act(obs))  # deterministic
        path = 0.0
        for _ in range(150):
            action = agent.act(obs)
            assert env.action_space.contains(action)
            before = np.array(obs["pose"][:2])
            obs, _, terminated, truncated, _ = env.step(action)
            path += float(np.hypot(*(np.array(obs["pose"][:2]) - before)))
            if terminated or truncated:
                break
        assert path > 1.0  # in 7.5 s it drives somewhere, not in place
    finally:
        env.close()


def test_fused_entry_env_has_the_seed_spaces_and_the_agent_acts_on_daemon_frames() -> None:
    d = Daemon(f"test_zoo_{uuid.uuid4().hex[:8]}").start()
    try:
        env = zoo.make_env("fused-maze", rl_obs_name=d.name, slot=0)
        try:
            assert env.observation_space["fused_image"].shape == (96, 96, 3)
            np.testing.assert_allclose(env.action_space.low, [-0.6, -math.pi], rtol=1e-6)
            assert env.unwrapped.rl_obs_name == d.name
            agent = zoo.load("fused-maze")
            obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
            agent.reset()
            for _ in range(5):
                action = agent.act(obs)
                assert env.action_space.contains(action)
                obs, *_ = env.step(action)
            # the image branch is live: a blank image changes the action
            blank = dict(obs, fused_image=np.zeros_like(obs["fused_image"]))
            assert not np.allclose(agent.act(blank), agent.act(obs))
            # stage 1's in-process fused image is the daemon's, for the same frame
            np.testing.assert_allclose(
                FusedView()(env.unwrapped), obs["fused_image"], atol=1e-4
            )
        finally:
            env.close()
    finally:
        d.stop()
        d.remove_leftovers()


def test_student_file_round_trip_gives_the_same_actions(tmp_path) -> None:
    agent = zoo.load("lidar-maze")
    path = tmp_path / "student.pt"
    agent.save(path)
    again = zoo.StudentAgent.load(path)
    env = zoo.make_env("lidar-maze")
    try:
        obs, _ = env.reset(seed=3)
        np.testing.assert_allclose(again.act(obs), agent.act(obs), atol=1e-3)
    finally:
        env.close()


def test_expert_goes_around_the_maze_wall() -> None:
    """Start and goal on either side of the central wall (x = 0, y in [-3, 3]): the
    straight line is blocked, the expert drives around and arrives."""
    env = make_training_env("lidar", "maze")
    expert = PlannerExpert("maze")
    try:
        env.reset(seed=5, options={"rover_pose": (-1.0, 0.0, 0.0), "goal": (1.0, 0.0)})
        field = expert.field((1.0, 0.0))
        assert field.value(1.0, 0.0) == 0.0
        # the planned cost from the start exceeds 5 m: the way round, not the 2 m line
        assert field.value(-1.0, 0.0) * expert.grid.res > 5.0
        expert.reset()
        reached = False
        for _ in range(600):
            _, _, terminated, truncated, info = env.step(expert.act_env(env))
            if info["goals_reached"]:
                reached = True
                break
            assert not terminated
        assert reached
    finally:
        env.close()


def test_expert_yielding_to_pedestrians_slows_down_for_turns_as_its_pursuit_does() -> None:
    """With a pedestrian near, the local planner picks the manoeuvre, but forward speed is
    capped as in plain pursuit (cos(heading)^3, less in tight corridors): at full speed a
    45-degree swerve swept the rover into the maze's walls (9 of the expert's 13 collided
    episodes in 100)."""
    expert = PlannerExpert("maze")
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        x, y = rng.uniform(-4.5, 4.5, 2)
        if expert.grid.clearance_at(x, y) < 0.4:
            continue
        yaw = rng.uniform(-math.pi, math.pi)
        peds = np.array([[x, y]]) + rng.uniform(-2.0, 2.0, (2, 2))
        speed, heading = expert.act((x, y), yaw, (4.0, 4.0), peds, time=0.0)
        if speed > 0:
            assert speed <= expert.config.max_speed * max(0.0, math.cos(heading)) ** 3 + 1e-6
            checked += 1
    assert checked > 50


@pytest.mark.parametrize("velocity_from", ["updates", "steps"])
def test_expert_reads_a_walker_the_crowd_moves_at_10_hz(velocity_from: str) -> None:
    """The crowd moves its walkers every other 20 Hz control step. Estimated over the
    positions' last change, a walker at 1 m/s reads 1 m/s at every step; differenced over
    steps (the shipped students' teacher) it read 0 and 2 m/s by turns."""
    expert = PlannerExpert("inspect", ExpertConfig(velocity_from=velocity_from))
    speeds = []
    for step in range(12):
        walker = np.array([[0.1 * (step // 2), 2.0]])  # 0.1 m per crowd update, 1 m/s
        expert.act((0.0, 0.0), 0.0, (8.0, 0.0), walker, time=0.05 * step)
        speeds.append(float(np.hypot(*expert._velocities[0])))
    late = np.round(speeds[3:], 6)
    if velocity_from == "updates":
        assert np.allclose(late, 1.0)
    else:
        assert set(late.tolist()) == {0.0, 2.0}


def test_an_old_student_files_recipe_reads_the_teacher_it_had() -> None:
    """The fused students' files predate ``teacher_velocity``: read, their recipe says
    ``steps`` (what taught them), so ``zoo.command`` remakes them; a new recipe's default
    is ``updates``."""
    assert read_recipe(zoo.ENTRIES["fused-maze"].path).teacher_velocity == "steps"
    assert DAggerConfig().teacher_velocity == "updates"
    with pytest.raises(ValueError, match="velocity_from"):
        ExpertConfig(velocity_from="frames")


def test_camera_expert_reacts_only_to_the_pedestrians_a_fused_student_can_see() -> None:
    """``sees="camera"``: a pedestrian inside the forward camera's 90-degree view (or with
    part of its body in it) changes the action as before; one beside or behind the rover
    does not: the action is the one with no pedestrian at all."""
    view = in_camera_view(0.0, 0.0, 0.0, np.array([[1.0, 0.0], [1.0, 1.1], [0.2, 1.0],
                                                   [-1.0, 0.0], [1.0, -1.6]]))
    assert view.tolist() == [True, True, False, False, False]
    # the same looking the other way: bearings are relative to the yaw
    assert in_camera_view(0.0, 0.0, math.pi, np.array([[-1.0, 0.0]])).tolist() == [True]
    all_round = PlannerExpert("maze")
    camera = PlannerExpert("maze", ExpertConfig(sees="camera"))
    x, y, yaw, goal = -3.0, -4.0, 0.0, (3.0, -4.0)  # the open south corridor, facing the goal
    assert all_round.grid.clearance_at(x, y) > 0.7
    clear = camera.act((x, y), yaw, goal, None, time=0.0)
    changed = 0
    for side in ([x + 0.9, y], [x - 0.2, y + 0.9], [x - 0.9, y], [x + 0.2, y - 0.9]):
        peds = np.array([side])
        seen = bool(in_camera_view(x, y, yaw, peds)[0])
        for expert in (all_round, camera):
            expert.reset()
        act_camera = camera.act((x, y), yaw, goal, peds, time=0.0)
        act_all = all_round.act((x, y), yaw, goal, peds, time=0.0)
        if seen:
            np.testing.assert_allclose(act_camera, act_all)
        else:
            np.testing.assert_allclose(act_camera, clear)
            changed += not np.allclose(act_all, clear)
    assert changed >= 1  # the all-round expert did react to one the camera cannot see
    with pytest.raises(ValueError, match="sees"):
        ExpertConfig(sees="lidar")


def test_firm_expert_passes_a_pedestrian_beside_its_path_that_the_polite_one_gives_way_to() -> None:
    """``firm`` manners (the LIDAR students' teacher) drive on past a pedestrian standing
    0.6-1 m beside the way, where ``polite`` slows and swerves (in the maze's corridors
    that is what timed it out); neither drives on into a pedestrian standing in its way."""
    polite = PlannerExpert("maze")
    firm = PlannerExpert("maze", ExpertConfig.with_manners("firm"))
    assert polite.config == ExpertConfig.with_manners("polite")
    x, y, yaw, goal = -3.0, -4.0, 0.0, (3.0, -4.0)  # the open south corridor, facing the goal
    for dx, dy in ((1.0, 0.8), (1.2, 0.7), (0.8, 0.9), (1.5, 0.6)):
        peds = np.array([[x + dx, y + dy]])
        for expert in (polite, firm):
            expert.reset()
        p_speed, p_heading = polite.act((x, y), yaw, goal, peds, time=0.0)
        f_speed, f_heading = firm.act((x, y), yaw, goal, peds, time=0.0)
        assert f_speed == pytest.approx(1.0) and f_heading == pytest.approx(0.0)
        assert p_speed < 0.8 and abs(p_heading) > 0.3
    for dx, dy in ((0.7, -0.1), (0.9, 0.0), (1.2, 0.1)):  # standing in the way
        for expert in (polite, firm):
            expert.reset()
            speed, heading = expert.act((x, y), yaw, goal, np.array([[x + dx, y + dy]]), 0.0)
            # a second of this action keeps the rover clear of contact (about 0.55 m)
            ahead = np.array([math.cos(heading), math.sin(heading)]) * speed * 1.0
            assert math.hypot(dx - ahead[0], dy - ahead[1]) > 0.6, (expert.config, dx, dy)
    with pytest.raises(ValueError, match="firm"):
        ExpertConfig.with_manners("rude")


def test_students_are_taught_by_the_polite_expert_the_lidar_ones_by_one_that_sees_all() -> None:
    """Every student's teacher keeps out of personal space; the LIDAR students', which sees
    every pedestrian, taught them among 10 people with the held velocity estimate (remade for
    the contact targets); the fused ones' sees what the camera shows."""
    for name, recipe in RECIPES.items():
        lidar = name.startswith("lidar")
        assert recipe.teacher_manners == "polite"
        assert recipe.teacher_sees == ("all" if lidar else "camera")
        assert recipe.teacher_velocity == ("updates" if lidar else "steps")
        if lidar:
            assert recipe.n_pedestrians == 10
    cfg = DAggerConfig(teacher_manners="firm", teacher_sees="camera")
    assert teacher_config(cfg) == ExpertConfig.with_manners("firm", sees="camera")
    assert teacher_config(DAggerConfig()) == ExpertConfig()


def test_dagger_fits_a_student_that_imitates_the_expert() -> None:
    env = make_training_env("lidar", "inspect")
    try:
        spec = feature_spec("lidar", env)
        agent = zoo.StudentAgent(zoo.StudentNet(spec))
        history: list[dict[str, float]] = []
        cfg = DAggerConfig(iterations=2, steps=300, epochs=15, status_every=1e9)
        run_dagger(env, "inspect", agent, cfg, label="test", history=history)
        assert [h["round"] for h in history] == [1, 2]
        assert history[0]["beta"] == 1.0 and history[1]["beta"] < 1.0
        # untrained: the cross-entropy is ln(classes)
        assert history[-1]["loss"] < 0.5 * math.log(spec.n_outputs)
    finally:
        env.close()


@pytest.mark.parametrize("speed,heading", [(1.0, 0.0), (0.35, 2.0), (0.0, -3.1), (-0.36, 0.0),
                                           (0.7, math.pi - 0.01)])
def test_binned_head_decodes_its_class_back_to_the_action(speed: float, heading: float) -> None:
    """An action's class, decoded from a one-hot output, is the action to within half a bin
    (the head's resolution), including headings either side of +-pi."""
    import torch

    spec = zoo.FeatureSpec(centre=(0.0, 0.0), scale=5.0)
    target = encode_action(np.array([speed, heading]), spec)
    cls = int(action_classes(torch.from_numpy(target)[None])[0])
    logits = np.full(spec.n_outputs, -20.0)
    logits[cls] = 20.0
    got_speed, got_heading = decode_action(logits, spec)
    assert abs(got_speed - speed) <= 0.09
    assert abs(math.remainder(got_heading - heading, 2 * math.pi)) <= math.pi / HEADING_BINS + 1e-6


def test_a_student_file_of_a_head_that_is_gone_is_refused_with_the_fix() -> None:
    agent = zoo.StudentAgent(zoo.StudentNet(zoo.FeatureSpec(centre=(0.0, 0.0), scale=5.0)))
    blob = agent.state_dict()
    zoo.StudentAgent.from_state_dict({**blob, "spec": {**blob["spec"], "head": "bins"}})
    for key, value in (("head", "regress"), ("pedestrian_scan", True)):
        with pytest.raises(ValueError, match=f"{key}=.*rover_train.zoo.command"):
            zoo.StudentAgent.from_state_dict({**blob, "spec": {**blob["spec"], key: value}})


def test_a_truncated_student_file_is_a_named_error_with_the_command_that_remakes_it(
    tmp_path: Path,
) -> None:
    shipped = zoo.ENTRIES["lidar-maze"].path
    cut = tmp_path / "lidar-maze.pt"
    data = shipped.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(zoo.StudentFileError) as err:
        zoo.load("lidar-maze", cut)
    text = str(err.value)
    assert str(cut) in text and "cut short" in text
    assert zoo.ENTRIES["lidar-maze"].command in text
    cut.write_bytes(b"")  # nothing at all: torch's bare EOFError
    with pytest.raises(zoo.StudentFileError, match="lidar-maze.pt"):
        zoo.load("lidar-maze", cut)


def test_random_agent_is_reproducible_from_its_seed() -> None:
    env = zoo.make_env("lidar-inspect")
    try:
        rows = []
        for _ in range(2):
            results = evaluate_agent(env, RandomAgent(env.action_space, 7), 2, max_steps=30)
            rows.append([(r.path_length, r.ret) for r in results])
        assert rows[0] == rows[1]
    finally:
        env.close()


def test_status_line_reports_steps_rate_eta_and_success() -> None:
    out = io.StringIO()
    status = StatusLine("job", total=100, every=0.0, stream=out)
    status.episode(True)
    status.episode(False)
    status.step(10)
    line = out.getvalue().strip().splitlines()[-1]
    assert line.startswith("job: 10/100 steps")
    assert "steps/s" in line and "ETA" in line and "50% of the last 2" in line


def test_history_features_show_progress_and_restart_with_each_goal_and_episode() -> None:
    """The history a student sees: nothing for the first 2 s, then how much nearer the
    goal is and how far the rover moved; a new goal or ``reset()`` starts it afresh."""
    spec = zoo.FeatureSpec(centre=(0.0, 0.0), scale=5.0, lidar_points=4, history=True)
    hist = ObsHistory(spec)

    def obs(x: float, goal_x: float, lidar: float = 2.0) -> dict[str, np.ndarray]:
        return {"pose": np.array([x, 0.0, 0.0], np.float32),
                "imu": np.zeros(3, np.float32),
                "target": np.array([abs(goal_x - x), 0.0 if goal_x > x else math.pi], np.float32),
                "velocities": np.zeros(2, np.float32),
                "lidar": np.full(4, lidar, np.float32)}

    feats = [hist.features(obs(0.025 * t, 5.0, 2.0 - 0.01 * t)) for t in range(HISTORY_STEPS + 1)]
    assert not feats[HISTORY_STEPS - 1][:3].any()  # not yet 2 s of past
    seen, progress, moved = feats[-1][:3]
    assert seen == 1.0 and progress == pytest.approx(0.5, abs=1e-3)  # 1 m nearer, / 2 m
    assert moved == pytest.approx(0.5, abs=1e-3)
    assert (feats[-1][3:] < 0).all()  # the ranges are shrinking
    assert len(state_features(obs(1.0, 5.0), spec, feats[-1])) == spec.state_dim
    # a new goal: no past again
    assert not hist.features(obs(1.0, -5.0)).any()
    agent = zoo.StudentAgent(zoo.StudentNet(spec))
    for t in range(HISTORY_STEPS + 1):
        agent.act(obs(0.025 * t, 5.0))
    assert agent.history.features(obs(1.05, 5.0))[0] == 1.0
    agent.reset()
    assert not agent.history.features(obs(1.05, 5.0)).any()


def test_depth_scan_sees_a_wall_ahead_and_drops_the_ground_and_the_sky() -> None:
    """The scan a fused student reads off the depth channel: the ground and the sky are
    "nothing within reach" (1.0); a wall 2 m ahead reads 2 m in the middle band and farther
    towards the edges of the view (the horizontal range grows off-axis)."""
    size = 96
    horizontal, up = _scan_geometry(size, size)
    sky = np.zeros((size, size), np.float32)  # 0: far
    np.testing.assert_array_equal(depth_scan(sky, 16), np.ones(16))
    # the flat ground: each pixel below the horizon at the depth where its ray meets it
    with np.errstate(divide="ignore"):
        z_ground = np.where(up < 0, FORWARD_CAMERA.height_m / -up, np.inf)
    for error in (1.0, 0.9, 1.1):  # exact, and 10 % near or far (the daemon's network)
        ground = np.clip(1.0 - error * z_ground / 10.0, 0.0, 1.0).astype(np.float32)
        np.testing.assert_array_equal(depth_scan(ground, 16), np.ones(16))
    # a wall across the view 2 m ahead of the camera (z-depth of a fronto-parallel plane)
    wall = np.full((size, size), 1.0 - 2.0 / 10.0, np.float32)
    scan = depth_scan(wall, 16) * LIDAR_CLIP
    assert scan[7] == pytest.approx(2.0, abs=0.05) and scan[8] == pytest.approx(2.0, abs=0.05)
    assert scan[0] > scan[4] > scan[7] and scan[15] > scan[11] > scan[8]
    with pytest.raises(ValueError, match="bands"):
        depth_scan(wall, 10)


def test_stage1_scan_shows_a_pedestrian_stood_ahead_in_the_middle_bands() -> None:
    """Stage 1's scan (RoverEnv with the fused image computed in-process): a pedestrian stood
    1.6 m ahead of the rover appears in the middle bands at about that range less the
    camera's offset and the pedestrian's half width, and in the pedestrian scan."""
    env = WithFusedView(make_training_env("lidar", "inspect", size=FUSED_SIZE))
    try:
        obs, _ = env.reset(seed=7)
        sim = env.unwrapped.sim
        x, y = float(obs["pose"][0]), float(obs["pose"][1])
        for i in range(len(sim.pedestrian_positions)):
            sim.place_pedestrian(i, x + 40.0, y + 40.0 + i, 0.0)
        # a heading with nothing within 3 m ahead
        for yaw in np.linspace(-math.pi, math.pi, 16, endpoint=False):
            sim.set_rover_pose(x, y, float(yaw))
            before = depth_scan(env.observation(obs)["fused_image"][:, :, 2], 16) * LIDAR_CLIP
            if before[6:10].min() > 3.0:
                break
        else:
            pytest.fail("no open heading at the spawn point")
        sim.place_pedestrian(0, x + 1.6 * math.cos(yaw), y + 1.6 * math.sin(yaw), 0.0)
        seen = env.observation(obs)
        after = depth_scan(seen["fused_image"][:, :, 2], 16) * LIDAR_CLIP
        assert 0.7 < after[7:9].min() < 1.7
        assert (before[7:9] - after[7:9]).min() > 1.0
        spec = feature_spec("fused", env, depth_scan=16)
        assert spec.scan_points == 16
        assert spec.state_dim == len(state_features(seen, spec, ObsHistory(spec)))
    finally:
        env.close()


def test_the_fused_view_refuses_an_env_that_renders_another_size() -> None:
    """A student reads the fused env's 96-pixel image; a RoverEnv at its default 64 pixels
    would feed it another image without any shape error (the CNN pools adaptively)."""
    env = make_training_env("lidar", "inspect")
    try:
        with pytest.raises(ValueError, match=r"renders 64x64 frames.*size=\(96, 96\)"):
            WithFusedView(env)
    finally:
        env.close()


def test_unmapped_scan_marks_a_pedestrian_and_not_the_maze_walls() -> None:
    """A LIDAR student's unmapped scan: with the pedestrians away it marks nothing, walls
    included, from poses all over the maze; a pedestrian stood 1.5 m ahead is marked in the
    points ahead at its range (less its half width), and nowhere else."""
    env = make_training_env("lidar", "maze")
    try:
        env.reset(seed=3)
        sim, base = env.unwrapped.sim, env.unwrapped
        world = base.world
        for i in range(len(sim.pedestrian_positions)):
            sim.place_pedestrian(i, 40.0, 40.0 + i, 0.0)

        def observe(x: float, y: float, yaw: float) -> dict[str, np.ndarray]:
            return {
                "pose": np.array([x, y, 0.0], np.float32),
                "imu": np.array([0.0, 0.0, yaw], np.float32),
                "velocities": np.zeros(2, np.float32),
                "lidar": sim.lidar(base.lidar_points, base.max_lidar_range),
            }

        rng = np.random.default_rng(0)
        for _ in range(30):
            x, y = world.sample_free(rng, world.goal, 0.4)
            yaw = float(rng.uniform(-math.pi, math.pi))
            sim.set_rover_pose(x, y, yaw)
            np.testing.assert_array_equal(unmapped_scan(observe(x, y, yaw), "maze"), 1.0)
        # facing +x from (-3, 0): the open corridor reaches the wall x = 0 (2.9 m)
        sim.set_rover_pose(-3.0, 0.0, 0.0)
        assert np.all(unmapped_scan(observe(-3.0, 0.0, 0.0), "maze") == 1.0)
        sim.place_pedestrian(0, -1.5, 0.0, 0.0)
        scan = unmapped_scan(observe(-3.0, 0.0, 0.0), "maze") * LIDAR_CLIP
        ahead = base.lidar_points // 2  # the points either side of the heading
        assert 1.1 < scan[ahead - 1 : ahead + 1].min() < 1.5
        assert np.count_nonzero(scan < LIDAR_CLIP) <= 3
    finally:
        env.close()


def test_unmapped_scan_leaves_the_walls_unmarked_while_the_rover_drives_and_turns() -> None:
    """The env's LIDAR is cast from the pose one physics step before ``obs["pose"]``; the
    map's scan follows it back by the odometry. Driving and turning hard through the maze
    with the pedestrians away, hardly any wall return is marked (0.01 %; cast from
    ``obs["pose"]`` as it is, 7.7 % of them were on this drive)."""
    env = make_training_env("lidar", "maze")
    try:
        obs, _ = env.reset(seed=11)
        sim = env.unwrapped.sim
        for i in range(len(sim.pedestrian_positions)):
            sim.place_pedestrian(i, 40.0, 40.0 + i, 0.0)
        rng = np.random.default_rng(0)
        marked = seen = 0
        for t in range(240):
            if t % 20 == 0:
                action = np.array([rng.uniform(0.2, 1.0), rng.choice([-1.2, 1.2])], np.float32)
            obs, _, terminated, truncated, _ = env.step(action)
            near = obs["lidar"] < LIDAR_CLIP
            marked += int(np.count_nonzero(unmapped_scan(obs, "maze")[near] < 1.0))
            seen += int(np.count_nonzero(near))
            if terminated or truncated:
                break
        assert seen > 2000 and marked / seen < 0.02
    finally:
        env.close()


def test_unmapped_scan_is_a_lidar_students_and_needs_its_world() -> None:
    env = make_training_env("lidar", "maze")
    try:
        plain = feature_spec("lidar", env)
        spec = feature_spec("lidar", env, unmapped_scan=True)
        assert spec.world == "maze" and spec.scan_points == spec.lidar_points == 32
        assert spec.state_dim == plain.state_dim + 2 * 32  # the scan, and its change
        obs, _ = env.reset(seed=1)
        assert spec.state_dim == len(state_features(obs, spec, ObsHistory(spec)))
        # a fused student has no LIDAR: the flag is dropped, not refused
        assert not feature_spec("fused", env, unmapped_scan=True).unmapped_scan
    finally:
        env.close()
    with pytest.raises(ValueError, match="unmapped_scan needs"):
        FeatureSpec(centre=(0.0, 0.0), scale=4.0, lidar_points=32, unmapped_scan=True)


def test_sample_weight_counts_pedestrians_within_two_metres_only() -> None:
    here = np.array([1.0, 1.0])
    assert sample_weight(here, np.array([[2.5, 1.0, 0.0]]), 3.0) == 3.0  # 1.5 m
    assert sample_weight(here, np.array([[4.0, 1.0, 0.0], [1.0, 5.0, 0.0]]), 3.0) == 1.0
    assert sample_weight(here, np.zeros((0, 3)), 3.0) == 1.0
    assert sample_weight(here, None, 3.0) == 1.0


def test_fit_follows_the_heavier_of_two_conflicting_labels() -> None:
    """Two labels for one state: the weighted fit picks the one with the larger total weight,
    which is the one with fewer samples here (what near_weight does for the rare states)."""
    import torch

    spec = zoo.FeatureSpec(centre=(0.0, 0.0), scale=5.0)
    net = zoo.StudentNet(spec, hidden=32)
    data = Dataset.empty(spec)
    state = np.zeros(spec.state_dim, np.float32)
    back, ahead = np.array([-0.36, 0.0]), np.array([1.0, 0.0])
    for _ in range(30):
        data.add(state, encode_action(ahead, spec), 1.0)
    for _ in range(15):
        data.add(state, encode_action(back, spec), 3.0)
    fit(net, data, DAggerConfig(epochs=60, batch=16), torch.Generator().manual_seed(0))
    speed, _ = decode_action(net(torch.from_numpy(state)[None])[0].detach().numpy(), spec)
    assert speed < 0.0


def test_stage2_rounds_refit_only_the_image_branch_with_the_student_driving() -> None:
    """A fused student's daemon rounds (distill's stage 2 and the demo's fine-tune) keep the
    caller's fit settings but never refit the state network, draw no synthetic states and
    let the student drive from the first round."""
    base = DAggerConfig(epochs=4, seed=7, near_weight=2.0, synthetic_goals=150)
    cfg = stage2_config(base, iterations=2, steps=500)
    assert (cfg.iterations, cfg.steps) == (2, 500)
    assert (cfg.epochs, cfg.seed, cfg.near_weight) == (4, 7, 2.0)
    assert cfg.image_only and not cfg.first_round_expert and cfg.synthetic_goals == 0
    assert 0 < cfg.beta0 < 1


def test_dagger_fits_on_fit_threads_and_collects_on_the_callers_threads(monkeypatch) -> None:
    """The fits run on ``fit_threads`` torch threads (the env and the daemon are idle then);
    collection, and the caller after the run, keep the caller's count."""
    import torch

    from rover_train.imitation import dagger
    from rover_train.threads import available_cores

    seen: list[int] = []
    real_fit = dagger.fit

    def counting_fit(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(torch.get_num_threads())
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(dagger, "fit", counting_fit)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    env = make_training_env("lidar", "inspect")
    try:
        agent = zoo.StudentAgent(zoo.StudentNet(feature_spec("lidar", env)))
        cfg = DAggerConfig(iterations=2, steps=50, epochs=1, status_every=1e9, fit_threads=2)
        run_dagger(env, "inspect", agent, cfg, label="test")
        assert seen == [min(2, available_cores())] * 2
        assert torch.get_num_threads() == 1
    finally:
        env.close()
        torch.set_num_threads(before)
    assert dagger.fit_threads(0) == available_cores()
    assert dagger.fit_threads(64) == available_cores()
    with pytest.raises(ValueError, match="fit_threads"):
        dagger.fit_threads(-1)


def _tiny_students(n: int) -> list[zoo.StudentAgent]:
    import torch

    env = make_training_env("lidar", "inspect")
    try:
        spec = feature_spec("lidar", env, "bins")
    finally:
        env.close()
    agents = []
    for seed in range(n):
        torch.manual_seed(seed)
        agents.append(zoo.StudentAgent(zoo.StudentNet(spec)))
    return agents


def test_an_ensemble_acts_on_its_members_mean_log_probabilities_and_round_trips(
    tmp_path,
) -> None:
    import torch

    from rover_train.zoo.agent import EnsembleNet

    a, b = _tiny_students(2)
    both = zoo.StudentAgent.ensemble([a, b])
    state = torch.randn(4, a.spec.state_dim)
    want = (a.net(state).log_softmax(-1) + b.net(state).log_softmax(-1)) / 2
    torch.testing.assert_close(both.net(state), want)
    # one student twice is that student (the decoding's softmax undoes the log-softmax)
    same = zoo.StudentAgent.ensemble([a, a])
    env = zoo.make_env("lidar-inspect")
    try:
        obs, _ = env.reset(seed=5)
        np.testing.assert_allclose(same.act(obs), a.act(obs), atol=1e-5)
        path = tmp_path / "ensemble.pt"
        both.save(path)
        again = zoo.StudentAgent.load(path)
        assert isinstance(again.net, EnsembleNet) and len(again.net.members) == 2
        np.testing.assert_allclose(again.act(obs), both.act(obs), atol=1e-3)
        # an ensemble of an ensemble and a student is flat: three members
        three = zoo.StudentAgent.ensemble([both, a])
        assert len(three.net.members) == 3
    finally:
        env.close()


def test_an_ensemble_refuses_members_of_another_entry_and_a_lone_member() -> None:
    from dataclasses import replace

    from rover_train.zoo.agent import EnsembleNet

    (a,) = _tiny_students(1)
    other = zoo.StudentNet(replace(a.spec, centre=(1.0, 2.0)))
    with pytest.raises(ValueError, match="another feature spec"):
        EnsembleNet([a.net, other])
    with pytest.raises(ValueError, match="at least 2"):
        EnsembleNet([a.net])


def test_fit_refits_every_member_of_an_ensemble() -> None:
    import torch

    agents = _tiny_students(2)
    both = zoo.StudentAgent.ensemble(agents)
    data = Dataset.empty(both.spec)
    rng = np.random.default_rng(0)
    for _ in range(64):
        data.add(rng.normal(size=both.spec.state_dim).astype(np.float32),
                 encode_action(np.array([0.7, 0.3], np.float32), both.spec), 1.0)
    before = [m.out.weight.detach().clone() for m in both.net.members]
    fit(both.net, data, DAggerConfig(epochs=2, batch=32), torch.Generator().manual_seed(0))
    for m, w in zip(both.net.members, before, strict=True):
        assert not torch.equal(m.out.weight, w)


TINY = {"iterations": 1, "steps": 60, "epochs": 1, "synthetic_goals": 0}
"""A recipe small enough for a test: one round of 60 steps, one epoch."""


def test_members_make_an_ensemble_from_whole_runs_and_resume_keeps_the_finished_ones(
    tmp_path, monkeypatch
) -> None:
    from rover_train.imitation import distill

    seeds: list[int] = []
    real = distill._distill_one

    def counting(recipe, seed, run):  # type: ignore[no-untyped-def]
        seeds.append(seed)
        return real(recipe, seed, run)

    monkeypatch.setattr(distill, "_distill_one", counting)
    recipe = replace(RECIPES["lidar-inspect"], members=2, seed=1, **TINY)
    out = tmp_path / "entry.pt"
    members = tmp_path / "members"
    distill.distill_entry(recipe, DistillRun(out=out, member_dir=members))
    assert seeds == [1, 2]
    assert sorted(p.name for p in members.iterdir()) == [
        "lidar-inspect-seed1.pt", "lidar-inspect-seed2.pt"
    ]
    agent = zoo.StudentAgent.load(out)
    assert len(agent.net.members) == 2 and agent.meta["name"] == "lidar-inspect"
    # a run stopped after its first member: --resume makes only the second again
    (members / "lidar-inspect-seed2.pt").unlink()
    distill.distill_entry(recipe, DistillRun(out=out, member_dir=members, resume=True))
    assert seeds == [1, 2, 2]


def test_recipe_flags_are_checked_before_any_work(capsys, tmp_path) -> None:
    from rover_train.imitation.distill import main

    for argv, needle in (
        (["lidar-inspect", "--members", "0"], "--members must be >= 1"),
        (["lidar-inspect", "--members", "3", "--seed", "3"], "diagnostic seeds"),
        (["fused-inspect", "--members", "2", "--stage1-only"], "one student"),
        (["lidar-inspect", "--stage1-only"], "fused entries"),
        (["lidar-inspect", "--init", str(tmp_path / "none.pt")], "no such student file"),
        ([], "name an entry"),
        (["--recipe", str(tmp_path / "none.pt")], "none.pt"),
        (["lidar-inspect", "--teacher-manners", "rude"], "invalid choice"),
    ):
        with pytest.raises(SystemExit):
            main(argv)
        assert needle in capsys.readouterr().err, argv


def test_an_entry_file_is_remade_from_the_recipe_it_stores(tmp_path) -> None:
    """The recipe travels in the file: ``--recipe FILE`` alone remakes the same student,
    bit for bit, and the file names the command that does it."""
    import torch

    from rover_train.imitation.distill import main, read_recipe

    first = tmp_path / "first.pt"
    tiny = ["--iterations", "1", "--steps", "60", "--epochs", "1", "--synthetic-goals", "0",
            "--members", "1", "--seed", "2"]  # fmt: skip
    assert main(["lidar-maze", *tiny, "--out", str(first)]) == 0
    recipe = read_recipe(first)
    assert recipe == replace(RECIPES["lidar-maze"], members=1, seed=2, **TINY)
    again = tmp_path / "again.pt"
    assert main(["--recipe", str(first), "--out", str(again)]) == 0
    assert read_recipe(again) == recipe
    a, b = zoo.StudentAgent.load(first), zoo.StudentAgent.load(again)
    for (k, va), (_, vb) in zip(a.net.state_dict().items(), b.net.state_dict().items(),
                                strict=True):  # fmt: skip
        assert torch.equal(va, vb), k
    # an option beside --recipe overrides the stored value
    other = tmp_path / "other.pt"
    assert main(["--recipe", str(first), "--seed", "3", "--out", str(other)]) == 0
    assert read_recipe(other).seed == 3


def test_a_fused_students_stage1_is_saved_and_resume_skips_it(tmp_path, monkeypatch) -> None:
    from rover_train.imitation import distill

    rounds: list[str] = []
    real = distill.run_dagger

    def counting(env, world, agent, cfg, label="dagger", **kw):  # type: ignore[no-untyped-def]
        rounds.append(label)
        return real(env, world, agent, cfg, label=label, **kw)

    monkeypatch.setattr(distill, "run_dagger", counting)
    recipe = replace(RECIPES["fused-inspect"], seed=3, stage1_only=True, iterations=1, steps=20,
                     epochs=1, synthetic_goals=0)  # fmt: skip
    out = tmp_path / "fused.pt"
    distill.distill_entry(recipe, DistillRun(out=out, member_dir=tmp_path))
    saved = tmp_path / "fused-inspect-seed3.stage1.pt"
    assert saved.is_file() and rounds == ["distill fused-inspect stage 1"]
    distill.distill_entry(recipe, DistillRun(out=out, member_dir=tmp_path, resume=True))
    assert rounds == ["distill fused-inspect stage 1"]  # stage 1 not made again
    assert zoo.StudentAgent.load(out).spec.image


def test_training_fused_envs_wait_out_a_starved_daemon() -> None:
    """Real daemon, real env: the training env carries the long frame timeout."""
    from rover_train.imitation import dagger

    d = Daemon(f"test_zoo_{uuid.uuid4().hex[:8]}").start()
    try:
        env = dagger.make_training_env("fused", "maze", name=d.name)
        try:
            assert env.unwrapped.frame_timeout == dagger.TRAINING_FRAME_TIMEOUT > 2.0
            env.reset(seed=1)
        finally:
            env.close()
        env = dagger.make_training_env("fused", "maze", name=d.name, frame_timeout=5.0)
        try:
            assert env.unwrapped.frame_timeout == 5.0
        finally:
            env.close()
    finally:
        d.stop()
        d.remove_leftovers()
    with pytest.raises(ValueError, match="frame_timeout is for the fused"):
        dagger.make_training_env("lidar", "maze", frame_timeout=5.0)
