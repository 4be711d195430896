"""Training-only reward shaping from the world's map: progress along the shortest path.

The seed's progress term pays for metres of straight-line distance won. In the maze that
leads into walls: the way to a goal behind one first leads away from it, and PPO from scratch
timed out there in 87 of 200 evaluation episodes (benchmarks/RESULTS.md). :class:`PathProgress`
pays instead for metres won along the shortest path around the obstacles (the planner's
occupancy grid, :meth:`rover_train.navgrid.OccupancyGrid.path_cost`). It is the difference
of a potential (minus the path length to the goal), so it rewards no loop and, undiscounted,
leaves the best policy as it was (Ng, Harada & Russell, 1999). The map is read by the reward
only: the policy sees what the env shows it.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from rover_train.navgrid import OccupancyGrid

PATH_PROGRESS_KEY = "reward_path_progress"
"""``info`` key of the term (beside the env's own ``reward_*`` parts)."""


class PathProgress(gym.Wrapper):
    """Adds ``scale`` times the metres won this step along the shortest path to the goal.

    Use it with the env's own progress term off (``distance_delta_scale=0``; the ``nav-path``
    task of :data:`rover_train.envs.TASKS` sets both). The path-length field is computed
    once per goal (about 60 ms on a 13 m world's 0.1 m grid) and read between cell centres
    (bilinear), so every step's movement counts; a new goal starts a new potential. Where
    the rover's four nearest cells are all inside an obstacle on the grid, the step pays
    nothing and the potential keeps its last value.
    """

    def __init__(self, env: gym.Env, scale: float) -> None:
        super().__init__(env)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"PathProgress scale must be a positive number of reward per "
                             f"metre, got {scale!r}")  # fmt: skip
        self.scale = float(scale)
        self._grid: OccupancyGrid | None = None
        self._cost: np.ndarray | None = None
        self._field: np.ndarray | None = None
        self._goal: tuple[float, float] | None = None
        self._last = math.nan

    def _length(self) -> float:
        """Metres along the shortest path from the rover to the goal (nan: no value here)."""
        base: Any = self.env.unwrapped
        if self._grid is None:
            self._grid = OccupancyGrid(base.world)
            self._cost = self._grid.path_cost()
        goal = (float(base.goal[0]), float(base.goal[1]))
        if goal != self._goal:
            self._field = self._grid.cost_to_go(goal, cost=self._cost)
            self._goal = goal
            self._last = math.nan
        assert self._field is not None
        value = self._grid.interpolate(self._field, base.position[0], base.position[1])
        return value * self._grid.res

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._goal = None
        self._last = self._length()
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        before, goal_before = self._last, self._goal
        now = self._length()
        term = 0.0
        if getattr(self.env.unwrapped, "goal_reached", False):
            # The potential at the goal reached is 0 (a new goal, if one was drawn, starts
            # its own potential from the next step).
            term = self.scale * before if math.isfinite(before) else 0.0
            if self._goal != goal_before:
                self._last = now
            else:
                self._last = 0.0
        elif math.isfinite(before) and math.isfinite(now):
            term = self.scale * (before - now)
            self._last = now
        elif math.isfinite(now):
            self._last = now
        info[PATH_PROGRESS_KEY] = term
        return obs, float(reward) + term, terminated, truncated, info
