"""shm_protocol layout and names (no shared memory needed); the fused image's channels and
depth encoding are tests/test_fused_image.py's."""

from __future__ import annotations

import ctypes
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import shm_protocol
from fused_image import FUSED_SHAPE
from shm_protocol import layout
from shm_protocol.errors import InvalidNameError, LayoutError
from shm_protocol.layout import Layout, TrailerInfo, decode_trailer, encode_trailer
from shm_protocol.names import MAX_NAME_LENGTH, camera_name, slot_name, validate_name

dims = st.integers(min_value=1, max_value=2**32 - 1)
u32 = st.integers(min_value=0, max_value=2**32 - 1)
u64 = st.integers(min_value=0, max_value=2**64 - 1)
wire_dtypes = st.sampled_from([np.float32, np.uint8, "<f4", "u1", np.dtype("float32")])


def test_public_api_is_exported() -> None:
    for name in ["FrameWriter", "FrameReader", "Frame", "slot_name", "camera_name",
                 "SegmentNotFoundError", "LayoutError", "FrameTimeoutError", "WriterGoneError",
                 "ShmError"]:
        assert hasattr(shm_protocol, name), name
    # the wire format knows bytes, not what the fused image's channels mean (fused_image)
    for name in ["FUSED_SHAPE", "CHANNEL_GRAY", "CHANNEL_HEATMAP", "CHANNEL_DEPTH",
                 "DEPTH_MAX_M", "depth_to_channel", "channel_to_depth"]:
        assert not hasattr(shm_protocol, name) and not hasattr(layout, name), name


def test_fused_layout_matches_the_seed_and_design() -> None:
    lay = Layout.of(FUSED_SHAPE, np.float32)
    assert lay.payload_nbytes == 96 * 96 * 3 * 4 == 110_592  # seed: data_size
    assert layout.HEADER_SIZE == 12 and layout.PAYLOAD_OFFSET == 12  # seed: header_size
    assert lay.trailer_offset == 12 + 110_592
    assert lay.segment_size == 12 + 110_592 + 64
    assert layout.TRAILER_STRUCT.size == 64


def test_ctypes_structures_match_the_documented_offsets() -> None:
    assert ctypes.sizeof(layout.Header) == 12 and ctypes.sizeof(layout.Trailer) == 64
    expected = {"magic": 0, "version": 4, "dtype": 6, "height": 8, "width": 12, "channels": 16,
                "pid": 20, "seq": 24, "source_seq": 32, "heartbeat": 40, "flags": 48,
                "wake": 52, "checksum": 56, "reserved": 60}
    for field, offset in expected.items():
        assert getattr(layout.Trailer, field).offset == offset, field
    assert layout.Header.timestamp.offset == 0 and layout.Header.valid.offset == 8


@given(h=dims, w=dims, c=dims, dtype=wire_dtypes, pid=u32, seq=u64, src=u64,
       hb=st.floats(allow_nan=False), flags=u32, wake=u32, crc=u32)
def test_trailer_encode_decode_round_trip(h: int, w: int, c: int, dtype: object, pid: int,
                                          seq: int, src: int, hb: float, flags: int,
                                          wake: int, crc: int) -> None:
    info = TrailerInfo(Layout.of((h, w, c), dtype), pid, seq, src, hb, flags, wake, crc)
    raw = encode_trailer(info)
    assert len(raw) == 64 and raw[:4] == b"AVX1" and raw[60:] == b"\0\0\0\0"
    assert decode_trailer(raw) == info
    # the ctypes view used on hot paths reads the same bytes the same way
    t = layout.Trailer.from_buffer_copy(raw)
    assert (t.height, t.width, t.channels, t.pid, t.seq, t.source_seq, t.flags, t.wake,
            t.checksum) == (h, w, c, pid, seq, src, flags, wake, crc)
    assert t.heartbeat == hb
    # and writing through ctypes gives the reference encoding
    buf = bytearray(64)
    v = layout.Trailer.from_buffer(buf)
    v.magic, v.version, v.dtype = b"AVX1", 1, info.layout.dtype_code
    v.height, v.width, v.channels, v.pid, v.seq, v.source_seq = h, w, c, pid, seq, src
    v.heartbeat, v.flags, v.wake, v.checksum = hb, flags, wake, crc
    del v
    assert bytes(buf) == raw


