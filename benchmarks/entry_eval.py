"""rover-eval of a zoo entry in a subprocess, for the benchmarks that tabulate entries
(``contact_table``, ``looking_rl``): its command line, and the episodes it dumped."""

from __future__ import annotations

import datetime as dt
import json
import sys
from pathlib import Path

from rover_train import zoo
from rover_train.evaluate import EpisodeResult
from rover_train.zoo.registry import STUDENT_FUSED_KINDS


def eval_command(entry: str, flags: list[str], dump: Path, daemon: str,
                 quiet_daemon: bool = False) -> list[str]:  # fmt: skip
    """``rover-eval ENTRY FLAGS --dump DUMP --json``; for a fused entry under ``rover-pair
    --name DAEMON --slots 1`` (its own daemon, its segments removed when done)."""
    bin_dir = Path(sys.executable).parent
    cmd = [str(bin_dir / "rover-eval"), entry, *flags, "--dump", str(dump), "--json"]
    if zoo.ENTRIES[entry].kind not in STUDENT_FUSED_KINDS:
        return cmd
    quiet = ["--daemon-arg=--log-level", "--daemon-arg=WARNING"] if quiet_daemon else []
    return [str(bin_dir / "rover-pair"), "--name", daemon, "--slots", "1", *quiet, "--", *cmd]


def dumped_episodes(rc: int, dump: Path, log: Path, episodes: int) -> list[EpisodeResult]:
    """The episodes a finished rover-eval (exit status ``rc``, output in ``log``) dumped;
    RuntimeError naming the log's last line, or the count, when it did not finish them all."""
    if rc != 0 or not dump.is_file():
        last = (log.read_text().strip().splitlines() or [""])[-1]
        raise RuntimeError(f"exit status {rc} ({log}): {last}")
    results = [EpisodeResult(**r) for r in json.loads(dump.read_text())]
    if len(results) != episodes:
        raise RuntimeError(f"{len(results)} of {episodes} episodes in {dump}")
    return results


def now() -> str:
    """The UTC time of day, for progress lines."""
    return dt.datetime.now(dt.UTC).strftime("%H:%M:%S")
