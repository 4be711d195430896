"""A waiter with no frames coming burns almost no CPU: a reader in the env, and the
daemon's camera wait over 1 and 2 slots (a generous bound on CPU time, not a timing of
speed)."""

from __future__ import annotations

import time
import uuid

import numpy as np
import pytest

from active_vision.sources import CameraSegmentSource
from shm_protocol import (
    SPIN_S,
    FrameReader,
    FrameTimeoutError,
    FrameWriter,
    camera_name,
    slot_name,
)

IDLE_S = 1.5
MAX_IDLE_CPU = 0.20  # of one core; the futex wait measured about 1 %


def _cpu_share(wait) -> float:  # noqa: ANN001
    c0, t0 = time.process_time(), time.monotonic()
    wait()
    return (time.process_time() - c0) / (time.monotonic() - t0)


@pytest.mark.parametrize("spin", [0.0, SPIN_S])
def test_an_idle_reader_burns_almost_no_cpu(spin: float) -> None:
    """Also when it spins before sleeping: once per wait call, a few ms."""
    name = f"test_idle_{uuid.uuid4().hex[:8]}"
    w = FrameWriter(name, shape=(8, 8, 3), dtype=np.uint8)
    try:
        r = FrameReader(name, spin=spin)
        for _ in range(20):  # a 1 ms cadence, then the frames stop
            w.publish(np.zeros((8, 8, 3), np.uint8))
            r.wait_next(timeout=1.0)
            time.sleep(0.001)

        def wait() -> None:
            end = time.monotonic() + IDLE_S
            while time.monotonic() < end:
                with pytest.raises(FrameTimeoutError):
                    r.wait_next(timeout=0.1)

        share = _cpu_share(wait)
        r.close()
    finally:
        w.close(unlink=True)
    assert share < MAX_IDLE_CPU, f"an idle reader used {share:.0%} of a core"


@pytest.mark.parametrize(("slots", "spin"), [(1, 0.0), (2, 0.0), (1, SPIN_S)])
def test_the_daemons_camera_wait_burns_almost_no_cpu_when_idle(slots: int, spin: float) -> None:
    base = f"test_idle_{uuid.uuid4().hex[:8]}"
    source = CameraSegmentSource(base, slots, 16, 3, spin=spin)
    envs = [FrameWriter(camera_name(slot_name(base, i)), shape=(16, 16, 3), dtype=np.uint8,
                        create=False) for i in range(slots)]
    try:
        frame = np.zeros((16, 16, 3), np.uint8)
        for _ in range(20):
            for e in envs:
                e.publish(frame)
            assert source.poll(1.0)
            time.sleep(0.001)

        def wait() -> None:
            end = time.monotonic() + IDLE_S
            while time.monotonic() < end:
                assert not source.poll(0.2)

        share = _cpu_share(wait)
        envs[-1].publish(frame)  # still served after the idle spell
        assert [f.slot for f in source.poll(1.0)] == [slots - 1]
    finally:
        for e in envs:
            e.close()
        source.close(unlink=True)
    assert share < MAX_IDLE_CPU, f"the daemon's idle wait used {share:.0%} of a core"
