"""One mapping of ``/dev/shm/<name>``, made with ``os.open`` + ``mmap``.

Why not ``multiprocessing.shared_memory.SharedMemory``: on Python 3.11 it registers even a
plain attach with the resource tracker, which unlinks the segment when the attaching
process exits (gh-82300), and a ``kill -9`` of the creator lets its tracker unlink it too.
Mapping the file ourselves keeps every tracker out, so a segment's lifetime is decided by
the daemon and the supervisor alone: nothing here unlinks except :meth:`Segment.unlink`.

Creation is atomic: the segment is built under a hidden temporary name (mode 0600, memory
reserved with ``posix_fallocate``, header and trailer written) and then hard-linked to its
real name, which fails if the name exists. A reader therefore never sees a half-initialised
trailer, and two creators racing for one name end with exactly one segment.
"""

from __future__ import annotations

import ctypes
import difflib
import errno
import logging
import mmap
import os
import secrets
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .errors import LayoutError, SegmentNotFoundError
from .layout import HEADER_SIZE, TRAILER_SIZE, TrailerInfo, decode_trailer, has_magic
from .names import CAMERA_SUFFIX, SHM_DIR, segment_path

logger = logging.getLogger(__name__)

SEGMENT_MODE = 0o600
_ATTACH_POLL_S = 0.05


