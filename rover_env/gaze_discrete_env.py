"""DiscreteRoverEnvFusedGaze: the original joint policy's Discrete(180) drive-and-look actions."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env.discrete_env import (
    N_SEED_ACTIONS,
    SeedActionTable,
    action_index,
    decode_action,
    encode_action,
    nearest_action,
)
from rover_env.gaze_env import RoverEnvFusedGaze

log = logging.getLogger(__name__)

PAN_NONE, PAN_LEFT, PAN_RIGHT = 0, 1, 2
N_PAN_MOVES = 3
N_GAZE_ACTIONS = N_SEED_ACTIONS * N_PAN_MOVES  # 180
PAN_WINDOWS = tuple(math.radians(d) for d in c.PAN_WINDOWS_DEG)  # rad, index 0 = -60 deg
CENTRE_WINDOW = PAN_WINDOWS.index(0.0)  # 2


def decode_gaze_action(action: Any) -> tuple[int, int, int]:
    """(speed_idx, direction_idx, pan_move) of a flat action in ``0..179``.

    ``speed_idx = a // 36``, ``direction_idx = (a // 3) % 12``, ``pan_move = a % 3``; so
    ``a // 3`` is the seed's Discrete(60) action and ``a % 3`` the pan move (0 none,
    1 left, 2 right). Non-integers or indices outside ``0..179`` raise ``ValueError``.
    """
    index = action_index(action, N_GAZE_ACTIONS)
    seed_action, pan_move = divmod(index, N_PAN_MOVES)
    speed_idx, direction_idx = decode_action(seed_action)
    return speed_idx, direction_idx, pan_move


def encode_gaze_action(speed_idx: int, direction_idx: int, pan_move: int) -> int:
    """The flat action of (speed_idx, direction_idx, pan_move): the inverse of decoding."""
    seed_action = encode_action(speed_idx, direction_idx)
    if pan_move not in (PAN_NONE, PAN_LEFT, PAN_RIGHT):
        raise ValueError(f"pan_move must be 0 (none), 1 (left) or 2 (right), got {pan_move}")
    return seed_action * N_PAN_MOVES + pan_move


def moved_window(window: int, pan_move: int) -> int:
    """The pan window (index into :data:`PAN_WINDOWS`) after ``pan_move`` from ``window``: one
    step left (+30 deg) or right, clamped at the end windows; ``PAN_NONE`` stays."""
    if pan_move == PAN_NONE:
        return window
    step = 1 if pan_move == PAN_LEFT else -1
    return min(max(window + step, 0), len(PAN_WINDOWS) - 1)


def nearest_gaze_action(speed: float, heading: float, pan_target: float, window: int) -> int:
    """The table action (``0..179``) nearest a continuous gaze command, with the camera's
    window at ``window``: the drive cell nearest (``speed`` m/s, absolute ``heading`` rad;
    :func:`~rover_env.discrete_env.nearest_action`) and the pan move one window towards the
    window nearest ``pan_target`` (rad from the heading), none when ``window`` is that one.
    The planner expert's gaze labelled for a Discrete(180) student."""
    if not 0 <= window < len(PAN_WINDOWS):
        raise ValueError(f"window must be in 0..{len(PAN_WINDOWS) - 1}, got {window}")
    want = int(np.argmin(np.abs(np.asarray(PAN_WINDOWS) - pan_target)))
    move = PAN_NONE if want == window else PAN_LEFT if want > window else PAN_RIGHT
    return nearest_action(speed, heading) * N_PAN_MOVES + move


class DiscreteRoverEnvFusedGaze(SeedActionTable, RoverEnvFusedGaze):
    """The original joint gaze policy's action space: 5 speeds x 12 headings x 3 pan moves.

    ## Action space

    ``Discrete(180)``, decoded (:func:`decode_gaze_action`) as

    ``speed_idx = a // 36``, ``direction_idx = (a // 3) % 12``, ``pan_move = a % 3``

    so ``a // 3`` is exactly :class:`~rover_env.discrete_env.DiscreteRoverEnvFused`'s
    Discrete(60) action (speed levels -0.2, 0.0, 0.3, 0.6, 1.0 m/s; absolute compass
    heading ``-pi + k * pi / 6``) and ``a % 3`` the pan move:

    | pan_move | 0 | 1 | 2 |
    |---|---|---|---|
    | meaning | none | left (+30 deg) | right (-30 deg) |

    The camera looks through one of 5 windows, -60, -30, 0, +30 and +60 deg from the
    heading (seed 001's ``pan_offsets``; positive = left). Every episode starts at 0 deg.
    A move steps one window and clamps at the ends (left at +60 stays at +60). The head
    turns to the window at ``pan_rate`` (180 deg/s: 30 deg takes 4 steps of 0.05 s) or
    at once with ``pan_rate=None``. Example: 85 = speed 2 (0.3 m/s), direction 4
    (-1.05 rad), pan left. Integer-like inputs are accepted; anything else or outside
    ``0..179`` raises ``ValueError``.

    ## Rewards

    RoverEnvFused's, plus ``-RewardConfig.pan_penalty`` (0.02) for each step whose
    action chose a pan move (1 or 2), also when clamped at an end window (``reward_pan``
    in ``info``; not on the goal step, whose only term is the goal).

    ## Info

    As :class:`~rover_env.gaze_env.RoverEnvFusedGaze`, except that ``pan_moves``
    counts the pan moves chosen (the charged ones), and ``pan_window`` gives the window
    index (0 = -60 deg ... 4 = +60 deg).

    Everything else (observation with ``gaze``, episode end, arguments) is
    :class:`~rover_env.gaze_env.RoverEnvFusedGaze`'s.

    ## Version history

    - v0: first release.
    """

    _counts_turns = 0  # pan_moves counts chosen moves, in _decode_action

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.pan_windows = PAN_WINDOWS
        self.pan_window = CENTRE_WINDOW
        self.action_space = spaces.Discrete(N_GAZE_ACTIONS)

    def _decode_action(self, action: Any) -> tuple[float, float]:
        speed_idx, direction_idx, pan_move = decode_gaze_action(action)
        log.debug(
            "action %r -> speed_idx %d, direction_idx %d, pan_move %d",
            action, speed_idx, direction_idx, pan_move,
        )  # fmt: skip
        self._pan_cost_units = 0
        if pan_move != PAN_NONE:
            self.pan_window = moved_window(self.pan_window, pan_move)
            self.pan_moves += 1
            self._pan_cost_units = 1
        self.pan_target = self.pan_windows[self.pan_window]
        return self._seed_command(speed_idx, direction_idx)

    def _on_reset(self) -> None:
        super()._on_reset()
        self.pan_window = CENTRE_WINDOW

    def _info(self, reward: float, reason: str) -> dict[str, Any]:
        info = super()._info(reward, reason)
        info["pan_window"] = self.pan_window
        return info
