"""``av-daemon --source bag:PATH[#TOPIC]``: a robot's recorded camera as the daemon's frames.

:class:`BagSource` plays one image topic of a ROS 2 bag (a ``.mcap`` file, a ``.db3`` file or
a rosbag2 directory; ``sensor_msgs/msg/Image`` in ``rgb8``, ``bgr8``, ``mono8``, ``rgba8`` or
``bgra8``, or ``sensor_msgs/msg/CompressedImage`` in JPEG or PNG) as the video source
(:class:`~active_vision.sources.OpenCVSource`) plays a video file: at the bag's own pace (its
message timestamps), skipping images when perception falls behind so playback keeps real
time, starting again at the end, every slot getting the same frame, each frame resized to the
fused size (``INTER_AREA``) in RGB. ``seq`` numbers the topic's images from 1 and goes on
counting over repeats, so image ``(seq - 1) % count`` of the topic is the one a fused frame's
``source_seq`` names.

``#TOPIC`` chooses the topic (it starts with ``/``); without it the bag's
``/camera/image_raw`` is read when it has one, else its image topic with the most messages.
A bag that is missing, truncated or corrupt, has no such topic or no image topic, or holds
images in an encoding not read here raises the matching
:class:`~active_vision.ros_formats.RosFormatError` when the source is made (the first image is
decoded then), so the daemon fails at start, says why, and removes its segments. Needs
``pip install 'roverav[ros]'``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np

from active_vision.ros_formats import BagImage, BagImageReader
from active_vision.sources import BAG_KIND, SourceError, SourceFrame, source_kind

logger = logging.getLogger(__name__)

_NS = 1e9


def camera_frame(rgb: np.ndarray, size: int) -> np.ndarray:
    """A decoded image as the daemon's camera frame: ``size`` x ``size`` RGB, resized with
    ``INTER_AREA`` (as the video source does)."""
    return cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)


def parse_bag_spec(spec: str) -> tuple[Path, str | None]:
    """(path, topic or None) of ``bag:PATH[#TOPIC]`` (a ``#`` followed by ``/`` starts the
    topic; any other ``#`` belongs to the path)."""
    if source_kind(spec) != BAG_KIND:
        raise SourceError(f"expected bag:PATH[#TOPIC], got {spec!r}")
    rest = spec.partition(":")[2]
    path, sep, topic = rest.rpartition("#")
    if sep and path and topic.startswith("/"):
        return Path(path), topic
    return Path(rest), None


class BagSource:
    """Frames of a bag's image topic for every slot (see the module docstring).

    :param spec: ``bag:PATH[#TOPIC]``.
    :param slots: number of slots that each get every frame.
    :param size: side of the square frames handed out.
    :param loop: start again at the end (else :meth:`poll` returns nothing more and
        :attr:`finished` becomes True).
    :param realtime: pace the images by their timestamps (else each :meth:`poll` hands out
        the next image at once).
    """

    channels = 3

    def __init__(self, spec: str, slots: int, size: int, loop: bool = True,
                 realtime: bool = True) -> None:
        path, topic = parse_bag_spec(spec)
        self.spec = spec
        self.slots = slots
        self.size = size
        self.loop = loop
        self.realtime = realtime
        self.finished = False
        self.reader = BagImageReader(path, topic)
        self._read = 0  # images read, over every pass: the seq of the last one read
        self._passes = 0
        try:
            self._images = self.reader.frames()
            first = self._next()  # decoded now: a bad encoding fails at start
        except BaseException:
            self.reader.close()
            raise
        if first is None:  # counted, yet none came out
            self.reader.close()
            raise SourceError(f"{spec}: topic {self.reader.topic} yielded no image")
        self.count = self.reader.count
        """Images of the topic (one pass)."""
        self._pending: tuple[BagImage, int] | None = first
        self._ns0 = first[0].log_ns  # timestamp of this pass's first image
        self._t0: float | None = None  # when this pass's first image was due
        logger.info("source %s: %s, %d images", spec, self.reader.topic, self.count)

    def _due(self, image: BagImage) -> float:
        assert self._t0 is not None
        return self._t0 + (image.log_ns - self._ns0) / _NS

    def _next(self) -> tuple[BagImage, int] | None:
        """The pass's next image and its seq (None at the pass's end)."""
        image = next(self._images, None)
        if image is None:
            return None
        self._read += 1
        return image, self._read

    def _new_pass(self) -> tuple[BagImage, int] | None:
        """The first image of the topic's next pass (None without ``loop``)."""
        if not self.loop:
            logger.info("source %s: no more images", self.spec)
            return None
        logger.info("source %s: end of the topic, starting again", self.spec)
        self._images.close()
        self._images = self.reader.frames()
        self._passes += 1
        self._read = self._passes * self.count
        first = self._next()
        self._t0 = None
        if first is not None:
            self._ns0 = first[0].log_ns
        return first

    def poll(self, timeout: float) -> list[SourceFrame]:
        pending = self._pending
        if pending is None:
            self.finished = True
            time.sleep(timeout)
            return []
        image, seq = pending
        if self.realtime:
            now = time.monotonic()
            if self._t0 is None:
                self._t0 = now
            due = self._due(image)
            if due > now:
                if due - now > timeout:
                    time.sleep(timeout)
                    return []
                time.sleep(due - now)
                now = due
            # behind by more than an image: skip to the newest one already due
            upcoming = self._next()
            while upcoming is not None and self._due(upcoming[0]) <= now:
                (image, seq), upcoming = upcoming, self._next()
        else:
            upcoming = self._next()
        self._pending = upcoming if upcoming is not None else self._new_pass()
        frame = camera_frame(image.rgb, self.size)
        return [SourceFrame(i, frame, seq) for i in range(self.slots)]

    def close(self) -> None:
        self._images.close()
        self.reader.close()


__all__ = ["BagSource", "camera_frame", "parse_bag_spec"]
