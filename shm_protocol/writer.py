"""FrameWriter: the single writer of a segment (the daemon for fused frames, the env for
camera frames).

Publishing is a seqlock, in the order docs/protocol.md fixes::

    seq += 1 (odd) -> valid = 0 -> timestamp -> payload -> [checksum] -> source_seq
    -> seq += 1 (even) -> valid = 1 -> heartbeat -> wake word += 1, FUTEX_WAKE

A seed-style reader (``timestamp`` changed and ``valid == 1``) sees the new timestamp only
while ``valid`` is 0, so it waits for the payload; our reader brackets its copy between two
reads of ``seq``/``valid``/``timestamp``.
"""

from __future__ import annotations

import logging
import operator
import os
import time
import weakref
import zlib
from collections.abc import Collection
from typing import Any

import numpy as np

from ._futex import AVAILABLE as FUTEX_AVAILABLE
from ._futex import TOTAL_STORE_ORDER, FutexWord, fence
from ._segment import Segment, open_waiting, pid_alive
from .errors import LayoutError, NonFiniteError, SegmentBusyError, ShmError
from .layout import (
    FLAG_CHECKSUM,
    FLAG_EPISODE_START,
    FLAG_SHUTTING_DOWN,
    MAGIC,
    PAYLOAD_OFFSET,
    U32_MAX,
    U64_MAX,
    VERSION,
    Header,
    Layout,
    Trailer,
    describe,
    normalize_dtype,
    normalize_shape,
)
from .names import segment_path, validate_name

logger = logging.getLogger(__name__)

_CREATE_ATTEMPTS = 8
_CMDLINE_CHARS = 160

# Open writers of this process: a second writer on the same inode in the same process has
# the same pid as the first, so the trailer's pid alone cannot tell them apart.
_open_writers: weakref.WeakSet[FrameWriter] = weakref.WeakSet()


