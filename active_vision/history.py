"""Per-slot frame history of the daemon, cut at episode boundaries.

The daemon keeps, for every slot, the fused detection frames (gray, per-frame heatmap, depth)
of the slot's last ``k`` camera frames. The env marks the first camera frame of each episode
(``Frame.episode_start``, trailer flag ``FLAG_EPISODE_START``): the slot's history is
cleared before that frame is pushed, so nothing of one episode is seen in the next, and
nothing of one slot is ever seen by another (each slot has its own buffer).

:meth:`SlotHistory.window` hands out exactly ``k`` frames, oldest first; while an episode
has fewer, its oldest frame is repeated (a scene seen once looks still). A daemon started
mid-episode therefore begins with an empty history and fills it from the frames it sees.
"""

from __future__ import annotations

import numpy as np


class SlotHistory:
    """The last ``k`` frames of each of ``slots`` slots (see the module docstring).

    :param slots: number of slots.
    :param k: frames kept per slot (the predictor's window).
    :param shape: shape of one frame, e.g. ``(96, 96, 3)``.
    """

    def __init__(self, slots: int, k: int, shape: tuple[int, ...]) -> None:
        if slots < 1 or k < 1:
            raise ValueError(f"slots and k must be >= 1, got slots={slots}, k={k}")
        self.k = k
        self._frames = np.zeros((slots, k, *shape), np.float32)
        self._count = [0] * slots  # frames pushed since the last clear
        self._window = np.zeros((k, *shape), np.float32)

    @property
    def slots(self) -> int:
        return len(self._count)

    def clear(self, slot: int) -> None:
        """Forget the slot's frames (an episode starts)."""
        self._count[slot] = 0

    def count(self, slot: int) -> int:
        """Frames the slot holds (at most ``k``)."""
        return min(self._count[slot], self.k)

    def push(self, slot: int, frame: np.ndarray, *, episode_start: bool = False) -> None:
        """Add the slot's newest frame (copied); ``episode_start`` clears the slot first."""
        if episode_start:
            self.clear(slot)
        self._frames[slot, self._count[slot] % self.k] = frame
        self._count[slot] += 1

    def window(self, slot: int, out: np.ndarray | None = None) -> np.ndarray:
        """``(k, *shape)``: the slot's last ``k`` frames, oldest first, the oldest repeated
        while fewer than ``k`` were pushed since the last clear.

        :raises ValueError: the slot holds no frame yet.
        """
        n = self._count[slot]
        if n == 0:
            raise ValueError(f"slot {slot} has no frame in its history; push one first")
        out = self._window if out is None else out
        k = self.k
        held = min(n, k)
        # ring positions of the held frames, oldest first
        idx = [(n - held + i) % k for i in range(held)]
        pad = k - held
        out[:pad] = self._frames[slot, idx[0]]
        out[pad:] = self._frames[slot, idx]
        return out


__all__ = ["SlotHistory"]
