"""MultiWaiter: one futex_waitv over several segments' wake words wakes on a publish to
any of them, and a publish between arm() and wait() is never lost."""

from __future__ import annotations

import threading
import time
import uuid

import numpy as np
import pytest

from shm_protocol import MULTIWAIT_AVAILABLE, FrameReader, FrameWriter, MultiWaiter

pytestmark = pytest.mark.skipif(not MULTIWAIT_AVAILABLE, reason="no futex_waitv (Linux < 5.16)")
LONG = 30.0  # a wait that runs this long was not woken


@pytest.fixture
def three():
    base = f"test_mw_{uuid.uuid4().hex[:8]}"
    writers = [FrameWriter(f"{base}_{i}", shape=(8, 8, 3), dtype=np.uint8)
               for i in range(3)]
    readers = [FrameReader(w.name) for w in writers]
    yield writers, readers
    for r in readers:
        r.close()
    for w in writers:
        w.close(unlink=True)


def test_a_publish_on_any_segment_ends_the_wait(three) -> None:
    writers, readers = three
    watch = MultiWaiter(readers)
    frame = np.full((8, 8, 3), 7, np.uint8)
    for k in (2, 0, 1):
        watch.arm()
        assert all(r.next_frame() is None for r in readers)
        timer = threading.Timer(0.05, writers[k].publish, args=(frame,))
        timer.start()
        t0 = time.monotonic()
        watch.wait(LONG)
        timer.join()
        assert time.monotonic() - t0 < LONG / 3, f"segment {k}'s publish did not wake it"
        got = [r.next_frame() for r in readers]
        assert [g is not None for g in got] == [i == k for i in range(3)]


def test_a_publish_between_arm_and_wait_is_not_lost(three) -> None:
    writers, readers = three
    watch = MultiWaiter(readers)
    watch.arm()
    writers[1].publish(np.zeros((8, 8, 3), np.uint8))
    t0 = time.monotonic()
    watch.wait(LONG)  # the word changed since arm(): returns at once
    assert time.monotonic() - t0 < LONG / 3
    assert readers[1].next_frame() is not None and readers[1].next_frame() is None


def test_without_a_publish_the_wait_ends_at_its_timeout(three) -> None:
    _, readers = three
    watch = MultiWaiter(readers)
    watch.arm()
    t0 = time.monotonic()
    watch.wait(0.05)
    assert time.monotonic() - t0 >= 0.04
    with pytest.raises(ValueError, match="1..128 readers"):
        MultiWaiter([])
