"""Sleep until any of several segments publishes: one ``futex_waitv`` over their wake words.

A reader waits on one segment's wake word (``FrameReader.wait_next``). A process that serves
several segments - the av-daemon reading one camera segment per slot - would otherwise
have to rotate short waits over them, and a frame on a segment it is not waiting on then
waits for the end of the current slice (up to that slice, 2 ms in the daemon; about half
of it on average). Linux 5.16+ has ``futex_waitv``, which sleeps on up to 128 futex words
at once and returns when any is woken::

    watch = MultiWaiter(readers)
    while True:
        watch.arm()                      # read every wake word BEFORE looking for frames
        frames = [r.next_frame(out=...) for r in readers]   # (never blocks)
        if not any(frames):
            watch.wait(0.2)              # returns at once if any word changed since arm()

Arming before looking is what makes a wake-up impossible to lose: a publish that lands
after :meth:`MultiWaiter.arm` changes its word, so the wait returns at once (``EAGAIN``).
The futexes are non-private (waker and waiters are different processes), as in
:mod:`shm_protocol._futex`. :data:`AVAILABLE` is False where the syscall is missing (older
kernels, not Linux); callers then fall back to waiting on one segment at a time.
"""

from __future__ import annotations

import ctypes
import errno
import logging
import sys
import time
from collections.abc import Callable, Sequence

from ._futex import AVAILABLE as FUTEX_AVAILABLE
from ._futex import MACHINE
from .reader import FrameReader

logger = logging.getLogger(__name__)

# futex_waitv is 449 in the unified syscall table every architecture adopted (5.16+).
_SYS_FUTEX_WAITV = {"x86_64": 449, "amd64": 449, "aarch64": 449, "arm64": 449,
                    "riscv64": 449, "ppc64le": 449, "ppc64": 449, "s390x": 449}
_FUTEX2_SIZE_U32 = 0x02  # a 32-bit futex word; no FUTEX2_PRIVATE: shared across processes
MAX_WAITERS = 128
"""The kernel's limit on futexes per ``futex_waitv`` call."""


class _WaitV(ctypes.Structure):
    _fields_ = [("val", ctypes.c_uint64), ("uaddr", ctypes.c_uint64),
                ("flags", ctypes.c_uint32), ("reserved", ctypes.c_uint32)]


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _load() -> tuple[Callable[..., int], int] | None:
    if not (sys.platform.startswith("linux") and FUTEX_AVAILABLE):
        return None
    nr = _SYS_FUTEX_WAITV.get(MACHINE)
    if nr is None:
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).syscall  # own handle: own argtypes
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_long
    fn.argtypes = [ctypes.c_long, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint,
                   ctypes.c_void_p, ctypes.c_int]
    # zero waiters: EINVAL where the call exists, ENOSYS where it does not
    if fn(nr, None, 0, 0, None, time.CLOCK_MONOTONIC) < 0 and ctypes.get_errno() == errno.ENOSYS:
        logger.debug("futex_waitv is not available (ENOSYS)")
        return None
    return fn, nr


_loaded = _load()
AVAILABLE = _loaded is not None
"""Whether ``futex_waitv`` works here."""
_syscall, _NR = _loaded if _loaded is not None else (None, 0)


class MultiWaiter:
    """Wait until any of ``readers``' segments publishes (see the module docstring).

    Every reader must be attached to a roverav segment with a futex wake word
    (:attr:`FrameReader.wake_address` not None). The waiter re-reads the addresses at every
    :meth:`arm`, so a reader that re-attached to a replaced segment is followed. Nothing is
    allocated per call.

    :raises OSError: ``futex_waitv`` is not available here (check :data:`AVAILABLE`).
    :raises ValueError: a reader has no futex, or more than 128 readers.
    """

    def __init__(self, readers: Sequence[FrameReader]) -> None:
        if not AVAILABLE:
            raise OSError("futex_waitv is not available on this host (Linux 5.16+ needed)")
        if not 0 < len(readers) <= MAX_WAITERS:
            raise ValueError(f"MultiWaiter takes 1..{MAX_WAITERS} readers, got {len(readers)}")
        for r in readers:
            if r.wake_address is None:
                raise ValueError(f"segment {r.name!r} has no futex wake word (a seed-style "
                                 "segment, or a payload size that is not a multiple of 4)")
        self.readers = list(readers)
        self._waiters = (_WaitV * len(readers))()
        for w in self._waiters:
            w.flags = _FUTEX2_SIZE_U32
        self._ts = _Timespec()
        self._args = (ctypes.addressof(self._waiters), len(readers), 0,
                      ctypes.addressof(self._ts), time.CLOCK_MONOTONIC)

    def arm(self) -> None:
        """Note every segment's wake word; call it before looking for new frames."""
        for w, r in zip(self._waiters, self.readers, strict=True):
            addr = r.wake_address
            if addr is not None:
                w.uaddr = addr
                w.val = r.wake_value
            # (a reader without a futex after a re-attach keeps its old entry: the wait
            # then simply runs to its timeout for that segment, which stays correct)

    def wait(self, timeout: float) -> None:
        """Sleep until a segment armed by :meth:`arm` publishes, or ``timeout`` s pass.

        Returns at once if a wake word changed since :meth:`arm`; EINTR and timeouts also
        just return: the caller looks for frames either way.
        """
        if timeout <= 0:
            return
        deadline = time.clock_gettime(time.CLOCK_MONOTONIC) + timeout
        sec = int(deadline)
        self._ts.tv_sec = sec
        self._ts.tv_nsec = int((deadline - sec) * 1e9)
        _syscall(_NR, *self._args)  # type: ignore[misc]


__all__ = ["AVAILABLE", "MAX_WAITERS", "MultiWaiter"]
