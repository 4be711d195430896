"""Bytes and offsets of a segment and the trailer's encoding.

What the fused image's channels mean (and its default size) is not the wire format's
business: see the top-level ``fused_image`` package.

A segment is ``header | payload | trailer``::

    offset 0      float64  timestamp  (time.time() of the publish; strictly increasing)
    offset 8      uint32   valid      (1: a complete frame is there, 0: being written)
    offset 12     payload  H x W x C, C-order, dtype float32 or uint8
    offset 12+P   trailer  64 bytes, little-endian (TRAILER_FORMAT below)

The first ``12 + P`` bytes are the seed's layout exactly (RoverEnvFused's
``get_fused_observation``), so seed-style peers interoperate with ours. Everything here is
little-endian; the package is meant for little-endian hosts (x86-64, ARM64).

Hot paths read and write the header and trailer through the ctypes structures
:class:`Header` and :class:`Trailer` laid over the mapping: one field is one plain load or
store of its full width. ``struct.pack_into`` is kept out of them (it is only used by the
reference encoder below) because a concurrent reader was measured to see a zero-filled
intermediate value of a field written that way.
"""

from __future__ import annotations

import ctypes
import operator
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import LayoutError

# --- the seed header -------------------------------------------------------------------

TIMESTAMP_OFFSET = 0
VALID_OFFSET = 8
PAYLOAD_OFFSET = 12
HEADER_SIZE = 12
"""Seed name: ``header_size = 12  # 8-byte timestamp + 4-byte valid flag``."""


class Header(ctypes.LittleEndianStructure):
    """The seed header at offset 0."""

    _pack_ = 1
    _fields_ = [("timestamp", ctypes.c_double), ("valid", ctypes.c_uint32)]


# --- the extension trailer -------------------------------------------------------------

TRAILER_SIZE = 64
MAGIC = b"AVX1"
VERSION = 1

TRAILER_FORMAT = "<4sHHIIIIQQdIIII"
"""Reference encoding of the trailer (the last 4 bytes are reserved and zero)."""
TRAILER_STRUCT = struct.Struct(TRAILER_FORMAT)

# Offsets inside the trailer.
T_MAGIC = 0
T_VERSION = 4
T_DTYPE = 6
T_HEIGHT = 8
T_WIDTH = 12
T_CHANNELS = 16
T_PID = 20
T_SEQ = 24
T_SOURCE_SEQ = 32
T_HEARTBEAT = 40
T_FLAGS = 48
T_WAKE = 52
T_CHECKSUM = 56
T_RESERVED = 60

FLAG_SHUTTING_DOWN = 1 << 0
"""Set by the writer's orderly ``close()``: readers report :class:`WriterGoneError` at once."""
FLAG_CHECKSUM = 1 << 1
"""Set when the writer stores ``crc32(payload, seq)`` at ``T_CHECKSUM`` (checksum mode,
the ordering safeguard for weakly ordered CPUs; see docs/protocol.md)."""
FLAG_EPISODE_START = 1 << 2
"""Per frame: set by ``publish(..., episode_start=True)`` on the first camera frame of an
episode, cleared by every other publish; written and read inside the seqlock bracket, so it
belongs to exactly the frame it was published with (``Frame.episode_start``)."""

U32_MAX = 0xFFFF_FFFF
U64_MAX = 0xFFFF_FFFF_FFFF_FFFF


