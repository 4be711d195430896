"""Gaze control: RoverEnvFusedGaze and DiscreteRoverEnvFusedGaze on a real daemon,
the camera's pan head in the MuJoCo model, and the crossing pedestrian mode."""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from helpers.daemon import Daemon

import rover_env
from rover_env.discrete_env import decode_action
from rover_env.gaze_discrete_env import (
    DiscreteRoverEnvFusedGaze,
    decode_gaze_action,
    encode_gaze_action,
)
from rover_env.gaze_env import RoverEnvFusedGaze
from rover_env.reward import RewardConfig
from rover_env.simulation import RoverSim

DEG = math.pi / 180.0
LEFT, RIGHT, NONE = 1, 2, 0
STOP = 1 * 36 + 6 * 3  # speed 0.0 m/s, heading 0 rad: add a pan move to it


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_gaze_{uuid.uuid4().hex[:8]}", slots=2).start()
    yield d
    assert d.proc is not None and d.proc.poll() is None, "daemon died:\n" + "".join(d.log)
    d.stop()
    d.remove_leftovers()


def _gaze(daemon: Daemon, **kw: object) -> RoverEnvFusedGaze:
    kw.setdefault("world_n", "maze")
    return RoverEnvFusedGaze(rl_obs_name=daemon.name, connection_check_timeout=5, **kw)


def _discrete(daemon: Daemon, **kw: object) -> DiscreteRoverEnvFusedGaze:
    kw.setdefault("world_n", "maze")
    return DiscreteRoverEnvFusedGaze(rl_obs_name=daemon.name, connection_check_timeout=5, **kw)


def _stand(env: RoverEnvFusedGaze, seed: int = 1) -> None:
    """Rover at the origin facing +x, every pedestrian pinned far behind it."""
    env.reset(seed=seed, options={"rover_pose": (0.0, 0.0, 0.0), "goal": (-3.0, 3.0)})
    for i in range(len(env.sim.pedestrian_positions)):
        env.sim.place_pedestrian(i, -4.0 - i, -4.0, 0.0)


# --- spaces -------------------------------------------------------------------------------------
def test_spaces(daemon: Daemon) -> None:
    f32 = np.float32
    with _gaze(daemon) as env:
        assert env.action_space == spaces.Box(
            np.array([-0.6, -np.pi, -np.pi / 3], f32), np.array([1.0, np.pi, np.pi / 3], f32)
        )
        assert env.observation_space["gaze"] == spaces.Box(
            -f32(np.pi / 3), f32(np.pi / 3), shape=(1,), dtype=f32
        )
        assert set(env.observation_space.spaces) == {
            "fused_image", "pose", "imu", "target", "velocities", "gaze",
        }  # fmt: skip
        obs, info = env.reset(seed=0)
        assert obs["gaze"].shape == (1,) and obs["gaze"][0] == 0.0
        assert {"pan", "pan_target", "pan_moves", "pedestrian_in_view"} <= info.keys()
    with _discrete(daemon) as env:
        assert env.action_space == spaces.Discrete(180)
        assert "gaze" in env.observation_space.spaces


def test_registered_ids_and_package_exports(daemon: Daemon) -> None:
    assert rover_env.RoverEnvFusedGaze is RoverEnvFusedGaze
    assert rover_env.DiscreteRoverEnvFusedGaze is DiscreteRoverEnvFusedGaze
    for env_id, cls in (
        ("roverav/RoverEnvFusedGaze-v0", RoverEnvFusedGaze),
        ("roverav/RoverEnvFusedGazeDiscrete-v0", DiscreteRoverEnvFusedGaze),
    ):
        env = gym.make(env_id, rl_obs_name=daemon.name, world_n="maze")
        try:
            assert type(env.unwrapped) is cls
        finally:
            env.close()


