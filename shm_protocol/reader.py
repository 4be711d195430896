"""FrameReader: attach to a segment and receive its frames, copied out.

Reading is the other half of the seqlock (see writer.py)::

    s1 = seq            (odd: a publish is in progress -> wait)
    new?                (s1 > last returned; or source_seq >= k for wait_for)
    copy payload
    re-read valid, timestamp, seq   (any change: the copy may be torn -> retry)
    [checksum mode: crc32(copy, s1) == trailer checksum, else retry]

Waiting sleeps on the trailer's futex word with short timeouts (falls back to 1 ms polling
where there is no futex), and every ``LIVENESS_INTERVAL_S`` checks that the writer is
alive and that the name still refers to this segment (re-attaching when it was replaced).

A segment without a trailer (written by a seed-style peer) is read by the seed's rule: a
frame is new when the timestamp changed and ``valid == 1``; there is no liveness or
``source_seq`` then.
"""

from __future__ import annotations

import logging
import os
import time
import zlib
from typing import Any, NamedTuple

import numpy as np

from ._futex import AVAILABLE as FUTEX_AVAILABLE
from ._futex import FutexWord, fence
from ._segment import Segment, open_waiting, pid_alive
from .errors import FrameTimeoutError, LayoutError, ShmError, WriterGoneError
from .layout import (
    FLAG_CHECKSUM,
    FLAG_EPISODE_START,
    FLAG_SHUTTING_DOWN,
    PAYLOAD_OFFSET,
    U32_MAX,
    Header,
    Layout,
    Trailer,
    describe,
    normalize_dtype,
    normalize_shape,
)
from .names import camera_segments, validate_name

logger = logging.getLogger(__name__)

LIVENESS_INTERVAL_S = 0.1
"""How often a waiting reader checks the writer's pid/heartbeat and the segment's name."""
WAIT_SLICE_S = 0.02
"""Longest single futex sleep: bounds the cost of a wake-up that never comes."""
POLL_INTERVAL_S = 0.001
"""Sleep between looks where there is no futex (seed-style segments): the seed's 1 ms."""
MAX_TEAR_RETRIES = 1000
"""Copies retried in one read before giving up on it for now (a writer flat out)."""
SPIN_S = 0.003
"""The spin (``FrameReader(spin=...)``) of an env and a daemon worker waiting on each other
where :func:`spin_for` allows it: longer than a frame's round trip through the daemon at
either precision and than an env's step between frames (benchmarks/RESULTS.md, "RoverEnvFused
and fused training speed")."""


SPIN_PAUSE_S = 1.0
"""How long a reader sleeps at once after its spins stopped paying (see ``FrameReader``)."""
_SPIN_EMA = 0.1  # weight of the latest spin in the reader's running share of failed spins
_SPIN_GIVE_UP = 0.5  # that share at which it pauses spinning for SPIN_PAUSE_S


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def spin_for(slots: int, cores: int | None = None) -> float:
    """The spin for the waits of av-daemons serving ``slots`` envs in all and of those
    envs: :data:`SPIN_S` when there are at least two cores per slot (``cores``: those this
    process may run on), one for each env and one for its daemon worker, so that watching
    for a frame takes no core from anyone; else 0 (sleep at once)."""
    if cores is None:
        cores = available_cores()
    return SPIN_S if 2 * max(slots, 1) <= cores else 0.0


def machine_spin(own_slots: int) -> float:
    """:func:`spin_for` the env slots of every av-daemon on this machine (its camera
    segments, and at least ``own_slots``): two rover-pairs or Ray workers on one machine
    count each other's envs."""
    return spin_for(max(own_slots, camera_segments()))


class Frame(NamedTuple):
    """One frame, copied out of the segment.

    :ivar data: ``(H, W, C)`` array owned by the caller (the ``out`` array if one was given).
    :ivar timestamp: the writer's ``time.time()`` at publish (seconds since the epoch).
    :ivar seq: frame number in this segment (1, 2, ...); for a seed-style segment, the
        count of distinct frames this reader has seen.
    :ivar source_seq: frame number of the input it was computed from (0 if none/seed-style).
    :ivar episode_start: the writer marked this frame as the first of an episode
        (``FLAG_EPISODE_START``; always False for seed-style segments).
    """

    data: np.ndarray
    timestamp: float
    seq: int
    source_seq: int
    episode_start: bool = False


