"""rover-pair (launch/run_pair.py) with a real av-daemon and a small real trainer."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TRAINER = [sys.executable, str(ROOT / "tests" / "helpers" / "pair_trainer.py")]
SHM = Path("/dev/shm")


def _name() -> str:
    return f"test_pair_{uuid.uuid4().hex[:8]}"


def _segments(name: str) -> list[str]:
    return sorted(p.name for p in SHM.iterdir() if p.name.startswith(name))


def _pair_argv(name: str, *extra: str) -> list[str]:
    return [
        sys.executable,
        str(ROOT / "launch" / "run_pair.py"),
        "--name",
        name,
        "--grace",
        "5",
        "--daemon-arg=--threads",
        "--daemon-arg=1",
        *extra,
    ]


def _run(argv: list[str], timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie still answers kill(0); it is dead for our purposes
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except FileNotFoundError:
        return False


def test_normal_run_relays_output_and_cleans_up() -> None:
    name = _name()
    res = _run(_pair_argv(name, "--", *TRAINER, "--frames", "5"))
    assert res.returncode == 0, res.stdout + res.stderr
    assert "[daemon]" in res.stdout and "ready" in res.stdout
    assert "[trainer] frame 5 " in res.stdout
    assert "[trainer] trainer finished" in res.stdout
    assert _segments(name) == []


def test_trainer_exit_status_is_passed_through() -> None:
    name = _name()
    res = _run(_pair_argv(name, "--", *TRAINER, "--frames", "2", "--exit-code", "3"))
    assert res.returncode == 3, res.stdout + res.stderr
    assert _segments(name) == []


def test_killed_daemon_is_restarted_and_trainer_finishes() -> None:
    name = _name()
    res = _run(
        _pair_argv(
            name, "--max-restarts", "2", "--", *TRAINER, "--frames", "8", "--kill-daemon-at", "3"
        )
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "restart 1/2" in res.stdout
    assert "[trainer] frame 8 " in res.stdout
    assert _segments(name) == []


def test_no_restarts_allowed_stops_the_trainer_with_a_reason() -> None:
    name = _name()
    res = _run(
        _pair_argv(
            name, "--max-restarts", "0", "--", *TRAINER, "--frames", "0", "--kill-daemon-at", "2"
        )
    )
    assert res.returncode == 70, res.stdout + res.stderr
    assert "crash loop, 1 crashes within 60 s" in res.stdout
    assert "trainer finished" not in res.stdout
    assert _segments(name) == []


def test_crashes_spread_wider_than_the_window_are_restarted_indefinitely() -> None:
    # one restart per 1.5 s window, three crashes at least 2 s apart: a fixed budget of one
    # restart would stop the run at the second crash; the window lets all three through
    name = _name()
    res = _run(
        _pair_argv(
            name, "--max-restarts", "1", "--restart-window", "1.5", "--", *TRAINER,
            "--frames", "4", "--kill-daemon-at", "2", "--kills", "3", "--kill-gap", "2",
        )
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.count("restart 1/1 of the 1.5 s window") == 3
    assert "(3 in this run)" in res.stdout and "crash loop" not in res.stdout
    assert "[trainer] trainer finished" in res.stdout
    assert _segments(name) == []


def test_crash_loop_within_the_window_stops_the_run_with_the_count() -> None:
    name = _name()
    res = _run(
        _pair_argv(
            name, "--max-restarts", "2", "--restart-window", "600", "--", *TRAINER,
            "--frames", "0", "--kill-daemon-at", "1", "--kills", "3",
        )
    )  # fmt: skip
    assert res.returncode == 70, res.stdout + res.stderr
    assert "restart 1/2" in res.stdout and "restart 2/2" in res.stdout
    assert "crash loop, 3 crashes within 600 s (3 in this run" in res.stdout
    # the trainer was stopped before the daemon's segments were removed, and nothing is left
    assert "trainer stopped (status" in res.stdout
    assert _segments(name) == []


def test_daemon_that_cannot_start_is_reported_with_its_log() -> None:
    name = _name()
    res = _run(_pair_argv(name, "--daemon-arg=--size", "--daemon-arg=-5", "--", *TRAINER))
    assert res.returncode == 69, res.stdout + res.stderr
    assert "before it was ready" in res.stdout and "log tail" in res.stdout
    assert "trainer started" not in res.stdout
    assert _segments(name) == []


def test_stale_segments_of_a_dead_run_are_removed_at_start() -> None:
    from shm_protocol import FrameWriter

    name = _name()
    # a writer from a "dead run": a child that creates the segment and is SIGKILLed
    code = (
        f"import sys, os, signal, numpy as np; sys.path.insert(0, {str(ROOT)!r});"
        "from shm_protocol import FrameWriter;"
        f"w = FrameWriter({name!r}, shape=(96, 96, 3), dtype=np.float32);"
        "os.kill(os.getpid(), signal.SIGKILL)"
    )
    subprocess.run([sys.executable, "-c", code], check=False)
    assert _segments(name) == [name]
    res = _run(_pair_argv(name, "--", *TRAINER, "--frames", "2"))
    assert res.returncode == 0, res.stdout + res.stderr
    assert "left by a dead earlier run" in res.stdout
    assert _segments(name) == []
    del FrameWriter


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_everything_within_the_grace_period(sig: signal.Signals) -> None:
    name = _name()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        _pair_argv(name, "--", *TRAINER, "--frames", "0"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
        env=env,
    )
    lines: list[str] = []
    assert proc.stdout is not None
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if "[trainer] frame 3 " in line:
            break
    else:
        proc.kill()
        pytest.fail("pair never got going:\n" + "".join(lines))
    text = "".join(lines)
    daemon_pid = int(re.search(r"daemon ready \(pid (\d+)\)", text).group(1))
    trainer_pid = int(re.search(r"trainer started \(pid (\d+)\)", text).group(1))
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=5 + 5 + 10)  # trainer grace + daemon grace + margin
    assert f"{sig.name} received" in out
    assert not _alive(daemon_pid) and not _alive(trainer_pid)
    assert _segments(name) == []
