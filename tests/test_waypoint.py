"""The map planner's waypoint as an observation key (``rover-train --waypoint``): it
leads round the maze's walls, it is computed from the observation alone, and a model trained
with it drives the plain env through ``zoo.load`` and ``rover-eval``."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import rover_env  # noqa: F401  (registers the roverav/ ids)
from rover_env.worlds import make_world
from rover_train import zoo
from rover_train.evaluate import load_policy
from rover_train.train import parse_args, train
from rover_train.waypoint import WAYPOINT_KEY, Waypoints, WithWaypoint, with_waypoint

MAZE = make_world("maze")


def _follow(waypoints: Waypoints, start: tuple[float, float], goal: tuple[float, float],
            step: float = 0.1, max_steps: int = 400) -> np.ndarray:  # fmt: skip
    """Points of a walk that moves ``step`` m towards the waypoint at every point."""
    x, y = start
    path = [(x, y)]
    for _ in range(max_steps):
        if math.hypot(goal[0] - x, goal[1] - y) < step:
            break
        px, py = waypoints.point(x, y, goal)
        d = math.hypot(px - x, py - y)
        x, y = x + step * (px - x) / d, y + step * (py - y) / d
        path.append((x, y))
    return np.asarray(path)


def test_a_goal_near_and_in_sight_is_its_own_waypoint() -> None:
    assert Waypoints("maze").point(-3.0, 0.0, (-2.0, 0.0)) == (-2.0, 0.0)


@pytest.mark.parametrize("start, goal", [((-1.0, 0.0), (1.0, 0.0)), ((-1.0, 2.5), (1.0, 2.5)),
                                         ((2.5, -1.0), (2.5, -3.0))])  # fmt: skip
def test_following_the_waypoints_goes_round_the_walls_to_the_goal(
    start: tuple[float, float], goal: tuple[float, float]
) -> None:
    line = np.linspace(start, goal, 50)
    assert MAZE.clearance_many(line[:, 0], line[:, 1]).min() <= 0.0  # a wall is in the way
    path = _follow(Waypoints("maze"), start, goal)
    assert math.hypot(path[-1, 0] - goal[0], path[-1, 1] - goal[1]) < 0.1
    assert MAZE.clearance_many(path[:, 0], path[:, 1]).min() > 0.3  # never touching a wall


def test_the_waypoint_key_is_computed_from_the_observation_alone() -> None:
    env = WithWaypoint(gym.make("roverav/RoverEnvDiscrete-v0", world_n="maze"), "maze")
    waypoints = Waypoints("maze")
    obs, _ = env.reset(seed=5)
    for _ in range(30):
        assert env.observation_space.contains(obs)
        sim = env.unwrapped
        x, y, yaw = float(sim.position[0]), float(sim.position[1]), float(sim.orientation[2])
        px, py = waypoints.point(x, y, sim.goal)  # from the true pose and goal
        dist, bearing = obs[WAYPOINT_KEY]
        assert dist == pytest.approx(math.hypot(px - x, py - y), abs=2e-3)
        assert math.cos(bearing - (math.atan2(py - y, px - x) - yaw)) == pytest.approx(1.0)
        obs, *_ = env.step(env.action_space.sample())
    env.close()


def test_a_batch_of_observations_gets_one_waypoint_a_row() -> None:
    env = gym.make("roverav/RoverEnvDiscrete-v0", world_n="maze")
    singles = [env.reset(seed=s)[0] for s in (1, 2, 3)]
    env.close()
    batch = {k: np.stack([o[k] for o in singles]) for k in singles[0]}
    waypoints = Waypoints("maze")
    rows = with_waypoint(batch, waypoints)[WAYPOINT_KEY]
    assert rows.shape == (3, 2)
    for row, obs in zip(rows, singles, strict=True):
        assert np.array_equal(row, with_waypoint(obs, waypoints)[WAYPOINT_KEY])
    assert len({tuple(r) for r in rows}) == 3  # each row its own episode's


def test_the_waypoint_needs_a_pose_to_plan_from() -> None:
    class NoPose(gym.ObservationWrapper):
        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            self.observation_space = gym.spaces.Dict(
                {k: s for k, s in env.observation_space.spaces.items() if k != "pose"})

        def observation(self, observation: dict) -> dict:
            return {k: v for k, v in observation.items() if k != "pose"}

    with pytest.raises(ValueError, match="pose"):
        WithWaypoint(NoPose(gym.make("roverav/RoverEnv-v0", world_n="maze")), "maze")


def test_a_model_trained_with_the_waypoint_drives_the_plain_env(tmp_path: Path) -> None:
    metrics = train(parse_args([
        "--env", "lidar-discrete", "--world", "maze", "--task", "nav", "--waypoint",
        "--n-steps", "64", "--batch-size", "32", "--n-epochs", "1", "--no-progress",
        "--checkpoint-every", "0", "--timesteps", "64", "--logdir", str(tmp_path)]))  # fmt: skip
    assert metrics["status"] == "complete"
    model = tmp_path / "model.zip"
    env = gym.make("roverav/RoverEnvDiscrete-v0", world_n="maze")
    assert WAYPOINT_KEY not in env.observation_space.spaces
    obs, _ = env.reset(seed=1)
    agent = zoo.load("rl-lidar-maze", path=model)
    policy = load_policy(model, env)
    for _ in range(5):
        assert env.action_space.contains(int(agent.act(obs)))
        assert env.action_space.contains(int(policy(obs)))
        obs, *_ = env.step(int(agent.act(obs)))
    env.close()
