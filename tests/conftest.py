"""Shared pytest fixtures. Each block is self-contained; add yours as a new block."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator

import pytest

# --- shared memory: unique segment names, and no segment left behind ---------------------
#
# Tests that create segments name them with the prefix "test_" (the `shm_name` fixture does).
# `_shm_no_leftover_segments` snapshots /dev/shm at the start of the session and fails the
# session if a "test_..." segment (or a hidden ".test_..." creation temporary) that was not
# there before is still there at the end. A segment whose writer is a live process that is
# neither this one nor its child belongs to another test session running beside this one
# (several people share the machine): it is neither removed nor reported.

_SHM_DIR = "/dev/shm"
_shm_leaks: list[str] = []


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


@pytest.fixture(scope="session", autouse=True)
def _shm_no_leftover_segments() -> Iterator[None]:
    before = _shm_test_entries()
    yield
    left = sorted(
        n for n in _shm_test_entries() - before
        if n.startswith(".") or not _shm_held_by_another_session(n)
    )
    for name in left:  # clean up so one failure does not pollute the next run
        try:
            os.unlink(os.path.join(_SHM_DIR, name))
        except FileNotFoundError:
            pass
    problems = left + [n for n in _shm_leaks if n not in left]
    assert not problems, f"the test suite left segments in {_SHM_DIR}: {problems}"


@pytest.fixture
def shm_name() -> Iterator[str]:
    """A unique segment name (``test_<pid>_<hex>``). A segment still there after the test
    is removed and reported as a leak at the end of the session."""
    name = f"test_{os.getpid()}_{uuid.uuid4().hex[:10]}"
    yield name
    for n in (name, f"{name}_camera"):
        path = os.path.join(_SHM_DIR, n)
        if os.path.exists(path):
            _shm_leaks.append(n)
            os.unlink(path)
