"""Where the daemon's camera frames come from.

A source hands the daemon new uint8 frames for its slots through :meth:`FrameSource.poll`:

- :class:`CameraSegmentSource` (``--source camera``, the default): one camera segment
  ``camera_name(slot_name(name, i))`` per slot, created by the daemon and written by the env
  (``FrameWriter(..., create=False)``); the daemon reads them. A frame's ``seq`` is the
  segment's frame sequence number, which the daemon echoes as the fused frame's
  ``source_seq``.
- :class:`OpenCVSource` (``--source video:PATH`` or ``--source device:N``): a video file
  played at its own frame rate (looping at its end; frames are skipped when perception falls
  behind, so playback keeps real time), or a camera device. Every slot gets the same frame,
  and ``seq`` counts frames from 1.
- :class:`~active_vision.bag_source.BagSource` (``--source bag:PATH[#TOPIC]``, in its own
  module: it needs ``pip install 'roverav[ros]'``): a ROS 2 bag's image topic, played like a
  video file.

:func:`source_kind` reads a ``--source`` spec (``SOURCE_SPECS``).

Frames are resized to the fused size (``INTER_AREA``) and converted to RGB by OpenCV sources;
camera segments already have the fused size (the daemon creates them that way).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from shm_protocol import (
    MULTIWAIT_AVAILABLE,
    FrameReader,
    FrameTimeoutError,
    FrameWriter,
    MultiWaiter,
    ShmError,
    WriterGoneError,
    camera_name,
    slot_name,
)

logger = logging.getLogger(__name__)


@dataclass
class SourceFrame:
    """One new camera frame for one slot."""

    slot: int
    data: np.ndarray
    """uint8 ``(S, S, 3)`` RGB or ``(S, S, 4)`` RGB + depth channel; owned by the caller."""
    seq: int
    """Sequence number of the camera frame (the fused frame's ``source_seq``)."""
    episode_start: bool = False
    """The env marked this frame as its episode's first (``Frame.episode_start``)."""
    row: int = 0
    """Row of the source's ``frames_buffer`` that ``data`` is (camera segment sources)."""


class SourceError(RuntimeError):
    """A frame source cannot be opened or read."""


CAMERA_KIND = "camera"
VIDEO_KIND = "video"
DEVICE_KIND = "device"
BAG_KIND = "bag"
SOURCE_SPECS = "camera, video:PATH, device:N or bag:PATH[#TOPIC]"
"""The source specs ``av-daemon --source`` takes."""


def source_kind(spec: str) -> str:
    """The kind of a source spec: ``CAMERA_KIND``, ``VIDEO_KIND``, ``DEVICE_KIND`` or
    ``BAG_KIND``; :class:`SourceError` naming ``SOURCE_SPECS`` for anything else."""
    if spec == CAMERA_KIND:
        return CAMERA_KIND
    kind, sep, arg = spec.partition(":")
    if sep and arg and kind in (VIDEO_KIND, DEVICE_KIND, BAG_KIND):
        return kind
    raise SourceError(f"unknown source {spec!r}: expected {SOURCE_SPECS}")


class FrameSource(Protocol):
    """What the daemon needs from a source of camera frames."""

    slots: int
    channels: int

    def poll(self, timeout: float) -> list[SourceFrame]:
        """New frames (at most one per slot), waiting up to ``timeout`` s for the first."""
        ...

    def close(self) -> None:
        """Release the source (segments it created are unlinked by ``unlink``)."""
        ...


class OpenCVSource:
    """Frames from a video file (at its frame rate) or a camera device, for every slot.

    :param spec: ``video:PATH`` or ``device:N``.
    :param slots: number of slots that each get every frame.
    :param size: side of the square frames handed out.
    :param loop: start a video again at its end (else :meth:`poll` returns nothing more and
        :attr:`finished` becomes True).
    """

    channels = 3

    def __init__(self, spec: str, slots: int, size: int, loop: bool = True) -> None:
        kind, _, arg = spec.partition(":")
        self.slots = slots
        self.size = size
        self.loop = loop
        self.finished = False
        self.is_video = kind == "video"
        if kind == "video":
            path = Path(arg)
            if not path.is_file():
                raise SourceError(f"--source {spec}: no video file at {path}")
            self._cap = cv2.VideoCapture(str(path))
        elif kind == "device":
            try:
                index = int(arg)
            except ValueError as exc:
                raise SourceError(f"--source {spec}: expected device:N with N an integer") from exc
            self._cap = cv2.VideoCapture(index)
        else:
            raise SourceError(f"unknown source {spec!r}: use camera, video:PATH or device:N")
        if not self._cap.isOpened():
            raise SourceError(f"OpenCV cannot open {spec}")
        fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if 0.5 < fps < 1000 else 30.0
        self.spec = spec
        self._seq = 0
        self._index = 0  # frames of the video consumed since _t0
        self._t0: float | None = None
        logger.info("source %s: %.1f fps", spec, self.fps)

    def _read(self) -> np.ndarray | None:
        ok, bgr = self._cap.read()
        if ok:
            return bgr
        if not (self.is_video and self.loop):
            return None
        logger.info("source %s: end of video, starting again", self.spec)
        self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        ok, bgr = self._cap.read()
        return bgr if ok else None

    def poll(self, timeout: float) -> list[SourceFrame]:
        if self.finished:
            time.sleep(timeout)
            return []
        if self.is_video:
            now = time.monotonic()
            if self._t0 is None:
                self._t0 = now
            due = self._t0 + self._index / self.fps
            if due > now:
                if due - now > timeout:
                    time.sleep(timeout)
                    return []
                time.sleep(due - now)
                now = due
            # behind by more than a frame: skip frames to stay in real time
            behind = int((now - self._t0) * self.fps) - self._index
            for _ in range(max(0, behind)):
                if not self._cap.grab():
                    break
                self._index += 1
            self._index += 1
        bgr = self._read()
        if bgr is None:
            self.finished = True
            logger.info("source %s: no more frames", self.spec)
            return []
        if bgr.ndim == 2:
            bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
        small = cv2.resize(bgr[..., :3], (self.size, self.size), interpolation=cv2.INTER_AREA)
        rgb = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
        self._seq += 1
        return [SourceFrame(i, rgb, self._seq) for i in range(self.slots)]

    def close(self) -> None:
        self._cap.release()


class CameraSegmentSource:
    """Camera segments for ``slots`` slots: created (or taken over) here, written by envs.

    For slot i the segment ``camera_name(slot_name(name, i))`` holds uint8
    ``(size, size, channels)`` frames (3: RGB; 4: RGB + rendered depth channel). The daemon
    creates each with ``FrameWriter(create=True)`` - reusing a segment of the same layout left
    by a dead daemon in place, so an attached env keeps writing - and never publishes into
    it: the env attaches as its writer (``FrameWriter(..., create=False)``). A
    :class:`FrameReader` per slot receives the frames.

    ``slot_ids`` (default: every slot) makes a source for some of the slots only: a daemon
    worker serves those (:class:`SourceFrame` ``slot`` is the slot's id; ``row`` its row of
    ``frames_buffer``, in ``slot_ids`` order).

    Waiting (:meth:`poll`): every slot is first looked at without blocking
    (``FrameReader.next_frame`` into a preallocated buffer: a copy only when there is a new
    frame); when none has a new frame, the call sleeps. With several slots where Linux
    has ``futex_waitv`` (5.16+) it sleeps on every slot's wake word at once
    (:class:`shm_protocol.MultiWaiter`), so any slot's frame wakes it at once. Otherwise it
    sleeps on one slot's futex (``wait_next``), rotating over the slots that have a live
    writer, in slices of at most ``slice_s`` (1 slot: the whole timeout), then looks at
    every slot again. After
    ``IDLE_AFTER_S`` without any frame the slices grow to ``idle_slice_s`` (a woken slot
    still answers at once; a frame on another slot waits at most one slice). Slots whose env
    has gone (closed or died) are only looked at, never waited on, until a frame arrives.

    ``spin`` (seconds): a one-slot source watches its slot's wake word that long before it
    sleeps (``FrameReader(spin=...)``), so a frame that comes meanwhile is taken without a
    futex wake-up; the daemon sets it where there are two cores for each env slot on the
    machine (``shm_protocol.machine_spin``).
    """

    IDLE_AFTER_S = 1.0

    def __init__(self, name: str, slots: int, size: int, channels: int,
                 slice_s: float = 0.002, idle_slice_s: float = 0.05,
                 slot_ids: Sequence[int] | None = None, spin: float = 0.0) -> None:
        self.slot_ids = list(range(slots)) if slot_ids is None else list(slot_ids)
        if not self.slot_ids or not all(0 <= i < slots for i in self.slot_ids):
            raise ValueError(f"slot_ids must be a non-empty subset of 0..{slots - 1}, "
                             f"got {slot_ids}")
        slots = len(self.slot_ids)
        self.slots = slots
        self.channels = channels
        self.names = [camera_name(slot_name(name, i)) for i in self.slot_ids]
        self.slice_s = slice_s
        self.idle_slice_s = idle_slice_s
        self._last_frame = time.monotonic()
        self.writers: list[FrameWriter] = []
        self.readers: list[FrameReader] = []
        try:
            for seg in self.names:
                w = FrameWriter(seg, shape=(size, size, channels), dtype=np.uint8, create=True,
                                replace=True)
                self.writers.append(w)
                self.readers.append(FrameReader(seg, spin=spin))
        except BaseException:
            self.close(unlink=True)
            raise
        self.reused = [not w.created for w in self.writers]
        self.frames_buffer = np.empty((slots, size, size, channels), dtype=np.uint8)
        """Row i holds the newest frame of ``slot_ids[i]``: the daemon runs perception on
        consecutive rows directly (no gathering copy)."""
        # One SourceFrame per slot and one result list, reused by every poll (the serve
        # loop makes no SourceFrame or list per frame); a result is valid until the next poll.
        self._frames = [SourceFrame(slot, self.frames_buffer[i], 0, row=i)
                        for i, slot in enumerate(self.slot_ids)]
        self._new: list[SourceFrame] = []
        # A frame already in a reused segment may be one the dead daemon never answered
        # (an env may still wait for it): it is handed out once more.
        self._done = [0] * slots
        self._writer_gone = [False] * slots
        self._live = list(range(slots))
        self._turn = 0
        # Several slots: sleep on all their wake words at once (futex_waitv), so a frame on
        # any slot wakes the daemon at once; else rotate slices over the slots.
        self._watch: MultiWaiter | None = None
        if slots > 1 and MULTIWAIT_AVAILABLE and all(
                r.wake_address is not None for r in self.readers):
            self._watch = MultiWaiter(self.readers)

    def _take(self, i: int, seq: int, episode_start: bool = False) -> None:
        self._done[i] = seq
        if self._writer_gone[i]:
            self._writer_gone[i] = False
            self._live = [j for j in range(self.slots) if not self._writer_gone[j]]
        frame = self._frames[i]
        frame.seq = seq
        frame.episode_start = episode_start
        self._new.append(frame)

    def _collect(self, skip: int = -1) -> list[SourceFrame]:
        # next_frame copies only a frame newer than the reader's last: an unchanged slot
        # costs a look at its seq, not a copy
        buf, done = self.frames_buffer, self._done
        for i, r in enumerate(self.readers):
            if i == skip:
                continue
            f = r.next_frame(out=buf[i])
            if f is not None and f.seq != done[i]:
                self._take(i, f.seq, f.episode_start)
        if skip >= 0:  # the woken slot first, so slot order matches the buffer's rows
            self._new.sort(key=_row_of)
        return self._new

    def poll(self, timeout: float) -> list[SourceFrame]:
        """New frames, at most one per slot (see the class docstring). The list and its
        :class:`SourceFrame` objects are reused: valid until the next call."""
        self._new.clear()
        watch = self._watch
        if watch is not None:
            watch.arm()  # before looking: a frame published after this ends the wait at once
            frames = self._collect()
            if frames:
                self._last_frame = time.monotonic()
                return frames
            watch.wait(timeout)
            return self._collect()
        frames = self._collect()
        now = time.monotonic()
        if frames:
            self._last_frame = now
            return frames
        live = self._live
        if not live:
            time.sleep(min(timeout, 0.02))
            return self._collect()
        self._turn = (self._turn + 1) % len(live)
        i = live[self._turn]
        idle = now - self._last_frame > self.IDLE_AFTER_S
        wait = timeout if self.slots == 1 else min(
            timeout, self.idle_slice_s if idle else self.slice_s)
        try:
            f = self.readers[i].wait_next(timeout=wait, out=self.frames_buffer[i])
        except FrameTimeoutError:
            return self._collect()
        except WriterGoneError as exc:
            logger.info("slot %d: camera writer gone (%s); waiting for an env to attach",
                        self.slot_ids[i], exc.reason)
            self._gone(i)
            return self._collect()
        except ShmError as exc:
            logger.warning("slot %d: %s", self.slot_ids[i], exc)
            self._gone(i)
            return self._collect()
        self._last_frame = time.monotonic()
        if f.seq != self._done[i]:
            self._take(i, f.seq, f.episode_start)
        # the woken slot's frame is already copied: look only at the other slots
        return self._collect(skip=i) if self.slots > 1 else self._new

    def _gone(self, i: int) -> None:
        self._writer_gone[i] = True
        self._live = [j for j in range(self.slots) if not self._writer_gone[j]]

    def close(self, unlink: bool = False) -> None:
        """Close readers and writers; ``unlink`` removes the camera segments."""
        for r in self.readers:
            r.close()
        for w in self.writers:
            w.close(unlink=unlink)


def _row_of(frame: SourceFrame) -> int:
    return frame.row


__all__ = [
    "BAG_KIND",
    "CAMERA_KIND",
    "DEVICE_KIND",
    "SOURCE_SPECS",
    "VIDEO_KIND",
    "CameraSegmentSource",
    "FrameSource",
    "OpenCVSource",
    "SourceError",
    "SourceFrame",
    "source_kind",
]
