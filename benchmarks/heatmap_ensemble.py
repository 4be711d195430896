"""Heatmap figures of networks and of their mean heatmaps, per world, at several thresholds.

    MUJOCO_GL=egl PYTHONPATH=. .venv/bin/python benchmarks/heatmap_ensemble.py \\
        --net ship=active_vision/weights/avnet.pt --net s0=runs/s0_m4/avnet.pt \\
        --mean ship+s0 --thresholds 0.5,0.3,0.25 [--split validation]

Each ``--net NAME=WEIGHTS`` is run once over the split (the validation split by default:
choices are made there, not on held-out frames). Each ``--mean A+B+...`` averages the named
networks' heatmaps (probabilities) pixel by pixel; every ``--net`` alone is a row too. The
figures are :mod:`active_vision.training.evaluate`'s (recall of pedestrians of at least 30 px,
false-positive frames, heatmap IoU), per world, at each threshold: whether an ensemble would
find more people at the same false detections, and at which operating point. What it answers
is what distilling several networks into one (``train --teacher``) could at best reach; the
daemon runs one network.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from active_vision.training.dataset import Dataset  # noqa: E402
from active_vision.training.evaluate import _Counts, _figures, frame_counts, heldout  # noqa: E402
from active_vision.training.train import network_heatmaps  # noqa: E402


def figures(heat: np.ndarray, data: Dataset, threshold: float) -> dict[str, dict[str, float]]:
    """Per world: recall, false-positive frames and IoU of ``heat`` at ``threshold``."""
    per = {w: _Counts() for w in data.worlds}
    for i in range(len(data)):
        per[data.worlds[int(data.world[i])]].add(
            frame_counts(heat[i], None, data.mask[i], data.depth[i], threshold))
    return {w: _figures(c) for w, c in per.items() if c.frames}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--net", action="append", required=True, metavar="NAME=WEIGHTS")
    p.add_argument("--mean", action="append", default=[], metavar="A+B+...")
    p.add_argument("--thresholds", default="0.5,0.4,0.3,0.25")
    p.add_argument("--split", default="validation", choices=("validation", "heldout"))
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    nets = {}
    for item in a.net:
        name, _, path = item.partition("=")
        if not name or not Path(path).is_file():
            p.error(f"--net {item!r}: give NAME=WEIGHTS with an existing weights file")
        nets[name] = Path(path)
    rows = [[n] for n in nets] + [m.split("+") for m in a.mean]
    for row in rows:
        if unknown := [n for n in row if n not in nets]:
            p.error(f"--mean {'+'.join(row)}: {', '.join(unknown)} not given by --net")
    thresholds = [float(t) for t in a.thresholds.split(",")]
    torch.set_num_threads(a.threads)
    data = heldout(split=a.split)
    rgb = torch.from_numpy(data.rgb).permute(0, 3, 1, 2)
    heat = {n: network_heatmaps(w, rgb, batch=64)[:, 0].numpy() for n, w in nets.items()}
    print(f"{a.split} split, {len(data)} frames; recall / false-positive frames / IoU")
    print(f"{'heatmap':<24} {'thr':>5}  " + "  ".join(f"{w:>26}" for w in data.worlds))
    for row in rows:
        mean = np.mean([heat[n] for n in row], axis=0)
        for t in thresholds:
            f = figures(mean, data, t)
            cells = [f"{f[w]['recall']:.3f} / {100 * f[w]['false_positive_rate']:4.2f}% / "
                     f"{f[w]['iou']:.3f}" for w in data.worlds]
            print(f"{'+'.join(row):<24} {t:5.2f}  " + "  ".join(f"{c:>26}" for c in cells),
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
