"""RoverEnv: seed spaces, env checkers, determinism, rewards and every episode end."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import rover_env  # noqa: F401  (registers roverav/RoverEnv-v0)
from rover_env import RewardConfig, RoverEnv
from rover_env.worlds import WORLD_NAMES

PI = np.float32(np.pi)
STAY = np.array([0.0, 0.0], dtype=np.float32)


def _open_spot(env: RoverEnv) -> None:
    """Maze: rover in an open corridor, pedestrians parked in the far corner."""
    for i in range(env.sim.pedestrians.n):
        env.sim.place_pedestrian(i, -5.4 + 0.6 * i, -5.4, 0.0)


@pytest.fixture
def maze_env() -> RoverEnv:
    env = RoverEnv(world_n="maze")
    yield env
    env.close()


def test_spaces_equal_the_seed() -> None:
    env = RoverEnv()
    obs_space, act_space = env.observation_space, env.action_space
    assert set(obs_space.spaces) == {"lidar", "pose", "imu", "target", "velocities"}
    expected = {
        "lidar": (np.zeros(32), np.full(32, 12.0)),
        "pose": ([-30, -30, -10], [30, 30, 10]),
        "imu": ([-np.pi] * 3, [np.pi] * 3),
        "target": ([0, -np.pi], [100, np.pi]),
        "velocities": ([-10, -10], [10, 10]),
    }
    for key, (low, high) in expected.items():
        box = obs_space[key]
        assert box.dtype == np.float32
        assert box.shape == np.asarray(low).shape
        np.testing.assert_array_equal(box.low, np.asarray(low, dtype=np.float32))
        np.testing.assert_array_equal(box.high, np.asarray(high, dtype=np.float32))
    assert act_space.dtype == np.float32 and act_space.shape == (2,)
    np.testing.assert_array_equal(act_space.low, np.array([-1.0, -np.pi], dtype=np.float32))
    np.testing.assert_array_equal(act_space.high, np.array([1.0, np.pi], dtype=np.float32))
    small = RoverEnv(lidar_points=16, max_lidar_range=5.0)
    assert small.observation_space["lidar"].shape == (16,)
    assert small.observation_space["lidar"].high.max() == np.float32(5.0)
    obs, _ = small.reset(seed=0)
    assert obs["lidar"].shape == (16,) and obs["lidar"].max() <= 5.0
    env.close()
    small.close()


def test_seed_constructor_arguments_are_accepted() -> None:
    env = RoverEnv(
        size=(64, 64), length=2000, scan_topic="/scan", imu_topic="/imu/data",
        cmd_vel_topic="/cmd_vel", camera_topic="/camera/image_raw", world_n="inspect",
        connection_check_timeout=30, lidar_points=32, max_lidar_range=12.0,
    )  # fmt: skip
    assert env.world_name == "inspect"
    env.close()


@pytest.mark.parametrize("world", WORLD_NAMES)
def test_gymnasium_check_env(world: str) -> None:
    env = RoverEnv(world_n=world)
    gym_check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("world", WORLD_NAMES)
def test_sb3_check_env(world: str) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = RoverEnv(world_n=world)
    # SB3 recommends a [-1, 1] action box; the seed's heading range is [-pi, pi].
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized Box action")
        sb3_check_env(env, warn=True)
    env.close()


def _rollout(env: RoverEnv, seed: int, n: int = 40) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(123)  # same actions every time
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(n):
        action = rng.uniform([-1, -np.pi], [1, np.pi]).astype(np.float32)
        obs, *_ = env.step(action)
        out.append(obs)
    return out


@pytest.mark.parametrize("world", ["moon", "inspect"])
def test_same_seed_and_actions_give_the_same_observations(world: str) -> None:
    a, b = RoverEnv(world_n=world), RoverEnv(world_n=world)
    first, again = _rollout(a, seed=7), _rollout(b, seed=7)
    for o1, o2 in zip(first, again, strict=True):
        for key in o1:
            np.testing.assert_array_equal(o1[key], o2[key])
    _rollout(a, seed=8)  # an episode in between must not leak into the next
    for o1, o2 in zip(first, _rollout(a, seed=7), strict=True):
        np.testing.assert_array_equal(o1["lidar"], o2["lidar"])
        np.testing.assert_array_equal(o1["pose"], o2["pose"])
    other = _rollout(b, seed=9)
    assert not np.array_equal(first[0]["pose"], other[0]["pose"])
    a.close()
    b.close()


def test_island_behaves_as_moon() -> None:
    island, moon = RoverEnv(world_n="island"), RoverEnv(world_n="moon")
    assert island.world_name == "moon"
    for o1, o2 in zip(_rollout(island, 3, 20), _rollout(moon, 3, 20), strict=True):
        for key in o1:
            np.testing.assert_array_equal(o1[key], o2[key])
    island.close()
    moon.close()


def test_unknown_world_raises() -> None:
    with pytest.raises(ValueError, match="choose one of"):
        RoverEnv(world_n="atlantis")


def test_non_finite_action_raises_and_out_of_range_is_clipped(maze_env: RoverEnv) -> None:
    maze_env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        maze_env.step(np.array([np.nan, 0.0], dtype=np.float32))
    with pytest.raises(ValueError, match="finite"):
        maze_env.step(np.array([0.5, np.inf], dtype=np.float32))
    other = RoverEnv(world_n="maze")
    maze_env.reset(seed=1)
    other.reset(seed=1)
    for _ in range(5):
        big, _, _, _, _ = maze_env.step(np.array([5.0, 10.0], dtype=np.float32))
        edge, _, _, _, _ = other.step(np.array([1.0, np.pi], dtype=np.float32))
        np.testing.assert_array_equal(big["pose"], edge["pose"])
    other.close()


def test_info_keys(maze_env: RoverEnv) -> None:
    _, info = maze_env.reset(seed=0)
    _, reward, _, _, info = maze_env.step(np.array([0.5, 0.0], dtype=np.float32))
    for key in (
        "steps", "total_steps", "reward", "goals_reached", "is_success", "collision",
        "termination_reason", "distance_to_goal", "min_pedestrian_distance",
        "reward_goal", "reward_progress", "reward_velocity", "reward_turn",
        "reward_collision", "reward_clearance", "reward_termination",
    ):  # fmt: skip
        assert key in info, key
    assert info["steps"] == 1 and info["reward"] == reward
    parts = sum(v for k, v in info.items() if k.startswith("reward_"))
    assert parts == pytest.approx(reward)
    assert info["min_pedestrian_distance"] > 0


def test_goal_reached_gives_100_and_moves_the_goal(maze_env: RoverEnv) -> None:
    obs, _ = maze_env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0), "goal": (-2.8, -1.0)})
    _open_spot(maze_env)
    assert obs["target"][0] == pytest.approx(0.2, abs=1e-3)
    obs, reward, terminated, truncated, info = maze_env.step(STAY)
    assert reward >= 100.0 and info["reward_goal"] == 100.0
    assert info["goals_reached"] == 1 and info["is_success"]
    assert not terminated and not truncated  # the episode continues
    new_goal = info["goal"]
    assert math.dist(new_goal, (-2.8, -1.0)) > 0.5
    assert maze_env.world.goal.contains(*new_goal)
    assert obs["target"][0] == pytest.approx(info["distance_to_goal"], abs=1e-4)
    assert info["distance_to_goal"] >= 1.0


def test_progress_reward_when_driving_to_the_goal(maze_env: RoverEnv) -> None:
    maze_env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0), "goal": (1.0, -1.0)})
    _open_spot(maze_env)
    total = 0.0
    for _ in range(20):
        _, _, _, _, info = maze_env.step(np.array([1.0, 0.0], dtype=np.float32))
        total += info["reward_progress"]
        assert info["reward_velocity"] >= 0
    moved = 4.0 - info["distance_to_goal"]
    assert total == pytest.approx(moved * 0.45, rel=1e-6)
    assert moved > 0.5


def test_flip_terminates(maze_env: RoverEnv) -> None:
    maze_env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0)})
    maze_env.sim.set_rover_pose(-3.0, -1.0, 0.0, z=0.3, roll=math.pi)  # upside down
    _, reward, terminated, truncated, info = maze_env.step(STAY)
    assert terminated and not truncated
    assert info["termination_reason"] == "flipped"
    assert info["flip_direction"] in ("roll_left", "roll_right")
    assert reward == -20.0 == info["reward_termination"]
    with pytest.raises(RuntimeError, match="reset"):
        maze_env.step(STAY)


def test_out_of_bounds_terminates() -> None:
    env = RoverEnv(world_n="inspect")
    env.reset(seed=0)
    env.sim.set_rover_pose(-14.0, -16.5, 0.0)  # y > -17: outside the seed rectangle
    _, reward, terminated, _, info = env.step(STAY)
    assert terminated and info["termination_reason"] == "out_of_bounds"
    assert reward == -10.0
    env.close()


def test_stuck_terminates_with_a_short_window() -> None:
    env = RoverEnv(world_n="maze", reward_config=RewardConfig(stuck_window=5))
    env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0), "goal": (3.0, 3.0)})
    _open_spot(env)
    for step in range(1, 6):
        _, reward, terminated, _, info = env.step(STAY)
        assert terminated == (step == 5), step
    assert info["termination_reason"] == "stuck" and reward == -25.0
    # Moving keeps it alive.
    env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0), "goal": (3.0, 3.0)})
    _open_spot(env)
    for _ in range(10):
        _, _, terminated, _, _ = env.step(np.array([0.5, 0.0], dtype=np.float32))
        assert not terminated
    env.close()


def test_collision_penalty_and_stuck_in_collision() -> None:
    cfg = RewardConfig(collision_limit=3)
    env = RoverEnv(world_n="maze", reward_config=cfg)
    # 0.25 m from the east wall: LIDAR min < 0.3 m every step.
    env.reset(seed=0, options={"rover_pose": (5.65, -4.8, 0.0), "goal": (0.0, 3.0)})
    _open_spot(env)
    for step in range(1, 5):
        _, reward, terminated, _, info = env.step(STAY)
        assert info["collision"]
        if step <= 3:
            assert not terminated and info["reward_collision"] == -0.5
    assert terminated and info["termination_reason"] == "stuck_in_collision"
    assert reward == -20.0
    env.close()


def test_length_truncates() -> None:
    env = RoverEnv(world_n="maze", length=5)
    env.reset(seed=0, options={"rover_pose": (-3.0, -1.0, 0.0)})
    _open_spot(env)
    for step in range(1, 6):
        _, _, terminated, truncated, info = env.step(np.array([0.3, 0.0], dtype=np.float32))
        assert not terminated
        assert truncated == (step == 5)
    assert info["termination_reason"] == "time_limit"
    env.close()


def test_one_step_is_control_dt_of_simulated_time() -> None:
    env = RoverEnv(world_n="maze", control_dt=0.1)
    env.reset(seed=0)
    env.step(STAY)
    assert env.sim.time == pytest.approx(0.1)
    env.close()


def test_registered_and_renders_a_chase_view() -> None:
    env = gym.make("roverav/RoverEnv-v0", world_n="maze", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8
    assert env.metadata["render_fps"] == 20
    env.close()
    # What RecordVideo relies on: one same-shaped frame per reset and step.
    video = gym.wrappers.RenderCollection(
        RoverEnv(world_n="moon", render_mode="rgb_array", render_size=(80, 60))
    )
    video.reset(seed=0)
    for _ in range(3):
        video.step(np.array([0.5, 0.0], dtype=np.float32))
    frames = video.render()
    assert len(frames) == 4 and all(f.shape == (60, 80, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[-1])  # the camera follows the rover
    video.close()


@pytest.mark.parametrize("world", WORLD_NAMES)
def test_spawns_and_goals_never_overlap_obstacles(world: str) -> None:
    env = RoverEnv(world_n=world)
    env.reset(seed=0)
    spec = env.world
    for _ in range(300):
        obs, info = env.reset()
        x, y = obs["pose"][:2]
        assert spec.clearance(x, y) > 0.4 and spec.spawn.contains(x, y)
        gx, gy = info["goal"]
        assert spec.clearance(gx, gy) > 0.3 and spec.goal.contains(gx, gy)
        assert info["distance_to_goal"] >= 1.0
    env.close()


def _maze_env() -> RoverEnv:
    return RoverEnv(world_n="maze", render_mode="rgb_array", render_size=(64, 48))


def _moon_env() -> RoverEnv:
    return RoverEnv(world_n="moon", render_mode="rgb_array", render_size=(64, 48))


def test_async_vector_env_with_two_workers() -> None:
    # forkserver: this test process has rendered already (see the next test).
    envs = gym.vector.AsyncVectorEnv([_maze_env, _moon_env], context="forkserver")
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs["lidar"].shape == (2, 32)
        for _ in range(5):
            obs, reward, terminated, truncated, info = envs.step(
                np.array([[0.5, 0.0], [0.5, 0.1]], dtype=np.float32)
            )
        assert reward.shape == (2,) and np.all(np.isfinite(reward))
        assert list(info["steps"]) == [5, 5]
        frames = envs.render()  # each worker creates its own renderer
        assert len(frames) == 2 and frames[0].shape == (48, 64, 3)
    finally:
        envs.close()


_NOTEBOOK = """
import multiprocessing
import gymnasium as gym
from rover_env import RoverEnv

