"""ROS 2 bags without ROS: MCAP files written, ROS 2 bags' image topics read.

The optional extra ``roverav[ros]`` brings two pure-Python libraries, imported here only
when a function needs them (so the package imports without them, and a call that does
raises :class:`RosExtraMissingError` naming ``pip install 'roverav[ros]'``):

- ``rosbags``: the standard ROS 2 message types (the ``ROS2_HUMBLE`` type store; Image,
  LaserScan, Odometry and the rest are the same in later distributions), their CDR
  serialisation, and the reader of every ROS 2 bag a robot leaves: a lone ``.mcap`` file,
  a rosbag2 directory (``metadata.yaml`` beside ``.mcap`` or ``.db3`` files) or a lone
  ``.db3`` file.
- ``mcap``: the MCAP writer Foxglove's own tools use. One self-contained ``.mcap`` file per
  recording (profile ``ros2``, schemas as ``ros2msg`` text, messages as CDR, chunked and
  indexed), which Foxglove opens directly and ``ros2 bag play`` plays.

What lives here:

- :class:`McapWriter`: ``write(topic, message, stamp_ns)`` registers each topic's schema on
  first use; the file is written under ``NAME.part`` and renamed when closed.
- :func:`message`, :func:`header`, :func:`image_message`, :func:`fused_messages`: messages
  built from numpy arrays; the fused image as three ``32FC1`` images on ``FUSED_TOPICS``
  (gray and heatmap in [0, 1], depth in metres by ``fused_image.channel_to_depth``).
- :class:`BagImageReader`: one image topic of a bag as RGB frames
  (``sensor_msgs/msg/Image`` in ``RAW_ENCODINGS``, ``sensor_msgs/msg/CompressedImage`` in
  JPEG or PNG), with :func:`decode_image`.
- The errors, all :class:`RosFormatError` (a ``SourceError``, so ``av-daemon --source bag:``
  fails at start with the message and removes its segments): :class:`NoImageTopicError`,
  :class:`TopicNotFoundError`, :class:`UnsupportedEncodingError`, :class:`BagReadError` and
  :class:`RosExtraMissingError`.
"""

from __future__ import annotations

import functools
import importlib
import logging
import os
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from active_vision.sources import SourceError
from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP, channel_to_depth

if TYPE_CHECKING:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

logger = logging.getLogger(__name__)

ROS_EXTRA = "pip install 'roverav[ros]'"
"""What installs the libraries this module needs."""
TYPESTORE = "ROS2_HUMBLE"
"""The rosbags type store whose message definitions recordings carry."""
MCAP_PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
LIBRARY = "roverav"
COMPRESSIONS = ("zstd", "lz4", "none")
"""MCAP chunk compressions: zstd (default, smallest), lz4 (faster), none."""

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)
RAW_CHANNELS: dict[str, int] = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4}
"""``sensor_msgs/msg/Image`` encodings :func:`decode_image` reads, and their channels."""
RAW_ENCODINGS = tuple(RAW_CHANNELS)
COMPRESSED_FORMATS = ("jpeg", "png")
"""``sensor_msgs/msg/CompressedImage`` formats :func:`decode_image` reads (``format`` as
image_transport writes it, e.g. ``"rgb8; jpeg compressed bgr8"``, or plain ``"jpeg"``,
``"jpg"`` or ``"png"``)."""
_FORMAT_WORDS = (*COMPRESSED_FORMATS, "jpg")
FLOAT_ENCODING = "32FC1"
CAMERA_TOPIC = "/camera/image_raw"
"""The topic a bag's camera is looked for on first (the seed's camera topic)."""

GRAY_TOPIC = "/active_vision/gray"
HEATMAP_TOPIC = "/active_vision/heatmap"
DEPTH_TOPIC = "/active_vision/depth"
FUSED_TOPICS: dict[int, str] = {
    CHANNEL_GRAY: GRAY_TOPIC,
    CHANNEL_HEATMAP: HEATMAP_TOPIC,
    CHANNEL_DEPTH: DEPTH_TOPIC,
}
"""Fused channel -> topic; each a ``32FC1`` image, depth in metres."""
_NS = 1_000_000_000


class RosFormatError(SourceError):
    """A ROS 2 bag cannot be read or written as asked (the message says what was expected)."""


class RosExtraMissingError(RosFormatError, ImportError):
    """The optional ``roverav[ros]`` libraries are not installed."""


class NoImageTopicError(RosFormatError):
    """The bag has no image topic (or the topic asked for is not an image); the message lists
    the bag's topics."""


class TopicNotFoundError(RosFormatError):
    """The topic asked for is not in the bag; the message lists the topics that are."""