@given(h=dims, w=dims, c=dims, dtype=wire_dtypes)
def test_layout_sizes(h: int, w: int, c: int, dtype: object) -> None:
    lay = Layout.of((h, w, c), dtype)
    item = np.dtype(dtype).itemsize
    assert lay.payload_nbytes == h * w * c * item
    assert lay.segment_size == 12 + h * w * c * item + 64
    assert lay.wake_offset == lay.trailer_offset + 52
    assert f"{h}x{w}x{c}" in lay.describe()


@given(raw=st.binary(min_size=64, max_size=64))
def test_decode_rejects_or_round_trips_any_bytes(raw: bytes) -> None:
    try:
        info = decode_trailer(raw)
    except LayoutError:
        return
    assert encode_trailer(info)[:60] == raw[:60]


@pytest.mark.parametrize(
    "shape, dtype",
    [((96, 96), np.float32), ((0, 96, 3), np.float32), ((96, 96, 3), np.float64),
     ((96, 96, 3), np.int32), ((96, 96, 3), ">f4"), ((2**32, 1, 1), np.uint8),
     ((96.0, 96, 3), np.float32)],
)
def test_layout_rejects_what_the_trailer_cannot_hold(shape: tuple, dtype: object) -> None:
    with pytest.raises(LayoutError):
        Layout.of(shape, dtype)


def test_decode_names_the_problem() -> None:
    good = encode_trailer(TrailerInfo(Layout.of((4, 4, 1), np.uint8)))
    with pytest.raises(LayoutError, match="magic"):
        decode_trailer(b"XXXX" + good[4:])
    with pytest.raises(LayoutError, match="version 2"):
        decode_trailer(good[:4] + struct.pack("<H", 2) + good[6:])
    with pytest.raises(LayoutError, match="dtype code 9"):
        decode_trailer(good[:6] + struct.pack("<H", 9) + good[8:])


# --- names -----------------------------------------------------------------------------


def test_slot_and_camera_names() -> None:
    assert slot_name("rl_observation", 0) == "rl_observation"
    assert slot_name("rl_observation", 3) == "rl_observation_3"
    assert camera_name("rl_observation") == "rl_observation_camera"
    assert camera_name(slot_name("rl_observation", 2)) == "rl_observation_2_camera"
    with pytest.raises(ValueError):
        slot_name("rl_observation", -1)


@pytest.mark.parametrize(
    "bad", ["", "a/b", "/rl_observation", "../etc", ".hidden", "-x", "has space", "tab\t",
            "é", "x" * (MAX_NAME_LENGTH + 1), "nul\0"],
)
def test_invalid_names_are_rejected(bad: str) -> None:
    with pytest.raises(InvalidNameError) as exc:
        validate_name(bad)
    assert isinstance(exc.value, ValueError)


def test_leading_slash_hint() -> None:
    with pytest.raises(InvalidNameError, match="use 'rl_observation'"):
        validate_name("/rl_observation")


@pytest.mark.parametrize("good", ["rl_observation", "a", "A-b.c_9", "x" * MAX_NAME_LENGTH])
def test_valid_names(good: str) -> None:
    assert validate_name(good) == good


@given(st.text(max_size=140))
def test_validation_never_accepts_a_path(name: str) -> None:
    try:
        validate_name(name)
    except InvalidNameError:
        return
    assert "/" not in name and "\0" not in name and not name.startswith(".")
    assert 1 <= len(name) <= MAX_NAME_LENGTH
