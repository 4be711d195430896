"""Starting and stopping an av-daemon from another process: the one launcher everyone uses.

    from active_vision import spawn_daemon

    with spawn_daemon("my_run", slots=2) as daemon:     # returns once the daemon is ready
        env = gym.make("roverav/RoverEnvFused-v0", rl_obs_name="my_run", slot=1)
        ...
    # the daemon got SIGTERM, unlinked its segments and exited

:class:`ChildProcess` is the general piece: a subprocess in its own session that dies with
its parent (``PR_SET_PDEATHSIG``), whose merged stdout/stderr is drained line by line on a
thread (a chatty child never blocks on a full pipe), kept as a tail for error messages and
handed to an optional ``on_line`` callback, and which notices a ready marker in its output.
``rover-pair`` runs both its daemon and its trainer through it; tests and benchmarks use
:func:`spawn_daemon`.

This module imports only the standard library and :mod:`shm_protocol`, so a supervisor can
use it without loading torch.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from shm_protocol.names import DEFAULT_NAME

READY_MARKER = "av-daemon ready"
"""The daemon prints a line starting with this once peers can attach to every segment."""

DEFAULT_READY_TIMEOUT = 120.0
"""Seconds to wait for :data:`READY_MARKER` (a cold start loads torch and the weights)."""

DEFAULT_GRACE = 10.0
"""Seconds between SIGTERM and SIGKILL when a child is stopped."""

TAIL_LINES = 40
_PR_SET_PDEATHSIG = 1
_REPO_ROOT = Path(__file__).resolve().parent.parent


class DaemonStartError(RuntimeError):
    """The daemon exited, or was not ready in time; the message carries its log tail."""


def _set_pdeathsig() -> None:  # runs in the child between fork and exec
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def daemon_command(
    name: str = DEFAULT_NAME,
    slots: int = 1,
    extra_args: Sequence[str] = (),
    python: str | None = None,
) -> list[str]:
    """The argv that starts an av-daemon serving ``name`` with ``slots`` slots."""
    return [python or sys.executable, "-m", "active_vision", "--name", name,
            "--slots", str(slots), *extra_args]  # fmt: skip


class ChildProcess:
    """A supervised subprocess whose output is drained, kept as a tail and relayed.

    :param argv: the command line.
    :param env: its environment (default: this process's).
    :param on_line: called with each output line (without the newline), from the drain thread.
    :param ready_marker: when a line contains it, :attr:`ready` is set.
    :param cwd: working directory.
    """

    def __init__(
        self,
        argv: Sequence[str],
        env: Mapping[str, str] | None = None,
        on_line: Callable[[str], None] | None = None,
        ready_marker: str | None = None,
        cwd: str | os.PathLike[str] | None = None,
    ) -> None:
        self.argv = list(argv)
        self.tail: collections.deque[str] = collections.deque(maxlen=TAIL_LINES)
        self.ready = threading.Event()
        self._on_line = on_line
        self._marker = ready_marker
        self.proc = subprocess.Popen(
            self.argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=dict(os.environ if env is None else env),
            cwd=cwd,
            start_new_session=True,
            preexec_fn=_set_pdeathsig,
        )
        self._drain = threading.Thread(target=self._pump, name=f"drain-{self.pid}", daemon=True)
        self._drain.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for raw in iter(self.proc.stdout.readline, b""):
            line = raw.decode(errors="replace").rstrip("\n")
            self.tail.append(line)
            if self._marker is not None and self._marker in line:
                self.ready.set()
            if self._on_line is not None:
                self._on_line(line)

    def poll(self) -> int | None:
        return self.proc.poll()

    def wait_ready(self, timeout: float, interrupted: Callable[[], bool] | None = None) -> str:
        """Wait for the ready marker. Returns ``""`` when ready, else why not (one line)."""
        deadline = time.monotonic() + timeout
        while not self.ready.wait(0.05):
            if self.proc.poll() is not None:
                self._drain.join(timeout=2.0)  # the last lines may hold the marker or the reason
                if self.ready.is_set():
                    return ""
                return f"exited with status {exit_status(self.proc.returncode)} before it was ready"
            if interrupted is not None and interrupted():
                return "was interrupted before it was ready"
            if time.monotonic() > deadline:
                return f"was not ready after {timeout:.0f} s"
        return ""

    def send_signal(self, sig: int) -> None:
        """Send ``sig`` to the child's whole process group."""
        try:
            os.killpg(self.proc.pid, sig)
        except ProcessLookupError:
            pass

    def stop(self, grace: float = DEFAULT_GRACE, sig: int = signal.SIGTERM) -> int:
        """``sig`` (SIGTERM) to the process group, SIGKILL after ``grace`` s; the exit code."""
        if self.proc.poll() is None:
            self.send_signal(sig)
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                self.send_signal(signal.SIGKILL)
                self.proc.wait()
        self._drain.join(timeout=2.0)
        return self.proc.returncode

    def tail_text(self, indent: str = "    ") -> str:
        return "\n".join(f"{indent}{line}" for line in self.tail) or f"{indent}(no output)"


def exit_status(returncode: int) -> int:
    """A shell-style status: the code, or 128 + n for death by signal n."""
    return 128 - returncode if returncode < 0 else returncode


def start_daemon(
    name: str = DEFAULT_NAME,
    slots: int = 1,
    *,
    extra_args: Sequence[str] = (),
    ready_timeout: float = DEFAULT_READY_TIMEOUT,
    on_line: Callable[[str], None] | None = None,
    env: Mapping[str, str] | None = None,
    python: str | None = None,
) -> ChildProcess:
    """Start an av-daemon and return it once it is ready; raise :class:`DaemonStartError`.

    The daemon runs from this checkout's packages (``PYTHONPATH`` gets the repository root
    first) with unbuffered output; a daemon that fails is stopped and its log tail is in the
    error.
    """
    child_env = dict(os.environ if env is None else env)
    child_env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(_REPO_ROOT), child_env.get("PYTHONPATH", "")) if p
    )
    child_env["PYTHONUNBUFFERED"] = "1"
    argv = daemon_command(name, slots, extra_args, python)
    child = ChildProcess(argv, child_env, on_line=on_line, ready_marker=READY_MARKER)
    why = child.wait_ready(ready_timeout)
    if why:
        child.stop()
        raise DaemonStartError(
            f"av-daemon {why}.\n  command: {' '.join(argv)}\n  log tail:\n{child.tail_text()}"
        )
    return child


@contextlib.contextmanager
def spawn_daemon(
    name: str = DEFAULT_NAME,
    slots: int = 1,
    *,
    grace: float = DEFAULT_GRACE,
    **options: Any,
) -> Iterator[ChildProcess]:
    """Run an av-daemon for the ``with`` block: started and ready on entry, stopped on exit.

    :param name: segment base name (``--name``).
    :param slots: slots served (``--slots``), one per env.
    :param grace: seconds between SIGTERM and SIGKILL on exit.
    :param options: :func:`start_daemon`'s keywords: ``extra_args`` (more daemon flags, e.g.
        ``["--threads", "1", "--depth", "render"]``), ``ready_timeout``, ``on_line`` (receives
        every line the daemon prints; default: kept in ``.tail`` only), ``env``, ``python``.
    """
    child = start_daemon(name, slots, **options)
    try:
        yield child
    finally:
        child.stop(grace)


__all__ = [
    "DEFAULT_GRACE",
    "DEFAULT_READY_TIMEOUT",
    "READY_MARKER",
    "ChildProcess",
    "DaemonStartError",
    "daemon_command",
    "exit_status",
    "spawn_daemon",
    "start_daemon",
]