class FrameReader:
    """Attach to segment ``name`` and read its frames.

    :param name: segment name.
    :param shape: expected ``(H, W, C)``; checked against the trailer (:class:`LayoutError`
        naming both on mismatch). Omitted: taken from the trailer (``.shape``). Required
        for a seed-style segment, which has no trailer to take it from.
    :param dtype: expected dtype, same rules.
    :param attach_timeout: seconds to wait for the segment to appear (0: fail at once with
        :class:`SegmentNotFoundError`).
    :param stale_after: if set, a writer whose heartbeat is older than this many seconds
        counts as gone (:class:`WriterGoneError`). Leave None for writers that do not
        heartbeat while idle (the env writing camera frames between episodes).
    :param check_pid: treat a vanished writer pid as gone. Turn off only when the writer
        lives in another pid namespace (another container), where its pid means nothing.
    :param spin: seconds a :meth:`wait_next` / :meth:`wait_for` call watches the segment's
        wake word in a busy loop before it sleeps on the futex (once per call; 0, the
        default, sleeps at once). A frame that comes within the spin is taken without a
        wake-up (tens of microseconds on a VM, and the core's caches cool while it sleeps),
        at the price of a busy core meanwhile: use it where the waiting thread has a core to
        itself. Settable later as the ``spin`` attribute. A spin fails when the frame came
        only after it (in the same call) or when the thread was kept off its core for a fifth
        of it (another thread wanted the core); a call that ends with no frame at all (an
        idle writer) does not count. Once half the recent spins (a running share) failed, the
        reader sleeps at once for ``SPIN_PAUSE_S`` and then tries again (``spin_paused``).

    Not thread-safe: use one reader per thread.
    """

    _recheck = True  # tests turn this off on an instance to prove torn reads are detected

    def __init__(
        self,
        name: str,
        shape: tuple[int, int, int] | None = None,
        dtype: Any = None,
        *,
        attach_timeout: float = 0.0,
        stale_after: float | None = None,
        check_pid: bool = True,
        spin: float = 0.0,
    ) -> None:
        self.name = validate_name(name)
        if not spin >= 0:
            raise ValueError(f"spin must be >= 0 seconds, got {spin!r}")
        self.spin = float(spin)
        self._spin_failures = 0.0  # running share of failed spins
        self._spin_paused_until = 0.0
        self._want_shape = None if shape is None else normalize_shape(shape)
        self._want_dtype = None if dtype is None else normalize_dtype(dtype)
        if stale_after is not None and not stale_after > 0:
            raise ValueError(f"stale_after must be > 0 seconds or None, got {stale_after!r}")
        self.stale_after = stale_after
        self.check_pid = check_pid
        self._closed = True
        self._seg: Segment | None = None
        self.layout: Layout | None = None
        self._last_seq = 0
        self._last_ts: float | None = None
        self._seed_count = 0
        self._next_check = 0.0
        self._tears = 0
        self._attach(open_waiting(self.name, False, attach_timeout))

    # --- attaching ---------------------------------------------------------------------

    def _attach(self, seg: Segment) -> None:
        """Bind to ``seg`` (first attach or a re-attach); closes ``seg`` on any error."""
        try:
            info = seg.trailer_info()
            if info is not None:
                layout = info.layout
                self._check_layout(layout)
            else:
                shape = self._want_shape or (self.layout.shape if self.layout else None)
                dtype = self._want_dtype or (self.layout.dtype if self.layout else None)
                if shape is None or dtype is None:
                    raise LayoutError(
                        f"segment {self.name!r} has no roverav trailer ({seg.size} bytes): it "
                        "looks like a seed-style writer's segment, whose layout cannot be read "
                        "from it; pass shape= and dtype= (the seed's fused frame: "
                        "shape=(96, 96, 3), dtype=np.float32)"
                    )
                layout = Layout.of(shape, dtype)
                self._check_layout(layout)
                if seg.size < layout.seed_size:
                    raise LayoutError(
                        f"segment {self.name!r} has {seg.size} bytes; a {layout.describe()} "
                        f"frame needs {layout.seed_size} (12-byte header + payload), or "
                        f"{layout.segment_size} with a roverav trailer"
                    )
                logger.warning(
                    "segment %s has no roverav trailer: reading it by the seed's rule (new "
                    "frame = timestamp changed and valid == 1); no writer liveness, no "
                    "source_seq", self.name,
                )
        except BaseException:
            seg.close()
            raise
        old = self._seg
        self._seg = seg
        self.layout = layout
        self.shape: tuple[int, int, int] = layout.shape
        self.dtype: np.dtype[Any] = layout.dtype
        self._h = seg.struct_at(Header, 0)
        self._t = seg.struct_at(Trailer, layout.trailer_offset) if info is not None else None
        self._payload: np.ndarray | None = seg.array_at(PAYLOAD_OFFSET, layout.shape, layout.dtype)
        wake_addr = seg.address + layout.wake_offset
        self._futex = (
            FutexWord(wake_addr)
            if info is not None and FUTEX_AVAILABLE and wake_addr % 4 == 0
            else None
        )
        if info is not None and self._futex is None:
            logger.info("segment %s: no futex here; waiting polls every 1 ms", self.name)
        self._last_seq = 0
        self._last_ts = None
        self._closed = False
        if old is not None:
            old.close()

    def _check_layout(self, layout: Layout) -> None:
        want_shape = self._want_shape or (self.layout.shape if self.layout else None)
        want_dtype = self._want_dtype or (self.layout.dtype if self.layout else None)
        if (want_shape is not None and want_shape != layout.shape) or (
            want_dtype is not None and want_dtype != layout.dtype
        ):
            expected = describe(want_shape or layout.shape, want_dtype or layout.dtype)
            if self.layout is None:
                where, fix = "", "or omit shape/dtype to take the segment's layout"
            else:
                where, fix = " (after it was replaced)", "or open a new FrameReader"
            raise LayoutError(
                f"segment {self.name!r}{where} holds {layout.describe()} frames; this reader "
                f"expects {expected}. Start the writer with matching settings, {fix}."
            )

    def _try_reattach(self) -> bool:
        """If the name now refers to another segment, attach to it. True if it did."""
        try:
            seg = Segment.open(self.name, False)
        except (FileNotFoundError, LayoutError):  # gone again, or still being created
            return False
        assert self._seg is not None
        if seg.ino == self._seg.ino and seg.dev == self._seg.dev:
            seg.close()
            return False
        self._attach(seg)
        logger.info("segment %s was replaced; re-attached to the new one", self.name)
        return True

    # --- reading -----------------------------------------------------------------------

    def _read(self, out: np.ndarray | None, newer: bool, min_src: int | None) -> Frame | None:
        """One consistent copy of the current frame, or None if there is none to return."""
        t = self._t
        if t is None:
            return self._read_seed(out, newer)
        h, payload, dst = self._h, self._payload, out
        assert payload is not None  # only close() clears it, and reads check _closed first
        for _ in range(MAX_TEAR_RETRIES):
            s1 = t.seq
            if s1 & 1 or s1 == 0:
                return None  # a publish is in progress, or nothing published yet
            if newer and s1 <= self._last_seq:
                return None
            ts = h.timestamp
            src = t.source_seq
            if h.valid != 1:
                return None  # after a writer crash: no complete frame until the next publish
            if min_src is not None and src < min_src:
                if t.seq == s1:
                    return None  # a consistent look: that input's frame is not there yet
                continue
            if dst is None:
                dst = np.empty(self.shape, self.dtype)
            fence()
            np.copyto(dst, payload)
            fence()
            flags, crc = t.flags, t.checksum  # inside the bracket: the checksum of frame s1
            if self._recheck and (h.valid != 1 or h.timestamp != ts or t.seq != s1):
                self._tears += 1
                continue
            # (an ndarray is a buffer; numpy declares __buffer__ for Python >= 3.12 only)
            if flags & FLAG_CHECKSUM and zlib.crc32(dst, s1 & U32_MAX) != crc:  # type: ignore[arg-type]
                self._tears += 1
                continue
            self._last_seq = s1
            return Frame(dst, ts, s1 >> 1, src, bool(flags & FLAG_EPISODE_START))
        logger.debug("segment %s: %d torn copies in a row", self.name, MAX_TEAR_RETRIES)
        return None

    def _read_seed(self, out: np.ndarray | None, newer: bool) -> Frame | None:
        """The seed's rule: timestamp changed and valid == 1; plus our re-check."""
        h, payload, dst = self._h, self._payload, out
        assert payload is not None  # only close() clears it, and reads check _closed first
        for _ in range(MAX_TEAR_RETRIES):
            ts = h.timestamp
            if h.valid != 1:
                return None
            if newer and ts == self._last_ts:
                return None
            if dst is None:
                dst = np.empty(self.shape, self.dtype)
            fence()
            np.copyto(dst, payload)
            fence()
            if self._recheck and (h.valid != 1 or h.timestamp != ts):
                self._tears += 1
                continue
            if ts != self._last_ts:
                self._seed_count += 1
                self._last_ts = ts
            return Frame(dst, ts, self._seed_count, 0)
        return None

    def _check_out(self, out: np.ndarray | None) -> None:
        if self._closed:
            raise ShmError(f"FrameReader for segment {self.name!r} is closed")
        if out is not None and (
            not isinstance(out, np.ndarray)
            or out.shape != self.shape
            or out.dtype != self.dtype
            or not out.flags.c_contiguous
            or not out.flags.writeable
        ):
            found = describe(out.shape, out.dtype) if isinstance(out, np.ndarray) else type(out)
            raise LayoutError(
                f"out= for segment {self.name!r} must be a writeable C-contiguous "
                f"{describe(self.shape, self.dtype)} array, got {found}"
            )

    def wait_next(self, timeout: float = 2.0, out: np.ndarray | None = None) -> Frame:
        """Block until a frame newer than the last one returned is there; return a copy.

        Frames are not queued: this returns the newest frame, skipping any that were
        overwritten meanwhile. The first call returns the frame already in the segment.

        :param timeout: seconds to wait.
        :param out: array to copy into (no allocation); else a new array per frame.
        :raises WriterGoneError: the writer died, went stale, or shut down (promptly, not
            at the end of the timeout).
        :raises FrameTimeoutError: no new frame within ``timeout`` while the writer lives.
        """
        return self._wait(timeout, out, None)

    def wait_for(
        self, source_seq: int, timeout: float = 2.0, out: np.ndarray | None = None
    ) -> Frame:
        """Block until the frame computed from input ``source_seq`` (or a later one) is there.

        Returns the current frame if its ``source_seq >= source_seq``, even when it was
        returned before. Same errors as :meth:`wait_next`.
        """
        if self._t is None and not self._closed:
            raise LayoutError(
                f"segment {self.name!r} has no roverav trailer (seed-style writer), so its "
                "frames carry no source_seq; use wait_next()"
            )
        return self._wait(timeout, out, int(source_seq))

    def next_frame(self, out: np.ndarray | None = None) -> Frame | None:
        """The newest frame if it is newer than the last one returned, else None; never
        blocks (what :meth:`wait_next` returns, without waiting). For a process that waits
        on several segments at once (:class:`~shm_protocol.multiwait.MultiWaiter`)."""
        self._check_out(out)
        f = self._read(out, True, None)
        if f is None and time.monotonic() >= self._next_check:
            self._next_check = time.monotonic() + LIVENESS_INTERVAL_S
            if self._seg is not None and self._seg.replaced() and self._try_reattach():
                f = self._read(out, True, None)
        return f

    @property
    def wake_address(self) -> int | None:
        """Address of the segment's futex wake word in this process (None: no futex)."""
        fw = self._futex
        return None if fw is None or self._closed else fw.address

    @property
    def wake_value(self) -> int:
        """The wake word's current value (0 without a trailer)."""
        t = self._t
        return 0 if t is None or self._closed else int(t.wake)

    def latest(self, out: np.ndarray | None = None) -> Frame | None:
        """The newest complete frame (even one returned before), or None; never blocks."""
        self._check_out(out)
        f = self._read(out, False, None)
        if f is None and time.monotonic() >= self._next_check:
            self._next_check = time.monotonic() + LIVENESS_INTERVAL_S
            if self._seg is not None and self._seg.replaced() and self._try_reattach():
                f = self._read(out, False, None)
        return f

    def _wait(self, timeout: float, out: np.ndarray | None, min_src: int | None) -> Frame:
        self._check_out(out)
        newer = min_src is None
        deadline = time.monotonic() + timeout
        spin_end = 0.0
        if self.spin > 0.0 and not self.spin_paused:
            spin_end = min(time.monotonic() + self.spin, deadline)
        missed = False  # a spin ended without a frame: a failure if one comes in this wait
        while True:
            t, fw = self._t, self._futex
            # read before looking: no lost wake-up (a futex is only set with a trailer)
            wake = t.wake if fw is not None and t is not None else 0
            f = self._read(out, newer, min_src)
            if f is not None:
                if missed:
                    self._judge_spin(failed=True)
                return f
            now = time.monotonic()
            shutdown = t is not None and t.flags & FLAG_SHUTTING_DOWN
            if shutdown or now >= self._next_check:
                self._next_check = now + LIVENESS_INTERVAL_S
                assert self._seg is not None
                if self._seg.replaced() and self._try_reattach():
                    continue
                gone = self._gone()
                if gone is not None:
                    reason, message = gone
                    assert self._t is not None  # _gone() found a writer to be gone
                    raise WriterGoneError(message, self.name, self._t.pid, reason)
            if now >= deadline:
                raise FrameTimeoutError(self._timeout_message(timeout, min_src), self.name, timeout)
            if spin_end and fw is not None and t is not None:
                clock = time.monotonic
                w0, c0 = clock(), time.thread_time()
                while t.wake == wake and clock() < spin_end:
                    pass  # watch the wake word: no futex wake-up for a frame that comes now
                w1 = clock()
                woken = t.wake != wake
                off_core = time.thread_time() - c0 < 0.8 * (w1 - w0)  # another thread wanted it
                if off_core or woken:
                    self._judge_spin(failed=off_core)
                if w1 >= spin_end or self.spin_paused:
                    # counted once: judged above if kept off the core, else when a frame comes
                    missed = not (woken or off_core or self.spin_paused)
                    spin_end = 0.0  # the rest of this wait sleeps
                continue
            pause = min(deadline, self._next_check) - now
            if fw is not None:
                fw.wait(wake, min(pause, WAIT_SLICE_S))
            else:
                time.sleep(min(pause, POLL_INTERVAL_S))

    @property
    def spin_paused(self) -> bool:
        """True while the reader sleeps at once because its recent spins did not pay."""
        return time.monotonic() < self._spin_paused_until

    def _judge_spin(self, failed: bool) -> None:
        """Count one spin that paid or ``failed`` (the frame came after it, or the thread
        was kept off its core); pause spinning once half the recent ones failed. A spin that
        ends a wait with no frame at all (an idle writer) counts neither way."""
        share = (1.0 - _SPIN_EMA) * self._spin_failures + _SPIN_EMA * failed
        if share >= _SPIN_GIVE_UP:
            self._spin_paused_until = time.monotonic() + SPIN_PAUSE_S
            share = 0.0
            logger.debug("%s: spins stopped paying; sleeping at once for %.1f s", self.name,
                         SPIN_PAUSE_S)
        self._spin_failures = share

    # --- liveness ----------------------------------------------------------------------

    def _gone(self) -> tuple[str, str] | None:
        """(reason, message) if the writer is gone, else None (also for seed-style)."""
        t = self._t
        if t is None:
            return None
        pid = t.pid
        who = f"the writer of segment {self.name!r} (pid {pid})"
        restart = (
            "This reader receives frames again once a writer is back on the same name "
            "(av-daemon for a fused segment; rover-pair restarts it)."
        )
        if t.flags & FLAG_SHUTTING_DOWN:
            return "shutdown", (
                f"{who} shut down in an orderly way: it closed the segment (for a fused "
                f"segment: the daemon shut down). {restart}"
            )
        if self.check_pid and pid and not pid_alive(pid):
            return "exited", (
                f"{who} is gone: the process exited or was killed without closing the "
                f"segment. {restart}"
            )
        if self.stale_after is not None:
            age = time.time() - t.heartbeat
            if age > self.stale_after:
                age = time.time() - t.heartbeat  # look twice before condemning a writer
                if age > self.stale_after:
                    return "stale", (
                        f"{who} looks hung: its last heartbeat was {age:.2f} s ago, over the "
                        f"stale_after bound of {self.stale_after:g} s. {restart}"
                    )
        return None

    def is_writer_alive(self) -> bool:
        """Whether the writer looks alive (pid exists, heartbeat fresh if ``stale_after``,
        not shut down). True for a seed-style segment, which carries no liveness."""
        if self._closed:
            raise ShmError(f"FrameReader for segment {self.name!r} is closed")
        assert self._seg is not None
        if self._seg.replaced():
            try:
                self._try_reattach()
            except ShmError:
                return False
        return self._gone() is None

    @property
    def writer_pid(self) -> int | None:
        """The pid in the trailer (None for a seed-style segment)."""
        if self._closed or self._t is None:
            return None
        return int(self._t.pid)

    @property
    def has_trailer(self) -> bool:
        """False for a seed-style segment (seed rule, no liveness, no source_seq)."""
        return self._t is not None

    @property
    def last_seq(self) -> int:
        """Frame number of the last frame returned (0: none yet)."""
        return self._last_seq >> 1 if self._t is not None else self._seed_count

    def _timeout_message(self, timeout: float, min_src: int | None) -> str:
        what = f"with source_seq >= {min_src}" if min_src is not None else "newer than the last"
        parts = [f"no frame {what} on segment {self.name!r} within {timeout:g} s."]
        t = self._t
        if t is None:
            parts.append("The segment is seed-style (no trailer): no liveness information.")
        else:
            seq, src = t.seq, t.source_seq
            ts_age = time.time() - self._h.timestamp
            if seq >= 2:
                parts.append(
                    f"Last frame published: #{seq >> 1} (source_seq {src}), {ts_age:.2f} s ago."
                )
            else:
                parts.append("Nothing has been published on it yet.")
            hb_age = time.time() - t.heartbeat
            parts.append(
                f"Its writer (pid {t.pid}) is alive, last heartbeat {hb_age:.2f} s ago: it is "
                "running but not publishing. Is its input stalled (for a fused segment: is "
                "the env publishing camera frames, and does the daemon see them)?"
            )
        assert self._seg is not None
        if self._seg.replaced() and not self._seg.name_exists():
            parts.append(f"The segment has been removed from /dev/shm ({self._seg.path}).")
        return " ".join(parts)

    # --- lifetime ----------------------------------------------------------------------

    def close(self) -> None:
        """Unmap the segment (never unlinks it). Idempotent."""
        if self._closed and self._seg is None:
            return
        self._closed = True
        self._h = self._t = self._payload = self._futex = None
        seg, self._seg = self._seg, None
        if seg is not None:
            seg.close()

    def __enter__(self) -> FrameReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        if self.layout is None:
            return f"FrameReader({self.name!r}, unattached)"
        state = "closed" if self._closed else f"last frame {self.last_seq}"
        return f"FrameReader({self.name!r}, {self.layout.describe()}, {state})"


def writer_alive(name: str) -> bool:
    """True when a live process writes segment ``name`` (its trailer's pid and heartbeat);
    False when the segment is missing, unreadable, or its writer is gone."""
    try:
        reader = FrameReader(name, attach_timeout=0.0)
    except (ShmError, OSError, ValueError):
        return False
    try:
        return bool(reader.is_writer_alive())
    finally:
        reader.close()


__all__ = ["Frame", "FrameReader", "writer_alive"]
