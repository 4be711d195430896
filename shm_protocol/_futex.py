"""Cross-process waking and memory ordering: the futex on the trailer's wake word, and fence().

Waking. The writer increments the trailer's 32-bit wake word after every publish and calls
``FUTEX_WAKE`` on it; a waiting reader calls ``FUTEX_WAIT`` with the value it read *before*
it last looked for a frame, so a publish that lands in between makes the wait return at once
(no lost wake-up). The futex is non-private (no ``FUTEX_PRIVATE_FLAG``): the waiters are
other processes mapping the same file, which the kernel keys by inode and offset. Waits
always carry a short timeout, so a writer that never wakes anyone (a seed-style peer) costs
a poll interval, never a hang. Where futexes cannot be used (not Linux, an unknown
architecture, a wake word that is not 4-byte aligned because the payload size is not a
multiple of 4) :data:`AVAILABLE` is False or the caller polls instead.

Ordering. The seqlock needs the payload stores to become visible between the two ``seq``
stores, and the reader's payload loads to happen between its two ``seq`` loads.

- x86-64 is TSO: stores become visible in program order and loads are not reordered with
  other loads. Every field access here is an opaque C call (ctypes, numpy), which the C
  compiler cannot move across, so program order is what the other process sees and
  :func:`fence` is a no-op.
- ARM64 (and POWER, RISC-V) may reorder both. Python has no fence instruction, so on those
  hosts :func:`fence` releases then re-acquires a per-thread lock: libc's release store
  followed by an acquire load, which ARMv8 keeps in order (load-acquire is RCsc there). That
  is the strongest ordering reachable from pure Python, but it has not been tested on ARM
  hardware in this project, so the writer also defaults to checksum mode off x86 (see
  ``FrameWriter(checksum=...)``): the reader then verifies ``crc32(payload, seq)`` and
  rejects any copy that ordering could have mixed, whatever the CPU did.
"""

from __future__ import annotations

import ctypes
import logging
import platform
import sys
import threading
from collections.abc import Callable

logger = logging.getLogger(__name__)

_SYS_FUTEX = {
    "x86_64": 202, "amd64": 202, "aarch64": 98, "arm64": 98, "riscv64": 98,
    "i386": 240, "i686": 240, "armv7l": 240, "ppc64le": 221, "ppc64": 221, "s390x": 238,
}
_FUTEX_WAIT = 0  # non-private on purpose: waker and waiters are different processes
_FUTEX_WAKE = 1
_WAKE_ALL = 0x7FFF_FFFF

MACHINE = platform.machine().lower()
TOTAL_STORE_ORDER = MACHINE in {"x86_64", "amd64", "i386", "i686", "x86"}
"""True on x86: stores and loads keep program order across processes (no fence needed)."""


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _load_syscall() -> tuple[Callable[..., int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    nr = _SYS_FUTEX.get(MACHINE)
    if nr is None:
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).syscall
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_long
    fn.argtypes = [ctypes.c_long, ctypes.c_void_p, ctypes.c_int, ctypes.c_uint32,
                   ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32]
    probe = ctypes.c_uint32(0)
    if fn(nr, ctypes.addressof(probe), _FUTEX_WAKE, 1, None, None, 0) < 0:
        logger.debug("futex probe failed (errno %d); readers will poll", ctypes.get_errno())
        return None
    return fn, nr


_loaded = _load_syscall()
AVAILABLE = _loaded is not None
_syscall, _NR = _loaded if _loaded is not None else (None, 0)
"""Whether futex wait/wake works here; readers fall back to polling when it does not."""


class FutexWord:
    """Wait on / wake a 32-bit word in shared memory at a fixed address.

    The address must stay mapped while this object is used; the owner (a reader or writer)
    drops it before unmapping. ``wait`` reuses one timespec, so waiting allocates nothing.
    """

    __slots__ = ("_addr", "_ts", "_tsp")

    def __init__(self, address: int) -> None:
        if not AVAILABLE:
            raise OSError("futex is not available on this host")
        if address % 4:
            raise ValueError(f"futex word address {address:#x} is not 4-byte aligned")
        self._addr = address
        self._ts = _Timespec()
        self._tsp = ctypes.addressof(self._ts)

    @property
    def address(self) -> int:
        """The word's address in this process."""
        return self._addr

    def wait(self, expected: int, timeout: float) -> None:
        """Sleep until woken, ``timeout`` s pass, or the word no longer equals ``expected``.

        Returns in every case (EAGAIN, ETIMEDOUT and EINTR are all "look again").
        """
        if timeout <= 0:
            return
        sec = int(timeout)
        self._ts.tv_sec = sec
        self._ts.tv_nsec = int((timeout - sec) * 1e9)
        _syscall(_NR, self._addr, _FUTEX_WAIT, expected, self._tsp, None, 0)  # type: ignore[misc]

    def wake(self) -> None:
        """Wake every process waiting on the word."""
        _syscall(_NR, self._addr, _FUTEX_WAKE, _WAKE_ALL, None, None, 0)  # type: ignore[misc]


if TOTAL_STORE_ORDER:

    def fence() -> None:
        """No-op on x86 (TSO): program order is already the order other processes see."""

else:
    _fence_state = threading.local()

    def fence() -> None:
        """Best-effort full barrier on weakly ordered CPUs: release, then acquire, a lock.

        See the module docstring; checksum mode is the guarantee on these hosts.
        """
        lock = getattr(_fence_state, "lock", None)
        if lock is None:
            lock = _fence_state.lock = threading.Lock()
            lock.acquire()
        lock.release()
        lock.acquire()


__all__ = ["AVAILABLE", "TOTAL_STORE_ORDER", "FutexWord", "fence"]
