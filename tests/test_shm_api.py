"""FrameWriter / FrameReader behaviour over real /dev/shm segments (mostly one process;
the liveness tests use real child processes)."""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import threading
import time

import numpy as np
import pytest

from shm_protocol import (
    SPIN_S,
    FrameReader,
    FrameTimeoutError,
    FrameWriter,
    LayoutError,
    NonFiniteError,
    SegmentNotFoundError,
    ShmError,
    WriterGoneError,
    machine_spin,
    spin_for,
)
from shm_protocol import reader as reader_mod
from shm_protocol.layout import FLAG_CHECKSUM, Layout

FUSED = (96, 96, 3)
CTX = mp.get_context("fork")


def _frame(value: float, shape: tuple[int, int, int] = FUSED) -> np.ndarray:
    return np.full(shape, value, dtype=np.float32)


# --- publish and read --------------------------------------------------------------------


def test_publish_then_read(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name, shape=FUSED, dtype=np.float32)
    try:
        assert r.latest() is None
        assert w.publish(_frame(1.0), source_seq=41) == 1
        assert w.publish(_frame(2.0), source_seq=42) == 2
        f = r.wait_next(timeout=2.0)
        assert (f.seq, f.source_seq) == (2, 42)  # frames are not queued: the newest one
        assert f.data.shape == FUSED and f.data.dtype == np.float32 and np.all(f.data == 2.0)
        assert abs(f.timestamp - time.time()) < 60
        with pytest.raises(FrameTimeoutError):
            r.wait_next(timeout=0.05)  # nothing newer than the last one returned
        again = r.latest()
        assert again is not None and again.seq == 2 and again.data is not f.data
        assert r.wait_for(source_seq=42, timeout=0.05).seq == 2  # already there
        assert r.wait_for(source_seq=40, timeout=0.05).seq == 2  # source_seq >= k
        with pytest.raises(FrameTimeoutError, match="source_seq >= 43"):
            r.wait_for(source_seq=43, timeout=0.05)
    finally:
        r.close()
        w.close(unlink=True)


def test_out_array_is_filled_in_place(shm_name: str) -> None:
    with FrameWriter(shm_name, shape=FUSED, dtype=np.float32) as w:
        r = FrameReader(shm_name)
        out = np.empty(FUSED, np.float32)
        w.publish(_frame(3.0))
        f = r.wait_next(timeout=1.0, out=out)
        assert f.data is out and np.all(out == 3.0)
        with pytest.raises(LayoutError, match="96x96x3 float32"):
            r.wait_next(timeout=0.1, out=np.empty((96, 96, 3), np.float64))
        r.close()
        w.close(unlink=True)


def test_timestamps_strictly_increase(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=(2, 2, 1), dtype=np.uint8)
    r = FrameReader(shm_name)
    try:
        stamps = []
        for i in range(500):
            w.publish(np.full((2, 2, 1), i % 256, np.uint8))
            stamps.append(r.latest().timestamp)
        assert all(b > a for a, b in zip(stamps, stamps[1:], strict=False))
    finally:
        r.close()
        w.close(unlink=True)


def test_layout_is_taken_from_the_trailer(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=(48, 64, 4), dtype=np.uint8)
    try:
        r = FrameReader(shm_name)
        cam = FrameWriter(shm_name, create=False)
        assert r.shape == cam.shape == (48, 64, 4)
        assert r.dtype == cam.dtype == np.uint8
        assert not cam.created and w.created
        r.close()
        cam.close()
    finally:
        w.close(unlink=True)


def test_segment_is_mode_0600_whatever_the_umask(shm_name: str) -> None:
    old = os.umask(0)
    try:
        w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    finally:
        os.umask(old)
    try:
        assert os.stat(f"/dev/shm/{shm_name}").st_mode & 0o777 == 0o600
        assert os.stat(f"/dev/shm/{shm_name}").st_size == Layout.of(FUSED, np.float32).segment_size
    finally:
        w.close(unlink=True)


# --- errors that say what to do ----------------------------------------------------------


def test_missing_segment_error_names_name_existing_and_daemon(shm_name: str) -> None:
    other = f"{shm_name}_other"
    w = FrameWriter(other, shape=FUSED, dtype=np.float32)
    try:
        with pytest.raises(SegmentNotFoundError) as exc:
            FrameReader(shm_name, attach_timeout=0.1)
        msg = str(exc.value)
        assert shm_name in msg and f"/dev/shm/{shm_name}" in msg
        assert other in msg and "96x96x3 float32" in msg  # what exists, with its layout
        assert f"av-daemon --name {shm_name}" in msg and "rover-pair" in msg
        assert exc.value.name == shm_name and isinstance(exc.value, FileNotFoundError)
        with pytest.raises(SegmentNotFoundError, match=f"av-daemon --name {shm_name}"):
            FrameWriter(f"{shm_name}_camera", create=False)
    finally:
        w.close(unlink=True)