class FrameWriter:
    """Create (or reuse) a segment and publish frames into it.

    :param name: segment name (file ``/dev/shm/<name>``), see :func:`validate_name`.
    :param shape: ``(H, W, C)``. Required with ``create=True``; with ``create=False`` it is
        read from the trailer when omitted (and checked when given).
    :param dtype: ``np.float32`` or ``np.uint8``; same rules as ``shape``.
    :param create: True: create the segment, or reuse an existing one of the same layout
        (same inode, so attached readers simply continue). False: attach as the writer of a
        segment someone else created (the env writing the daemon's camera segment).
        Either way the writer stamps its pid in the trailer and clears the shutting-down
        flag; one writer at a time is the caller's responsibility unless ``exclusive``.
    :param replace: with ``create=True``, an existing segment of another layout is unlinked
        and a new one created (readers re-attach and see the new layout). Without it that is
        a :class:`LayoutError`.
    :param attach_timeout: with ``create=False``, seconds to wait for the segment to appear.
    :param exclusive: with ``create=False``, refuse (:class:`SegmentBusyError`, naming the
        pid) when the segment already has a live writer: a process that is alive, whose pid
        is in the trailer and that has not closed the segment, or another open writer of
        this process. A writer that closed or died does not block. (Checked at attach; two
        writers attaching in the same instant can both pass.)
    :param ignore_pids: with ``exclusive``, pids whose stamp in the trailer does not count
        as a live writer: the creator of a segment it never publishes into (the daemon of a
        camera segment).
    :param check_finite: reject float frames holding NaN/inf (:class:`NonFiniteError`).
    :param checksum: store ``crc32(payload, seq)`` with every frame so readers can verify
        each copy independently of CPU memory ordering. Default: on where stores may be
        reordered (not x86), off on x86-64 where the seqlock alone is exact.

    Not thread-safe and not fork-safe: one writer object per process, used by one thread.
    """

    def __init__(
        self,
        name: str,
        shape: tuple[int, int, int] | None = None,
        dtype: Any = None,
        *,
        create: bool = True,
        replace: bool = False,
        attach_timeout: float = 0.0,
        check_finite: bool = True,
        checksum: bool | None = None,
        exclusive: bool = False,
        ignore_pids: Collection[int] = (),
    ) -> None:
        self.name = validate_name(name)
        self._closed = True
        self._pid = os.getpid()
        self._checksum = (not TOTAL_STORE_ORDER) if checksum is None else bool(checksum)
        self.created = False
        """True if this writer created the segment (False: it reused or attached to one)."""
        if create:
            if shape is None or dtype is None:
                raise TypeError(
                    f"FrameWriter({name!r}, create=True) needs shape= and dtype=; "
                    "pass create=False to attach to a segment someone else created"
                )
            layout = Layout.of(shape, dtype)
            seg = self._create_or_reuse(layout, replace)
        else:
            seg = open_waiting(self.name, True, attach_timeout)
            try:
                layout = self._existing_layout(seg, shape, dtype)
                if exclusive:
                    self._check_no_live_writer(seg, ignore_pids)
            except BaseException:
                seg.close()
                raise
        self._bind(seg, layout, check_finite)
        self._claim()
        _open_writers.add(self)

    # --- set-up ------------------------------------------------------------------------

    def _create_or_reuse(self, layout: Layout, replace: bool) -> Segment:
        for _ in range(_CREATE_ATTEMPTS):
            try:
                seg = Segment.open(self.name, True)
            except FileNotFoundError:
                created = Segment.create(
                    self.name, layout.segment_size, lambda s: _initialise(s, layout, self._pid)
                )
                if created is None:  # someone created it meanwhile: open theirs
                    continue
                self.created = True
                logger.info(
                    "created segment %s (%s, %d bytes, mode 0600)",
                    self.name, layout.describe(), layout.segment_size,
                )
                return created
            try:
                info = seg.trailer_info()
                found = info.layout.describe() if info else f"no roverav trailer, {seg.size} bytes"
            except LayoutError as exc:
                info, found = None, f"unreadable trailer ({exc})"
            if info is not None and info.layout == layout:
                logger.info(
                    "reusing segment %s (%s): attached readers continue", self.name, found
                )
                return seg
            if not replace:
                seg.close()
                raise LayoutError(
                    f"segment {self.name!r} exists with layout {found}; this writer expects "
                    f"{layout.describe()} ({layout.segment_size} bytes). Stop the processes "
                    f"using it and remove {seg.path}, or pass replace=True to replace it "
                    "(attached readers then re-attach to the new segment)."
                )
            logger.warning(
                "replacing segment %s (%s) with a new one (%s)",
                self.name, found, layout.describe(),
            )
            seg.unlink()
            seg.close()
        raise ShmError(
            f"could not create or open segment {self.name!r} after {_CREATE_ATTEMPTS} tries: "
            "another process keeps creating and removing it"
        )

    def _existing_layout(self, seg: Segment, shape: Any, dtype: Any) -> Layout:
        info = seg.trailer_info()
        if info is None:
            raise LayoutError(
                f"segment {self.name!r} has no roverav trailer ({seg.size} bytes): it was not "
                "made by FrameWriter (a seed-style segment?). FrameWriter(create=False) "
                "attaches only to segments a FrameWriter created; let the daemon create it."
            )
        layout = info.layout
        want_shape = None if shape is None else normalize_shape(shape)
        want_dtype = None if dtype is None else normalize_dtype(dtype)
        if (want_shape is not None and want_shape != layout.shape) or (
            want_dtype is not None and want_dtype != layout.dtype
        ):
            raise LayoutError(
                f"segment {self.name!r} has layout {layout.describe()}; this writer expects "
                f"{describe(want_shape or layout.shape, want_dtype or layout.dtype)}. "
                "Omit shape/dtype to adopt the segment's layout, or start the daemon with "
                "matching settings."
            )
        return layout

    def _check_no_live_writer(self, seg: Segment, ignore_pids: Collection[int]) -> None:
        """Raise :class:`SegmentBusyError` if ``seg`` has a live writer (see ``exclusive``)."""
        me = self._pid
        for other in list(_open_writers):
            oseg = other._seg
            same = oseg is not None and (oseg.ino, oseg.dev) == (seg.ino, seg.dev)
            if same and not other._closed:
                if me in ignore_pids:
                    break
                raise SegmentBusyError(
                    f"segment {self.name!r} already has a live writer in this process (pid "
                    f"{me}): an open FrameWriter on the same segment. One writer at a time: "
                    "close that writer first, or write to another segment.",
                    self.name,
                    me,
                    _command_line(me),
                )
        info = seg.trailer_info()
        pid, flags = (info.pid, info.flags) if info is not None else (0, 0)
        if (
            pid
            and pid != me
            and pid not in ignore_pids
            and not flags & FLAG_SHUTTING_DOWN
            and pid_alive(pid)
        ):
            command = _command_line(pid)
            raise SegmentBusyError(
                f"segment {self.name!r} already has a live writer: pid {pid} "
                f"({command or 'command line unknown'}), which attached as its writer and "
                "has not closed it. One writer at a time: close that writer or stop that "
                "process first, or write to another segment.",
                self.name,
                pid,
                command,
            )

    def _bind(self, seg: Segment, layout: Layout, check_finite: bool) -> None:
        self._seg: Segment | None = seg
        self.layout = layout
        self.shape: tuple[int, int, int] = layout.shape
        self.dtype: np.dtype[Any] = layout.dtype
        self._h = seg.struct_at(Header, 0)
        self._t = seg.struct_at(Trailer, layout.trailer_offset)
        self._payload: np.ndarray | None = seg.array_at(PAYLOAD_OFFSET, layout.shape, layout.dtype)
        wake_addr = seg.address + layout.wake_offset
        self._futex = FutexWord(wake_addr) if FUTEX_AVAILABLE and wake_addr % 4 == 0 else None
        self._finite = (
            np.empty(layout.shape, dtype=bool)
            if check_finite and layout.dtype.kind == "f"
            else None
        )
        self._closed = False

    def _claim(self) -> None:
        """Become the segment's writer: pid, heartbeat, flags, and repair of a torn frame."""
        t, h = self._t, self._h
        prev = t.pid
        if prev and prev != self._pid and not t.flags & FLAG_SHUTTING_DOWN and pid_alive(prev):
            logger.info(
                "segment %s: taking over as writer from pid %d (one writer at a time)",
                self.name, prev,
            )
        seq = t.seq
        if seq & 1:
            # The previous writer died between its two seq stores: the payload is half
            # written. Close the seqlock on "no complete frame" (even seq, valid 0).
            h.valid = 0
            fence()
            seq += 1
            t.seq = seq
            logger.warning(
                "segment %s: the previous writer (pid %d) stopped in the middle of a publish; "
                "its half-written frame is discarded",
                self.name, prev,
            )
        self._seq = seq
        self._last_ts = h.timestamp
        self._now = time.time()
        t.heartbeat = self._now
        t.pid = self._pid
        flags = t.flags & ~FLAG_SHUTTING_DOWN
        if self._checksum:
            if h.valid == 1:  # make the frame already there verifiable before announcing it
                assert self._payload is not None
                # (an ndarray is a buffer; numpy declares __buffer__ for Python >= 3.12 only)
                t.checksum = zlib.crc32(self._payload, seq & U32_MAX)  # type: ignore[arg-type]
            flags |= FLAG_CHECKSUM
        else:
            flags &= ~FLAG_CHECKSUM
        t.flags = flags
        self._wake()

    # --- publishing --------------------------------------------------------------------

    def publish(self, array: np.ndarray, source_seq: int = 0, *,
                episode_start: bool = False) -> int:
        """Publish one frame; returns its frame number (1, 2, 3, ... per segment).

        :param array: exactly :attr:`shape` and :attr:`dtype` (any strides). Float frames
            with NaN/inf are rejected when ``check_finite`` (the default): a NaN in a fused
            observation would poison training silently, so it fails loudly here instead.
        :param source_seq: the frame number of the input this frame was computed from (the
            camera frame's number for a fused frame); readers wait for it with ``wait_for``.
        :param episode_start: mark this frame as the first of an episode (trailer flag
            ``FLAG_EPISODE_START``, read back as ``Frame.episode_start``); every publish
            without it clears the mark.
        :raises LayoutError: wrong shape or dtype (the message names expected and found).
        :raises NonFiniteError: NaN/inf values (the message says how many and where).
        """
        if self._closed:
            raise ShmError(f"FrameWriter for segment {self.name!r} is closed")
        a = array if isinstance(array, np.ndarray) else np.asarray(array)
        if a.shape != self.shape or a.dtype != self.dtype:
            raise LayoutError(
                f"publish to segment {self.name!r}: expected an array of "
                f"{describe(self.shape, self.dtype)}, got {describe(a.shape, a.dtype)}"
            )
        if self._finite is not None:
            np.isfinite(a, out=self._finite)
            if not self._finite.all():
                raise NonFiniteError(_non_finite_message(self.name, a, self._finite))
        src = operator.index(source_seq)
        if not 0 <= src <= U64_MAX:
            raise ValueError(f"source_seq must be in 0..2**64-1, got {src}")
        seq = self._begin()
        np.copyto(self._payload, a)  # type: ignore[arg-type]
        t = self._t
        flags = t.flags
        want = (flags | FLAG_EPISODE_START) if episode_start else (flags & ~FLAG_EPISODE_START)
        if want != flags:
            t.flags = want
        self._commit(seq, src)
        return (seq + 1) >> 1

    def _begin(self) -> int:
        """First half of a publish: open the seqlock (odd seq, valid 0) and stamp the time."""
        t, h = self._t, self._h
        seq = self._seq + 1
        t.seq = seq
        h.valid = 0
        fence()
        self._now = now = time.time()
        ts = max(now, self._last_ts + 1e-6)  # strictly increasing: no two frames share a stamp
        h.timestamp = ts
        self._last_ts = ts
        return seq

    def _commit(self, seq: int, source_seq: int) -> None:
        """Second half of a publish: close the seqlock (even seq, valid 1), heartbeat, wake."""
        t, h = self._t, self._h
        if self._checksum:
            t.checksum = zlib.crc32(self._payload, (seq + 1) & U32_MAX)  # type: ignore[arg-type]
        t.source_seq = source_seq
        fence()
        t.seq = seq + 1
        h.valid = 1
        t.heartbeat = self._now
        if t.pid != self._pid:  # someone claimed the segment meanwhile (a restarted creator)
            t.pid = self._pid
        self._seq = seq + 1
        self._wake()

    def _wake(self) -> None:
        t = self._t
        t.wake = (t.wake + 1) & U32_MAX
        if self._futex is not None:
            self._futex.wake()

    def heartbeat(self) -> None:
        """Refresh the trailer's heartbeat while idle (publish refreshes it too)."""
        if self._closed:
            raise ShmError(f"FrameWriter for segment {self.name!r} is closed")
        self._t.heartbeat = time.time()

    # --- lifetime ----------------------------------------------------------------------

    @property
    def seq(self) -> int:
        """Frame number of the last frame in the segment (0: none yet)."""
        return self._seq >> 1

    @property
    def path(self) -> str:
        return segment_path(self.name)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self, unlink: bool = False) -> None:
        """Stop writing. Idempotent.

        Sets the shutting-down flag (readers raise :class:`WriterGoneError` at once, saying
        the writer shut down) if this process is still the segment's writer, or always when
        ``unlink``. ``unlink=True`` also removes the name (only if it still names this
        segment): the daemon's orderly exit. ``unlink=False`` leaves the segment for a
        restarted writer, which reuses it.
        """
        if self._closed:
            return
        self._closed = True
        seg = self._seg
        try:
            t = self._t
            if unlink or t.pid == self._pid:
                t.flags = t.flags | FLAG_SHUTTING_DOWN
                self._wake()
            if unlink and seg is not None and seg.unlink():
                logger.info("unlinked segment %s", self.name)
        finally:
            self._h = self._t = self._payload = self._futex = None
            self._seg = None
            if seg is not None:
                seg.close()

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"frame {self.seq}"
        return f"FrameWriter({self.name!r}, {describe(self.shape, self.dtype)}, {state})"