class Trailer(ctypes.LittleEndianStructure):
    """The 64-byte trailer at offset ``12 + P``."""

    _pack_ = 1
    _fields_ = [
        ("magic", ctypes.c_char * 4),
        ("version", ctypes.c_uint16),
        ("dtype", ctypes.c_uint16),
        ("height", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("channels", ctypes.c_uint32),
        ("pid", ctypes.c_uint32),
        ("seq", ctypes.c_uint64),
        ("source_seq", ctypes.c_uint64),
        ("heartbeat", ctypes.c_double),
        ("flags", ctypes.c_uint32),
        ("wake", ctypes.c_uint32),
        ("checksum", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
    ]


assert ctypes.sizeof(Header) == HEADER_SIZE
assert ctypes.sizeof(Trailer) == TRAILER_SIZE == TRAILER_STRUCT.size
assert Trailer.seq.offset == T_SEQ and Trailer.wake.offset == T_WAKE

# --- dtypes ----------------------------------------------------------------------------

DTYPE_CODES: dict[np.dtype[Any], int] = {np.dtype("<f4"): 1, np.dtype("u1"): 2}
"""Trailer dtype code of each payload dtype the wire format allows."""
CODE_DTYPES: dict[int, np.dtype[Any]] = {code: dt for dt, code in DTYPE_CODES.items()}


def normalize_dtype(dtype: Any) -> np.dtype[Any]:
    """``dtype`` as one of the wire dtypes (little-endian float32 or uint8), else LayoutError."""
    try:
        dt = np.dtype(dtype)
    except TypeError as exc:
        raise LayoutError(f"not a dtype: {dtype!r} (expected float32 or uint8)") from exc
    if dt.byteorder == "=":
        dt = dt.newbyteorder("<") if dt.itemsize > 1 else dt
    if dt not in DTYPE_CODES:
        raise LayoutError(
            f"dtype {dt.str} is not allowed on the wire: expected float32 (code 1) or uint8 "
            f"(code 2), little-endian"
        )
    return dt


def normalize_shape(shape: Any) -> tuple[int, int, int]:
    """``shape`` as ``(H, W, C)`` ints, each in 1 .. 2**32-1, else LayoutError."""
    try:
        dims = tuple(operator.index(d) for d in shape)
    except TypeError as exc:
        raise LayoutError(f"shape must be (height, width, channels) ints, got {shape!r}") from exc
    if len(dims) != 3:
        raise LayoutError(
            f"shape must be (height, width, channels), got {shape!r} ({len(dims)} dims); "
            "use channels=1 for a single-channel image"
        )
    if not all(1 <= d <= U32_MAX for d in dims):
        raise LayoutError(f"every dimension must be in 1..{U32_MAX}, got {dims}")
    return dims


# --- one segment's layout --------------------------------------------------------------


@dataclass(frozen=True)
class Layout:
    """Shape and dtype of a segment's payload, and the sizes and offsets that follow."""

    shape: tuple[int, int, int]
    dtype: np.dtype[Any]

    @classmethod
    def of(cls, shape: Any, dtype: Any) -> Layout:
        """Validate and normalise: ``shape`` is ``(H, W, C)``, each 1 .. 2**32-1."""
        return cls(normalize_shape(shape), normalize_dtype(dtype))

    @property
    def dtype_code(self) -> int:
        return DTYPE_CODES[self.dtype]

    @property
    def payload_nbytes(self) -> int:
        h, w, c = self.shape
        return h * w * c * self.dtype.itemsize

    @property
    def trailer_offset(self) -> int:
        return PAYLOAD_OFFSET + self.payload_nbytes

    @property
    def seed_size(self) -> int:
        """Size of a seed-style segment (no trailer) of this layout."""
        return PAYLOAD_OFFSET + self.payload_nbytes

    @property
    def segment_size(self) -> int:
        return PAYLOAD_OFFSET + self.payload_nbytes + TRAILER_SIZE

    @property
    def wake_offset(self) -> int:
        """Offset of the futex word; futex needs it 4-byte aligned (true unless P % 4 != 0)."""
        return self.trailer_offset + T_WAKE

    def describe(self) -> str:
        """``96x96x3 float32``: used in every error message that names a layout."""
        return describe(self.shape, self.dtype)


def describe(shape: Any, dtype: Any) -> str:
    """Human form of a shape and dtype, as error messages print them."""
    try:
        dims = "x".join(str(int(d)) for d in shape)
    except (TypeError, ValueError):
        dims = repr(shape)
    try:
        name = np.dtype(dtype).name
    except TypeError:
        name = repr(dtype)
    return f"{dims} {name}"


@dataclass(frozen=True)
class TrailerInfo:
    """Every trailer field, decoded. ``encode_trailer(decode_trailer(b)) == b`` for valid b."""

    layout: Layout
    pid: int = 0
    seq: int = 0
    source_seq: int = 0
    heartbeat: float = 0.0
    flags: int = 0
    wake: int = 0
    checksum: int = 0


def encode_trailer(info: TrailerInfo) -> bytes:
    """The 64 trailer bytes of ``info`` (reference encoder; not used on hot paths)."""
    h, w, c = info.layout.shape
    return TRAILER_STRUCT.pack(
        MAGIC, VERSION, info.layout.dtype_code, h, w, c, info.pid, info.seq, info.source_seq,
        info.heartbeat, info.flags, info.wake, info.checksum, 0,
    )


def has_magic(raw: bytes | bytearray | memoryview) -> bool:
    """True if ``raw`` (a segment's last 64 bytes) starts with the trailer magic."""
    return bytes(raw[:4]) == MAGIC


def decode_trailer(raw: bytes | bytearray | memoryview) -> TrailerInfo:
    """Decode 64 trailer bytes; :class:`LayoutError` says what is wrong with bad ones."""
    if len(raw) != TRAILER_SIZE:
        raise LayoutError(f"trailer must be {TRAILER_SIZE} bytes, got {len(raw)}")
    (magic, version, code, h, w, c, pid, seq, src, hb, flags, wake, crc, reserved) = (
        TRAILER_STRUCT.unpack(bytes(raw))
    )
    if magic != MAGIC:
        raise LayoutError(f"trailer magic is {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise LayoutError(
            f"trailer version {version}, expected {VERSION}: the writer speaks another "
            "revision of the protocol; run matching versions of roverav on both sides"
        )
    if code not in CODE_DTYPES:
        raise LayoutError(f"trailer dtype code {code}, expected one of {sorted(CODE_DTYPES)}")
    if min(h, w, c) < 1:
        raise LayoutError(f"trailer shape {h}x{w}x{c} has a zero dimension")
    layout = Layout((h, w, c), CODE_DTYPES[code])
    return TrailerInfo(layout, pid, seq, src, hb, flags, wake, crc)


__all__ = [
    "DTYPE_CODES",
    "FLAG_CHECKSUM",
    "FLAG_EPISODE_START",
    "FLAG_SHUTTING_DOWN",
    "HEADER_SIZE",
    "Header",
    "Layout",
    "MAGIC",
    "PAYLOAD_OFFSET",
    "TRAILER_SIZE",
    "Trailer",
    "TrailerInfo",
    "VERSION",
    "decode_trailer",
    "describe",
    "encode_trailer",
]
