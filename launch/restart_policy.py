"""When to restart a crashed daemon, and when to give up: a windowed start limit.

The rule is systemd's ``StartLimitBurst``/``StartLimitIntervalSec`` with Kubernetes'
crash-loop backoff on top:

- **Window.** A crash is allowed when fewer than ``max_restarts`` restarts happened in the
  last ``window`` seconds. A daemon that crashes less often than that is restarted for as
  long as the run lasts (once an hour for five hours is five restarts, never a crash loop).
- **Crash loop.** The crash that would make ``max_restarts + 1`` restarts within
  ``window`` seconds is refused: the supervisor stops the run and says how many crashes it
  counted in how many seconds.
- **Backoff.** The delay before restart k of the current window is
  ``backoff * 2 ** (k - 1)`` seconds, capped at ``backoff_cap``. Crashes older than the window
  drop out of the count, so after a healthy period as long as the window the next restart is
  immediate-ish again (``backoff``).

``max_restarts = 0`` never restarts (the first crash ends the run); ``window = inf`` turns
the window into a budget for the whole run (the supervisor's old behaviour).
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

DEFAULT_MAX_RESTARTS = 5
"""Restarts allowed within one window (systemd's StartLimitBurst defaults to 5 too)."""
DEFAULT_RESTART_WINDOW_S = 60.0
"""Length of the window in seconds."""
DEFAULT_BACKOFF_S = 0.5
"""Delay before the first restart of a window; doubles on each further one."""
DEFAULT_BACKOFF_CAP_S = 8.0
"""Longest delay before a restart."""


@dataclass
class RestartDecision:
    """What to do about one crash."""

    restart: bool
    """Restart the daemon (True) or stop the run (False)."""
    delay: float
    """Seconds to wait before the restart (0 when not restarting)."""
    recent: int
    """Crashes counted in the window, this one included."""
    total: int
    """Crashes in the whole run, this one included."""


@dataclass
class RestartPolicy:
    """A sliding-window restart limit with exponential backoff (see the module docstring)."""

    max_restarts: int = DEFAULT_MAX_RESTARTS
    window: float = DEFAULT_RESTART_WINDOW_S
    backoff: float = DEFAULT_BACKOFF_S
    backoff_cap: float = DEFAULT_BACKOFF_CAP_S
    _crashes: collections.deque[float] = field(default_factory=collections.deque, repr=False)
    _total: int = field(default=0, repr=False)

    def __post_init__(self) -> None:
        if self.max_restarts < 0:
            raise ValueError(f"max_restarts must be 0 or more, got {self.max_restarts}")
        if not self.window > 0:
            raise ValueError(f"the restart window must be a positive number of seconds, "
                             f"got {self.window}")  # fmt: skip

    @property
    def total(self) -> int:
        """Crashes seen in the whole run."""
        return self._total

    def recent(self, now: float) -> int:
        """Crashes within the window that ends at ``now`` (monotonic seconds)."""
        while self._crashes and now - self._crashes[0] > self.window:
            self._crashes.popleft()
        return len(self._crashes)

    def on_crash(self, now: float) -> RestartDecision:
        """Record a crash at ``now`` (monotonic seconds) and decide what to do."""
        self._total += 1
        self._crashes.append(now)
        recent = self.recent(now)
        if recent > self.max_restarts:
            return RestartDecision(False, 0.0, recent, self._total)
        delay = min(self.backoff * 2 ** (recent - 1), self.backoff_cap)
        return RestartDecision(True, delay, recent, self._total)

    def describe(self) -> str:
        """The limit in words, for messages."""
        if math.isinf(self.window):
            return f"at most {self.max_restarts} restart(s) per run"
        return f"at most {self.max_restarts} restart(s) within {self.window:g} s"


__all__ = [
    "DEFAULT_BACKOFF_CAP_S",
    "DEFAULT_BACKOFF_S",
    "DEFAULT_MAX_RESTARTS",
    "DEFAULT_RESTART_WINDOW_S",
    "RestartDecision",
    "RestartPolicy",
]
