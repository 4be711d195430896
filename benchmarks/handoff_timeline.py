"""Where a fused env step's round trip goes beyond the network: a per-frame timeline.

A stand-in env (this process: a busy loop of ``--env-ms`` for physics + render, then
publish a camera frame and ``wait_for`` its fused frame, exactly as ``RoverEnvFused``
does) against a real av-daemon ``Daemon`` in a child process whose source poll and
perception are timed per frame. For every frame (wall clock, one clock for both processes):

    env publish -> daemon has the frame (woken + copied) -> perception start -> end
    -> fused frame stamped (publish) -> env has the fused frame

and prints the medians of each gap, per daemon precision, interleaved over ``--repeats``
rounds::

    python -m benchmarks.handoff_timeline --precision fp32,int8 --frames 400 --repeats 3
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time

import numpy as np

from fused_image import FUSED_SIZE

STAGES = ("wake+read", "gather", "perception", "publish", "env wake+read")


def _daemon_child(name: str, precision: str, times, ready, stop) -> None:
    from active_vision.daemon import Daemon, DaemonConfig

    d = Daemon(DaemonConfig(name=name, precision=precision, log_every=0,
                            log_level="WARNING"))
    d.start()
    worker = d.workers[0]
    src, perc = worker.source, worker.perception
    poll, call = src.poll, perc.__call__
    last = [0]

    def timed_poll(timeout):
        new = poll(timeout)
        if new:
            last[0] = new[0].seq % len(times)
            times[last[0]][0] = time.time()
        return new

    class Timed:
        timings = perc.timings

        def __call__(self, frames):
            row = times[last[0]]
            row[1] = time.time()
            out = call(frames)
            row[2] = time.time()
            return out

    src.poll = timed_poll
    worker.perception = Timed()
    ready.set()
    import threading

    threading.Thread(target=lambda: (stop.wait(), setattr(d.stop, "signal", 15)),
                     daemon=True).start()
    try:
        d.serve()
    finally:
        d.shutdown()


def run_once(name: str, precision: str, frames: int, env_ms: float):
    from shm_protocol import FrameReader, FrameWriter, camera_name

    ctx = mp.get_context("spawn")
    n = frames + 50
    times = ctx.Array("d", n * 3, lock=False)
    rows = np.frombuffer(times, np.float64).reshape(n, 3)
    ready, stop = ctx.Event(), ctx.Event()
    child = ctx.Process(target=_daemon_child,
                        args=(name, precision, rows_proxy(times, n), ready, stop))
    child.start()
    ready.wait(120)
    cam = FrameWriter(camera_name(name), shape=(*FUSED_SIZE, 3), dtype=np.uint8, create=False)
    fused = FrameReader(name, dtype=np.float32)
    frame = np.random.default_rng(0).integers(0, 255, (*FUSED_SIZE, 3), dtype=np.uint8)
    env = np.empty((n, 3))
    try:
        for _ in range(n):
            end = time.perf_counter() + env_ms / 1e3
            while time.perf_counter() < end:
                pass
            t0 = time.time()
            seq = cam.publish(frame)
            f = fused.wait_for(seq, timeout=5.0)
            env[seq % n] = (t0, f.timestamp, time.time())
    finally:
        stop.set()
        child.join(30)
        cam.close()
        fused.close()
    env, rows = env[50:], rows[50:]
    gaps = np.stack([rows[:, 0] - env[:, 0], rows[:, 1] - rows[:, 0], rows[:, 2] - rows[:, 1],
                     env[:, 1] - rows[:, 2], env[:, 2] - env[:, 1]], axis=1)
    total = env[:, 2] - env[:, 0]
    return np.median(gaps, axis=0) * 1e6, float(np.median(total)) * 1e6


def rows_proxy(times, n):
    return _Rows(times, n)


class _Rows:
    """Picklable view of the shared timing array as rows of 3 (built in the child)."""

    def __init__(self, times, n):
        self.times, self.n = times, n

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        return np.frombuffer(self.times, np.float64).reshape(self.n, 3)[i]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--precision", default="fp32,int8",
                   help="comma-separated daemon precisions, in run order")
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--env-ms", type=float, default=1.1, help="physics + render stand-in")
    a = p.parse_args()
    precisions = [s.strip() for s in a.precision.split(",") if s.strip()]
    res: dict[str, list] = {s: [] for s in precisions}
    for r in range(a.repeats):
        for s in precisions:
            res[s].append(run_once(f"bench_timeline_{os.getpid()}_{r}_{s}", s, a.frames,
                                   a.env_ms))
    print(f"\nmedian us per frame ({a.frames} frames x {a.repeats} rounds, "
          f"env stand-in {a.env_ms} ms)\n")
    print("| precision | " + " | ".join(STAGES) + " | round trip | beyond perception |")
    print("|---" * (len(STAGES) + 3) + "|")
    for s in precisions:
        g = np.median(np.stack([x[0] for x in res[s]]), axis=0)
        tot = float(np.median([x[1] for x in res[s]]))
        print(f"| {s} | " + " | ".join(f"{v:.0f}" for v in g)
              + f" | {tot:.0f} | {tot - g[2]:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
