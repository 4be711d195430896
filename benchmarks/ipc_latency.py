"""Publish-to-receive latency, frame rate and idle cost of shm_protocol readers.

Three readers of the same fused segment (96x96x3 float32), each in its own process, against
one writer (this process, a ``FrameWriter``), in one run:

- ``FrameReader``: ``wait_next(out=...)``, sleeping on the trailer's futex word.
- ``seed 1 ms poll``: the seed's ``get_fused_observation`` rule (timestamp changed and
  valid == 1, ``bytes()`` + ``np.frombuffer().copy()``, else ``time.sleep(0.001)``).
- ``spin``: the floor: a loop that never sleeps, then the same consistent copy.
- ``FrameReader, checksum mode``: the writer adds ``crc32(payload, seq)`` and the reader
  verifies it (the default on CPUs that are not x86; here to show its cost).

Measured per reader:

- latency: ``time.time()`` after the reader's copy minus the frame's timestamp (taken by
  the writer before its own copy), so both copies are included; frames published at
  ``--rate`` Hz with +/-50 % random jitter, so polling phases are sampled fairly;
- max rate: frames per second the reader receives (each one copied out) while the writer
  publishes flat out;
- idle CPU: CPU seconds per second the reader burns while waiting for frames that do not
  come (the writer alive, heartbeating).

    python -m benchmarks.ipc_latency            # about 50 s
    python -m benchmarks.ipc_latency --quick    # about 12 s
"""

from __future__ import annotations

import argparse
import mmap
import multiprocessing as mp
import os
import platform
import random
import resource
import struct
import sys
import time
from dataclasses import dataclass

import numpy as np

from fused_image import FUSED_SHAPE
from shm_protocol import FrameReader, FrameTimeoutError, FrameWriter

SHAPE = FUSED_SHAPE
READERS = ("FrameReader", "seed 1 ms poll", "spin", "FrameReader, checksum mode")
STOP = -1.0  # payload value of the frame that ends a phase


@dataclass
class Args:
    """What one run measures."""

    frames: int = 3000
    """Frames published in the latency phase (per reader)."""
    rate: float = 500.0
    """Mean publish rate of the latency phase, Hz."""
    flat_out_s: float = 2.0
    """Seconds the writer publishes flat out in the max-rate phase (per reader)."""
    idle_s: float = 3.0
    """Seconds a reader waits with nothing published in the idle phase (per reader)."""


# --- readers (each runs in a child process) ---------------------------------------------


class _SeedPoller:
    """The seed's get_fused_observation, over a plain read-only mapping of the segment."""

    def __init__(self, name: str) -> None:
        fd = os.open(f"/dev/shm/{name}", os.O_RDONLY)
        self._mm = mmap.mmap(fd, os.fstat(fd).st_size, access=mmap.ACCESS_READ)
        os.close(fd)
        self._buf = memoryview(self._mm)
        self._last_obs_ts = struct.unpack_from("<d", self._buf, 0)[0]
        self._last_seq = struct.unpack_from("<Q", self._buf, len(self._buf) - 64 + 24)[0]
        self._size = int(np.prod(SHAPE)) * 4

    def get(self, deadline: float) -> np.ndarray | None:
        buf = self._buf
        while time.monotonic() < deadline:
            ts = struct.unpack_from("<d", buf, 0)[0]
            valid_flag = struct.unpack_from("<L", buf, 8)[0]
            if ts != self._last_obs_ts and valid_flag == 1:
                self._last_obs_ts = ts
                raw = bytes(buf[12 : 12 + self._size])
                return np.frombuffer(raw, dtype=np.float32).reshape(SHAPE).copy()
            time.sleep(0.001)
        return None

    def spin_until_new(self, deadline: float) -> bool:
        """Spin (no sleep) until the trailer's seq is even and new: a frame is complete."""
        buf, off = self._buf, len(self._buf) - 64 + 24
        while time.monotonic() < deadline:
            seq = struct.unpack_from("<Q", buf, off)[0]
            if seq != self._last_seq and not seq & 1:
                self._last_seq = seq
                return True
        return False


def _receive(kind: str, reader: FrameReader, poller: _SeedPoller, out: np.ndarray,
             deadline: float) -> tuple[float, float] | None:
    """Next frame by ``kind``'s rule: (payload marker, timestamp) or None at the deadline."""
    if kind.startswith("FrameReader"):
        try:
            f = reader.wait_next(timeout=max(0.0, deadline - time.monotonic()), out=out)
        except FrameTimeoutError:
            return None
        return float(f.data[0, 0, 0]), f.timestamp
    if kind == "seed 1 ms poll":
        data = poller.get(deadline)
        if data is None:
            return None
        return float(data[0, 0, 0]), poller._last_obs_ts
    while poller.spin_until_new(deadline):  # spin
        f = reader.latest(out=out)
        if f is not None:
            return float(f.data[0, 0, 0]), f.timestamp
    return None


