"""Seed conformance, both ways, with real processes.

- A reader that follows the seed's ``get_fused_observation`` to the letter (SharedMemory
  attach, resource-tracker unregister, timestamp changed and valid == 1, 1 ms polling)
  reads the frames a ``FrameWriter`` publishes.
- ``FrameReader`` reads the frames of a writer that writes only the seed's 12-byte header
  and payload (no trailer).
"""

from __future__ import annotations

import hashlib
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shm_protocol import FrameReader, FrameWriter, LayoutError

ROOT = Path(__file__).resolve().parents[1]
FUSED = (96, 96, 3)


def _popen(code: str, *args: str) -> subprocess.Popen[str]:
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return subprocess.Popen(
        [sys.executable, "-c", code, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONPATH=path),
    )


def _pattern(k: int) -> np.ndarray:
    """A frame whose every element differs, so a wrong offset or order shows."""
    base = np.arange(96 * 96 * 3, dtype=np.float32).reshape(FUSED) / (96 * 96 * 3)
    return base + np.float32(k)


def _digest(a: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(a, dtype=np.float32).tobytes()).hexdigest()


# The seed's reader (seed 000, "Shared Memory Interface"), as written there.
SEED_READER = '''
import struct, sys, time, hashlib
import numpy as np
from multiprocessing import resource_tracker, shared_memory

class SeedEnv:
    def __init__(self, rl_obs_name):
        self.rl_obs_name = rl_obs_name
        self.rl_obs_shm = shared_memory.SharedMemory(name=self.rl_obs_name)
        resource_tracker.unregister(self.rl_obs_shm._name, "shared_memory")
        self._last_obs_ts = 0.0

    def get_fused_observation(self) -> np.ndarray:
        """Block until a new frame arrives, then return the fused observation."""
        buf = self.rl_obs_shm.buf
        header_size = 12        # 8-byte timestamp + 4-byte valid flag
        data_size   = 96 * 96 * 3 * 4  # float32 elements

        while True:
            ts         = struct.unpack_from('<d', buf, 0)[0]
            valid_flag = struct.unpack_from('<L', buf, 8)[0]

            if ts != self._last_obs_ts and valid_flag == 1:
                self._last_obs_ts = ts
                raw = bytes(buf[header_size : header_size + data_size])
                obs = np.frombuffer(raw, dtype=np.float32).reshape(96, 96, 3)
                return obs.copy()

            time.sleep(0.001)

env = SeedEnv(sys.argv[1])
for _ in sys.stdin:
    obs = env.get_fused_observation()
    print(obs.shape, obs.dtype, hashlib.sha1(obs.tobytes()).hexdigest(), flush=True)
'''


def test_seed_reader_reads_frame_writer(shm_name: str) -> None:
    w = FrameWriter(shm_name, shape=FUSED, dtype=np.float32)
    proc = _popen(SEED_READER, shm_name)
    try:
        for k in range(1, 6):
            frame = _pattern(k)
            w.publish(frame, source_seq=k)
            proc.stdin.write("next\n")
            proc.stdin.flush()
            line = proc.stdout.readline().strip()
            assert line == f"(96, 96, 3) float32 {_digest(frame)}", proc.stderr.read()
        proc.stdin.close()
        assert proc.wait(30) == 0, proc.stderr.read()
        assert os.path.exists(f"/dev/shm/{shm_name}")  # the seed's attach did not unlink it
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        w.close(unlink=True)


# A writer that knows only the seed layout: 12-byte header + payload, no trailer, created
# with SharedMemory like the original Active Vision pipeline.
SEED_WRITER = '''
import struct, sys, time
import numpy as np
from multiprocessing import shared_memory

shm = shared_memory.SharedMemory(name=sys.argv[1], create=True, size=12 + 96 * 96 * 3 * 4)
print("created", flush=True)
base = np.arange(96 * 96 * 3, dtype=np.float32).reshape(96, 96, 3) / (96 * 96 * 3)
for line in sys.stdin:
    k = int(line)
    frame = base + np.float32(k)
    struct.pack_into("<L", shm.buf, 8, 0)
    shm.buf[12 : 12 + frame.nbytes] = frame.tobytes()
    struct.pack_into("<d", shm.buf, 0, time.time())
    struct.pack_into("<L", shm.buf, 8, 1)
    print("published", k, flush=True)
shm.close()
shm.unlink()
'''


def test_frame_reader_reads_a_seed_style_writer(
    shm_name: str, caplog: pytest.LogCaptureFixture
) -> None:
    proc = _popen(SEED_WRITER, shm_name)
    try:
        assert proc.stdout.readline().strip() == "created", proc.stderr.read()
        with pytest.raises(LayoutError, match="shape="):
            FrameReader(shm_name)  # no trailer to take the layout from
        with caplog.at_level(logging.WARNING, logger="shm_protocol"):
            r = FrameReader(shm_name, shape=FUSED, dtype=np.float32)
        assert any("seed" in rec.getMessage() for rec in caplog.records)
        assert not r.has_trailer and r.writer_pid is None
        assert r.latest() is None  # nothing written yet (valid == 0)
        for k in range(1, 6):
            proc.stdin.write(f"{k}\n")
            proc.stdin.flush()
            assert proc.stdout.readline().split()[0] == "published"
            f = r.wait_next(timeout=5)
            assert _digest(f.data) == _digest(_pattern(k))
            assert f.seq == k and f.source_seq == 0
        with pytest.raises(LayoutError, match="wait_next"):
            r.wait_for(source_seq=1, timeout=0.1)
        r.close()
        proc.stdin.close()
        assert proc.wait(30) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
