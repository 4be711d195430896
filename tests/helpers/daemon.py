"""Test helper: a real av-daemon subprocess, started through the project's one launcher."""

from __future__ import annotations

import signal
import subprocess

from active_vision.launcher import ChildProcess, start_daemon
from shm_protocol import existing_segments, remove_segments


class Daemon:
    """A real ``python -m active_vision`` process serving ``name`` (one torch thread)."""

    def __init__(self, name: str, slots: int = 1, extra_args: tuple[str, ...] = ()) -> None:
        self.name = name
        self.slots = slots
        self.extra_args = extra_args
        self.child: ChildProcess | None = None

    @property
    def proc(self) -> subprocess.Popen[bytes] | None:
        """The daemon's Popen (pid, poll, send_signal in tests)."""
        return None if self.child is None else self.child.proc

    @property
    def log(self) -> list[str]:
        return [] if self.child is None else list(self.child.tail)

    def start(self) -> Daemon:
        self.child = start_daemon(self.name, self.slots,
                                  extra_args=["--threads", "1", *self.extra_args])  # fmt: skip
        return self

    def remove_leftovers(self) -> None:
        """Unlink any segment of this daemon's name (after a SIGKILL test)."""
        remove_segments(existing_segments(self.name))

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.child is not None:
            self.child.stop(15.0, sig=sig)
        self.child = None
