"""CameraSegmentSource: new frames per slot, in slot order, read once into the source's own
buffer (the daemon runs perception on it directly), reused result objects."""

from __future__ import annotations

import threading
import uuid

import numpy as np
import pytest

from active_vision.sources import CameraSegmentSource
from shm_protocol import FrameWriter, camera_name, slot_name


def _frame(value: int) -> np.ndarray:
    return np.full((32, 32, 3), value, dtype=np.uint8)


def test_poll_hands_out_each_frame_once_in_slot_order() -> None:
    name = f"test_avs_{uuid.uuid4().hex[:8]}"
    src = CameraSegmentSource(name, slots=3, size=32, channels=3)
    envs = [FrameWriter(camera_name(slot_name(name, i)), create=False) for i in range(3)]
    try:
        assert src.poll(0.01) == []
        s2 = envs[2].publish(_frame(12))
        new = src.poll(0.5)
        assert [(f.slot, f.seq) for f in new] == [(2, s2)]
        assert np.all(src.frames_buffer[2] == 12) and new[0].data is not None
        assert np.shares_memory(new[0].data, src.frames_buffer)
        assert src.poll(0.01) == []  # handed out once
        s1, s0 = envs[1].publish(_frame(11)), envs[0].publish(_frame(10))
        new = src.poll(0.5)
        assert [(f.slot, f.seq) for f in new] == [(0, s0), (1, s1)]
        assert [int(src.frames_buffer[i, 0, 0, 0]) for i in range(3)] == [10, 11, 12]
        # a frame that arrives while the source sleeps on a slot's futex is handed out
        timer = threading.Timer(0.05, envs[1].publish, args=(_frame(21),))
        timer.start()
        new = []
        for _ in range(200):  # 2 ms slices rotating over the slots
            new = list(src.poll(0.5))
            if new:
                break
        timer.join()
        assert [f.slot for f in new] == [1] and int(src.frames_buffer[1, 0, 0, 0]) == 21
    finally:
        for w in envs:
            w.close()
        src.close(unlink=True)


def test_single_slot_wait_wakes_on_the_frame() -> None:
    name = f"test_avs_{uuid.uuid4().hex[:8]}"
    src = CameraSegmentSource(name, slots=1, size=32, channels=3)
    env = FrameWriter(camera_name(name), create=False)
    try:
        for k in range(1, 4):  # published while poll() sleeps on the futex
            timer = threading.Timer(0.05, env.publish, args=(_frame(k),))
            timer.start()
            new = src.poll(2.0)
            timer.join()
            assert [(f.slot, f.seq) for f in new] == [(0, k)]
            assert int(src.frames_buffer[0, 5, 5, 1]) == k
    finally:
        env.close()
        src.close(unlink=True)


def test_a_source_for_some_slots_names_them_and_fills_its_own_rows() -> None:
    name = f"test_avs_{uuid.uuid4().hex[:8]}"
    src = CameraSegmentSource(name, slots=4, size=32, channels=3, slot_ids=[1, 3])
    try:
        assert src.names == [camera_name(slot_name(name, i)) for i in (1, 3)]
        assert src.frames_buffer.shape[0] == 2
        with FrameWriter(camera_name(slot_name(name, 3)), create=False) as env3:
            s3 = env3.publish(_frame(33))
            new = src.poll(0.5)
        assert [(f.slot, f.row, f.seq) for f in new] == [(3, 1, s3)]
        assert np.all(src.frames_buffer[1] == 33)
    finally:
        src.close(unlink=True)
    with pytest.raises(ValueError, match="subset of 0..3"):
        CameraSegmentSource(name, slots=4, size=32, channels=3, slot_ids=[4])