def maze():
    return RoverEnv(world_n="maze", render_mode="rgb_array", render_size=(64, 48))

if __name__ == "__main__":
    env = gym.make("roverav/RoverEnv-v0", world_n="maze", render_mode="rgb_array")
    env.reset(seed=0)
    env.render()  # OpenGL now lives in this process
    env.close()
    envs = gym.vector.AsyncVectorEnv([maze, maze])  # the default context, as make_vec's
    envs.reset(seed=0)
    frames = envs.render()
    envs.close()
    print(multiprocessing.get_start_method(), frames[0].shape, bool(frames[1].any()))
"""


def test_async_vector_env_after_rendering_in_process_works_by_default(tmp_path: Path) -> None:
    # a notebook's order: render in-process first, then subprocess envs with no context given
    script = tmp_path / "notebook.py"
    script.write_text(_NOTEBOOK)
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=240, env=dict(os.environ, MUJOCO_GL="egl"))  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.split("\n")[-2] == "forkserver (48, 64, 3) True"


def test_forked_after_rendering_raises_instead_of_hanging() -> None:
    env = RoverEnv(world_n="maze", render_mode="rgb_array", render_size=(64, 48))
    env.reset(seed=0)
    env.render()  # OpenGL now lives in this process
    env.close()
    envs = gym.vector.AsyncVectorEnv([_maze_env], context="fork")
    try:
        envs.reset(seed=0)  # physics and LIDAR need no OpenGL: fine after fork
        with pytest.raises(RuntimeError, match="forkserver"):
            envs.render()
    finally:
        envs.close(terminate=True)


def test_sb3_subproc_vec_env() -> None:
    from stable_baselines3.common.vec_env import SubprocVecEnv

    venv = SubprocVecEnv([_maze_env, _moon_env])
    try:
        venv.seed(3)
        obs = venv.reset()
        assert obs["pose"].shape == (2, 3)
        obs, reward, done, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
        assert reward.shape == (2,) and infos[0]["steps"] == 1
        frames = venv.get_images()
        assert frames[1].shape == (48, 64, 3)
    finally:
        venv.close()