def test_attach_with_another_layout_names_both(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=(48, 48, 3), dtype=np.uint8)
    try:
        for make in (
            lambda: FrameReader(shm_name, shape=FUSED, dtype=np.float32),
            lambda: FrameReader(shm_name, dtype=np.float32),
            lambda: FrameWriter(shm_name, shape=FUSED, dtype=np.float32, create=False),
            lambda: FrameWriter(shm_name, shape=FUSED, dtype=np.float32),  # create, no replace
        ):
            with pytest.raises(LayoutError) as exc:
                make()
            assert "48x48x3 uint8" in str(exc.value), str(exc.value)
            assert "float32" in str(exc.value)
    finally:
        w.close(unlink=True)


def test_publish_rejects_wrong_shape_and_dtype(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    try:
        with pytest.raises(LayoutError, match=r"expected .*96x96x3 float32.*got 96x96x3 float64"):
            w.publish(np.zeros(FUSED, np.float64))
        with pytest.raises(ValueError, match=r"expected .*96x96x3 float32.*got 96x96x4 float32"):
            w.publish(np.zeros((96, 96, 4), np.float32))
        assert w.seq == 0
    finally:
        w.close(unlink=True)


def test_publish_rejects_non_finite_and_says_where(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name)
    try:
        bad = _frame(0.5)
        bad[3, 4, 1] = np.nan
        bad[10, 0, 1] = np.inf
        bad[90, 5, 2] = -np.inf
        with pytest.raises(NonFiniteError) as exc:
            w.publish(bad)
        msg = str(exc.value)
        assert "3 non-finite" in msg and "1 NaN" in msg and "2 +/-inf" in msg
        assert "(3, 4, 1)" in msg and "1: 2" in msg and "2: 1" in msg  # where, per channel
        assert "poisons training" in msg
        assert isinstance(exc.value, ValueError)
        assert r.latest() is None  # nothing was published
        FrameWriter(shm_name, shape=FUSED, dtype=np.float32, check_finite=False).publish(bad)
        assert np.isnan(r.latest().data[3, 4, 1])
    finally:
        r.close()
        w.close(unlink=True)


def test_errors_survive_pickling() -> None:
    for exc in (
        WriterGoneError("gone", "n", 12, "exited"),
        FrameTimeoutError("late", "n", 2.0),
        SegmentNotFoundError("missing", "n", ["a"]),
    ):
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and str(back) == str(exc)
        assert back.name == "n"


# --- liveness: timeout vs writer gone -----------------------------------------------------


def test_timeout_while_writer_alive_is_a_timeout(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name, stale_after=5.0)
    try:
        w.publish(_frame(1.0), source_seq=7)
        r.wait_next(timeout=1.0)
        with pytest.raises(FrameTimeoutError) as exc:
            r.wait_next(timeout=0.3)
        assert not isinstance(exc.value, WriterGoneError)
        assert f"pid {os.getpid()}" in str(exc.value) and "alive" in str(exc.value)
        assert r.is_writer_alive() and r.writer_pid == os.getpid()
    finally:
        r.close()
        w.close(unlink=True)


def test_orderly_close_wakes_a_waiting_reader_with_writer_gone(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name)
    closer = threading.Timer(0.2, w.close)  # close(unlink=False): the restart path
    closer.start()
    try:
        with pytest.raises(WriterGoneError) as exc:
            r.wait_next(timeout=30.0)
        assert exc.value.reason == "shutdown" and "shut down" in str(exc.value)
        assert not r.is_writer_alive()
        assert os.path.exists(f"/dev/shm/{shm_name}")  # close(unlink=False) keeps it
    finally:
        closer.join()
        r.close()
        FrameWriter(shm_name, create=False).close(unlink=True)


def _publish_then_idle(name: str, heartbeat: bool, ready: mp.synchronize.Event,
                       stop: mp.synchronize.Event) -> None:
    w = FrameWriter(name, shape=FUSED, dtype=np.float32)
    w.publish(np.ones(FUSED, np.float32))
    ready.set()
    while not stop.wait(0.05):
        if heartbeat:
            w.heartbeat()
    w.close(unlink=True)


@pytest.mark.parametrize("heartbeat", [False, True])
def test_stale_heartbeat_is_writer_gone_and_heartbeat_keeps_it_alive(
    shm_name: str, heartbeat: bool
) -> None:
    ready, stop = CTX.Event(), CTX.Event()
    child = CTX.Process(target=_publish_then_idle, args=(shm_name, heartbeat, ready, stop))
    child.start()
    try:
        assert ready.wait(10)
        r = FrameReader(shm_name, stale_after=0.3)
        assert r.writer_pid == child.pid
        r.wait_next(timeout=2.0)
        if heartbeat:  # alive and idle: a plain timeout
            with pytest.raises(FrameTimeoutError):
                r.wait_next(timeout=0.8)
            assert r.is_writer_alive()
        else:  # alive pid, no heartbeat: hung
            with pytest.raises(WriterGoneError) as exc:
                r.wait_next(timeout=30.0)
            assert exc.value.reason == "stale" and "heartbeat" in str(exc.value)
            assert not r.is_writer_alive()
        r.close()
    finally:
        stop.set()
        child.join(10)


def _attach_as_writer_and_publish(name: str, done: mp.synchronize.Event) -> None:
    cam = FrameWriter(name, create=False)
    cam.publish(np.full(cam.shape, 7, cam.dtype), source_seq=0)
    done.wait(10)
    cam.close()


def test_create_false_writer_stamps_its_own_pid(shm_name: str) -> None:
    owner = FrameWriter(shm_name, shape=(8, 8, 3), dtype=np.uint8)  # the daemon's role
    r = FrameReader(shm_name)
    done = CTX.Event()
    child = CTX.Process(target=_attach_as_writer_and_publish, args=(shm_name, done))
    child.start()
    try:
        f = r.wait_next(timeout=10.0)
        assert np.all(f.data == 7) and r.writer_pid == child.pid
    finally:
        done.set()
        child.join(10)
        r.close()
        owner.close(unlink=True)


# --- waking without a futex, checksum mode ------------------------------------------------


def _publish_later(name: str, shape: tuple[int, int, int], dtype: object, delay: float) -> None:
    w = FrameWriter(name, create=False)
    time.sleep(delay)
    w.publish(np.ones(shape, dtype))
    time.sleep(0.5)


@pytest.mark.parametrize("case", ["no futex", "unaligned wake word"])
def test_waiting_works_without_a_futex(
    shm_name: str, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    if case == "no futex":
        monkeypatch.setattr(reader_mod, "FUTEX_AVAILABLE", False)
        shape, dtype = FUSED, np.float32
    else:
        shape, dtype = (3, 3, 1), np.uint8  # 9-byte payload: wake word not 4-byte aligned
    w = FrameWriter(shm_name, shape=shape, dtype=dtype)
    r = FrameReader(shm_name)
    assert r._futex is None
    child = CTX.Process(target=_publish_later, args=(shm_name, shape, dtype, 0.2))
    child.start()
    try:
        f = r.wait_next(timeout=10.0)
        assert np.all(f.data == 1)
    finally:
        child.join(10)
        r.close()
        w.close(unlink=True)


def test_checksum_mode_verifies_every_copy(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32, checksum=True)
    r = FrameReader(shm_name)
    try:
        w.publish(_frame(1.0), source_seq=1)
        assert r._t.flags & FLAG_CHECKSUM
        assert np.all(r.wait_next(timeout=1.0).data == 1.0)
        # corrupt the payload behind the seqlock's back: the checksum rejects the copy
        fd = os.open(f"/dev/shm/{shm_name}", os.O_RDWR)
        os.pwrite(fd, np.float32(9.0).tobytes(), 12 + 4 * 100)
        os.close(fd)
        assert r.latest() is None
        with pytest.raises(FrameTimeoutError):
            r.wait_for(source_seq=1, timeout=0.2)
        w.publish(_frame(2.0), source_seq=2)
        assert np.all(r.wait_next(timeout=1.0).data == 2.0)
        # a writer that attaches with checksum off clears the flag
        FrameWriter(shm_name, create=False, checksum=False).close()
        assert not r._t.flags & FLAG_CHECKSUM
    finally:
        r.close()
        w.close(unlink=True)


def test_closed_objects_refuse_work(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=(2, 2, 1), dtype=np.uint8)
    r = FrameReader(shm_name)
    r.close()
    r.close()
    with pytest.raises(ShmError):
        r.wait_next(timeout=0.1)
    w.close(unlink=True)
    w.close(unlink=True)
    with pytest.raises(ShmError):
        w.publish(np.zeros((2, 2, 1), np.uint8))
    assert not os.path.exists(f"/dev/shm/{shm_name}")


# --- spinning before the futex sleep -----------------------------------------------------


class _CountingFutex:
    """Stands in for a reader's futex word and counts its sleeps."""

    def __init__(self, word) -> None:  # noqa: ANN001
        self.word, self.sleeps = word, 0
        self.address = word.address

    def wait(self, expected: int, timeout: float) -> None:
        self.sleeps += 1
        self.word.wait(expected, timeout)


@pytest.mark.parametrize("spin", [0.0, 1.0])
def test_a_spinning_reader_takes_a_frame_without_sleeping(shm_name: str, spin: float) -> None:
    """With a spin longer than the frame takes to come, the wait never sleeps on the futex;
    without one it does. The frame is the same either way."""
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name, spin=spin)
    futex = r._futex = _CountingFutex(r._futex)  # type: ignore[assignment]
    try:
        w.publish(_frame(1.0), source_seq=1)
        r.wait_next(timeout=1.0)
        later = threading.Timer(0.05, lambda: w.publish(_frame(2.0), source_seq=2))
        later.start()
        f = r.wait_for(source_seq=2, timeout=5.0)
        later.join()
        assert f.source_seq == 2 and f.data[0, 0, 0] == 2.0
        assert (futex.sleeps == 0) == (spin > 0), futex.sleeps
    finally:
        r.close()
        w.close(unlink=True)


def test_a_spin_ends_in_the_futex_sleep_and_keeps_the_timeout(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name, spin=0.05)
    futex = r._futex = _CountingFutex(r._futex)  # type: ignore[assignment]
    try:
        w.publish(_frame(1.0))
        r.wait_next(timeout=1.0)
        with pytest.raises(FrameTimeoutError):
            r.wait_next(timeout=0.3)  # spins 0.05 s, then sleeps
        assert futex.sleeps > 0
        with pytest.raises(ValueError, match="spin must be >= 0"):
            FrameReader(shm_name, spin=-1.0)
    finally:
        r.close()
        w.close(unlink=True)


def test_a_reader_whose_spins_do_not_pay_sleeps_at_once_for_a_while(
    shm_name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frames that keep coming after the spin pause the spinning, then it resumes; waits
    that end with no frame at all (an idle writer) do not."""
    monkeypatch.setattr(reader_mod, "SPIN_PAUSE_S", 0.3)
    # the thread always has its core here: a spin that a busy machine keeps off its core is
    # a failure by design, which would pause the idle waits below on a loaded CI machine
    monkeypatch.setattr(reader_mod.time, "thread_time", time.monotonic)
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name, spin=0.002)
    try:
        w.publish(_frame(1.0))
        r.wait_next(timeout=1.0)
        for _ in range(10):  # idle: no frames at all
            with pytest.raises(FrameTimeoutError):
                r.wait_next(timeout=0.004)
        assert not r.spin_paused
        for i in range(10):  # each frame 10 ms after the call: every spin is too short
            if r.spin_paused:
                break
            later = threading.Timer(0.01, lambda v=float(i): w.publish(_frame(v)))
            later.start()
            r.wait_next(timeout=1.0)
            later.join()
        assert r.spin_paused
        futex = r._futex = _CountingFutex(r._futex)  # type: ignore[assignment]
        later = threading.Timer(0.02, lambda: w.publish(_frame(2.0)))
        later.start()
        assert r.wait_next(timeout=1.0).data[0, 0, 0] == 2.0
        later.join()
        assert futex.sleeps > 0  # paused: slept at once
        time.sleep(0.35)
        assert not r.spin_paused
    finally:
        r.close()
        w.close(unlink=True)


def test_spin_for_wants_a_core_for_each_env_and_each_worker() -> None:
    assert spin_for(1, cores=2) == SPIN_S
    assert spin_for(2, cores=4) == SPIN_S
    assert spin_for(2, cores=2) == 0.0  # two envs and two workers on two cores: sleep
    assert spin_for(1, cores=1) == 0.0


def test_machine_spin_counts_every_daemons_envs_on_this_machine() -> None:
    """Two daemons of one slot each on a machine: four busy threads, not two."""
    cores = len(os.sched_getaffinity(0))
    names = [f"test_spin_{os.getpid()}_{i}_camera" for i in range(cores)]
    writers = [FrameWriter(n, shape=(4, 4, 3), dtype=np.uint8) for n in names]
    try:
        assert machine_spin(1) == 0.0  # at least `cores` env slots: two cores each is too many
    finally:
        for w in writers:
            w.close(unlink=True)
