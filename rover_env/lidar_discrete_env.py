"""RoverEnvDiscrete: RoverEnv with ``Discrete(60)`` actions, the seed's speed levels x 12
headings relative to the rover's yaw (the RL baselines' action space).

Why relative, when the seed's discrete fused env steers to absolute compass headings: the
LIDAR observation gives the goal's bearing relative to the heading, so with relative
headings "drive at the goal" is the same class at every yaw. PPO from scratch learns this
space where it does not learn the continuous box, explored by per-step Gaussian noise that
the rover's inertia filters out (docs/decisions.md, "RL").
"""

from __future__ import annotations

from typing import Any

from gymnasium import spaces

from rover_env.discrete_env import N_SEED_ACTIONS, SeedActionTable
from rover_env.lidar_env import RoverEnv


class RoverEnvDiscrete(SeedActionTable, RoverEnv):
    """RoverEnv with ``Discrete(60)`` actions: 5 speeds x 12 headings relative to the yaw.

    ## Action space

    ``Discrete(60)``: ``speed_idx = a // 12``, ``direction_idx = a % 12``, as the seed's
    discrete table (:class:`~rover_env.discrete_env.DiscreteRoverEnvFused`) decodes it.

    | speed_idx | 0 | 1 | 2 | 3 | 4 |
    |---|---|---|---|---|---|
    | speed (m/s) | -0.2 | 0.0 | 0.3 | 0.6 | 1.0 |

    ``direction_idx`` k is the desired heading ``-pi + k * pi / 6`` rad *relative to the
    current yaw* (k = 6: straight on; k = 0: turn round), exactly RoverEnv's continuous
    ``[speed, relative heading]`` action ``[speed_levels[a // 12], direction_angles[a % 12]]``
    through the same PID. Example: 54 -> 1.0 m/s straight on. Integer-like inputs are
    accepted; anything else or outside ``0..59`` raises ``ValueError``.

    Everything else (observation, reward, episode end, info, arguments) is
    :class:`~rover_env.lidar_env.RoverEnv`'s.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.action_space = spaces.Discrete(N_SEED_ACTIONS)

    def _decode_action(self, action: Any) -> tuple[float, float]:
        speed, relative = self._table_entry(action)
        return speed, float(self.orientation[2]) + relative
