"""Cost of ``--heatmap predict`` next to ``detect``: ms/frame at batch 1, one torch thread.

    .venv/bin/python -m benchmarks.predict_speed [--iters 300] [--repeats 5]

Both rows run what the daemon runs per camera frame, on the shipped weights:

- ``detect``: :class:`~active_vision.perception.Perception` (gray, AVNet heatmap + depth);
- ``predict``: the same, then the slot's :class:`~active_vision.history.SlotHistory` push and
  window, and :class:`~active_vision.predict.Predictor` on the window.

Median and best of ``repeats`` runs of ``iters`` frames; the machine's load average is
printed with the table (a shared 2-core machine moves timings by tens of percent). The
budget: AVNet <= 2 ms/frame at batch 1 on one thread.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import torch

from active_vision.history import SlotHistory
from active_vision.perception import Perception, PerceptionConfig
from active_vision.predict import K, Predictor
from fused_image import FUSED_SHAPE, FUSED_SIZE


def _run(perception: Perception, predictor: Predictor | None, frames: np.ndarray) -> float:
    history = SlotHistory(1, K, FUSED_SHAPE)
    window = np.empty((1, K, *FUSED_SHAPE), np.float32)
    t0 = time.perf_counter()
    for f in frames:
        out = perception(f[None])
        if predictor is not None:
            history.push(0, out[0])
            history.window(0, out=window[0])
            out[:, :, :, 1] = predictor(window)
    return 1e3 * (time.perf_counter() - t0) / len(frames)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--iters", type=int, default=300)
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (a.iters, *FUSED_SIZE, 3), dtype=np.uint8)
    perception = Perception(PerceptionConfig(threads=1, max_batch=1))
    predictor = Predictor()
    rows = {}
    for name, pred in (("detect", None), ("predict", predictor)):
        _run(perception, pred, frames[:20])  # warm-up
        runs = [_run(perception, pred, frames) for _ in range(a.repeats)]
        rows[name] = (statistics.median(runs), min(runs))
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; batch 1, 1 thread, "
          f"{a.repeats} x {a.iters} frames")
    print("| mode | median ms/frame | best ms/frame |\n|---|---:|---:|")
    for name, (med, best) in rows.items():
        print(f"| {name} | {med:.3f} | {best:.3f} |")
    extra = rows["predict"][0] - rows["detect"][0]
    print(f"predict adds {extra:.3f} ms/frame (median)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