class UnsupportedEncodingError(RosFormatError):
    """An image in an encoding or compressed format this module does not read."""


class BagReadError(RosFormatError):
    """The file is missing, not a ROS 2 bag, truncated or corrupt."""


def _require(module: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise RosExtraMissingError(
            f"ROS 2 bags need the optional libraries (module {module!r} is missing): "
            f"{ROS_EXTRA}"
        ) from exc


@functools.cache
def typestore() -> Typestore:
    """The ROS 2 message types (``TYPESTORE``), loaded once."""
    typesys = _require("rosbags.typesys")
    return typesys.get_typestore(getattr(typesys.Stores, TYPESTORE))


def message(msgtype: str, **fields: Any) -> Any:
    """A ``msgtype`` message (``"sensor_msgs/msg/Imu"``) of the type store with ``fields``."""
    return typestore().types[msgtype](**fields)


def stamp(ns: int) -> Any:
    """``builtin_interfaces/msg/Time`` of ``ns`` nanoseconds."""
    sec, nanosec = divmod(int(ns), _NS)
    return message("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def header(ns: int, frame_id: str) -> Any:
    """``std_msgs/msg/Header`` stamped ``ns`` nanoseconds in ``frame_id``."""
    return message("std_msgs/msg/Header", stamp=stamp(ns), frame_id=frame_id)


def stamp_ns(time: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/msg/Time``."""
    return int(time.sec) * _NS + int(time.nanosec)


def image_message(image: np.ndarray, ns: int, frame_id: str) -> Any:
    """``sensor_msgs/msg/Image`` of ``image``: uint8 ``(H, W, 3)`` as ``rgb8``, uint8
    ``(H, W)`` as ``mono8``, float32 ``(H, W)`` as ``32FC1`` (little-endian)."""
    if image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3:
        encoding = "rgb8"
    elif image.dtype == np.uint8 and image.ndim == 2:
        encoding = "mono8"
    elif image.dtype == np.float32 and image.ndim == 2:
        encoding = FLOAT_ENCODING
    else:
        raise ValueError(f"expected uint8 (H, W, 3), uint8 (H, W) or float32 (H, W), got "
                         f"{image.dtype} {image.shape}")
    data = np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("<"))
    height, width = image.shape[:2]
    return message(IMAGE_TYPE, header=header(ns, frame_id), height=height, width=width,
                   encoding=encoding, is_bigendian=0, step=data.strides[0],
                   data=data.reshape(-1).view(np.uint8))


def fused_messages(fused: np.ndarray, ns: int, frame_id: str) -> list[tuple[str, Any]]:
    """(topic, ``32FC1`` image) for each channel of a fused image ``(H, W, 3)`` float32:
    gray and heatmap as they are, depth in metres (``channel_to_depth``)."""
    out = []
    for channel, topic in FUSED_TOPICS.items():
        plane = np.ascontiguousarray(fused[:, :, channel], dtype=np.float32)
        if channel == CHANNEL_DEPTH:
            plane = channel_to_depth(plane)
        out.append((topic, image_message(plane, ns, frame_id)))
    return out


def decode_image(msg: Any, msgtype: str) -> np.ndarray:
    """RGB uint8 ``(H, W, 3)`` of an ``Image`` (``RAW_ENCODINGS``) or ``CompressedImage``
    (JPEG or PNG) message. :class:`UnsupportedEncodingError` for any other encoding,
    :class:`BagReadError` for data that does not hold the image its fields describe."""
    if msgtype == COMPRESSED_IMAGE_TYPE:
        fmt = str(msg.format).lower()
        if not any(word in fmt for word in _FORMAT_WORDS):
            raise UnsupportedEncodingError(
                f"CompressedImage format {msg.format!r} is not read here: expected one of "
                f"{', '.join(COMPRESSED_FORMATS)}")
        bgr = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise BagReadError(f"a CompressedImage ({msg.format!r}) does not decode: its "
                               "data is not a whole JPEG or PNG image")
        return np.ascontiguousarray(bgr[:, :, ::-1])
    if msgtype != IMAGE_TYPE:
        raise NoImageTopicError(f"{msgtype} is not an image type: expected one of "
                                f"{', '.join(IMAGE_TYPES)}")
    encoding = str(msg.encoding).lower()
    channels = RAW_CHANNELS.get(encoding)
    if channels is None:
        raise UnsupportedEncodingError(
            f"Image encoding {msg.encoding!r} is not read here: expected one of "
            f"{', '.join(RAW_ENCODINGS)} (or a CompressedImage in "
            f"{' or '.join(COMPRESSED_FORMATS)})")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if height < 1 or width < 1 or step < width * channels or data.size < height * step:
        raise BagReadError(f"an Image of {width}x{height} {encoding} with step {step} holds "
                           f"{data.size} bytes: expected at least {height * max(step, 1)}")
    pixels = data[: height * step].reshape(height, step)[:, : width * channels]
    pixels = pixels.reshape(height, width, channels)
    if encoding == "mono8":
        return np.repeat(pixels, 3, axis=2)
    if encoding.startswith("bgr"):
        return np.ascontiguousarray(pixels[:, :, 2::-1])
    return np.ascontiguousarray(pixels[:, :, :3])


class McapWriter:
    """One MCAP file of ROS 2 messages (see the module docstring). Written under
    ``<path>.part`` and renamed to ``path`` by :meth:`close`; :meth:`abort` removes it.

    :param path: the ``.mcap`` file to write (its folder is made).
    :param compression: chunk compression, one of ``COMPRESSIONS``.
    """

    def __init__(self, path: Path | str, compression: str = "zstd") -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        mcap_writer = _require("mcap.writer")
        self._store = typestore()
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._part = self.path.with_name(self.path.name + ".part")
        kind = {"zstd": "ZSTD", "lz4": "LZ4", "none": "NONE"}[compression]
        self._file = open(self._part, "wb")  # closed by close() or abort()
        self._writer = mcap_writer.Writer(
            self._file, compression=getattr(mcap_writer.CompressionType, kind))
        self._writer.start(profile=MCAP_PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._sequence: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        """Messages written per topic."""
        self.closed = False

    def _channel(self, topic: str, msgtype: str, msgdef: str | None) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise ValueError(f"topic {topic} carries {known[1]}, not {msgtype}")
            return known[0]
        schema = self._schemas.get(msgtype)
        if schema is None:
            if not msgdef:
                msgdef, _ = self._store.generate_msgdef(msgtype, ros_version=2)
            schema = self._writer.register_schema(msgtype, SCHEMA_ENCODING, msgdef.encode())
            self._schemas[msgtype] = schema
        channel = self._writer.register_channel(topic, MESSAGE_ENCODING, schema)
        self._channels[topic] = (channel, msgtype)
        return int(channel)

    def write(self, topic: str, msg: Any, ns: int) -> None:
        """Serialise ``msg`` (a type-store message) on ``topic`` at log time ``ns``."""
        msgtype = msg.__msgtype__
        data = self._store.serialize_cdr(msg, msgtype)
        self.write_raw(topic, msgtype, data, ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes | memoryview, ns: int,
                  msgdef: str | None = None) -> None:
        """Write already serialised CDR ``data`` of ``msgtype`` (``msgdef``: its ``ros2msg``
        definition when the type store lacks it)."""
        channel = self._channel(topic, msgtype, msgdef)
        seq = self._sequence.get(topic, 0)
        self._writer.add_message(channel, log_time=int(ns), data=data, publish_time=int(ns),
                                 sequence=seq)
        self._sequence[topic] = seq + 1
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> Path:
        """Finish the file (index and summary), fsync it and rename it to ``path``."""
        if not self.closed:
            self.closed = True
            try:
                self._writer.finish()
                self._file.flush()
                os.fsync(self._file.fileno())
            finally:
                self._file.close()
            os.replace(self._part, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the file being written."""
        if not self.closed:
            self.closed = True
            self._file.close()
            self._part.unlink(missing_ok=True)

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


@dataclass
class BagImage:
    """One image of a bag's image topic."""

    log_ns: int
    """The bag's timestamp of the message (receive / log time), ns."""
    stamp_ns: int
    """The message header's stamp, ns."""
    frame_id: str
    rgb: np.ndarray
    """uint8 ``(H, W, 3)`` RGB at the image's own size."""
    raw: bytes
    """The message as stored (CDR)."""


def _describe(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} ({k})" for t, k in sorted(topics.items())) or "none"


class BagImageReader:
    """One image topic of a ROS 2 bag, as RGB frames in the bag's order.

    :param path: a ``.mcap`` file, a ``.db3`` file or a rosbag2 directory.
    :param topic: the image topic; None picks ``CAMERA_TOPIC`` when the bag has it as an
        image, else the image topic (not one of ``FUSED_TOPICS``) with the most messages.
    :raises BagReadError: missing, not a bag, truncated or corrupt.
    :raises TopicNotFoundError: ``topic`` is not in the bag (the message lists its topics).
    :raises NoImageTopicError: no image topic, ``topic`` is not an image, or it is empty.
    """

    def __init__(self, path: Path | str, topic: str | None = None) -> None:
        highlevel = _require("rosbags.highlevel")
        self.path = Path(path)
        if not self.path.exists():
            raise BagReadError(f"no bag at {self.path}: expected a .mcap file, a .db3 file "
                               "or a rosbag2 directory")
        self._reader: AnyReader = highlevel.AnyReader([self.path],
                                                      default_typestore=typestore())
        try:
            self._reader.open()
        except Exception as exc:  # the library's errors vary with the damage
            raise BagReadError(
                f"{self.path} is not a readable ROS 2 bag (expected an MCAP file, a .db3 file "
                f"or a rosbag2 directory; it may be truncated or corrupt): {exc}") from exc
        try:
            self.topics = {c.topic: c.msgtype for c in self._reader.connections}
            """Every topic of the bag -> its message type."""
            self.topic = self._choose(topic)
            self._connections: list[Connection] = [
                c for c in self._reader.connections if c.topic == self.topic]
            self.msgtype = self.topics[self.topic]
            self.count = sum(c.msgcount for c in self._connections)
            if self.count == 0:
                raise NoImageTopicError(f"topic {self.topic} of {self.path} has no messages")
            conn = self._connections[0]
            stored = conn.msgdef.data if conn.msgdef.format.name == "MSG" else ""
            self.msgdef: str | None = stored or None
            """The topic's ``ros2msg`` definition as the bag stores it (None: not stored, or
            stored as IDL)."""
        except BaseException:
            self.close()
            raise
        logger.info("bag %s: topic %s (%s), %d messages", self.path, self.topic,
                    self.msgtype, self.count)

    def _choose(self, topic: str | None) -> str:
        topics = self.topics
        images = {t: k for t, k in topics.items() if k in IMAGE_TYPES}
        if topic is not None:
            if topic not in topics:
                raise TopicNotFoundError(
                    f"{self.path} has no topic {topic!r}; its topics: {_describe(topics)}")
            if topic not in images:
                raise NoImageTopicError(
                    f"topic {topic} of {self.path} is {topics[topic]}, not an image (expected "
                    f"{' or '.join(IMAGE_TYPES)}); its image topics: {_describe(images)}")
            return topic
        if not images:
            raise NoImageTopicError(
                f"{self.path} has no image topic (expected one of type "
                f"{' or '.join(IMAGE_TYPES)}); its topics: {_describe(topics)}")
        if CAMERA_TOPIC in images:
            return CAMERA_TOPIC
        counts: dict[str, int] = {}
        for c in self._reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        fused = set(FUSED_TOPICS.values())
        candidates = sorted(images, key=lambda t: (t in fused, -counts.get(t, 0), t))
        if len(candidates) > 1:
            logger.info("bag %s: image topics %s; reading %s (choose with #TOPIC / --topic)",
                        self.path, ", ".join(sorted(images)), candidates[0])
        return candidates[0]

    def frames(self) -> Generator[BagImage, None, None]:
        """The topic's images in the bag's order, decoded to RGB (:func:`decode_image`)."""
        reader = self._reader
        it = reader.messages(connections=self._connections)
        index = 0
        while True:
            try:
                item = next(it, None)
                if item is None:
                    return
                conn, log_ns, raw = item
                msg: Any = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # the library's errors vary with the damage
                raise BagReadError(
                    f"{self.path}: message {index} of {self.topic} cannot be read (the file "
                    f"may be truncated or corrupt): {exc}") from exc
            try:
                rgb = decode_image(msg, conn.msgtype)
            except RosFormatError as exc:
                raise type(exc)(f"{self.path}, {self.topic}, message {index}: {exc}") from exc
            yield BagImage(int(log_ns), stamp_ns(msg.header.stamp), str(msg.header.frame_id),
                           rgb, bytes(raw))
            index += 1

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> BagImageReader:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


__all__ = [
    "CAMERA_TOPIC",
    "COMPRESSED_FORMATS",
    "COMPRESSIONS",
    "DEPTH_TOPIC",
    "FUSED_TOPICS",
    "GRAY_TOPIC",
    "HEATMAP_TOPIC",
    "IMAGE_TYPES",
    "RAW_CHANNELS",
    "RAW_ENCODINGS",
    "ROS_EXTRA",
    "BagImage",
    "BagImageReader",
    "BagReadError",
    "McapWriter",
    "NoImageTopicError",
    "RosExtraMissingError",
    "RosFormatError",
    "TopicNotFoundError",
    "UnsupportedEncodingError",
    "decode_image",
    "fused_messages",
    "header",
    "image_message",
    "message",
    "stamp",
    "stamp_ns",
]