def _reader_main(kind: str, name: str, conn: mp.connection.Connection) -> None:
    reader = FrameReader(name, shape=SHAPE, dtype=np.float32)
    poller = _SeedPoller(name)
    out = np.empty(SHAPE, np.float32)
    reader.latest(out=out)  # mark what is there as seen
    while True:
        cmd = conn.recv()
        if cmd[0] == "quit":
            break
        if cmd[0] == "latency":
            lat: list[float] = []
            conn.send("ready")
            while True:
                got = _receive(kind, reader, poller, out, time.monotonic() + 5.0)
                if got is None or got[0] == STOP:
                    break
                lat.append(time.time() - got[1])
            conn.send(lat)
        elif cmd[0] == "rate":
            count, first, last = 0, 0.0, 0.0
            conn.send("ready")
            while True:
                got = _receive(kind, reader, poller, out, time.monotonic() + 5.0)
                if got is None or got[0] == STOP:
                    break
                now = time.monotonic()
                if count == 0:
                    first = now
                count, last = count + 1, now
            conn.send((count, last - first))
        elif cmd[0] == "idle":
            seconds = cmd[1]
            conn.send("ready")
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            t0 = time.monotonic()
            _receive(kind, reader, poller, out, t0 + seconds)
            wall = time.monotonic() - t0
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
            conn.send(cpu / wall)
    reader.close()


# --- the writer side (this process) ----------------------------------------------------


def _run_reader(kind: str, name: str, writer: FrameWriter, args: Args) -> dict[str, float]:
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_reader_main, args=(kind, name, child), daemon=True)
    proc.start()
    frame = np.zeros(SHAPE, np.float32)
    stop = np.full(SHAPE, STOP, np.float32)
    rng = random.Random(0)
    try:
        # latency: paced publishes
        parent.send(("latency",))
        parent.recv()
        time.sleep(0.2)
        for i in range(args.frames):
            frame[0, 0, 0] = i
            writer.publish(frame)
            time.sleep(rng.uniform(0.5, 1.5) / args.rate)
        time.sleep(0.01)
        writer.publish(stop)
        lat_us = np.array(parent.recv()) * 1e6
        # max rate: flat out
        parent.send(("rate",))
        parent.recv()
        time.sleep(0.2)
        published = 0
        t_end = time.monotonic() + args.flat_out_s
        while time.monotonic() < t_end:
            writer.publish(frame)
            published += 1
        time.sleep(0.01)
        writer.publish(stop)
        received, span = parent.recv()
        # idle: nothing published, writer heartbeating
        parent.send(("idle", args.idle_s))
        parent.recv()
        t_end = time.monotonic() + args.idle_s + 0.5
        while time.monotonic() < t_end:
            writer.heartbeat()
            time.sleep(0.2)
        idle = parent.recv()
        parent.send(("quit",))
    finally:
        proc.join(10)
        if proc.is_alive():
            proc.kill()
    return {
        "p50": float(np.percentile(lat_us, 50)) if len(lat_us) else float("nan"),
        "p99": float(np.percentile(lat_us, 99)) if len(lat_us) else float("nan"),
        "max": float(lat_us.max()) if len(lat_us) else float("nan"),
        "received": len(lat_us),
        "sent": args.frames,
        "rate": received / span if span > 0 else float("nan"),
        "writer_rate": published / args.flat_out_s,
        "idle_cpu": idle * 100.0,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="short run (about 12 s)")
    p.add_argument("--frames", type=int, help="latency-phase frames per reader")
    p.add_argument("--rate", type=float, help="latency-phase publish rate, Hz")
    ns = p.parse_args(argv)
    args = Args(frames=400, flat_out_s=0.5, idle_s=1.0) if ns.quick else Args()
    if ns.frames:
        args.frames = ns.frames
    if ns.rate:
        args.rate = ns.rate

    name = f"bench_ipc_{os.getpid()}"
    writer = FrameWriter(name, shape=SHAPE, dtype=np.float32)
    results: dict[str, dict[str, float]] = {}
    try:
        for kind in READERS:
            if kind.endswith("checksum mode"):  # last: the same segment, a checksumming writer
                writer.close()
                writer = FrameWriter(name, create=False, checksum=True)
            results[kind] = _run_reader(kind, name, writer, args)
    finally:
        writer.close(unlink=True)

    print(
        f"# ipc_latency: {SHAPE[0]}x{SHAPE[1]}x{SHAPE[2]} float32 ({np.prod(SHAPE) * 4} B), "
        f"{args.frames} frames at ~{args.rate:g} Hz per reader, flat out {args.flat_out_s:g} s, "
        f"idle {args.idle_s:g} s"
    )
    print(
        f"# {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"numpy {np.__version__}, load average {os.getloadavg()[0]:.2f} at end"
    )
    print()
    print("| reader | p50 µs | p99 µs | max µs | received | max rate (frames/s) | idle CPU |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for kind, r in results.items():
        print(
            f"| {kind} | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} | "
            f"{r['received']}/{r['sent']} | {r['rate']:.0f} | {r['idle_cpu']:.1f} % |"
        )
    print()
    fr, seed = results["FrameReader"], results["seed 1 ms poll"]
    print(f"writer flat out: {fr['writer_rate']:.0f} publishes/s (with the FrameReader attached)")
    speedup = seed["p50"] / fr["p50"]
    checks = [
        ("FrameReader p50 <= 100 µs", fr["p50"] <= 100),
        ("FrameReader p99 <= 500 µs", fr["p99"] <= 500),
        (f"p50 >= 5x lower than seed polling ({speedup:.1f}x)", speedup >= 5),
        ("idle FrameReader < 5 % of a core", fr["idle_cpu"] < 5),
    ]
    for label, ok in checks:
        print(f"target {'met ' if ok else 'MISSED'}: {label}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
