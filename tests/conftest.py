"""Shared pytest fixtures. Each block is self-contained; add yours as a new block."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator

import pytest

# --- shared memory: unique segment names, and no segment left behind ---------------------
#
# Tests that create segments name them with the prefix "test_" (the `shm_name` fixture does).
# The session hooks below snapshot /dev/shm at the start of the session and fail the
# session if a "test_..." segment (or a hidden ".test_..." creation temporary) that was not
# there before is still there at the end. A segment whose writer is a live process that is
# neither this one nor its child belongs to another test session running beside this one
# (several people share the machine): it is neither removed nor reported.

_SHM_DIR = "/dev/shm"
_SHM_BEFORE = pytest.StashKey[set[str]]()


def _shm_test_entries() -> set[str]:
    try:
        names = os.listdir(_SHM_DIR)
    except FileNotFoundError:
        return set()
    return {n for n in names if n.startswith(("test_", ".test_"))}


def _shm_held_by_another_session(name: str) -> bool:
    """Whether segment ``name``'s writer (trailer pid) is alive and not this process or one
    of its children."""
    from shm_protocol import FrameReader, ShmError
    from shm_protocol._segment import pid_alive

    try:
        reader = FrameReader(name)
    except (ShmError, OSError):
        return False
    try:
        pid = reader.writer_pid
    finally:
        reader.close()
    if not pid or pid == os.getpid() or not pid_alive(pid):
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            ppid = int(f.read().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return False
    return ppid != os.getpid()


def _is_xdist_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


def pytest_sessionstart(session: pytest.Session) -> None:
    # Under pytest-xdist the controller runs this before any worker starts and checks after
    # every worker has finished, so one worker never mistakes another's segments for leaks.
    if not _is_xdist_worker(session.config):
        session.config.stash[_SHM_BEFORE] = _shm_test_entries()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if _is_xdist_worker(session.config) or _SHM_BEFORE not in session.config.stash:
        return
    before = session.config.stash[_SHM_BEFORE]
    left = sorted(
        n for n in _shm_test_entries() - before
        if n.startswith(".") or not _shm_held_by_another_session(n)
    )
    for name in left:  # clean up so one failure does not pollute the next run
        try:
            os.unlink(os.path.join(_SHM_DIR, name))
        except FileNotFoundError:
            pass
    if left:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        message = f"the test suite left segments in {_SHM_DIR}: {left}"
        if reporter is not None:
            reporter.write_line(message, red=True, bold=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture
def shm_name() -> Iterator[str]:
    """A unique segment name (``test_<pid>_<hex>``). A segment still there after the test
    is removed, and the test errors at teardown naming it."""
    name = f"test_{os.getpid()}_{uuid.uuid4().hex[:10]}"
    yield name
    leaked = [n for n in (name, f"{name}_camera") if os.path.exists(os.path.join(_SHM_DIR, n))]
    for n in leaked:
        os.unlink(os.path.join(_SHM_DIR, n))
    if leaked:
        pytest.fail(f"the test left segments in {_SHM_DIR}: {leaked}")


# --- Stable-Baselines3's logger: no SB3-<date> directories left in /tmp ------------------
#
# A model's learn() without ``tensorboard_log`` configures SB3's logger with no folder, and
# SB3 then makes an (empty) directory $TMPDIR/SB3-<date and time> unless $SB3_LOGDIR names
# one. For the session (and the processes it starts) that folder is one under the session's
# temporary directory, which pytest removes with it.


@pytest.fixture(scope="session", autouse=True)
def _sb3_logdir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    old = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3_logger"))
    yield
    if old is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = old
