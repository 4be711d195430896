"""Supervise an Active Vision daemon and a trainer as one unit.

    python launch/run_pair.py [--name N] [--slots K] [--daemon-arg ARG ...]
                              [--max-restarts R] [--restart-window S] -- TRAINER COMMAND ...

What it does, in order:

1. Removes segments of that name left behind by a dead earlier run (and only those: a
   segment whose writer is alive belongs to a running daemon, and the supervisor refuses
   to start beside it).
2. Starts ``python -m active_vision --name N --slots K [daemon args]`` and waits for the
   line that contains ``ready`` (bounded by ``--ready-timeout``). A daemon that exits or
   never gets ready is reported with the tail of its log.
3. Starts the trainer with ``ROVERAV_SHM_NAME`` and ``ROVERAV_SLOTS`` in its environment.
   Both processes' output is interleaved line by line with a ``[daemon]`` / ``[trainer]``
   prefix.
4. While the trainer runs, a daemon that exits (or fails to get ready again) is restarted
   on the same name (it reuses the segments, so the trainer's env goes on after its next
   ``reset()``). The limit is a window, as systemd's start limits: at most
   ``--max-restarts`` restarts (default 5) within any ``--restart-window`` seconds
   (default 60). A daemon that crashes less often than that is restarted for as long as the
   run lasts. Restart k of a window waits ``0.5 * 2 ** (k - 1)`` s (at most 8 s), so the
   backoff resets once the daemon has been healthy for a whole window. A crash loop (one
   crash more than the window allows) stops the trainer (SIGTERM: rover-train saves a
   final checkpoint) and the supervisor exits with status 70, the crash count and the
   daemon's log tail. ``--max-restarts 0`` never restarts; ``--restart-window inf`` makes
   the limit a budget for the whole run.
5. SIGINT and SIGTERM stop the trainer first (SIGTERM, then SIGKILL after
   ``--trainer-grace`` seconds, default 60: time for rover-train to write its final
   checkpoint while its env still has a daemon), then the daemon (``--grace``).

Exit status: the trainer's (128 + n when it died of signal n; rover-train stopped by a
signal saves and exits 130 for SIGINT, 143 for SIGTERM); 69 when the daemon never became
ready; 70 when the daemon crash-looped; 2 for bad usage. On every way out no segment of that
name remains in ``/dev/shm``.

Children run in their own sessions (so a terminal's Ctrl-C reaches the supervisor, which
stops them in order) and get SIGTERM from the kernel if the supervisor itself is killed
(``PR_SET_PDEATHSIG``), so even ``kill -9`` of the supervisor leaves no orphan daemon.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

# Runnable as a plain script (``python launch/run_pair.py``) from a checkout.
if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from active_vision.launcher import (  # noqa: E402  (standard library only: no torch here)
    READY_MARKER,
    ChildProcess,
    daemon_command,
    exit_status,
)
from launch.restart_policy import (  # noqa: E402
    DEFAULT_MAX_RESTARTS,
    DEFAULT_RESTART_WINDOW_S,
    RestartPolicy,
)
from roverav_cli import Connection, add_group  # noqa: E402
from shm_protocol import (  # noqa: E402
    DEFAULT_NAME,
    camera_name,
    existing_segments,
    remove_segments,
    slot_name,
    writer_alive,
)
from shm_protocol.names import NAME_ENV_VAR, SLOTS_ENV_VAR  # noqa: E402

EXIT_USAGE = 2
EXIT_DAEMON_NOT_READY = 69  # EX_UNAVAILABLE
EXIT_RESTARTS_EXHAUSTED = 70  # EX_SOFTWARE: the daemon crash-looped
DEFAULT_TRAINER_GRACE_S = 60.0


@dataclass
class PairConfig:
    """Options of one supervised run."""

    trainer: list[str]
    """The trainer command line."""
    name: str = DEFAULT_NAME
    """Base name of the daemon's segments."""
    slots: int = 1
    """Number of daemon slots (one per env of a vector env)."""
    daemon_args: list[str] = field(default_factory=list)
    """Extra arguments passed to the daemon."""
    max_restarts: int = DEFAULT_MAX_RESTARTS
    """Daemon restarts allowed within any ``restart_window`` seconds (more is a crash loop)."""
    restart_window: float = DEFAULT_RESTART_WINDOW_S
    """Length of the restart window in seconds (``inf``: the whole run)."""
    ready_timeout: float = 120.0
    """Seconds to wait for the daemon's ready line."""
    grace: float = 10.0
    """Seconds the daemon gets between SIGTERM and SIGKILL."""
    trainer_grace: float = DEFAULT_TRAINER_GRACE_S
    """Seconds the trainer gets between SIGTERM and SIGKILL (its final checkpoint)."""
    backoff: float = 0.5
    """First restart delay of a window in seconds; doubles on each restart, capped at 8 s."""
    log_level: str = "INFO"
    """Log level of the supervisor, passed on to the daemon (``--log-level``) and to the
    trainer (``ROVERAV_LOG_LEVEL``)."""
    python: str = sys.executable
    """The interpreter that runs the daemon."""


