"""A plain-line status reporter: readable through a pipe (rover-pair relays it), no tty needed."""

from __future__ import annotations

import sys
import time
from collections import deque
from typing import TextIO


def _duration(seconds: float) -> str:
    seconds = max(0, int(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    if seconds >= 60:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds}s"


class StatusLine:
    """Prints ``label steps/total, steps/s, ETA, recent success`` every ``every`` seconds.

    :param total: steps expected in all (for the ETA).
    :param window: episodes in the recent success rate.
    """

    def __init__(
        self,
        label: str,
        total: int,
        every: float = 5.0,
        window: int = 20,
        stream: TextIO | None = None,
    ) -> None:
        self.label = label
        self.total = max(1, int(total))
        self.every = float(every)
        self.stream = stream if stream is not None else sys.stdout
        self.steps = 0
        self.successes: deque[bool] = deque(maxlen=window)
        self._start = time.monotonic()
        self._last = self._start

    def step(self, n: int = 1) -> None:
        self.steps += n
        now = time.monotonic()
        if now - self._last >= self.every:
            self._last = now
            self.print()

    def episode(self, success: bool) -> None:
        self.successes.append(bool(success))

    def line(self) -> str:
        elapsed = max(time.monotonic() - self._start, 1e-9)
        rate = self.steps / elapsed
        eta = (self.total - self.steps) / rate if rate > 0 else float("inf")
        recent = (
            f"{sum(self.successes) / len(self.successes):.0%} of the last {len(self.successes)}"
            if self.successes
            else "no episode finished yet"
        )
        eta_s = _duration(eta) if eta != float("inf") else "?"
        return (
            f"{self.label}: {self.steps}/{self.total} steps, {rate:.0f} steps/s, "
            f"ETA {eta_s}, success {recent}"
        )

    def print(self) -> None:
        print(self.line(), file=self.stream, flush=True)
