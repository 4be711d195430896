"""Clear errors where two processes (or a user and a process) disagree.

Every bad input below gives a named error (envs) or a usage message (CLIs) that says what
was expected, what was found and what to do; CLIs exit with 2 (usage) or 1 (runtime) and
print no traceback. Real av-daemon subprocesses, real shared memory.

The seams checked:

1. Two envs on the same daemon slot (same process, or another process): ``SegmentBusyError``
   at attach naming the pid that holds the slot's camera segment and ``slot=`` /
   ``--slots N``. A holder that closed or crashed (SIGKILL) does not block a new env.
2. Env ``size=(96, 96)`` against ``av-daemon --size 64``: ``LayoutError`` naming both sizes
   and the fix, at construction and at ``reset()`` after the daemon was restarted with
   another size (was numpy's "could not broadcast" error); rover-train's ``DaemonRecovery``
   raises it at once instead of retrying for a minute.
3. ``reset()`` / ``step()`` / ``render()`` after ``close()``, LIDAR and fused envs:
   ``EnvClosedError`` (a Gymnasium ``ClosedEnvironmentError`` and a ``RuntimeError``) saying
   to make a new env (was a bare AssertionError, or silently working).

Further bad inputs tried (``fixed`` = gave a traceback or a misleading message before):

4. Env ``slot=`` beyond the daemon's ``--slots``: ``SegmentNotFoundError`` at once, saying
   how many slots the daemon serves (fixed: waited ``connection_check_timeout`` for a
   segment that would never come).
5. Env ``slot=-1`` or ``slot=1.5``: ``ValueError`` naming the daemon's slot range (fixed
   message).
6. Env ``rl_obs_name="a/b"``: ``InvalidNameError``.
7. Env ``world_n="mars"``: ``ValueError`` listing the worlds.
8. Actions of the wrong shape, NaN, or a non-integer discrete action: ``ValueError``.
9. ``av-daemon --size 50`` (not a multiple of 16): usage error, status 2.
10. ``av-daemon --slots 0``: usage error, status 2.
11. ``av-daemon --name a/b``: usage error, status 2.
12. ``av-daemon --source video:/missing.mp4``: status 1, "no video file".
13. ``rover-pair`` without ``--``: usage error, status 2.
14. ``rover-pair -- /no/such/trainer``: usage error, status 2 (fixed: a FileNotFoundError
    traceback after the daemon had been started).
15. ``rover-train --resume DIR`` of a directory with no checkpoint: usage error, status 2
    (fixed: traceback after the env was built).
16. ``rover-train --world mars``: usage error, status 2 (fixed: traceback).
17. ``rover-train --length 0``, ``--n-steps 1``, ``--batch-size 0``, ``--gamma 1.5``: usage
    error, status 2 (fixed: the first two gave tracebacks, SB3's AssertionError for n_steps;
    ``--batch-size 0`` silently trained with the default; ``--gamma 1.5`` was accepted).
18. ``rover-train --name a/b``: usage error, status 2 (fixed: traceback).
19. ``rover-eval`` of a missing model file: status 1, "no model file".
20. ``rover-eval --world mars``: usage error, status 2 (fixed: traceback).
21. ``rover-eval --episodes 0``: usage error, status 2 (fixed: ZeroDivisionError).
22. ``rover-eval --slot -1``: usage error, status 2 (the hidden --slot is gone).
23. ``rover-eval`` of a model made for another env (a LIDAR model on the fused env, or one
    with another LIDAR size): status 1 naming both observation spaces and ``--env`` (fixed:
    a traceback deep in SB3's predict).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from gymnasium.error import ClosedEnvironmentError
from helpers.daemon import Daemon

from rover_env.discrete_env import DiscreteRoverEnvFused
from rover_env.errors import EnvClosedError
from rover_env.fused_env import RoverEnvFused
from rover_env.lidar_env import RoverEnv
from rover_train.envs import DaemonRecovery
from shm_protocol import InvalidNameError, LayoutError, SegmentBusyError, SegmentNotFoundError

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_seams_{uuid.uuid4().hex[:8]}", 2).start()
    yield d
    d.stop()
    d.remove_leftovers()


def _fused(name: str, **kw: object) -> RoverEnvFused:
    kw.setdefault("world_n", "maze")
    kw.setdefault("connection_check_timeout", 5)
    return RoverEnvFused(rl_obs_name=name, **kw)


def _env_vars() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1", MUJOCO_GL="egl")


# --- 1. two envs on one slot -------------------------------------------------------------------
def test_second_env_on_a_slot_in_this_process_is_refused(daemon: Daemon) -> None:
    with _fused(daemon.name) as first:
        first.reset(seed=0)
        with pytest.raises(SegmentBusyError) as err:
            _fused(daemon.name)
        msg = str(err.value)
        assert err.value.pid == os.getpid() and f"pid {os.getpid()}" in msg
        assert "slot=" in msg and "--slots N" in msg and "this process" in msg
        first.step(first.action_space.sample())  # the holder is unaffected
        with _fused(daemon.name, slot=1) as other:  # another slot is fine
            other.reset(seed=1)
    with _fused(daemon.name) as again:  # a closed holder does not block
        again.reset(seed=2)


_HOLDER = """
import sys, time
from rover_env.fused_env import RoverEnvFused
env = RoverEnvFused(rl_obs_name=sys.argv[1], slot=1, world_n="maze", connection_check_timeout=5)
env.reset(seed=0)
print("attached", flush=True)
time.sleep(60)
"""


def test_slot_held_by_another_process_names_it_and_a_crashed_holder_does_not_block(
    daemon: Daemon,
) -> None:
    holder = subprocess.Popen(
        [PY, "-c", _HOLDER, daemon.name], stdout=subprocess.PIPE, text=True, env=_env_vars()
    )
    try:
        assert holder.stdout is not None
        assert holder.stdout.readline().strip() == "attached"
        with pytest.raises(SegmentBusyError) as err:
            _fused(daemon.name, slot=1)
        msg = str(err.value)
        assert err.value.pid == holder.pid and f"pid {holder.pid}" in msg
        assert err.value.command.startswith(PY) and err.value.command in msg
        assert "daemon slot 1" in msg and "another process" in msg and "--slots N" in msg
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
    # The holder crashed without closing: re-attaching on its slot works.
    with _fused(daemon.name, slot=1) as env:
        env.reset(seed=0)
        env.step(env.action_space.sample())


# --- 2. size mismatch -------------------------------------------------------------------------
def test_size_mismatch_at_attach_and_after_a_daemon_restart(
    caplog: pytest.LogCaptureFixture,
) -> None:
    name = f"test_seams_size_{uuid.uuid4().hex[:8]}"
    small = Daemon(name, 1, ("--size", "64")).start()
    try:
        with pytest.raises(LayoutError) as err:
            _fused(name)  # size=(96, 96) by default
        msg = str(err.value)
        assert "size=(96, 96)" in msg and "--size 64" in msg and "size=(64, 64)" in msg
        assert "--size 96" in msg
        with _fused(name, size=(64, 64)) as env:  # the fix it names works
            env.reset(seed=0)
    finally:
        small.stop()
    big = Daemon(name, 1).start()
    try:
        env = _fused(name)
        try:
            env.reset(seed=0)
            big.stop()  # orderly stop: segments unlinked; a 64-pixel daemon takes the name
            big = Daemon(name, 1, ("--size", "64")).start()
            with pytest.raises(LayoutError) as err:
                env.reset(seed=1)
            msg = str(err.value)
            assert "size=(96, 96)" in msg and "64x64" in msg and "--size 96" in msg
            # rover-train's recovery wrapper does not retry what a restart cannot fix
            with caplog.at_level(logging.WARNING), pytest.raises(LayoutError):
                DaemonRecovery(env, recover_timeout=1.0).reset(seed=1)
            assert "retrying" not in caplog.text
            big.stop()  # and back to 96: the same env resets again
            big = Daemon(name, 1).start()
            env.reset(seed=2)
            env.step(env.action_space.sample())
        finally:
            env.close()
    finally:
        big.stop()
        big.remove_leftovers()


# --- 3. use after close -----------------------------------------------------------------------
def test_lidar_env_after_close_raises_closed_error() -> None:
    env = RoverEnv(world_n="maze", render_mode="rgb_array")
    env.reset(seed=0)
    env.close()
    env.close()  # idempotent
    assert env.closed
    for call in (lambda: env.step(env.action_space.sample()), lambda: env.reset(), env.render):
        with pytest.raises(EnvClosedError, match=r"after close\(\).*Make a new env"):
            call()
    assert issubclass(EnvClosedError, ClosedEnvironmentError)
    assert issubclass(EnvClosedError, RuntimeError)


def test_fused_envs_after_close_raise_closed_error(daemon: Daemon) -> None:
    for cls in (RoverEnvFused, DiscreteRoverEnvFused):
        env = cls(rl_obs_name=daemon.name, world_n="maze", connection_check_timeout=5)
        env.reset(seed=0)
        env.close()
        with pytest.raises(EnvClosedError, match=rf"{cls.__name__}\.step\(\) called after close"):
            env.step(env.action_space.sample())
        with pytest.raises(EnvClosedError, match=r"reset\(\) called after close"):
            env.reset(seed=0)


# --- 4-8. more bad env inputs -----------------------------------------------------------------
def test_slot_beyond_the_daemons_slots_fails_at_once(daemon: Daemon) -> None:
    t0 = time.monotonic()
    with pytest.raises(SegmentNotFoundError) as err:
        _fused(daemon.name, slot=2, connection_check_timeout=60)
    msg = str(err.value)
    assert "serves 2 slot(s)" in msg and "--slots 3" in msg and "slot= in 0..1" in msg
    assert time.monotonic() - t0 < 60  # it did not wait for connection_check_timeout


@pytest.mark.parametrize("slot", [-1, 1.5])
def test_bad_slot_is_a_value_error(slot: object) -> None:
    with pytest.raises(ValueError, match=r"slot must be an int >= 0.*--slots N"):
        _fused("test_seams_unused", slot=slot)


def test_segment_name_with_a_slash_is_refused() -> None:
    with pytest.raises(InvalidNameError, match="must not contain '/'"):
        _fused("a/b")


def test_unknown_world_lists_the_worlds() -> None:
    with pytest.raises(ValueError, match=r"unknown world 'mars'.*maze"):
        RoverEnv(world_n="mars")


def test_bad_actions_are_value_errors(daemon: Daemon) -> None:
    with RoverEnv(world_n="maze") as env:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="2 values"):
            env.step(np.zeros(3, np.float32))
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([np.nan, 0.0], np.float32))
    with DiscreteRoverEnvFused(
        rl_obs_name=daemon.name, world_n="maze", connection_check_timeout=5
    ) as env:
        env.reset(seed=0)
        for bad in (2.5, 60, np.array([1, 2])):
            with pytest.raises(ValueError, match="0..59|one integer"):
                env.step(bad)


# --- 9-23. the command lines ------------------------------------------------------------------
def _cli(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [PY, *argv], capture_output=True, text=True, env=_env_vars(), cwd=ROOT, timeout=timeout
    )


def _assert_fails(proc: subprocess.CompletedProcess[str], status: int, *words: str) -> None:
    out = proc.stdout + proc.stderr
    assert proc.returncode == status, out
    assert "Traceback" not in out, out
    for w in words:
        assert w in out, out


@pytest.mark.parametrize(
    "args, status, words",
    [
        (["--size", "50"], 2, ["--size", "multiple of 16", "got 50"]),
        (["--slots", "0"], 2, ["--slots", "must be >= 1"]),
        (["--name", "a/b"], 2, ["--name", "must not contain '/'"]),
        (["--source", "video:/no/such/file.mp4"], 1, ["no video file at /no/such/file.mp4"]),
    ],
    ids=["size", "slots0", "name", "video"],
)
def test_av_daemon_bad_input(args: list[str], status: int, words: list[str]) -> None:
    name = f"test_seams_cli_{uuid.uuid4().hex[:8]}"
    _assert_fails(_cli("-m", "active_vision", "--name", name, *args), status, *words)


def test_rover_pair_bad_input() -> None:
    pair = str(ROOT / "launch" / "run_pair.py")
    name = f"test_seams_pair_{uuid.uuid4().hex[:8]}"
    _assert_fails(_cli(pair, "--name", name), 2, "no trainer command", "'--'")
    proc = _cli(pair, "--name", name, "--", "/no/such/trainer", "--flag")
    _assert_fails(proc, 2, "/no/such/trainer", "not an executable file")
    assert "[daemon]" not in proc.stdout  # refused before a daemon was started
    assert not list(Path("/dev/shm").glob(f"{name}*"))


@pytest.mark.parametrize(
    "args, words",
    [
        (["--resume", "{tmp}"], ["--resume", "no run.json", "checkpoints"]),
        (["--world", "mars"], ["--world", "mars", "maze"]),
        (["--length", "0"], ["--length", "at least 1"]),
        (["--n-steps", "1"], ["--n-steps", "at least 2"]),
        (["--batch-size", "0"], ["--batch-size", "must be > 0"]),
        (["--gamma", "1.5"], ["--gamma", "(0, 1]"]),
        (["--env", "fused", "--name", "a/b"], ["name", "must not contain '/'"]),
    ],
    ids=["resume", "world", "length", "n_steps", "batch_size", "gamma", "name"],
)
def test_rover_train_bad_input(args: list[str], words: list[str], tmp_path: Path) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    proc = _cli("-m", "rover_train.train", "--logdir", str(tmp_path / "run"), *args)
    _assert_fails(proc, 2, *words)
    assert not (tmp_path / "run").exists()  # refused before anything was built


@pytest.mark.parametrize(
    "args, status, words",
    [
        (["{tmp}/missing.zip"], 1, ["no model file at", "missing.zip"]),
        (["--random", "--world", "mars"], 2, ["--world", "mars", "maze"]),
        (["--random", "--episodes", "0"], 2, ["--episodes", "must be >= 1"]),
        (["--random", "--slot", "-1"], 2, ["unrecognized arguments: --slot"]),
    ],
    ids=["missing_model", "world", "episodes0", "slot"],
)
def test_rover_eval_bad_input(
    args: list[str], status: int, words: list[str], tmp_path: Path
) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    _assert_fails(_cli("-m", "rover_train.evaluate", *args), status, *words)


def test_rover_eval_of_a_model_for_another_env(tmp_path: Path) -> None:
    from stable_baselines3 import PPO

    # A model whose observation space differs from rover-eval's env (16 LIDAR points, the
    # CLI's env has 32): the same check catches a LIDAR model given --env fused.
    with RoverEnv(world_n="maze", lidar_points=16) as env:
        PPO("MultiInputPolicy", env, n_steps=64, device="cpu").save(tmp_path / "other.zip")
    proc = _cli(
        "-m", "rover_train.evaluate", str(tmp_path / "other.zip"), "--env", "lidar",
        "--episodes", "1",
    )  # fmt: skip
    _assert_fails(proc, 1, "other.zip", "trained for another env", "lidar: Box(16,)",
                  "lidar: Box(32,)", "--env")  # fmt: skip