# --- the discrete action table ------------------------------------------------------------------
def test_decode_table_covers_all_180_actions_in_the_documented_order() -> None:
    seen = set()
    for a in range(180):
        s, d, p = decode_gaze_action(a)
        assert (s, d, p) == (a // 36, (a // 3) % 12, a % 3)
        assert decode_action(a // 3) == (s, d)  # a // 3 is the seed's Discrete(60) action
        assert encode_gaze_action(s, d, p) == a
        seen.add((s, d, p))
    assert len(seen) == 180
    assert decode_gaze_action(85) == (2, 4, LEFT)  # the docstring's example
    assert decode_gaze_action(np.int64(179)) == (4, 11, RIGHT)
    for bad in (180, -1, 2.5, True, "3", np.array([1, 2]), None):
        with pytest.raises(ValueError):
            decode_gaze_action(bad)


def test_pan_moves_step_between_five_windows_and_clamp(daemon: Daemon) -> None:
    with _discrete(daemon, pan_rate=None) as env:
        _stand(env)
        pans = []
        for move in (LEFT, LEFT, LEFT, NONE, RIGHT, RIGHT, RIGHT, RIGHT, RIGHT, RIGHT):
            obs, *_, info = env.step(STOP + move)
            pans.append(round(info["pan"] / DEG))
            assert obs["gaze"][0] == pytest.approx(info["pan"], abs=1e-6)
        assert pans == [30, 60, 60, 60, 30, 0, -30, -60, -60, -60]
        assert info["pan_window"] == 0 and info["pan_moves"] == 9
        env.reset(seed=2)
        _, *_, info = env.step(STOP)
        assert info["pan"] == 0.0 and info["pan_moves"] == 0  # every episode starts ahead


def test_pan_turns_at_the_servo_rate(daemon: Daemon) -> None:
    with _discrete(daemon) as env:  # 180 deg/s: 9 deg per 0.05 s step
        _stand(env)
        pans = []
        for move in (LEFT, LEFT, NONE, NONE, NONE, NONE, NONE, NONE):
            *_, info = env.step(STOP + move)
            pans.append(round(info["pan"] / DEG, 6))
        assert pans == [9, 18, 27, 36, 45, 54, 60, 60]
    with _gaze(daemon, pan_rate=math.radians(90)) as env:
        _stand(env)
        *_, info = env.step(np.array([0.0, 0.0, -1.0], np.float32))
        assert info["pan"] == pytest.approx(-4.5 * DEG) and info["pan_target"] == -1.0
        *_, info = env.step(np.array([0.0, 0.0, 5.0], np.float32))  # clipped to +60 deg
        assert info["pan"] == pytest.approx(0.0, abs=1e-9) and info["pan_target"] == pytest.approx(
            math.pi / 3
        )
    with pytest.raises(ValueError, match="pan_rate"):
        _gaze(daemon, pan_rate=0.0)


# --- the pan penalty ----------------------------------------------------------------------------
def test_each_pan_move_costs_pan_penalty(daemon: Daemon) -> None:
    assert RewardConfig().pan_penalty == 0.02
    cfg = RewardConfig.fused(pan_penalty=0.5)
    with _discrete(daemon, pan_rate=None, reward_config=cfg) as env:
        _stand(env)
        for move, cost in ((LEFT, -0.5), (NONE, 0.0), (RIGHT, -0.5), (LEFT, -0.5), (LEFT, -0.5)):
            _, reward, *_, info = env.step(STOP + move)
            assert info["reward_pan"] == cost
            terms = sum(v for k, v in info.items() if k.startswith("reward_") and k != "reward")
            assert reward == pytest.approx(terms)
        _, reward, *_, info = env.step(STOP + LEFT)  # clamped at +60: still a chosen move
        assert info["pan_window"] == 4 and info["reward_pan"] == -0.5
    with _gaze(daemon) as env:  # the continuous env's pan is free
        _stand(env)
        _, _, *_, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
        assert info["reward_pan"] == 0.0 and info["pan_moves"] == 1


# --- the camera turns: image and in-view flags --------------------------------------------------
def test_fused_image_changes_with_the_pan(daemon: Daemon) -> None:
    with _gaze(daemon, pan_rate=None, report_latency=False) as env:
        images = {}
        for pan in (0.0, math.pi / 3, -math.pi / 3):
            _stand(env)
            env.sim.place_pedestrian(0, 2.0, 2.0 * math.sqrt(3.0), -math.pi / 2)  # 60 deg left
            obs, *_, info = env.step(np.array([0.0, 0.0, pan], np.float32))
            images[pan] = obs["fused_image"]
            assert info["pedestrian_in_view"] == (pan > 0)
        heat = {pan: float(img[:, :, 1].sum()) for pan, img in images.items()}
    gray_diff = np.abs(images[0.0][:, :, 0] - images[math.pi / 3][:, :, 0]).mean()
    assert gray_diff > 0.02
    assert heat[math.pi / 3] > 10.0 * max(heat[0.0], heat[-math.pi / 3], 1.0)


def test_in_view_test_agrees_with_the_rendered_pedestrian_mask() -> None:
    sim = RoverSim("maze")
    try:
        sim.set_rover_pose(0.0, 0.0, 0.0)
        for i in range(sim.pedestrians.n):
            sim.place_pedestrian(i, -4.0 - i, -4.0, 0.0)
        sim.place_pedestrian(0, 1.5, -1.5 * math.sqrt(3.0), 0.0)  # 3 m away, 60 deg right
        for pan_deg, seen in ((0, False), (-60, True), (60, False), (-30, True)):
            sim.set_camera_pan(pan_deg * DEG)
            assert sim.camera_heading == pytest.approx(pan_deg * DEG, abs=1e-6)
            in_view = sim.pedestrians_in_view()
            mask = sim.render_camera(segmentation=True).pedestrian_mask
            assert bool(in_view[0]) is seen and not in_view[1:].any()
            assert bool(mask.any()) is seen, pan_deg
    finally:
        sim.close()


def test_chase_view_draws_the_view_cone(daemon: Daemon) -> None:
    with _gaze(daemon, render_mode="rgb_array", render_size=(160, 120)) as env:
        env.reset(seed=1, options={"rover_pose": (0.0, 0.0, math.pi / 2)})  # an open view
        frame = env.render()
        plain = env.sim.render_chase(160, 120)
    yellow = (frame[..., 0] > 200) & (frame[..., 1] > 170) & (frame[..., 2] < 80)
    plain_yellow = (plain[..., 0] > 200) & (plain[..., 1] > 170) & (plain[..., 2] < 80)
    assert yellow.sum() > 100 and plain_yellow.sum() == 0


# --- determinism, checkers, training ------------------------------------------------------------
def _rollout(env: gym.Env, seed: int, actions: list) -> list[tuple]:
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    for a in actions:
        obs, reward, term, trunc, info = env.step(a)
        out.append((obs, reward, info))
        if term or trunc:
            break
    return out


@pytest.mark.parametrize("kind", ["continuous", "discrete"])
def test_seeded_episodes_are_identical(daemon: Daemon, kind: str) -> None:
    rng = np.random.default_rng(3)
    if kind == "continuous":
        make = _gaze
        actions = list(rng.uniform([-0.6, -np.pi, -1.0], [1.0, np.pi, 1.0], (30, 3)).astype("f4"))
    else:
        make, actions = _discrete, [int(a) for a in rng.integers(0, 180, 30)]
    with make(daemon, report_latency=False, pedestrian_mode="crossing") as env:
        a = _rollout(env, 7, actions)
        b = _rollout(env, 7, actions)
    assert len(a) == len(b)
    for (oa, ra, ia), (ob, rb, ib) in zip(a, b, strict=True):
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key], err_msg=key)
        assert ra == rb and ia == ib
    assert any(step[0]["gaze"][0] != 0.0 for step in a)


