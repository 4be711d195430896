"""The bounded spin before the futex sleep (shm_protocol.spin): frames still arrive, the
budget is read from the caller or $ROVERAV_SPIN_US, and a waiter with no frames coming
burns almost no CPU (a generous bound on CPU time, not a timing of speed)."""

from __future__ import annotations

import threading
import time
import uuid

import numpy as np
import pytest

from active_vision.sources import CameraSegmentSource
from shm_protocol import FrameReader, FrameTimeoutError, FrameWriter, camera_name, slot_name
from shm_protocol._futex import AVAILABLE as FUTEX_AVAILABLE
from shm_protocol.spin import DEFAULT_SPIN_US, SPIN_ENV, SpinPlan, spin_budget_us

IDLE_S = 1.5
MAX_IDLE_CPU = 0.20  # of one core; the spin-wait's goal is < 5 %
needs_futex = pytest.mark.skipif(not FUTEX_AVAILABLE, reason="no futex here")


def test_budget_comes_from_the_caller_then_the_environment(monkeypatch) -> None:
    monkeypatch.delenv(SPIN_ENV, raising=False)
    assert spin_budget_us() == DEFAULT_SPIN_US
    monkeypatch.setenv(SPIN_ENV, "0")
    assert spin_budget_us() == 0.0
    assert spin_budget_us(50) == 50.0
    monkeypatch.setenv(SPIN_ENV, "fast")
    with pytest.raises(ValueError, match=SPIN_ENV):
        spin_budget_us()
    with pytest.raises(ValueError, match="spin_us"):
        spin_budget_us(-1)


def test_plan_sleeps_until_shortly_before_the_frame_is_due() -> None:
    plan = SpinPlan(200.0)
    assert plan.sleep_s(0.0) <= 0.0  # nothing learnt: spin at once
    for _ in range(50):
        plan.learn(0.002)
    assert plan.expected_s == pytest.approx(0.002)
    assert plan.sleep_s(0.0) == pytest.approx(0.0018)
    assert plan.spin_end(10.0, 0.0018) == pytest.approx(10.0004)
    plan.learn(5.0)  # an idle gap is not learnt
    plan.learn(0.05)  # an outlier moves the estimate a little only
    assert plan.expected_s < 0.003


@needs_futex
@pytest.mark.parametrize("spin_us", [0.0, 200.0, 5000.0])
def test_frames_arrive_early_on_time_and_late(spin_us: float) -> None:
    name = f"test_spin_{uuid.uuid4().hex[:8]}"
    w = FrameWriter(name, shape=(8, 8, 3), dtype=np.uint8)
    try:
        r = FrameReader(name, spin_us=spin_us)
        delays = [0.002] * 10 + [0.0, 0.02, 0.0005]  # learn a cadence, then late/early frames
        for i, delay in enumerate(delays):
            timer = threading.Timer(delay, w.publish, args=(np.zeros((8, 8, 3), np.uint8),))
            timer.start()
            f = r.wait_next(timeout=5.0)
            timer.join()
            assert f.seq == i + 1
        r.close()
    finally:
        w.close(unlink=True)


def _cpu_share(wait) -> float:
    c0, t0 = time.process_time(), time.monotonic()
    wait()
    return (time.process_time() - c0) / (time.monotonic() - t0)


@needs_futex
def test_an_idle_reader_burns_almost_no_cpu() -> None:
    name = f"test_spin_{uuid.uuid4().hex[:8]}"
    w = FrameWriter(name, shape=(8, 8, 3), dtype=np.uint8)
    try:
        r = FrameReader(name, spin_us=2000.0)
        for _ in range(20):  # learn a 1 ms cadence, then the frames stop
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


@needs_futex
@pytest.mark.parametrize("slots", [1, 2])
def test_the_daemons_camera_wait_burns_almost_no_cpu_when_idle(slots: int) -> None:
    base = f"test_spin_{uuid.uuid4().hex[:8]}"
    source = CameraSegmentSource(base, slots, 16, 3, spin_us=2000.0)
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


def test_the_fused_env_refuses_a_bad_spin_budget_before_attaching() -> None:
    from rover_env.fused_env import RoverEnvFused

    with pytest.raises(ValueError, match="spin_us"):
        RoverEnvFused(rl_obs_name=f"test_spin_{uuid.uuid4().hex[:8]}", spin_us=-1)
