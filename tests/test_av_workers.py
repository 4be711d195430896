"""The daemon's worker threads (``--workers``), in-process with real shared memory: a slot's
frame does not wait for another worker's frame, one loop does, and a failing worker stops
the daemon with its error."""

from __future__ import annotations

import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from active_vision.daemon import Daemon, DaemonConfig, camera_spin, worker_count
from shm_protocol import (
    SPIN_S,
    FrameReader,
    FrameTimeoutError,
    FrameWriter,
    camera_name,
    machine_spin,
    slot_name,
)

FRAME = np.full((96, 96, 3), 128, np.uint8)


@pytest.fixture
def make_daemon() -> Iterator[Callable[[int], Daemon]]:
    started: list[Daemon] = []

    def make(workers: int) -> Daemon:
        d = Daemon(DaemonConfig(name=f"test_wk_{uuid.uuid4().hex[:8]}", slots=2,
                                workers=workers, log_every=0))
        d.start()
        started.append(d)
        return d

    yield make
    for d in started:
        d.shutdown()


class _Held:
    """Stands in for worker 0's network: holds its frame until released."""

    def __init__(self, inner) -> None:
        self.inner, self.entered, self.release = inner, threading.Event(), threading.Event()
        self.timings = inner.timings

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        self.entered.set()
        self.release.wait(30.0)
        return self.inner(frames)


def _serve(d: Daemon) -> tuple[threading.Thread, list[BaseException]]:
    errors: list[BaseException] = []

    def run() -> None:
        try:
            d.serve()
        except BaseException as exc:
            errors.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, errors


def _stop(d: Daemon, t: threading.Thread) -> None:
    d.stop.signal = 15
    t.join(10.0)
    assert not t.is_alive(), "the daemon did not stop"


def _slot_frame_while_slot0_is_held(d: Daemon) -> tuple[bool, bool]:
    """Hold slot 0's network, send a frame on each slot: (slot 1 answered while slot 0 was
    held, slot 0 answered after its release)."""
    held = _Held(d.workers[0].perception)
    d.workers[0].perception = held  # type: ignore[assignment]
    cams = [FrameWriter(camera_name(slot_name(d.config.name, i)), create=False)
            for i in range(2)]
    fused = [FrameReader(slot_name(d.config.name, i)) for i in range(2)]
    t, errors = _serve(d)
    try:
        s0 = cams[0].publish(FRAME)
        assert held.entered.wait(10.0)
        s1 = cams[1].publish(FRAME)
        try:
            fused[1].wait_for(source_seq=s1, timeout=1.0)
            early = True
        except FrameTimeoutError:
            early = False
        held.release.set()
        late = fused[0].wait_for(source_seq=s0, timeout=10.0).source_seq == s0
        fused[1].wait_for(source_seq=s1, timeout=10.0)
    finally:
        held.release.set()
        _stop(d, t)
        for c in cams:
            c.close()
        for r in fused:
            r.close()
    assert not errors, errors
    return early, late


def test_a_worker_serves_its_slot_while_another_worker_computes(make_daemon) -> None:
    d = make_daemon(2)
    assert [w.slots for w in d.workers] == [[0], [1]]
    assert d.workers[0].perception is not d.workers[1].perception
    assert _slot_frame_while_slot0_is_held(d) == (True, True)


def test_one_loop_makes_a_slot_wait_for_the_other(make_daemon) -> None:
    d = make_daemon(1)
    assert [w.slots for w in d.workers] == [[0, 1]]
    assert _slot_frame_while_slot0_is_held(d) == (False, True)


def test_a_failing_worker_stops_the_daemon_with_its_error(make_daemon) -> None:
    d = make_daemon(2)

    def broken(frames: np.ndarray) -> np.ndarray:
        raise RuntimeError("network broke")

    d.workers[1].perception = broken  # type: ignore[assignment]
    t, errors = _serve(d)
    with FrameWriter(camera_name(slot_name(d.config.name, 1)), create=False) as cam:
        cam.publish(FRAME)
        t.join(10.0)
    assert not t.is_alive(), "worker 0 kept serving after worker 1 failed"
    assert len(errors) == 1 and "network broke" in str(errors[0])


def test_worker_count() -> None:
    cpus = len(os.sched_getaffinity(0))
    assert worker_count(DaemonConfig(slots=2, workers=5)) == 2  # at most one per slot
    assert worker_count(DaemonConfig(slots=8, workers=3)) == 3
    assert worker_count(DaemonConfig(slots=8)) == min(8, cpus)
    assert worker_count(DaemonConfig(slots=1)) == 1
    assert worker_count(DaemonConfig(slots=4, workers=4, source="video:x.avi")) == 1


def test_workers_flag_refuses_a_negative_count(capsys) -> None:
    from active_vision.daemon import parse_args

    assert parse_args(["--workers", "3"]).workers == 3
    with pytest.raises(SystemExit):
        parse_args(["--workers", "-1"])
    assert "0: one per CPU core" in capsys.readouterr().err


def test_idle_workers_burn_almost_no_cpu(make_daemon) -> None:
    """Two workers with no frames coming (a generous bound on CPU time, not a timing)."""
    d = make_daemon(2)
    t, errors = _serve(d)
    try:
        time.sleep(0.3)  # both workers in their waits
        c0, t0 = time.process_time(), time.monotonic()
        time.sleep(1.5)
        share = (time.process_time() - c0) / (time.monotonic() - t0)
    finally:
        _stop(d, t)
    assert not errors, errors
    assert share < 0.2, f"two idle workers used {share:.0%} of a core"


def test_a_worker_of_one_slot_spins_where_spin_wait_says() -> None:
    from active_vision.daemon import parse_args

    assert camera_spin(DaemonConfig(slots=1)) == machine_spin(1)  # auto: 2 cores a slot
    assert camera_spin(DaemonConfig(slots=1, spin_wait="on")) == SPIN_S
    assert camera_spin(DaemonConfig(slots=1, spin_wait="off")) == 0.0
    # a worker over several slots sleeps on all of them at once, never spins
    assert camera_spin(DaemonConfig(slots=2, workers=1, spin_wait="on")) == 0.0
    assert parse_args(["--spin-wait", "off"]).spin_wait == "off"
    with pytest.raises(SystemExit):
        parse_args(["--spin-wait", "always"])
