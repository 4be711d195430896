"""Reward shaping for RL training: a potential on the geodesic distance to the goal.

:class:`GeodesicShaping` adds ``gamma * phi(s') - phi(s)`` to the env's reward, with
``phi(s) = -scale * d(s)`` and ``d`` the cost-to-go from the rover's position to its goal on
the world's planning grid (:mod:`rover_train.navgrid`: metres of path around the obstacles,
weighted up near walls). Potential-based shaping (Ng, Harada & Russell 1999) leaves the
optimal policies of the env's reward unchanged when ``gamma`` is the learner's discount and
``phi`` is 0 at episode ends; it only tells the learner, every step, whether it came nearer
along a path that exists. It reads the true map and pose, so it is for training only: the
env, its observation and its evaluation are the env's own. ``rover-train --shaping
geodesic`` wraps each training env with it (outside the Monitor, which logs the env's
reward).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from rover_train.navgrid import CostToGo, OccupancyGrid

SHAPINGS = ("none", "geodesic")
"""``rover-train --shaping`` choices."""
DEFAULT_SCALE = 1.0
"""Reward per metre of cost-to-go (the seed's Euclidean progress pays 0.45 per metre)."""

_GRIDS: dict[str, OccupancyGrid] = {}


class GeodesicShaping(gym.Wrapper):
    """Adds ``gamma * phi(s') - phi(s)`` to each reward, ``phi = -scale * cost-to-go``
    (0 after a terminal step); ``info["shaping"]`` holds the term. The env must be a
    roverav env (``unwrapped.position``, ``.goal``, ``.world``)."""

    def __init__(self, env: gym.Env, gamma: float, scale: float = DEFAULT_SCALE) -> None:
        super().__init__(env)
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {gamma}: pass the learner's own")
        self.gamma, self.scale = float(gamma), float(scale)
        world = self.env.unwrapped.world  # type: ignore[attr-defined]
        if world.name not in _GRIDS:
            _GRIDS[world.name] = OccupancyGrid(world)
        self._grid = _GRIDS[world.name]
        self._fields: dict[tuple[float, float], np.ndarray] = {}
        self._phi = 0.0

    def potential(self) -> float:
        """``phi`` of the current state: minus ``scale`` times the cost-to-go (m)."""
        base: Any = self.env.unwrapped
        goal = (round(float(base.goal[0]), 3), round(float(base.goal[1]), 3))
        field = self._fields.get(goal)
        if field is None:
            if len(self._fields) > 64:
                self._fields.clear()
            raw = CostToGo(self._grid, goal).field * self._grid.res
            finite = raw[np.isfinite(raw)]
            # a cell inside a footprint (the rover's centre never is; its grid cell may be):
            # the worst reachable value, so phi stays finite
            field = self._fields[goal] = np.where(np.isfinite(raw), raw, finite.max())
        i, j = self._grid.cell(float(base.position[0]), float(base.position[1]))
        return -self.scale * float(field[i, j])

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._phi = self.potential()
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        phi = 0.0 if terminated else self.potential()
        term = self.gamma * phi - self._phi
        self._phi = phi
        info["shaping"] = term
        return obs, float(reward) + term, terminated, truncated, info
