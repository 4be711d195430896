"""fp32 against int8 perception, side by side in one run: speed at batch 1 and 8 on one
thread, and the held-out figures per world of each precision.

    .venv/bin/python -m benchmarks.precision_speed [--precision fp32,int8]
        [--repeats 7] [--iters 200] [--no-quality]

What runs:

1. :class:`~active_vision.perception.Perception` (the daemon's code path, shipped weights,
   ONNX Runtime, ``threads=1``) once per precision, on uint8 96x96 rendered-like frames
   (random bytes: the network's cost does not depend on them); a call is one ONNX Runtime
   run of the export, uint8 frames to fused frames. The precisions are timed
   **interleaved**: each repeat times ``iters`` calls of every precision in turn, so a
   change in the shared machine's load falls on all of them; the table gives the median
   ms/frame over the repeats and each one's speed-up over the first precision, computed
   per repeat and then the median.
2. Unless ``--no-quality``: ``active_vision.training.evaluate`` on the held-out split at each
   precision (per world: IoU, recall, false-positive rate, AbsRel, delta1) and the int8
   minus fp32 differences against the int8 tolerances (0.01 IoU/recall, 0.005
   AbsRel/delta1).

Targets: int8 >= 2x faster than fp32 ONNX at batch 1 and at batch 8 on one
thread; quality within the tolerances in every world. Name the CPU and the machine's other
load beside the figures (the script prints ``lscpu``'s model name and the load average).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from active_vision.backends import PRECISIONS
from active_vision.perception import Perception, PerceptionConfig
from benchmarks.machine import cpu_name

BATCHES = (1, 8)
FIGURES = ("iou", "recall", "false_positive_rate", "abs_rel", "delta1")
TOLERANCES = {"iou": 0.01, "recall": 0.01, "abs_rel": 0.005, "delta1": 0.005}
"""Largest loss of int8 against fp32 per world; no tolerance on false positives
(their target, <= 0.02, still holds per world)."""


def interleaved(runners: dict[str, object], batch: int, iters: int, repeats: int
                ) -> dict[str, tuple[float, float]]:
    """``{name: (median ms/frame, median speed-up over the first runner)}``; each runner is
    a no-argument callable running one batch; all are timed in turn within each repeat."""
    names = list(runners)
    for fn in runners.values():
        for _ in range(10):
            fn()  # type: ignore[operator]
    times: dict[str, list[float]] = {n: [] for n in names}
    for _ in range(repeats):
        for n in names:
            fn = runners[n]
            t = time.perf_counter()
            for _ in range(iters):
                fn()  # type: ignore[operator]
            times[n].append(1e3 * (time.perf_counter() - t) / iters / batch)
    base = times[names[0]]
    return {n: (statistics.median(v),
                statistics.median(b / x for b, x in zip(base, v, strict=True)))
            for n, v in times.items()}


def perception_runners(precisions: list[str], batch: int) -> dict[str, object]:
    frames = np.random.default_rng(0).integers(0, 256, (batch, 96, 96, 3), dtype=np.uint8)
    out = {}
    for prec in precisions:
        p = Perception(PerceptionConfig(threads=1, max_batch=batch, backend="onnx",
                                        precision=prec))
        if p.precision != prec:
            raise SystemExit(f"{prec} does not run here (see the log line above)")
        out[f"ORT {prec} (Perception)"] = (lambda p=p: p(frames))
    return out


def quality(precisions: list[str]) -> None:
    from active_vision.models import load_model
    from active_vision.training.evaluate import evaluate, heldout

    data = heldout(split="heldout")
    model = load_model(None)
    per = {prec: evaluate(model, data, threads=1, precision=prec).per_world
           for prec in precisions}
    print("\nheld-out quality per world (evaluate, 2700 driving frames):")
    print(f"  {'precision':<9} {'world':<8} " + " ".join(f"{k[:10]:>10}" for k in FIGURES))
    for prec, worlds in per.items():
        for w, f in worlds.items():
            print(f"  {prec:<9} {w:<8} " + " ".join(f"{f[k]:10.4f}" for k in FIGURES))
    if len(precisions) > 1:
        base = precisions[0]
        for prec in precisions[1:]:
            print(f"  {prec} - {base}, against the tolerances:")
            for w in per[base]:
                parts = []
                for k in FIGURES:
                    d = per[prec][w][k] - per[base][w][k]
                    loss = -d if k in ("iou", "recall", "delta1") else d
                    tol = TOLERANCES.get(k)
                    mark = "" if tol is None else (" ok" if loss <= tol else " OVER")
                    parts.append(f"{k} {d:+.4f}{mark}")
                print(f"    {w:<8} " + ", ".join(parts))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.precision_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--precision", default="fp32,int8",
                   help="comma-separated precisions, the first is the baseline")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--iters", type=int, default=200, help="calls per repeat at batch 1 "
                   "(batch 8: a quarter)")
    p.add_argument("--no-quality", action="store_true")
    a = p.parse_args(argv)
    precisions = [s.strip() for s in a.precision.split(",") if s.strip()]
    bad = [s for s in precisions if s not in PRECISIONS]
    if bad or not precisions:
        p.error(f"--precision: give some of {', '.join(PRECISIONS)}, got {a.precision!r}")
    if a.repeats < 1 or a.iters < 4:
        p.error("--repeats must be >= 1 and --iters >= 4")
    print(f"CPU: {cpu_name()}; load average before: {os.getloadavg()[0]:.2f}")
    print(f"{'runner':<28} {'batch':>5} {'ms/frame':>9} {'speed-up':>9}")
    for batch in BATCHES:
        iters = a.iters if batch == 1 else max(4, a.iters // 4)
        runners = perception_runners(precisions, batch)
        for name, (ms, up) in interleaved(runners, batch, iters, a.repeats).items():
            print(f"{name:<28} {batch:5d} {ms:9.3f} {up:8.2f}x")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if not a.no_quality:
        quality(precisions)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
