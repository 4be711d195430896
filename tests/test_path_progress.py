"""The ``nav-path`` task's shaping (issue 38): progress paid along the map's shortest path to
the goal (:class:`rover_train.shaping.PathProgress`), not the straight line."""

from __future__ import annotations

import math

import gymnasium as gym
import pytest

from rover_train.envs import NAV_PROGRESS_SCALE, get_task, make_env
from rover_train.imitation.expert import PlannerExpert
from rover_train.shaping import PATH_PROGRESS_KEY, PathProgress

BEHIND_A_WALL = 2  # maze, no pedestrians: the goal 2.8 m away in line, 5 m by the corridors


def _shaping(env: gym.Env) -> PathProgress:
    while not isinstance(env, PathProgress):
        env = env.env  # type: ignore[attr-defined]
    return env


@pytest.fixture(scope="module")
def drive() -> tuple[float, float, list[tuple[float, float, dict]]]:
    """The planner expert's drive to a goal behind a maze wall under ``nav-path``: the path
    length at the start, the straight-line distance, and each step's (straight-line
    distance, reward, info)."""
    env = make_env("lidar", world="maze", task="nav-path", n_pedestrians=0)
    base = env.unwrapped
    expert = PlannerExpert("maze")
    try:
        env.reset(seed=BEHIND_A_WALL)
        start_path, start_line = _shaping(env)._last, math.dist(base.position[:2], base.goal)
        steps = []
        for _ in range(600):
            _, reward, terminated, truncated, info = env.step(expert.act_env(env))
            steps.append((math.dist(base.position[:2], base.goal), float(reward), info))
            if terminated or truncated:
                break
    finally:
        env.close()
    return start_path, start_line, steps


def test_the_goal_pays_the_whole_path_length_and_no_straight_line_progress(drive) -> None:
    start_path, start_line, steps = drive
    assert start_path > 1.5 * start_line  # the way round the wall is the longer one
    assert steps[-1][2]["goals_reached"] == 1 and not steps[-1][2]["collision"]
    paid = sum(info[PATH_PROGRESS_KEY] for _, _, info in steps)
    # a potential's differences: what the drive earned is the path length it started from
    assert paid == pytest.approx(NAV_PROGRESS_SCALE * start_path, rel=1e-9)
    assert all(info["reward_progress"] == 0.0 for _, _, info in steps)  # the env's own is off


def test_the_detour_is_paid_where_the_straight_line_charges_it(drive) -> None:
    _, start_line, steps = drive
    line = [start_line] + [d for d, _, _ in steps]
    away = [i for i in range(len(steps)) if line[i + 1] > line[i] + 1e-3]
    assert away  # the way round leads away from the goal for a while ...
    paid_away = sum(steps[i][2][PATH_PROGRESS_KEY] for i in away)
    assert paid_away > 0.0  # ... and that stretch is progress under nav-path
    assert sum(steps[i][2][PATH_PROGRESS_KEY] < 0 for i in away) < len(away) / 4


def test_the_reward_adds_the_term_to_the_envs_own() -> None:
    shaped = make_env("lidar", world="maze", task="nav-path", n_pedestrians=0)
    plain = make_env("lidar", world="maze", task="nav-path", n_pedestrians=0)
    plain = plain.env if isinstance(plain, PathProgress) else plain  # unwrap the one layer
    try:
        assert isinstance(shaped, PathProgress) and not isinstance(plain, PathProgress)
        shaped.reset(seed=BEHIND_A_WALL)
        plain.reset(seed=BEHIND_A_WALL)
        for action in ([1.0, 0.5], [1.0, 0.5], [0.5, -0.3]):
            _, r_shaped, *_, info = shaped.step(action)
            _, r_plain, *_ = plain.step(action)
            assert info[PATH_PROGRESS_KEY] != 0.0
            assert r_shaped == pytest.approx(r_plain + info[PATH_PROGRESS_KEY])
    finally:
        shaped.close()
        plain.close()


def test_only_nav_path_shapes_and_it_turns_the_straight_line_term_off() -> None:
    task = get_task("nav-path")
    assert task.path_progress == NAV_PROGRESS_SCALE
    assert task.reward_config("lidar").distance_delta_scale == 0.0
    assert get_task("nav").path_progress == 0.0 == get_task("seed").path_progress
    env = make_env("lidar", world="inspect", task="nav")
    try:
        assert not isinstance(env, PathProgress)
    finally:
        env.close()


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan])
def test_scale_must_be_positive(scale: float) -> None:
    env = make_env("lidar", world="inspect", task="nav")
    try:
        with pytest.raises(ValueError, match="positive number of reward per metre"):
            PathProgress(env, scale)
    finally:
        env.close()
