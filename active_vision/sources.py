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

Frames are resized to the fused size (``INTER_AREA``) and converted to RGB by OpenCV sources;
camera segments already have the fused size (the daemon creates them that way).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from shm_protocol import (
    FrameReader,
    FrameTimeoutError,
    FrameWriter,
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


class SourceError(RuntimeError):
    """A frame source cannot be opened or read."""


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

    Waiting (:meth:`poll`): every slot is first looked at without blocking
    (``FrameReader.latest`` into a preallocated buffer, compared with the last frame number
    handed out); when none has a new frame, the call sleeps on one slot's futex
    (``wait_next``), rotating over the slots that have a live writer, in slices of at most
    ``slice_s`` (1 slot: the whole timeout), then looks at every slot again. After
    ``IDLE_AFTER_S`` without any frame the slices grow to ``idle_slice_s`` (a woken slot
    still answers at once; a frame on another slot waits at most one slice). Slots whose env
    has gone (closed or died) are only looked at, never waited on, until a frame arrives.
    """

    IDLE_AFTER_S = 1.0

    def __init__(self, name: str, slots: int, size: int, channels: int,
                 slice_s: float = 0.002, idle_slice_s: float = 0.05) -> None:
        self.slots = slots
        self.channels = channels
        self.names = [camera_name(slot_name(name, i)) for i in range(slots)]
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
                self.readers.append(FrameReader(seg))
        except BaseException:
            self.close(unlink=True)
            raise
        self.reused = [not w.created for w in self.writers]
        self._buf = np.empty((slots, size, size, channels), dtype=np.uint8)
        # A frame already in a reused segment may be one the dead daemon never answered
        # (an env may still wait for it): it is handed out once more.
        self._done = [0] * slots
        self._writer_gone = [False] * slots
        self._turn = 0

    def _collect(self) -> list[SourceFrame]:
        out = []
        for i, r in enumerate(self.readers):
            f = r.latest(out=self._buf[i])
            if f is not None and f.seq != self._done[i]:
                self._done[i] = f.seq
                self._writer_gone[i] = False
                out.append(SourceFrame(i, self._buf[i], f.seq, f.episode_start))
        return out

    def poll(self, timeout: float) -> list[SourceFrame]:
        frames = self._collect()
        now = time.monotonic()
        if frames:
            self._last_frame = now
            return frames
        live = [i for i in range(self.slots) if not self._writer_gone[i]]
        if not live:
            time.sleep(min(timeout, 0.02))
            return self._collect()
        self._turn = (self._turn + 1) % len(live)
        i = live[self._turn]
        idle = now - self._last_frame > self.IDLE_AFTER_S
        wait = timeout if self.slots == 1 else min(
            timeout, self.idle_slice_s if idle else self.slice_s)
        try:
            self.readers[i].wait_next(timeout=wait, out=self._buf[i])
            self._last_frame = time.monotonic()
        except FrameTimeoutError:
            pass
        except WriterGoneError as exc:
            logger.info("slot %d: camera writer gone (%s); waiting for an env to attach", i,
                        exc.reason)
            self._writer_gone[i] = True
        except ShmError as exc:
            logger.warning("slot %d: %s", i, exc)
            self._writer_gone[i] = True
        return self._collect()

    def close(self, unlink: bool = False) -> None:
        """Close readers and writers; ``unlink`` removes the camera segments."""
        for r in self.readers:
            r.close()
        for w in self.writers:
            w.close(unlink=unlink)


__all__ = ["CameraSegmentSource", "FrameSource", "OpenCVSource", "SourceError", "SourceFrame"]
