"""DiscreteRoverEnvFused: RoverEnvFused with the seed's Discrete(60) speed x compass actions.

The seed's discrete action table (speed levels x absolute compass headings) is declared
here once: :class:`SeedActionTable`, :func:`decode_action` and :func:`encode_action`, which
the gaze env's Discrete(180) (``gaze_discrete_env``) builds on.
"""

from __future__ import annotations

import logging
import numbers
from typing import Any

import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env.fused_env import RoverEnvFused

log = logging.getLogger(__name__)

SPEED_LEVELS = np.array(c.DISCRETE_SPEED_LEVELS, dtype=np.float32)  # m/s, seed 002
N_SPEEDS = len(SPEED_LEVELS)  # 5
N_DIRECTIONS = c.DISCRETE_N_DIRECTIONS  # 12
DIRECTION_ANGLES = np.linspace(-np.pi, np.pi, N_DIRECTIONS, endpoint=False)  # absolute, rad
N_SEED_ACTIONS = N_SPEEDS * N_DIRECTIONS  # 60


def action_index(action: Any, n: int) -> int:
    """The integer in ``0..n-1`` that a discrete action names.

    Accepts a Python int, a numpy integer or a 0-d/size-1 integer array; anything else,
    or an index outside ``0..n-1``, raises ``ValueError``.
    """
    value = action
    if isinstance(value, np.ndarray):
        if value.size != 1:
            raise ValueError(
                f"a discrete action is one integer, got an array of shape {value.shape}"
            )
        value = value.reshape(()).item() if np.issubdtype(value.dtype, np.integer) else value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(
            f"a discrete action must be an integer in 0..{n - 1}, "
            f"got {action!r} ({type(action).__name__})"
        )
    index = int(value)
    if not 0 <= index < n:
        raise ValueError(f"action {index} is outside 0..{n - 1}")
    return index


def decode_action(action: Any) -> tuple[int, int]:
    """(speed_idx, direction_idx) of a flat action in ``0..59``, as the seed decodes it.

    Accepts a Python int, a numpy integer or a 0-d/size-1 integer array; anything else,
    or an index outside ``0..59``, raises ``ValueError``.
    """
    index = action_index(action, N_SEED_ACTIONS)
    return index // N_DIRECTIONS, index % N_DIRECTIONS


def encode_action(speed_idx: int, direction_idx: int) -> int:
    """The flat action in ``0..59`` of (speed_idx, direction_idx): the inverse of decoding."""
    if not (0 <= speed_idx < N_SPEEDS and 0 <= direction_idx < N_DIRECTIONS):
        raise ValueError(
            f"speed_idx must be in 0..{N_SPEEDS - 1} and direction_idx in "
            f"0..{N_DIRECTIONS - 1}, got {speed_idx}, {direction_idx}"
        )
    return speed_idx * N_DIRECTIONS + direction_idx


def nearest_action(speed: float, heading: float) -> int:
    """The table action (``0..59``) nearest a continuous command: the speed level nearest
    ``speed`` (m/s) and the direction nearest ``heading`` (rad, any turn; absolute in the
    fused env, relative to the yaw in RoverEnvDiscrete). A planner's or a person's command
    labelled for a discrete student."""
    speed_idx = int(np.argmin(np.abs(SPEED_LEVELS - speed)))
    direction_idx = int(np.rint((heading + np.pi) / (2 * np.pi / N_DIRECTIONS))) % N_DIRECTIONS
    return encode_action(speed_idx, direction_idx)


class SeedActionTable:
    """The seed's table as env attributes (``n_speeds``, ``n_directions``,
    ``speed_levels``, ``direction_angles``), mixed into both discrete envs."""

    n_speeds = N_SPEEDS
    n_directions = N_DIRECTIONS
    speed_levels = SPEED_LEVELS
    direction_angles = DIRECTION_ANGLES

    def _table_entry(self, action: Any) -> tuple[float, float]:
        """(speed m/s, heading rad) of the table cell a flat action in ``0..59`` names; the
        heading is absolute in the fused env, relative to the yaw in RoverEnvDiscrete."""
        speed_idx, direction_idx = decode_action(action)
        log.debug("action %r -> speed_idx %d, direction_idx %d", action, speed_idx, direction_idx)
        return self._seed_command(speed_idx, direction_idx)

    def _seed_command(self, speed_idx: int, direction_idx: int) -> tuple[float, float]:
        """(speed m/s, absolute heading rad) of a cell of the table."""
        return float(self.speed_levels[speed_idx]), float(self.direction_angles[direction_idx])


class DiscreteRoverEnvFused(SeedActionTable, RoverEnvFused):
    """RoverEnvFused with ``Discrete(60)`` actions: 5 speeds x 12 absolute compass headings.

    ## Action space

    ``Discrete(60)``: ``speed_idx = a // 12``, ``direction_idx = a % 12``.

    | speed_idx | 0 | 1 | 2 | 3 | 4 |
    |---|---|---|---|---|---|
    | speed (m/s) | -0.2 | 0.0 | 0.3 | 0.6 | 1.0 |

    ``direction_idx`` k gives the absolute heading ``-pi + k * pi / 6`` (``np.linspace(-pi,
    pi, 12, endpoint=False)``: -pi, -2.62, ..., 2.62 rad, 0 = +x, "East"), tracked by the same
    PID as the continuous env. Example: 27 -> 0.3 m/s towards -1.57 rad ("South").
    Integer-like inputs (int, numpy integer, 0-d array) are accepted; anything else or
    outside ``0..59`` raises ``ValueError``. The seed printed each action; this env logs
    it at DEBUG.

    Everything else (observation, reward, episode end, info, arguments) is
    :class:`~rover_env.fused_env.RoverEnvFused`'s.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.action_space = spaces.Discrete(N_SEED_ACTIONS)

    def _decode_action(self, action: Any) -> tuple[float, float]:
        return self._table_entry(action)
