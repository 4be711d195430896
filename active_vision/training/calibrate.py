"""Calibrate the heatmap head: move its operating point to the threshold chosen on validation.

    python -m active_vision.training.calibrate --weights runs/x/avnet.pt [--out FILE]

The evaluation counts a pixel as a pedestrian at 0.5 (``THRESHOLD``), and the fused envs'
reward and the predictor read the heatmap's values as they are, so a network's operating point
is wherever its 0.5 lies. A network's best operating point can lie elsewhere: one that misses
inspect's recall at 0.5 may meet every heatmap target at 0.3. Calibration sweeps the detection
threshold on the **validation** split (never the held-out one, which reports) and picks the
threshold ``t`` with the highest worst-world recall among those whose worst-world
false-positive frames stay within ``FP_BUDGET`` and whose worst-world IoU meets its target
(ties: the higher threshold). A network trained among several pedestrian scenes (``train
--crowds``) is calibrated on the validation split of each, every world of every scene counting
as a world (a threshold chosen on the pacers' split alone can break the false-positive target
among crowds: docs/decisions.md, "Perception network and int8"). It then folds ``-logit(t)``
into the heatmap head's bias, so that the calibrated network's 0.5 is the old network's ``t``
for every pixel: ``sigmoid(z - logit(t)) >= 0.5`` exactly where ``sigmoid(z) >= t``. The depth
head is untouched.

``python -m active_vision.training.train --calibrate`` calibrates the network it trains this way
before its held-out evaluation; this command calibrates an existing weights file (and
writes its ONNX export beside the result). The shift is stored in the weights' ``meta`` as
``heat_logit_shift`` (summed over calibrations) with the chosen ``heat_threshold``.

The shipped network is not calibrated: its recipe does not ask for it, and its weights'
``meta`` has no ``heat_logit_shift``, so its threshold is 0.5. A calibrated heatmap costs in
two places (docs/decisions.md, "Perception network and int8"):

- a lower threshold makes detection itself a better guess of where people will be, so the
  predictive heatmap's margin over detection shrinks;
- the fused students read channel 1's values as they were distilled on them: a hotter
  channel 1 changes what they do. A calibrated detector calls for students distilled again
  on its heatmaps.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from active_vision.models import HEAD_HEATMAP, AVNet, load_model
from active_vision.training.dataset import DEFAULT_DATA_DIR, Dataset, crowd_config, parse_crowds
from active_vision.training.evaluate import (
    TARGETS,
    THRESHOLD,
    format_sweep,
    heldout,
    threshold_sweep,
)
from rover_train.cli import build_parser, instance_from, setup_logging

logger = logging.getLogger(__name__)

CALIBRATION_THRESHOLDS: tuple[float, ...] = (0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)
"""Detection thresholds the calibration chooses among (0.5: no change)."""
FP_BUDGET = TARGETS["false_positive_rate"] / 2
"""Worst-world false-positive frames a chosen threshold may reach on validation: half the
target, so that the held-out split (other episodes) has room to read higher."""


def choose_threshold(sweep: dict[float, dict[str, dict[str, float]]],
                     fp_budget: float = FP_BUDGET) -> float:
    """The threshold of ``sweep`` (:func:`evaluate.threshold_sweep`'s result) with the highest
    worst-world recall among those within ``fp_budget`` false-positive frames and at or over
    the IoU target in every world (ties: the higher threshold); ``THRESHOLD`` (no change)
    when none qualifies."""
    best: tuple[float, float] | None = None
    for t, per_world in sweep.items():
        worlds = per_world.values()
        worst_fp = max(w["false_positive_rate"] for w in worlds)
        worst_iou = min(w["iou"] for w in worlds)
        if worst_fp > fp_budget or worst_iou < TARGETS["iou"]:
            continue
        key = (min(w["recall"] for w in worlds), t)
        if best is None or key > best:
            best = key
    if best is None:
        logger.warning("no threshold keeps false-positive frames within %.3f and IoU over "
                       "%.2f in every world; the heatmap is left as it is", fp_budget,
                       TARGETS["iou"])
        return THRESHOLD
    return best[1]


@torch.no_grad()
def fold_threshold(model: AVNet, threshold: float) -> float:
    """Shift ``model``'s heatmap logit so that 0.5 on the result is ``threshold`` on the input
    (in place); returns the shift added to the head's bias, ``-logit(threshold)``."""
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold {threshold}: give a value in (0, 1)")
    shift = -math.log(threshold / (1.0 - threshold))
    model.head.bias[HEAD_HEATMAP] += shift
    return shift


def validation_splits(data_dir: Path, crowds: Sequence[str] = ("pacing",)
                      ) -> dict[str, Dataset]:  # fmt: skip
    """The validation split among each pedestrian scene of ``crowds`` (``train --crowds``
    entries), rendered on first use: what a network trained among those scenes is
    calibrated on."""
    out = {}
    for spec in crowds:
        mode, count = crowd_config(spec)
        out[spec] = heldout(data_dir, split="validation", pedestrian_mode=mode,
                            n_pedestrians=count)
    return out


def calibrate(model: AVNet, data: Dataset | Mapping[str, Dataset], *,
              thresholds: Sequence[float] = CALIBRATION_THRESHOLDS,
              threads: int | None = None) -> tuple[float, float, str]:
    """Choose a threshold on ``data`` (the validation split, or the validation splits of
    several pedestrian scenes by name: :func:`validation_splits`) and fold it into ``model``
    (an unfused network, in place). With several scenes each world of each scene counts as
    a world of its own, so the chosen threshold keeps false-positive frames within budget
    and IoU over target in every one. Returns (threshold, logit shift, the sweep's table)."""
    splits = {"": data} if isinstance(data, Dataset) else dict(data)
    sweep: dict[float, dict[str, dict[str, float]]] = {t: {} for t in thresholds}
    for scene, split in splits.items():
        for t, per_world in threshold_sweep(model, split, thresholds, threads=threads).items():
            for world, figures in per_world.items():
                sweep[t][f"{world} {scene}".strip()] = figures
    t = choose_threshold(sweep)
    shift = fold_threshold(model, t) if t != THRESHOLD else 0.0
    logger.info("heatmap calibrated on %d validation frames (%s): threshold %.2f (logit shift "
                "%+.3f)", sum(len(d) for d in splits.values()),
                ", ".join(splits) or "one split", t, shift)
    return t, shift, format_sweep(sweep)


def calibrated_meta(meta: dict[str, Any], threshold: float, shift: float) -> dict[str, Any]:
    """A weights file's ``meta`` after a calibration: ``heat_threshold`` set,
    ``heat_logit_shift`` summed over calibrations, the stored recipe's ``calibrate`` on, and
    the held-out figures (``heldout_*``, measured with the old head) dropped."""
    out = {k: v for k, v in meta.items() if not k.startswith("heldout_")}
    if isinstance(out.get("recipe"), dict):  # the recipe now includes the calibration
        out["recipe"] = {**out["recipe"], "calibrate": True}
    out["heat_threshold"] = threshold
    out["heat_logit_shift"] = float(meta.get("heat_logit_shift", 0.0)) + shift
    return out


@dataclass(frozen=True)
class CalibrateRun:
    """What ``python -m active_vision.training.calibrate`` calibrates, on what, and where it
    writes."""

    weights: Path | None = None
    """The weights to calibrate (required)."""
    out: Path | None = None
    """Where to write the result (default: overwrite ``weights``)."""
    data_dir: Path = DEFAULT_DATA_DIR
    """Where the validation split is rendered on first use."""
    data: Path | None = None
    """A dataset ``.npz`` to choose on (default: the validation splits; never the held-out
    split, which reports)."""
    crowds: tuple[str, ...] | None = field(default=None, metadata={"parse": parse_crowds})
    """Pedestrian scenes whose validation splits to choose on, as ``train --crowds``
    (default: those the weights' recipe was trained among; the pacers without one)."""
    export: bool = True
    """Write the ONNX export beside the result."""
    threads: int = 2
    """torch threads."""


def _parse(argv: Sequence[str] | None) -> CalibrateRun:
    p = build_parser(CalibrateRun, "python -m active_vision.training.calibrate",
                     "Fold the heatmap threshold chosen on the validation split into a "
                     "weights file.")  # fmt: skip
    a = p.parse_args(argv)
    run = instance_from(CalibrateRun, a)
    if run.weights is None or not run.weights.is_file():
        p.error(f"--weights {run.weights}: give an existing weights file to calibrate")
    if run.data is not None and not run.data.is_file():
        p.error(f"--data {run.data}: no such file")
    setup_logging(a.log_level)
    return run


def main(argv: Sequence[str] | None = None) -> int:
    from active_vision.models import save_weights, weights_meta

    a = _parse(argv)
    assert a.weights is not None  # _parse refuses a run without it
    torch.set_num_threads(a.threads)
    model = load_model(a.weights, fuse=False)
    meta = weights_meta(a.weights)
    crowds = a.crowds or tuple(meta.get("recipe", {}).get("crowds", ("pacing",)))
    data = Dataset.load(a.data) if a.data else validation_splits(a.data_dir, crowds)
    t, shift, table = calibrate(model, data, threads=a.threads)
    print(table)
    print(f"chosen threshold {t:.2f}: logit shift {shift:+.4f}")
    out = save_weights(model, a.out or a.weights, calibrated_meta(meta, t, shift))
    print(f"wrote {out}")
    if a.export:
        from active_vision.training.quantize import write_exports_beside

        write_exports_beside(out, a.data_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
