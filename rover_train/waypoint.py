"""The map planner's next waypoint as an observation key, for RL in worlds where the way to
the goal is not the straight line.

In the maze a goal straight ahead behind the middle wall is reached by a detour of several
metres, first away from it. A reactive policy over the LIDAR, the target and the pose learns
that detour poorly from the reward (PPO from scratch: timeouts at the middle wall,
``benchmarks/RESULTS.md``). Navigation stacks pair such a policy with a global planner on the
known map and give it the planner's next subgoal (as Arena-Rosnav's DRL local planners do).
:class:`WithWaypoint` does that for any roverav env (they share the seed's ``pose``, ``imu``
and ``target`` keys): it adds the key ``waypoint`` = (distance m,
bearing rad relative to the rover's heading) of the point the planner expert would steer at,
the farthest point of the world map's shortest path (:mod:`rover_train.navgrid`) within
``WAYPOINT_LOOKAHEAD`` m that the rover sees in a straight line, or the goal when near and
in sight. The path keeps off the scenery (its cells cost more near walls) and ignores
pedestrians, which the policy sees in the LIDAR.

The waypoint is a function of the observation and the world's static map only: the goal is
recovered from the pose, the yaw and the target, so a policy trained with it needs nothing
from the simulator at run time (``rover_train.zoo.load`` adds it for an entry trained with
``rover-train --waypoint``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rover_env.controller import wrap_angle
from rover_env.worlds import WorldSpec, make_world
from rover_train.navgrid import FieldCache, OccupancyGrid

WAYPOINT_KEY = "waypoint"
WAYPOINT_RES = 0.2
"""Metres per cell of the waypoint's map: coarser than the expert's 0.1 m grid, so a goal's
field costs about a tenth as much."""
WAYPOINT_LOOKAHEAD = 2.0
"""Metres of planned path the waypoint may be taken from."""
WAYPOINT_SIGHT_CLEARANCE = 0.45
"""Metres: the straight line to the waypoint keeps this clearance from the scenery, as read
from the map's cells (whose centres lie up to 0.14 m from a point: 0.3 m, the collision
distance, plus that)."""
WAYPOINT_MAX_M = 5.0
"""The distance's bound in the observation space (a rover outside the map's edge is clipped)."""
_SIGHT_SAMPLES = 21  # points checked along a line of sight (every 0.1 m at the lookahead)


class Waypoints:
    """The waypoint towards a goal from a position, on one world's map (fields cached by
    goal)."""

    def __init__(self, world: str | WorldSpec) -> None:
        self.world = make_world(world) if isinstance(world, str) else world
        self.grid = OccupancyGrid(self.world, res=WAYPOINT_RES)
        self.fields = FieldCache(self.grid)

    def point(self, x: float, y: float, goal: tuple[float, float]) -> tuple[float, float]:
        """The map point to steer at from (x, y) towards ``goal``."""
        return self.fields.get(goal).pursuit_point(
            x, y, WAYPOINT_LOOKAHEAD, WAYPOINT_SIGHT_CLEARANCE, _SIGHT_SAMPLES
        )

    def observe(self, obs: dict[str, Any]) -> np.ndarray:
        """``(distance, relative bearing)`` float32 of the waypoint for a RoverEnv observation
        (its ``pose``, ``imu`` and ``target`` keys)."""
        x, y = float(obs["pose"][0]), float(obs["pose"][1])
        yaw = float(obs["imu"][2])
        dist, bearing = float(obs["target"][0]), float(obs["target"][1])
        goal = (x + dist * math.cos(yaw + bearing), y + dist * math.sin(yaw + bearing))
        px, py = self.point(x, y, goal)
        d = min(math.hypot(px - x, py - y), WAYPOINT_MAX_M)
        b = wrap_angle(math.atan2(py - y, px - x) - yaw) if d > 0.0 else 0.0
        return np.array([d, b], dtype=np.float32)


def waypoint_space() -> spaces.Box:
    return spaces.Box(np.array([0.0, -math.pi], dtype=np.float32),
                      np.array([WAYPOINT_MAX_M, math.pi], dtype=np.float32))  # fmt: skip


def with_waypoint(obs: dict[str, Any], waypoints: Waypoints) -> dict[str, Any]:
    """``obs`` with the ``waypoint`` key added (a new dict): ``(2,)`` for one observation,
    ``(n, 2)`` for a batch of ``n`` (a vector env's)."""
    pose = np.asarray(obs["pose"])
    if pose.ndim == 1:
        return {**obs, WAYPOINT_KEY: waypoints.observe(obs)}
    keys = ("pose", "imu", "target")
    rows = [waypoints.observe({k: np.asarray(obs[k])[i] for k in keys})
            for i in range(pose.shape[0])]  # fmt: skip
    return {**obs, WAYPOINT_KEY: np.stack(rows)}


def observer(world: str | WorldSpec) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """A function adding the ``waypoint`` key to ``world``'s observations (for an agent
    trained with it, driving the plain env)."""
    return functools.partial(with_waypoint, waypoints=Waypoints(world))


class WithWaypoint(gym.ObservationWrapper):
    """A roverav env with the ``waypoint`` key (see the module docstring).

    :param world: the env's world (a name or a :class:`WorldSpec`).
    :raises ValueError: the env's observations lack ``pose``, ``imu`` or ``target``.
    """

    def __init__(self, env: gym.Env, world: str | WorldSpec) -> None:
        super().__init__(env)
        space = env.observation_space
        missing = {"pose", "imu", "target"} - set(getattr(space, "spaces", {}))
        if missing:
            raise ValueError(f"the waypoint is planned from the observation keys pose, imu "
                             f"and target; this env lacks {sorted(missing)}")  # fmt: skip
        self.waypoints = Waypoints(world)
        self.observation_space = spaces.Dict({**space.spaces, WAYPOINT_KEY: waypoint_space()})

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        return with_waypoint(observation, self.waypoints)


__all__ = ["WAYPOINT_KEY", "Waypoints", "WithWaypoint", "observer", "waypoint_space",
           "with_waypoint"]