@pytest.mark.parametrize("make", [_gaze, _discrete], ids=["continuous", "discrete"])
def test_gymnasium_and_sb3_checkers_pass(daemon: Daemon, make) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with make(daemon, report_latency=False) as env:
        check_env(env, skip_render_check=True)
    with make(daemon) as env:
        sb3_check_env(env, warn=False)


def test_bad_actions_are_clear_errors(daemon: Daemon) -> None:
    with _gaze(daemon) as env:
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"expected 3 finite numbers.*found shape \(2,\)"):
            env.step(np.zeros(2, np.float32))
        with pytest.raises(ValueError, match="found non-finite values"):
            env.step(np.array([0.0, 0.0, np.nan], np.float32))
        with pytest.raises(ValueError, match="found not numbers"):
            env.step(["fast", "left", "up"])
    with _discrete(daemon) as env:
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"outside 0\.\.179"):
            env.step(180)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["fused-gaze", "fused-gaze-discrete"])
def test_ppo_trains_a_few_steps_on_two_daemon_slots(daemon: Daemon, kind: str) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from rover_train.envs import env_factory
    from rover_train.policies import RoverExtractor

    venv = DummyVecEnv(
        [
            env_factory(kind, world="maze", slot=i, name=daemon.name, length=20,
                        pedestrian_mode="crossing")
            for i in range(2)
        ]
    )  # fmt: skip
    try:
        model = PPO(
            "MultiInputPolicy", venv, n_steps=16, batch_size=16, n_epochs=1, seed=0,
            policy_kwargs={"features_extractor_class": RoverExtractor}, device="cpu",
        )  # fmt: skip
        model.learn(32)
        assert model.num_timesteps == 32
        action, _ = model.predict(venv.reset(), deterministic=True)
        assert venv.action_space.contains(action[0])
    finally:
        venv.close()


