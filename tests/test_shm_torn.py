"""Torn reads: a writer process publishing flat out, reader processes checking every frame.

Every element of frame k holds k, so a copy that mixes two frames is caught by
``min != max`` (and a copy labelled with the wrong frame number by ``!= seq``). The same
harness with a reader that skips the re-check must catch tears: that proves the harness
can fail, so its passing the real reader means something.
"""

from __future__ import annotations

import multiprocessing as mp

import numpy as np
import pytest

from shm_protocol import FrameReader, FrameWriter, ShmError

SHAPE = (96, 96, 3)  # the fused frame: 110,592 bytes per copy
FRAMES = 30_000
CTX = mp.get_context("fork")


def _writer(name: str, frames: int, checksum: bool, stop: mp.synchronize.Event,
            finished: mp.synchronize.Event) -> None:
    w = FrameWriter(name, create=False, checksum=checksum)
    a = np.empty(SHAPE, np.float32)
    for k in range(1, frames + 1):
        a.fill(k)  # exact in float32 up to 2**24
        w.publish(a, source_seq=k)
        if k % 256 == 0 and stop.is_set():
            break
    w.close()  # waiting readers get WriterGoneError(shutdown)
    finished.set()


def _reader(name: str, how: str, recheck: bool, frames: int, stop: mp.synchronize.Event,
            finished: mp.synchronize.Event, ready: mp.synchronize.Event,
            conn: mp.connection.Connection) -> None:
    """Check every copy returned. ``how``: "wait" (wait_next: woken by the writer, so in
    step with it) or "poll" (latest() in a loop: copies start at any point of the
    writer's cycle, which is where tears happen)."""
    r = FrameReader(name, shape=SHAPE, dtype=np.float32)
    r._recheck = recheck
    out = np.empty(SHAPE, np.float32)
    copies = torn = 0
    distinct = set()
    ready.set()
    while True:
        if how == "wait":
            try:
                f = r.wait_next(timeout=20.0, out=out)
            except ShmError:
                break
        else:
            f = r.latest(out=out)
            if f is None:
                if finished.is_set():
                    break
                continue
        copies += 1
        distinct.add(f.seq)
        if not (out.min() == out.max() == f.seq == f.source_seq):
            torn += 1
            if not recheck:  # the control run only needs one
                stop.set()
                break
        if f.seq >= frames or (how == "poll" and finished.is_set()):
            break
    conn.send((copies, len(distinct), torn))
    r.close()


def _run(name: str, readers: tuple[str, ...], recheck: bool, checksum: bool) -> list[tuple]:
    """Writer process flat out + one process per entry of ``readers``; their reports."""
    owner = FrameWriter(name, shape=SHAPE, dtype=np.float32)  # the daemon's role: creates
    stop, finished = CTX.Event(), CTX.Event()
    pipes, procs, ready = [], [], []
    try:
        for how in readers:
            parent, child = CTX.Pipe()
            ev = CTX.Event()
            p = CTX.Process(target=_reader,
                            args=(name, how, recheck, FRAMES, stop, finished, ev, child))
            p.start()
            pipes.append(parent)
            procs.append(p)
            ready.append(ev)
        for ev in ready:
            assert ev.wait(30)
        writer = CTX.Process(target=_writer, args=(name, FRAMES, checksum, stop, finished))
        writer.start()
        procs.append(writer)
        results = []
        for conn in pipes:
            assert conn.poll(60), "reader process did not report"
            results.append(conn.recv())
        return results
    finally:
        stop.set()
        for p in procs:
            p.join(30)
            if p.is_alive():
                p.kill()
                p.join()
        owner.close(unlink=True)


def test_frame_reader_never_returns_a_torn_frame(shm_name: str) -> None:
    results = _run(shm_name, ("wait", "poll"), recheck=True, checksum=False)
    for copies, distinct, torn in results:
        assert torn == 0, f"{torn} torn frames out of {copies} copies"
        assert distinct > 0


def test_checksum_mode_alone_also_rejects_torn_copies(shm_name: str) -> None:
    # The ARM64 safeguard: with the seqlock re-check skipped, crc32(payload, seq) alone
    # rejects every mixed copy.
    [(copies, distinct, torn)] = _run(shm_name, ("poll",), recheck=False, checksum=True)
    assert torn == 0, f"{torn} torn frames out of {copies} copies"
    assert distinct > 0


def test_harness_catches_tears_when_the_recheck_is_skipped(shm_name: str) -> None:
    [(copies, distinct, torn)] = _run(shm_name, ("poll",), recheck=False, checksum=False)
    assert torn >= 1, f"no torn copy in {copies} copies: the harness could not fail"


@pytest.fixture(autouse=True)
def _fork_only() -> None:
    if "fork" not in mp.get_all_start_methods():
        pytest.skip("needs fork")