def _command_line(pid: int) -> str:
    """``pid``'s command line from ``/proc``, shortened ("" when unknown)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            raw = f.read()
    except OSError:
        return ""
    cmd = " ".join(raw.replace(b"\0", b" ").decode(errors="replace").split())
    return cmd if len(cmd) <= _CMDLINE_CHARS else cmd[: _CMDLINE_CHARS - 3] + "..."


def _initialise(seg: Segment, layout: Layout, pid: int) -> None:
    """Fill a freshly created (zeroed) segment's header and trailer."""
    h = seg.struct_at(Header, 0)
    h.timestamp = 0.0
    h.valid = 0
    t = seg.struct_at(Trailer, layout.trailer_offset)
    t.magic = MAGIC
    t.version = VERSION
    t.dtype = layout.dtype_code
    t.height, t.width, t.channels = layout.shape
    t.pid = pid
    t.seq = 0
    t.source_seq = 0
    t.heartbeat = time.time()
    t.flags = 0
    t.wake = 0
    t.checksum = 0
    t.reserved = 0


def _non_finite_message(name: str, a: np.ndarray, finite: np.ndarray) -> str:
    bad = ~finite
    n = int(bad.sum())
    nan = int(np.isnan(a).sum())
    first = ", ".join(str(tuple(int(i) for i in row)) for row in np.argwhere(bad)[:5])
    per_channel = bad.reshape(-1, a.shape[-1]).sum(axis=0)
    channels = ", ".join(f"{c}: {int(k)}" for c, k in enumerate(per_channel) if k)
    return (
        f"frame for segment {name!r} holds {n} non-finite value(s) out of {a.size} "
        f"({nan} NaN, {n - nan} +/-inf); first at (row, col, channel) {first}; "
        f"per channel {{{channels}}}. The frame was not published: a NaN in an observation "
        "poisons training silently (every gradient that touches it becomes NaN). Fix the "
        "producer, or clean the frame (np.nan_to_num) before publishing."
    )


__all__ = ["FrameWriter"]