def test_rover_train_accepts_the_gaze_envs() -> None:
    from rover_train.train import parse_args

    args = parse_args(["--env", "fused-gaze", "--pedestrian-mode", "crossing"])
    assert args.env == "fused-gaze" and args.pedestrian_mode == "crossing"
    assert parse_args(["--env", "fused-gaze-discrete", "--algo", "dqn"]).algo == "dqn"
    with pytest.raises(SystemExit):
        parse_args(["--env", "fused-gaze-discrete", "--algo", "sac"])


# --- the crossing scenario ----------------------------------------------------------------------
def _side(start: tuple, goal: tuple, p: np.ndarray) -> np.ndarray:
    return np.sign((goal[0] - start[0]) * (p[:, 1] - start[1]) - (goal[1] - start[1]) * (
        p[:, 0] - start[0]
    ))  # fmt: skip


def test_crossing_pedestrians_cross_the_rovers_path_from_the_side() -> None:
    sim = RoverSim("moon")
    rng = np.random.default_rng(4)
    try:
        crossed_total = 0
        for _ in range(5):
            sim.reset(rng)
            start = (float(sim.position[0]), float(sim.position[1]))
            goal = sim.world.sample_free(rng, sim.world.goal, 0.4)
            n = sim.pedestrians.lay_crossings(rng, start, goal)
            first = _side(start, goal, sim.pedestrian_positions)
            crossed = np.zeros(sim.pedestrians.n, dtype=bool)
            for _ in range(200):  # 10 s: every crossing path is walked across at least once
                sim.pedestrians.advance(0.05)
                crossed |= _side(start, goal, sim.pedestrian_positions) != first
            assert crossed.sum() >= n
            crossed_total += n
        assert crossed_total >= 10  # most of the 15 pedestrians get a crossing on the moon
    finally:
        sim.close()


def test_pedestrian_mode_is_checked(daemon: Daemon) -> None:
    with pytest.raises(ValueError, match="pedestrian_mode must be one of"):
        _gaze(daemon, pedestrian_mode="stampede")
