"""Test helper: a real av-daemon subprocess."""

from __future__ import annotations

import collections
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


class Daemon:
    """A real `python -m active_vision` process serving ``name``."""

    def __init__(self, name: str, slots: int = 1, args: tuple[str, ...] = ()) -> None:
        self.name = name
        self.slots = slots
        self.args = tuple(args)  # extra av-daemon flags
        self.proc: subprocess.Popen[str] | None = None
        self.log: collections.deque[str] = collections.deque(maxlen=200)

    def start(self) -> Daemon:
        env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "active_vision", "--name", self.name,
             "--slots", str(self.slots), "--threads", "1", *self.args],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
        )  # fmt: skip
        assert self.proc.stdout is not None
        lines = []
        for line in self.proc.stdout:
            lines.append(line)
            if "ready" in line:
                # keep draining its output, or a chatty daemon blocks on a full pipe
                threading.Thread(target=self._drain, args=(self.proc,), daemon=True).start()
                return self
        raise RuntimeError("daemon died before ready:\n" + "".join(lines))

    def _drain(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.log.append(line)

    def remove_leftovers(self) -> None:
        """Unlink any segment of this daemon's name (after a SIGKILL test)."""
        for p in Path("/dev/shm").glob(f"{self.name}*"):
            p.unlink(missing_ok=True)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            self.proc.wait(15)
        self.proc = None