_status = exit_status


class Supervisor:
    """Runs one daemon + trainer pair to completion. ``run()`` returns the exit status."""

    def __init__(self, cfg: PairConfig):
        self.cfg = cfg
        self._out_lock = threading.Lock()
        self._stop_signal: int | None = None
        self.daemon: ChildProcess | None = None
        self.trainer: ChildProcess | None = None

    def say(self, msg: str) -> None:
        with self._out_lock:
            sys.stdout.write(f"[rover-pair] {msg}\n")
            sys.stdout.flush()

    # -- lifecycle ------------------------------------------------------------------
    def run(self) -> int:
        previous = {
            sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            return self._run()
        finally:
            # the trainer first: its envs need the daemon while it saves its checkpoint
            if self.trainer is not None:
                self.trainer.stop(self.cfg.trainer_grace)
            if self.daemon is not None:
                self.daemon.stop(self.cfg.grace)
            left = remove_segments(existing_segments(self.cfg.name))
            if left:
                self.say(f"removed leftover segments: {', '.join(left)}")
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _on_signal(self, signum: int, _frame: object) -> None:
        self._stop_signal = signum

    def _run(self) -> int:
        cfg = self.cfg
        if not self._clear_stale():
            return EXIT_USAGE
        if not self._start_daemon():
            return EXIT_DAEMON_NOT_READY
        env = dict(os.environ)
        env.update({NAME_ENV_VAR: cfg.name, SLOTS_ENV_VAR: str(cfg.slots),
                    "ROVERAV_LOG_LEVEL": cfg.log_level})  # fmt: skip
        self.trainer = ChildProcess(cfg.trainer, env, on_line=self._relay("trainer"))
        self.say(f"trainer started (pid {self.trainer.proc.pid}): {' '.join(cfg.trainer)}")
        policy = RestartPolicy(cfg.max_restarts, cfg.restart_window, backoff=cfg.backoff)
        while True:
            code = self.trainer.poll()
            if code is not None:
                self.trainer.stop(cfg.trainer_grace)  # reap its process group's stragglers
                self.say(f"trainer exited with status {_status(code)}")
                return _status(code)
            if self._stop_signal is not None:
                name = signal.Signals(self._stop_signal).name
                self.say(f"{name} received: stopping trainer, then daemon")
                code = self.trainer.stop(cfg.trainer_grace)
                return _status(code)
            assert self.daemon is not None
            dcode = self.daemon.poll()
            if dcode is None:
                time.sleep(0.05)
                continue
            if not self._restart_daemon(policy, f"exited with status {_status(dcode)}"):
                if self._stop_signal is not None:
                    continue  # the signal branch above stops the trainer and reports
                code = self.trainer.stop(cfg.trainer_grace)
                self.say(f"trainer stopped (status {_status(code)})")
                return EXIT_RESTARTS_EXHAUSTED

    def _restart_daemon(self, policy: RestartPolicy, how: str) -> bool:
        """Restart the daemon under ``policy`` until it is ready; False on a crash loop."""
        cfg = self.cfg
        while True:
            if self.trainer is not None and self.trainer.poll() is not None:
                return True  # nothing to serve: the main loop reports the trainer's exit
            decision = policy.on_crash(time.monotonic())
            if not decision.restart:
                assert self.daemon is not None
                self.say(
                    f"daemon {how}: crash loop, {decision.recent} crashes within "
                    f"{cfg.restart_window:g} s ({decision.total} in this run; the limit is "
                    f"{policy.describe()}: --max-restarts/--restart-window). Stopping the "
                    f"trainer (it saves a checkpoint).\n  daemon log tail:\n"
                    f"{self.daemon.tail_text()}"
                )
                return False
            self.say(
                f"daemon {how}; restart {decision.recent}/{cfg.max_restarts} of the "
                f"{cfg.restart_window:g} s window ({decision.total} in this run) in "
                f"{decision.delay:.1f} s (segments are reused)"
            )
            if not self._sleep(decision.delay):
                return False
            if self._start_daemon():
                return True
            if self._stop_signal is not None:
                return False
            how = "did not get ready again"

    def _sleep(self, seconds: float) -> bool:
        """Sleep unless a stop signal arrives; True when the sleep ran out normally."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if self._stop_signal is not None:
                return False
            time.sleep(0.02)
        return True

    def _clear_stale(self) -> bool:
        segments = existing_segments(self.cfg.name)
        live = [s for s in segments if not s.endswith("_camera") and writer_alive(s)]
        if live:
            self.say(
                f"a live daemon already serves '{self.cfg.name}' (segments: {', '.join(live)}). "
                "Stop it first, or pick another --name."
            )
            return False
        removed = remove_segments(segments)
        if removed:
            self.say(f"removed segments left by a dead earlier run: {', '.join(removed)}")
        return True

    def _relay(self, label: str) -> Callable[[str], None]:
        def on_line(line: str) -> None:
            with self._out_lock:
                sys.stdout.write(f"[{label}] {line}\n")
                sys.stdout.flush()

        return on_line

    def _start_daemon(self) -> bool:
        cfg = self.cfg
        extra = [*cfg.daemon_args]
        if not any(a == "--log-level" or a.startswith("--log-level=") for a in extra):
            extra += ["--log-level", cfg.log_level]
        argv = daemon_command(cfg.name, cfg.slots, extra, cfg.python)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.daemon = ChildProcess(argv, env, on_line=self._relay("daemon"),
                                   ready_marker=READY_MARKER)  # fmt: skip
        why = self.daemon.wait_ready(cfg.ready_timeout, lambda: self._stop_signal is not None)
        if why:
            if "not ready after" in why:
                why += " (--ready-timeout)"
            self.daemon.stop(cfg.grace)
            self.say(f"daemon {why}.\n  command: {' '.join(argv)}\n  log tail:\n"
                     f"{self.daemon.tail_text()}")  # fmt: skip
            return False
        self.say(f"daemon ready (pid {self.daemon.pid}) on '{cfg.name}', {cfg.slots} slot(s)")
        return True


def check_usage(
    name: str, trainer: Sequence[str], ready_timeout: float, grace: float
) -> str | None:
    """What is wrong with these options (and how to fix it), or None. Checked before the
    daemon starts, so a typo costs no daemon start-up."""
    try:
        camera_name(slot_name(name, 0))
    except ValueError as exc:
        return f"--name: {exc}"
    if shutil.which(trainer[0]) is None:
        where = "is not an executable file" if "/" in trainer[0] else "was not found on PATH"
        return (
            f"trainer command {trainer[0]!r} {where}: expected a program after '--', e.g. "
            "-- rover-train --env fused. Check the spelling, give its path, or install the "
            "project (pip install -e .) so rover-train is on PATH."
        )
    if not ready_timeout > 0:
        return f"--ready-timeout must be > 0 seconds, got {ready_timeout}"
    if not grace >= 0:
        return f"--grace must be 0 or more seconds, got {grace}"
    return None


def build_parser() -> argparse.ArgumentParser:
    """rover-pair's own command line (the trainer's follows ``--``)."""
    parser = argparse.ArgumentParser(
        prog="rover-pair",
        description="Run the Active Vision daemon and a trainer together, supervised.",
        epilog="Example: rover-pair --slots 2 -- rover-train --env fused  (the trainer's "
        "--slots defaults to the supervisor's)",
    )
    add_group(parser, Connection).description = (
        "The daemon's --name, --slots and --log-level; the trainer gets them as "
        "$ROVERAV_SHM_NAME, $ROVERAV_SLOTS and $ROVERAV_LOG_LEVEL.")
    parser.add_argument(
        "--daemon-arg",
        action="append",
        default=[],
        metavar="ARG",
        help="extra daemon argument (repeatable; use --daemon-arg=--depth for dashes)",
    )
    parser.add_argument(
        "--max-restarts", type=int, default=PairConfig.max_restarts, metavar="N",
        help="daemon restarts allowed within any --restart-window seconds; one crash more "
        "is a crash loop and stops the run with status 70 (0: never restart; default "
        "%(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--restart-window", type=float, default=PairConfig.restart_window, metavar="S",
        help="length of that window in seconds; crashes older than this are forgotten and "
        "the restart backoff (0.5 s doubling to 8 s) starts over (inf: one budget for the "
        "whole run; default %(default)s)",
    )  # fmt: skip
    parser.add_argument("--ready-timeout", type=float, default=PairConfig.ready_timeout)
    parser.add_argument("--grace", type=float, default=PairConfig.grace,
                        help="seconds the daemon gets between SIGTERM and SIGKILL")
    parser.add_argument("--trainer-grace", type=float, default=PairConfig.trainer_grace,
                        help="seconds the trainer gets between SIGTERM and SIGKILL, to save "
                        "its final checkpoint (default %(default)s)")
    return parser


def parse_args(argv: Sequence[str] | None = None) -> PairConfig:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" in argv:
        split = argv.index("--")
        own, trainer = argv[:split], argv[split + 1 :]
    else:
        own, trainer = argv, []
    parser = build_parser()
    ns = parser.parse_args(own)
    if not trainer:
        parser.error("no trainer command: put it after '--', e.g. -- rover-train --env fused")
    if ns.max_restarts < 0:
        parser.error(f"--max-restarts must be 0 or more, got {ns.max_restarts}")
    if not ns.restart_window > 0:
        parser.error(f"--restart-window must be a positive number of seconds (or inf), "
                     f"got {ns.restart_window}")  # fmt: skip
    problem = check_usage(ns.name, trainer, ns.ready_timeout, ns.grace)
    if problem:
        parser.error(problem)
    return PairConfig(
        trainer=trainer,
        name=ns.name,
        slots=ns.slots,
        daemon_args=ns.daemon_arg,
        max_restarts=ns.max_restarts,
        restart_window=ns.restart_window,
        trainer_grace=ns.trainer_grace,
        ready_timeout=ns.ready_timeout,
        grace=ns.grace,
        log_level=ns.log_level,
    )


def main(argv: Sequence[str] | None = None) -> int:
    cfg = parse_args(argv)
    logging.basicConfig(level=cfg.log_level, format="[rover-pair] %(levelname)s %(message)s")
    return Supervisor(cfg).run()


if __name__ == "__main__":
    sys.exit(main())
