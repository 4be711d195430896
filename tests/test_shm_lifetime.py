"""Segment lifetime across real processes: nobody but the owner unlinks, writers die and
restart, segments get replaced."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from shm_protocol import FrameReader, FrameWriter, LayoutError, WriterGoneError

ROOT = Path(__file__).resolve().parents[1]
FUSED = (96, 96, 3)
CTX = mp.get_context("fork")


def _python(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in a fresh interpreter (its own resource tracker, its own exit path)."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    env = dict(os.environ, PYTHONPATH=path)
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=60, env=env)


def _inode(name: str) -> int:
    return os.stat(f"/dev/shm/{name}").st_ino


# --- attaching never unlinks ---------------------------------------------------------------

ATTACH = """
import os, signal, sys
import numpy as np
from shm_protocol import FrameReader, FrameWriter
name, role, how = sys.argv[1:4]
if role == "reader":
    r = FrameReader(name)
    assert r.wait_next(timeout=5).seq == 1
else:
    w = FrameWriter(name, create=False)
    w.publish(np.full(w.shape, 5, w.dtype))
print("attached", flush=True)
if how == "kill":
    os.kill(os.getpid(), signal.SIGKILL)
# "exit": leave without closing anything; the interpreter and its tracker shut down
"""


@pytest.mark.parametrize("role", ["reader", "writer"])
@pytest.mark.parametrize("how", ["exit", "kill"])
def test_attaching_process_never_unlinks(shm_name: str, role: str, how: str) -> None:
    w = FrameWriter(shm_name, shape=(8, 8, 3), dtype=np.uint8)
    try:
        w.publish(np.zeros((8, 8, 3), np.uint8))
        ino = _inode(shm_name)
        res = _python(ATTACH, shm_name, role, how)
        assert "attached" in res.stdout, res.stderr
        assert res.returncode == (-signal.SIGKILL if how == "kill" else 0), res.stderr
        assert _inode(shm_name) == ino
        assert "leaked shared_memory" not in res.stderr
    finally:
        w.close(unlink=True)


CREATE_AND_DIE = """
import os, signal, sys
import numpy as np
from shm_protocol import FrameWriter
w = FrameWriter(sys.argv[1], shape=(96, 96, 3), dtype=np.float32)
w.publish(np.full((96, 96, 3), 4.0, np.float32), source_seq=9)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_creator_killed_leaves_segment_and_readers_see_writer_gone(shm_name: str) -> None:
    res = _python(CREATE_AND_DIE, shm_name)
    assert res.returncode == -signal.SIGKILL, res.stderr
    try:
        r = FrameReader(shm_name)
        f = r.latest()
        assert f is not None and f.source_seq == 9 and np.all(f.data == 4.0)
        with pytest.raises(WriterGoneError) as exc:
            r.wait_next(timeout=30.0)
        assert exc.value.reason == "exited" and "killed" in str(exc.value)
        assert not r.is_writer_alive()
        r.close()
    finally:
        os.unlink(f"/dev/shm/{shm_name}")  # the supervisor's clean-up


# --- a restarted writer reuses the segment ------------------------------------------------


def _writer_run(name: str, value: float, go: mp.synchronize.Event,
                published: mp.synchronize.Event) -> None:
    w = FrameWriter(name, shape=FUSED, dtype=np.float32)
    w.publish(np.full(FUSED, value, np.float32), source_seq=int(value))
    published.set()
    go.wait(10)
    w.close(unlink=False)  # the restart path: leave the segment for the next writer


def test_restarted_writer_reuses_segment_and_attached_reader_continues(shm_name: str) -> None:
    go, published = CTX.Event(), CTX.Event()
    first = CTX.Process(target=_writer_run, args=(shm_name, 1.0, go, published))
    first.start()
    assert published.wait(10)
    r = FrameReader(shm_name)
    ino = _inode(shm_name)
    go2, published2 = CTX.Event(), CTX.Event()
    second = None
    try:
        assert r.wait_next(timeout=5).source_seq == 1
        go.set()
        first.join(10)
        with pytest.raises(WriterGoneError):  # orderly close: shutting-down flag
            r.wait_next(timeout=30)
        second = CTX.Process(target=_writer_run, args=(shm_name, 2.0, go2, published2))
        second.start()
        assert published2.wait(10)
        f = r.wait_next(timeout=10)
        assert f.source_seq == 2 and np.all(f.data == 2.0) and f.seq == 2
        assert _inode(shm_name) == ino and r._seg.ino == ino  # same segment, no re-attach
        assert r.writer_pid == second.pid
    finally:
        go.set()
        go2.set()
        for p in (first, second):
            if p is not None:
                p.join(10)
        r.close()
        os.unlink(f"/dev/shm/{shm_name}")


# --- a replaced segment is re-attached -------------------------------------------------------


def test_reader_reattaches_to_a_replacement_created_before_the_wait(shm_name: str) -> None:
    a = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name)
    a.publish(np.full(FUSED, 1.0, np.float32))
    assert r.wait_next(timeout=1).seq == 1
    old = _inode(shm_name)
    a.close(unlink=True)
    b = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    try:
        assert b.created and _inode(shm_name) != old
        b.publish(np.full(FUSED, 2.0, np.float32))
        f = r.wait_next(timeout=5)
        assert np.all(f.data == 2.0) and f.seq == 1  # the new segment's first frame
        assert r._seg.ino == _inode(shm_name)
    finally:
        r.close()
        b.close(unlink=True)