class Segment:
    """A shared mapping of one segment file; read-only for readers, read-write for writers.

    Field access goes through ctypes structures made with :meth:`struct_at` (plain loads and
    stores at fixed addresses, no buffer exports) and numpy views from :meth:`array_at`.
    The owner must drop both before :meth:`close`; using them afterwards is a crash.
    """

    def __init__(self, name: str, fd: int, writable: bool, path: str | None = None) -> None:
        self.name = name
        self.path = path or segment_path(name)
        self.fd = fd
        self.writable = writable
        st = os.fstat(fd)
        self.ino = st.st_ino
        self.dev = st.st_dev
        self.size = st.st_size
        if self.size < HEADER_SIZE:
            raise LayoutError(
                f"segment {name!r} has {self.size} bytes, less than the 12-byte header "
                f"({self.path} is being created, or is not a frame segment)"
            )
        access = mmap.ACCESS_WRITE if writable else mmap.ACCESS_READ
        self._mm: mmap.mmap | None = mmap.mmap(fd, self.size, access=access)
        self._base: np.ndarray | None = np.frombuffer(self._mm, dtype=np.uint8)
        self.address: int = self._base.ctypes.data

    # --- opening -----------------------------------------------------------------------

    @classmethod
    def open(cls, name: str, writable: bool) -> Segment:
        """Map the existing segment ``name``; FileNotFoundError if there is none."""
        path = segment_path(name)
        fd = os.open(path, (os.O_RDWR if writable else os.O_RDONLY) | os.O_CLOEXEC)
        try:
            return cls(name, fd, writable, path)
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def create(cls, name: str, size: int, init: Callable[[Segment], None]) -> Segment | None:
        """Create segment ``name`` of ``size`` bytes, initialised by ``init``, atomically.

        Returns None when the name already exists (the caller opens that one instead).
        Raises OSError(ENOSPC) with a clear message when ``/dev/shm`` cannot hold it.
        """
        path = segment_path(name)
        tmp = os.path.join(SHM_DIR, f".{name}.{os.getpid()}.{secrets.token_hex(4)}.init")
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, SEGMENT_MODE)
        seg: Segment | None = None
        try:
            os.fchmod(fd, SEGMENT_MODE)  # exactly 0600, whatever the umask
            _reserve(fd, size, name)
            seg = cls(name, fd, True, path)
            init(seg)
            try:
                os.link(tmp, path)
            except FileExistsError:
                seg.close()
                return None
            st = os.stat(path)
            seg.ino, seg.dev = st.st_ino, st.st_dev
            return seg
        except BaseException:
            if seg is not None:
                seg.close()
            else:
                os.close(fd)
            raise
        finally:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass

    # --- access ------------------------------------------------------------------------

    def struct_at(self, ctype: Any, offset: int) -> Any:
        """A ctypes structure over the mapping at ``offset`` (no copy, no buffer export)."""
        if offset < 0 or offset + ctypes.sizeof(ctype) > self.size:
            raise ValueError(f"{ctype.__name__} at {offset} does not fit in {self.size} bytes")
        return ctype.from_address(self.address + offset)

    def array_at(self, offset: int, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """A numpy view of ``shape``/``dtype`` over the mapping at ``offset``."""
        assert self._base is not None
        dt = np.dtype(dtype)
        n = int(np.prod(shape)) * dt.itemsize
        return self._base[offset : offset + n].view(dt).reshape(shape)

    def read_bytes(self, offset: int, n: int) -> bytes:
        assert self._base is not None
        return self._base[offset : offset + n].tobytes()

    def trailer_info(self) -> TrailerInfo | None:
        """The decoded trailer, or None for a segment without one (seed-style).

        The trailer is the last 64 bytes; its magic identifies it. A trailer whose layout
        does not account for the file's size is a :class:`LayoutError`.
        """
        if self.size < HEADER_SIZE + TRAILER_SIZE:
            return None
        raw = self.read_bytes(self.size - TRAILER_SIZE, TRAILER_SIZE)
        if not has_magic(raw):
            return None
        info = decode_trailer(raw)
        if info.layout.segment_size != self.size:
            raise LayoutError(
                f"segment {self.name!r}: its trailer says {info.layout.describe()} "
                f"({info.layout.segment_size} bytes) but {self.path} has {self.size} bytes"
            )
        return info

    # --- lifetime ----------------------------------------------------------------------

    def replaced(self) -> bool:
        """True when this inode no longer is ``/dev/shm/<name>``: unlinked, or another
        segment now has the name. A reader then re-attaches (when the name exists again)."""
        try:
            if os.fstat(self.fd).st_nlink == 0:
                return True
            st = os.stat(self.path)
        except FileNotFoundError:
            return True
        return st.st_ino != self.ino or st.st_dev != self.dev

    def name_exists(self) -> bool:
        return os.path.exists(self.path)

    def unlink(self) -> bool:
        """Remove the name, but only while it still names this inode (never a successor)."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return False
        if st.st_ino != self.ino or st.st_dev != self.dev:
            logger.info("segment %s was replaced; leaving the new one in place", self.name)
            return False
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            return False
        return True

    def close(self) -> None:
        """Unmap and close; idempotent. Views handed out must have been dropped."""
        self._base = None
        mm, self._mm = self._mm, None
        if mm is not None:
            try:
                mm.close()
            except BufferError:  # a caller still holds a view: the GC unmaps it later
                logger.debug("segment %s: views still exported; unmapped by the GC", self.name)
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def _reserve(fd: int, size: int, name: str) -> None:
    """Give the file its size with its memory reserved now, so a full /dev/shm is an error
    at creation instead of a SIGBUS in the middle of a run."""
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            raise OSError(
                errno.ENOSPC,
                f"cannot create segment {name!r}: {SHM_DIR} has less than {size} bytes free "
                f"(see `df -h {SHM_DIR}`; remove stale segments or enlarge the tmpfs)",
            ) from exc
        if exc.errno in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
            os.ftruncate(fd, size)  # a filesystem without fallocate: size only
        else:
            raise


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie.

    ``os.kill(pid, 0)`` alone says "alive" for a killed child its parent has not reaped yet,
    so ``/proc/<pid>/stat`` is consulted for state Z/X. The pid must be in this pid
    namespace (a writer in another container looks dead: pass ``check_pid=False`` there).
    """
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
    except FileNotFoundError:
        return False
    except OSError:
        return True
    end = stat.rfind(b")")
    state = stat[end + 2 : end + 3]
    return state not in (b"Z", b"X", b"x")


def describe_existing(limit: int = 20) -> list[str]:
    """Plausible segments in /dev/shm, for error messages: roverav ones with their layout
    first, then other visible files that could be seed-style segments."""
    ours: list[str] = []
    others: list[str] = []
    try:
        entries = sorted(os.scandir(SHM_DIR), key=lambda e: e.name)
    except OSError:
        return []
    for entry in entries:
        name = entry.name
        if name.startswith(".") or name.startswith("sem."):
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            size = entry.stat(follow_symlinks=False).st_size
        except OSError:
            continue
        desc = None
        if size >= TRAILER_SIZE + 12:
            try:
                fd = os.open(entry.path, os.O_RDONLY | os.O_CLOEXEC)
                try:
                    raw = os.pread(fd, TRAILER_SIZE, size - TRAILER_SIZE)
                finally:
                    os.close(fd)
                if has_magic(raw):
                    info = decode_trailer(raw)
                    desc = f"{name} ({info.layout.describe()}, writer pid {info.pid})"
            except (OSError, ValueError):
                desc = None
        if desc is not None:
            ours.append(desc)
        elif size > 12:
            others.append(f"{name} ({size} bytes, no roverav trailer)")
    found = ours + others
    if len(found) > limit:
        found = found[:limit] + [f"... and {len(found) - limit} more"]
    return found




def not_found_error(name: str, waited: float) -> SegmentNotFoundError:
    """The error for a missing segment: what was looked for, what exists, what to run."""
    available = describe_existing()
    fused = name[: -len(CAMERA_SUFFIX)] if name.endswith(CAMERA_SUFFIX) else name
    wait = f" for {waited:g} s" if waited > 0 else ""
    lines = [
        f"shared-memory segment {name!r} not found: looked for {segment_path(name)}{wait}.",
        "Segments in /dev/shm: " + (", ".join(available) if available else "none") + ".",
    ]
    close = difflib.get_close_matches(name, [a.split(" ", 1)[0] for a in available], n=3)
    if close:
        lines.append(f"Did you mean {' or '.join(repr(c) for c in close)}?")
    lines.append(
        f"Start the daemon that creates it first: `av-daemon --name {fused}` (slot i > 0 of a "
        "vector env: `--name <base> --slots N`), or run trainer and daemon together with "
        "`rover-pair`."
    )
    return SegmentNotFoundError(" ".join(lines), name, available)


def open_waiting(name: str, writable: bool, attach_timeout: float) -> Segment:
    """Open segment ``name``, waiting up to ``attach_timeout`` s for it to appear."""
    deadline = time.monotonic() + max(0.0, attach_timeout)
    while True:
        try:
            return Segment.open(name, writable)
        except FileNotFoundError:
            if time.monotonic() >= deadline:
                raise not_found_error(name, attach_timeout) from None
        except LayoutError:  # a seed-style creator between shm_open and ftruncate
            if time.monotonic() >= deadline:
                raise
        time.sleep(_ATTACH_POLL_S)


__all__ = [
    "SEGMENT_MODE",
    "Segment",
    "describe_existing",
    "not_found_error",
    "open_waiting",
    "pid_alive",
]
