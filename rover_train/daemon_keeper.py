"""A daemon kept alive by its host process: what ``rover-pair`` does, for one Ray worker.

    keeper = DaemonKeeper("run_w0", slots=2)
    keeper.start()          # returns once the av-daemon is ready; DaemonStartError if not
    ...                     # envs attach to run_w0, run_w0_1; a crashed daemon comes back
    keeper.stop()           # SIGTERM: the daemon unlinks its segments; leftovers removed

One thread owns the daemon for its whole life: it starts it, watches it, and restarts it on
the same name when it exits (the new daemon takes over the segments its dead predecessor
left, so attached envs continue after their next ``reset()``; ``DaemonRecovery`` turns the
interrupted step into a truncated episode). Restarts back off like rover-pair's (0.5 s,
doubling, capped at 8 s) and stop after ``max_restarts``.

The daemon is started from that long-lived thread on purpose: ``PR_SET_PDEATHSIG`` fires
when the *thread* that forked the child ends, so a daemon forked from a short-lived thread
would be killed early; forked from the keeper thread it lives exactly as long as the host
process (a ``kill -9`` of the host sends the daemon SIGTERM, and it unlinks its segments;
under Ray the raylet may SIGKILL a dead worker's children first, which is why Ray workers
also sweep dead segments).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from active_vision.launcher import (
    DEFAULT_GRACE,
    DEFAULT_READY_TIMEOUT,
    ChildProcess,
    DaemonStartError,
    exit_status,
    start_daemon,
)
from shm_protocol import SHM_DIR, existing_segments

log = logging.getLogger(__name__)

RESTART_BACKOFF_S = 0.5
"""First restart delay; doubles on each restart (as rover-pair's ``--max-restarts``)."""
RESTART_BACKOFF_CAP_S = 8.0
POLL_S = 0.05


class DaemonKeeper:
    """Starts an av-daemon on a thread of its own and restarts it when it exits.

    :param name: segment base name (``--name``).
    :param slots: daemon slots (``--slots``), one per env.
    :param extra_args: more daemon flags (e.g. ``["--threads", "1"]``).
    :param max_restarts: restarts allowed after the first start.
    :param ready_timeout: seconds to wait for each start's ready line.
    :param grace: seconds between SIGTERM and SIGKILL on stop.
    """

    def __init__(
        self,
        name: str,
        slots: int,
        extra_args: Sequence[str] = (),
        max_restarts: int = 3,
        ready_timeout: float = DEFAULT_READY_TIMEOUT,
        grace: float = DEFAULT_GRACE,
    ) -> None:
        self.name = name
        self.slots = slots
        self.extra_args = list(extra_args)
        self.max_restarts = max_restarts
        self.ready_timeout = ready_timeout
        self.grace = grace
        self.restarts = 0
        """Restarts done so far."""
        self.failure: str | None = None
        """Why the keeper gave up (restarts used up, or a start failed), else None."""
        self._child: ChildProcess | None = None
        self._stop = threading.Event()
        self._first = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    @property
    def pid(self) -> int | None:
        """The running daemon's pid (None before the first start or after giving up)."""
        with self._lock:
            child = self._child
        return None if child is None or child.poll() is not None else child.pid

    def start(self) -> DaemonKeeper:
        """Start the keeper thread and return once the daemon is ready."""
        if self._thread is not None:
            raise RuntimeError(f"DaemonKeeper({self.name!r}) was already started")
        self._thread = threading.Thread(target=self._run, name=f"keeper-{self.name}", daemon=True)
        self._thread.start()
        self._first.wait()
        if self.failure is not None:
            self._thread.join()
            raise DaemonStartError(self.failure)
        return self

    def _launch(self) -> ChildProcess | None:
        try:
            child = start_daemon(self.name, self.slots, extra_args=self.extra_args,
                                 ready_timeout=self.ready_timeout)  # fmt: skip
        except DaemonStartError as exc:
            self.failure = str(exc)
            return None
        with self._lock:
            self._child = child
        log.info("av-daemon ready (pid %d) on %r, %d slot(s)", child.pid, self.name, self.slots)
        return child

    def _run(self) -> None:
        child = self._launch()
        self._first.set()
        while child is not None and not self._stop.wait(POLL_S):
            code = child.poll()
            if code is None:
                continue
            if self.restarts >= self.max_restarts:
                self.failure = (
                    f"av-daemon {self.name!r} exited with status {exit_status(code)} and its "
                    f"{self.max_restarts} restart(s) are used up.\n  log tail:\n"
                    f"{child.tail_text()}"
                )
                log.error("%s", self.failure)
                return
            self.restarts += 1
            delay = min(RESTART_BACKOFF_S * 2 ** (self.restarts - 1), RESTART_BACKOFF_CAP_S)
            log.warning("av-daemon %r exited with status %d; restart %d/%d in %.1f s",
                        self.name, exit_status(code), self.restarts, self.max_restarts,
                        delay)  # fmt: skip
            if self._stop.wait(delay):
                return
            child = self._launch()
            if child is None:
                log.error("%s", self.failure)

    def stop(self) -> list[str]:
        """Stop the daemon (it unlinks its segments) and the keeper; returns the names of
        segments that were still there afterwards and were removed."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with self._lock:
            child, self._child = self._child, None
        if child is not None:
            child.stop(self.grace)
        left = existing_segments(self.name)
        for seg in left:
            (Path(SHM_DIR) / seg).unlink(missing_ok=True)
        return left

    def wait_restarted(self, timeout: float) -> bool:
        """True once the daemon has been restarted at least once and is running (tests)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.restarts and self.pid is not None:
                return True
            time.sleep(POLL_S)
        return False


__all__ = ["DaemonKeeper"]
