"""The seed's discrete action table on an env without it: stage 1 of a discrete student, and
the benchmarks that drive a discrete student without the daemon.

:class:`WithSeedTable` gives RoverEnv (``Discrete(60)``) or :class:`~rover_train.imitation.
gaze.WithPanHead` over RoverEnv (``Discrete(180)``) the action space of the fused discrete
envs, decoded as they decode it (:mod:`rover_env.discrete_env`, :mod:`rover_env.
gaze_discrete_env`): absolute compass headings, and pan moves that step the camera's window.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rover_env.controller import wrap_angle
from rover_env.discrete_env import (
    DIRECTION_ANGLES,
    N_SEED_ACTIONS,
    SPEED_LEVELS,
    decode_action,
)
from rover_env.gaze_discrete_env import (
    CENTRE_WINDOW,
    N_GAZE_ACTIONS,
    PAN_WINDOWS,
    decode_gaze_action,
    moved_window,
)
from rover_train.imitation.expert import takes_pan


class WithSeedTable(gym.Wrapper):
    """``env`` driven through the seed's table: ``Discrete(60)`` (5 speeds x 12 absolute
    compass headings, RoverEnvFusedDiscrete's) over an env of ``[speed, relative heading]``,
    ``Discrete(180)`` (with the 3 pan moves, RoverEnvFusedGazeDiscrete's) over one of
    ``[speed, relative heading, pan target]``. A pan move steps :attr:`pan_window` (centre at
    every reset), whose angle is the pan target the inner env's servo turns to; ``info``
    gains ``pan_window``. Everything else is the inner env's."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.gaze = takes_pan(env)
        if not self.gaze and getattr(env.action_space, "shape", None) != (2,):
            raise ValueError(f"the seed's table drives an env of [speed, relative heading] "
                             f"(or with a pan target); this one takes {env.action_space}")
        self.action_space = spaces.Discrete(N_GAZE_ACTIONS if self.gaze else N_SEED_ACTIONS)
        self.pan_window = CENTRE_WINDOW

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.pan_window = CENTRE_WINDOW
        obs, info = self.env.reset(**kwargs)
        return obs, self._info(info)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self.gaze:
            speed_idx, direction_idx, pan_move = decode_gaze_action(action)
            self.pan_window = moved_window(self.pan_window, pan_move)
            pan = [PAN_WINDOWS[self.pan_window]]
        else:
            speed_idx, direction_idx = decode_action(action)
            pan = []
        yaw = float(self.env.unwrapped.orientation[2])  # type: ignore[attr-defined]
        heading = wrap_angle(float(DIRECTION_ANGLES[direction_idx]) - yaw)
        command = np.array([SPEED_LEVELS[speed_idx], heading, *pan], dtype=np.float32)
        obs, reward, terminated, truncated, info = self.env.step(command)
        return obs, float(reward), terminated, truncated, self._info(info)

    def _info(self, info: dict[str, Any]) -> dict[str, Any]:
        return {**info, "pan_window": self.pan_window} if self.gaze else info