def _replace_and_publish(name: str) -> None:
    time.sleep(0.3)
    os.unlink(f"/dev/shm/{name}")  # e.g. a supervisor's clean-up, then a new daemon
    w = FrameWriter(name, shape=FUSED, dtype=np.float32)
    w.publish(np.full(FUSED, 3.0, np.float32))
    time.sleep(1.0)
    w.close()


def test_waiting_reader_reattaches_when_the_segment_is_replaced(shm_name: str) -> None:
    a = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)  # stays alive, never closes
    r = FrameReader(shm_name)
    child = CTX.Process(target=_replace_and_publish, args=(shm_name,))
    child.start()
    try:
        f = r.wait_next(timeout=10)
        assert np.all(f.data == 3.0)
    finally:
        child.join(10)
        r.close()
        a.close(unlink=True)  # the name is the replacement's: a must not remove it
        assert os.path.exists(f"/dev/shm/{shm_name}")
        os.unlink(f"/dev/shm/{shm_name}")


def test_replacement_with_another_layout_is_a_layout_error(shm_name: str) -> None:
    a = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    r = FrameReader(shm_name)  # layout taken from the trailer
    b = FrameWriter(shm_name, shape=(48, 48, 3), dtype=np.float32, replace=True)
    try:
        b.publish(np.zeros((48, 48, 3), np.float32))
        with pytest.raises(LayoutError, match=r"48x48x3 float32.*expects 96x96x3 float32"):
            r.wait_next(timeout=5)
    finally:
        r.close()
        a.close()
        b.close(unlink=True)


# --- a writer killed in the middle of a publish --------------------------------------------


def _die_mid_publish(name: str, conn: mp.connection.Connection) -> None:
    w = FrameWriter(name, shape=FUSED, dtype=np.float32)
    w.publish(np.full(FUSED, 1.0, np.float32), source_seq=1)
    conn.send("published")
    conn.recv()
    w._begin()  # seq odd, valid 0, new timestamp: exactly where publish() copies
    w._payload[:48] = 2.0  # half the frame written
    conn.send("mid-publish")
    time.sleep(60)


def test_writer_killed_mid_publish(shm_name: str) -> None:
    parent, child_end = CTX.Pipe()
    child = CTX.Process(target=_die_mid_publish, args=(shm_name, child_end))
    child.start()
    try:
        assert parent.poll(10) and parent.recv() == "published"
        r = FrameReader(shm_name, shape=FUSED, dtype=np.float32)
        assert np.all(r.wait_next(timeout=5).data == 1.0)
        parent.send("go")
        assert parent.poll(10) and parent.recv() == "mid-publish"
        assert r._t.seq % 2 == 1 and r._h.valid == 0
        assert r.latest() is None  # never the half-written frame
        os.kill(child.pid, signal.SIGKILL)  # not reaped yet: a zombie, still dead to us
        with pytest.raises(WriterGoneError) as exc:
            r.wait_next(timeout=30)
        assert exc.value.reason == "exited" and exc.value.pid == child.pid
        with pytest.raises(WriterGoneError):
            r.wait_for(source_seq=2, timeout=30)
        assert r.latest() is None
        child.join(10)
        # a new writer on the same name recovers the reader
        w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
        assert not w.created
        assert r.latest() is None  # the torn frame stays discarded
        w.publish(np.full(FUSED, 3.0, np.float32), source_seq=2)
        f = r.wait_for(source_seq=2, timeout=5)
        assert np.all(f.data == 3.0) and f.seq > 1
        assert r.is_writer_alive()
        r.close()
        w.close(unlink=True)
    finally:
        if child.is_alive():
            child.kill()
        child.join(10)


def _publish_flat_out(name: str, ready: mp.synchronize.Event) -> None:
    w = FrameWriter(name, shape=(64, 64, 3), dtype=np.float32)
    a = np.empty((64, 64, 3), np.float32)
    k = 0
    while True:
        k += 1
        a.fill(k)
        assert w.publish(a, source_seq=k) == k
        if k == 100:
            ready.set()


def test_writer_killed_while_publishing_flat_out(shm_name: str) -> None:
    ready = CTX.Event()
    child = CTX.Process(target=_publish_flat_out, args=(shm_name, ready))
    child.start()
    try:
        assert ready.wait(10)
        r = FrameReader(shm_name)
        killer = threading.Timer(0.3, os.kill, (child.pid, signal.SIGKILL))
        killer.start()
        frames = 0
        with pytest.raises(WriterGoneError):
            while True:
                f = r.wait_next(timeout=30)
                assert f.data.min() == f.data.max() == f.seq == f.source_seq
                frames += 1
        killer.join()
        assert frames > 0
        last = r.latest()  # whatever is left is complete, or nothing
        assert last is None or last.data.min() == last.data.max() == last.seq
        r.close()
    finally:
        if child.is_alive():
            child.kill()
        child.join(10)
        os.unlink(f"/dev/shm/{shm_name}")
