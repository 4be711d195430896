"""Quality of the perception network on the held-out split.

``python -m active_vision.training.evaluate [--weights PATH] [--data FILE] [--json]``
runs the shipped
(or given) network through :class:`~active_vision.perception.Perception` - exactly what the
daemon runs - on held-out frames (rendered with ``dataset.HELDOUT_SEED`` when no file is
given) and prints the figures overall and per world. With ``--json`` the last line is one
JSON object with the keys ``iou``, ``recall``, ``false_positive_rate``, ``abs_rel``,
``delta1`` (plus counts, ``abs_rel_near``, ``worst`` and ``per_world``). With
``--heatmap predict`` it also evaluates the predictive heatmap on held-out driving
sequences (:mod:`active_vision.training.predict_train`) and adds ``predict_iou``,
``detect_baseline_iou`` and ``oracle_now_iou``, overall and in each ``per_world`` entry,
and ``margin_interval``: the 90 % interval of predict - detect over bootstrap draws of whole
episodes. ``--sweep 0.5,0.3,0.1`` also prints the heatmap figures (IoU, recall,
false-positive frames) per world at each of those detection thresholds, from the same pass
of the network: where a threshold other than 0.5 would put the operating point.
``--precision int8`` evaluates the int8 model (:mod:`active_vision.training.quantize`) in
ONNX Runtime instead of the fp32 network in torch (the JSON line says which: ``precision``).
``--depth-bands`` also prints, per world, the depth figures by true depth and by image row
(:func:`depth_bands`): where the depth channel goes wrong.
``--pedestrian-mode crowd --pedestrians 10`` renders (and caches under its own file name)
the split with those pedestrians instead of the world's 3 pacers: the crowds, where
the targets are held at 3 and at 10 people.

Definitions (``THRESHOLD`` = 0.5, ``MIN_PEDESTRIAN_PX`` = 30, ``MIN_BLOB_PX`` = 5):

- **heatmap IoU**: pixels with heatmap >= 0.5 against the ground-truth pedestrian mask,
  ``sum(pred & gt) / sum(pred | gt)`` summed over every pixel of every frame (frames without
  pedestrians add their false pixels to the union).
- **detection blob**: an 8-connected component of ``heatmap >= 0.5`` with at least
  ``MIN_BLOB_PX`` pixels.
- **pedestrian** (for recall): an 8-connected component of the ground-truth mask covering at
  least ``MIN_PEDESTRIAN_PX`` pixels (people overlapping in the image count as one).
- **pedestrian-present recall**: the fraction of such pedestrians that some detection blob
  overlaps by at least one pixel.
- **false-positive rate**: among frames whose ground-truth mask is empty (no pedestrian
  pixel at all), the fraction with at least one detection blob.
- **depth AbsRel** and **delta1**: over pixels whose true depth is in
  ``[NEAR_DEPTH_M, DEPTH_MAX_M)`` (0.3-10 m; farther pixels and the sky are 0 in the depth
  channel and carry no metric depth), with the predicted metric depth
  ``channel_to_depth(channel)`` clipped to at least 0.05 m: ``mean(|d_pred - d| / d)`` and
  ``mean(max(d_pred / d, d / d_pred) < 1.25)``.
- **abs_rel_near**: the same AbsRel over the pixels nearer than ``NEAR_DEPTH_M`` (a wall
  at arm's length), reported apart.

Every figure is also given per world (``per_world``), and ``worst`` holds, per figure, the
worst world's value: the targets (``TARGETS``) are met when the worst world meets them.
``intervals`` gives, per world and target figure, the 90 % interval over bootstrap draws of
whole driving episodes: a world's figures come from a dozen or so episodes, and one
episode's frames see the same figures, so an episode can move recall by several points.
The held-out split is ``HELDOUT_FRAMES`` frames recorded while driving
(``drive_fraction=1``) from ``HELDOUT_SEED``: seeds, pedestrian appearances and lighting
never used in training.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from active_vision.backends import PRECISIONS, BackendError
from active_vision.models import MIN_DEPTH_M, AVNet, load_model
from active_vision.perception import Perception, PerceptionConfig
from active_vision.training.dataset import (
    DEFAULT_DATA_DIR,
    SPLIT_SEEDS,
    WORLDS,
    Dataset,
    DatasetConfig,
    build,
)
from fused_image import CHANNEL_DEPTH, CHANNEL_HEATMAP, DEPTH_MAX_M, channel_to_depth
from rover_env.pedestrians import PEDESTRIAN_MODES

logger = logging.getLogger(__name__)

THRESHOLD = 0.5
MIN_PEDESTRIAN_PX = 30
MIN_BLOB_PX = 5
NEAR_DEPTH_M = 0.3
HELDOUT_FRAMES = 2700
"""Frames of the held-out (and validation) split: 37-38 driving episodes a world, enough that
no single episode (a dark figure against a wall, the camera pressed against a pedestrian)
moves a world's figure by several points, as it does at 12-13 episodes."""
BOOTSTRAP_RESAMPLES = 2000
"""Bootstrap draws of episodes behind ``Metrics.intervals``."""
_LOWER_IS_BETTER = ("false_positive_rate", "abs_rel")
TARGETS = {"iou": 0.6, "recall": 0.95, "false_positive_rate": 0.02, "abs_rel": 0.15,
           "delta1": 0.85}


@dataclass
class FrameCounts:
    """Sums over frames that the figures are ratios of (:func:`frame_counts` of one frame;
    :meth:`add` another's, :func:`figures_of` the figures)."""

    inter: int = 0
    union: int = 0
    peds: int = 0
    peds_hit: int = 0
    empty_frames: int = 0
    fp_frames: int = 0
    frames: int = 0
    depth_px: int = 0
    abs_rel_sum: float = 0.0
    delta1_hits: int = 0
    near_px: int = 0
    near_abs_rel_sum: float = 0.0

    def add(self, other: FrameCounts) -> None:
        for k in asdict(self):
            setattr(self, k, getattr(self, k) + getattr(other, k))


@dataclass
class Metrics:
    """Figures of one evaluation (see the module docstring for the definitions)."""

    iou: float
    recall: float
    false_positive_rate: float
    abs_rel: float
    delta1: float
    frames: int
    pedestrians: int
    empty_frames: int
    abs_rel_near: float = float("nan")
    per_world: dict[str, dict[str, float]] = field(default_factory=dict)
    intervals: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    """Per world, per target figure: the 5th and 95th percentiles over bootstrap draws of
    whole driving episodes (:func:`episode_intervals`)."""

    def summary(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in TARGETS}

    def worst(self) -> dict[str, float]:
        """Per target figure, the worst world's value (NaN worlds skipped)."""
        out = {}
        for k in TARGETS:
            vals = [f[k] for f in self.per_world.values() if f[k] == f[k]]
            if not vals:
                out[k] = getattr(self, k)
            else:
                out[k] = max(vals) if k in _LOWER_IS_BETTER else min(vals)
        return out

    def meets_targets(self) -> dict[str, bool]:
        """Whether the worst world meets each target."""
        s = self.worst()
        return {k: (s[k] <= t if k in _LOWER_IS_BETTER else s[k] >= t)
                for k, t in TARGETS.items()}


def _blobs(binary: np.ndarray, min_px: int) -> np.ndarray:
    """Label image of the 8-connected components of ``binary`` with >= min_px pixels."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_px
    return np.where(keep[labels], labels, 0)


def frame_counts(heat: np.ndarray, depth_ch: np.ndarray | None, gt_mask: np.ndarray,
                 gt_depth: np.ndarray, threshold: float = THRESHOLD) -> FrameCounts:
    """Counts for one frame (heatmap and depth channel predicted; mask and metres true); a
    heatmap pixel is a detection at ``threshold`` or above. Without ``depth_ch``, the
    heatmap's counts only."""
    c = FrameCounts(frames=1)
    pred = heat >= threshold
    c.inter = int(np.count_nonzero(pred & gt_mask))
    c.union = int(np.count_nonzero(pred | gt_mask))
    det = _blobs(pred, MIN_BLOB_PX) > 0
    if not gt_mask.any():
        c.empty_frames = 1
        c.fp_frames = int(det.any())
    else:
        peds = _blobs(gt_mask, MIN_PEDESTRIAN_PX)
        ids = np.unique(peds[peds > 0])
        c.peds = int(ids.size)
        if ids.size:
            hit = np.unique(peds[det & (peds > 0)])
            c.peds_hit = int(hit.size)
    if depth_ch is None:
        return c
    finite = np.isfinite(gt_depth) & (gt_depth > 0)
    near = finite & (gt_depth < NEAR_DEPTH_M)
    if near.any():
        d = gt_depth[near].astype(np.float64)
        p = np.maximum(channel_to_depth(depth_ch[near]).astype(np.float64), MIN_DEPTH_M)
        c.near_px = int(d.size)
        c.near_abs_rel_sum = float(np.sum(np.abs(p - d) / d))
    valid = finite & (gt_depth >= NEAR_DEPTH_M) & (gt_depth < DEPTH_MAX_M)
    if valid.any():
        d = gt_depth[valid].astype(np.float64)
        p = np.maximum(channel_to_depth(depth_ch[valid]).astype(np.float64), MIN_DEPTH_M)
        c.depth_px = int(d.size)
        c.abs_rel_sum = float(np.sum(np.abs(p - d) / d))
        c.delta1_hits = int(np.count_nonzero(np.maximum(p / d, d / p) < 1.25))
    return c


def figures_of(c: FrameCounts) -> dict[str, float]:
    """The figures of summed counts (NaN where a figure has nothing to count), with the
    frames, pedestrians and empty frames they were counted on."""
    nan = float("nan")
    return {
        "iou": c.inter / c.union if c.union else nan,
        "recall": c.peds_hit / c.peds if c.peds else nan,
        "false_positive_rate": c.fp_frames / c.empty_frames if c.empty_frames else nan,
        "abs_rel": c.abs_rel_sum / c.depth_px if c.depth_px else nan,
        "delta1": c.delta1_hits / c.depth_px if c.depth_px else nan,
        "abs_rel_near": c.near_abs_rel_sum / c.near_px if c.near_px else nan,
        "frames": float(c.frames),
        "pedestrians": float(c.peds),
        "empty_frames": float(c.empty_frames),
    }


def _fused_frames(model: AVNet, data: Dataset, batch: int, threads: int | None,
                  precision: str = "fp32", weights: Path | None = None
                  ) -> Iterator[tuple[int, np.ndarray]]:
    """(index, fused frame) of every frame of ``data``, through :class:`Perception` as the
    daemon runs it: ``model`` in torch for ``fp32``; for ``int8``, the int8 ONNX model of
    ``weights`` (default: the shipped ones), which ``model`` must be loaded from, run
    without the daemon's agreement check (:mod:`active_vision.precision`): this measures
    it."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "int8":
        perception = Perception(PerceptionConfig(
            size=data.rgb.shape[1], threads=threads, max_batch=batch, weights=weights,
            backend="onnx", precision="int8", int8_check=False))
        if perception.precision != "int8":  # the fallback logged why
            raise BackendError(
                f"no int8 model of {weights or 'the shipped weights'} runs here (see the log "
                "line above); make it with `python -m active_vision.training.quantize`, or "
                "evaluate --precision fp32")
    else:
        perception = Perception(PerceptionConfig(size=data.rgb.shape[1], threads=threads,
                                                 max_batch=batch, precision="fp32"),
                                model=model)
    for start in range(0, len(data), batch):
        fused = perception(data.rgb[start:start + batch])
        for j in range(fused.shape[0]):
            yield start + j, fused[j]


def episode_intervals(units: Sequence[FrameCounts], resamples: int = BOOTSTRAP_RESAMPLES,
                      seed: int = 0) -> dict[str, list[float]]:
    """Per target figure, the 5th and 95th percentiles over ``resamples`` bootstrap draws of
    ``units`` (one :class:`FrameCounts` per driving episode): how far the figure could move on
    other episodes like these. An episode's frames are not independent (the same figure
    seen from the same place for seconds), so episodes are the unit drawn."""
    nan = [float("nan"), float("nan")]
    if not units:
        return {k: nan for k in TARGETS}
    keys = list(asdict(units[0]))
    table = np.array([[getattr(u, k) for k in keys] for u in units], np.float64)
    draws = np.random.default_rng(seed).integers(0, len(units), size=(resamples, len(units)))
    totals = table[draws].sum(axis=1)  # (resamples, fields): each draw's summed counts
    figures = [figures_of(FrameCounts(**dict(zip(keys, row, strict=True)))) for row in totals]
    out = {}
    for k in TARGETS:
        v = np.array([f[k] for f in figures])
        v = v[np.isfinite(v)]
        out[k] = [float(x) for x in np.percentile(v, [5.0, 95.0])] if v.size else nan
    return out


def evaluate(model: AVNet, data: Dataset, *, batch: int = 32, threads: int | None = None,
             precision: str = "fp32", weights: Path | None = None) -> Metrics:
    """Run ``model`` through :class:`Perception` on ``data`` and compute :class:`Metrics`
    (``precision="int8"``: the int8 model of ``weights`` instead, see :func:`_fused_frames`)."""
    total = FrameCounts()
    per_world = {w: FrameCounts() for w in data.worlds}
    units: dict[tuple[str, int, int], FrameCounts] = {}
    episode = np.asarray(data.episode)
    for i, fused in _fused_frames(model, data, batch, threads, precision, weights):
        c = frame_counts(fused[:, :, CHANNEL_HEATMAP], fused[:, :, CHANNEL_DEPTH],
                         data.mask[i], data.depth[i])
        total.add(c)
        world = data.worlds[int(data.world[i])]
        per_world[world].add(c)
        # a driving episode is one unit of the bootstrap; a posed frame is its own
        key = (world, int(episode[i]), i if episode[i] < 0 else -1)
        units.setdefault(key, FrameCounts()).add(c)
    f = {k: v for k, v in figures_of(total).items() if k in TARGETS or k == "abs_rel_near"}
    return Metrics(**f, frames=len(data), pedestrians=total.peds,
                   empty_frames=total.empty_frames,
                   per_world={w: figures_of(c) for w, c in per_world.items() if c.frames},
                   intervals={w: episode_intervals([u for k, u in units.items() if k[0] == w])
                              for w, c in per_world.items() if c.frames})


SWEEP_KEYS = ("iou", "recall", "false_positive_rate")


def threshold_sweep(model: AVNet, data: Dataset, thresholds: Sequence[float], *,
                    batch: int = 32, threads: int | None = None
                    ) -> dict[float, dict[str, dict[str, float]]]:
    """The heatmap figures (``SWEEP_KEYS``) per world at each detection threshold, from one
    pass of ``model`` over ``data``: ``{threshold: {world: {figure: value}}}``."""
    counts = {t: {w: FrameCounts() for w in data.worlds} for t in thresholds}
    for i, fused in _fused_frames(model, data, batch, threads):
        world = data.worlds[int(data.world[i])]
        for t in thresholds:
            counts[t][world].add(frame_counts(fused[:, :, CHANNEL_HEATMAP], None,
                                              data.mask[i], data.depth[i], t))
    return {t: {w: {k: figures_of(c)[k] for k in SWEEP_KEYS} for w, c in per.items() if c.frames}
            for t, per in counts.items()}


DEPTH_BANDS_M = (NEAR_DEPTH_M, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, DEPTH_MAX_M)
"""Edges of the true-depth bands of :func:`depth_bands` (metres)."""
ROW_BAND = 16
"""Image rows per band of :func:`depth_bands`."""


def depth_bands(model: AVNet, data: Dataset, *, batch: int = 32, threads: int | None = None
                ) -> dict[str, dict[str, list[dict[str, float]]]]:
    """Where the depth channel goes wrong: :func:`depth_band_figures` of one pass of
    ``model`` over ``data``."""
    return depth_band_figures(_fused_frames(model, data, batch, threads), data)


def depth_band_figures(frames: Iterable[tuple[int, np.ndarray]], data: Dataset
                       ) -> dict[str, dict[str, list[dict[str, float]]]]:
    """Per world, delta1, AbsRel and the mean log ratio ``log(d_pred / d)`` (its sign says
    too far or too near) of the 0.3-10 m pixels grouped by true depth (``DEPTH_BANDS_M``,
    with each band's share of the world's pixels) and by image row (``ROW_BAND`` rows a
    band, top first), for fused ``frames`` ``(index in data, (H, W, 3) frame)``:
    ``{world: {"depth": [...], "rows": [...]}}``, each entry a dict with ``lo``, ``hi``,
    ``share``, ``delta1``, ``abs_rel``, ``log_ratio``."""
    edges = np.asarray(DEPTH_BANDS_M)
    size = data.rgb.shape[1]
    n_rows = -(-size // ROW_BAND)
    # per world: (band, [pixels, delta1 hits, abs rel sum, log ratio sum])
    by_depth = {w: np.zeros((len(edges) - 1, 4)) for w in data.worlds}
    by_row = {w: np.zeros((n_rows, 4)) for w in data.worlds}
    for i, fused in frames:
        world = data.worlds[int(data.world[i])]
        d = data.depth[i].astype(np.float64)
        valid = np.isfinite(d) & (d >= edges[0]) & (d < edges[-1])
        if not valid.any():
            continue
        rows, _ = np.nonzero(valid)
        d = d[valid]
        p = np.maximum(channel_to_depth(fused[:, :, CHANNEL_DEPTH][valid]).astype(np.float64),
                       MIN_DEPTH_M)
        stats = np.stack([np.ones_like(d), np.maximum(p / d, d / p) < 1.25,
                          np.abs(p - d) / d, np.log(p / d)], axis=1)
        np.add.at(by_depth[world], np.searchsorted(edges, d, side="right") - 1, stats)
        np.add.at(by_row[world], rows // ROW_BAND, stats)

    def table(acc: np.ndarray, lo: Sequence[float], hi: Sequence[float]) -> list[dict[str, float]]:
        total = acc[:, 0].sum()
        return [{"lo": float(a), "hi": float(b), "share": float(n / total),
                 "delta1": float(h / n), "abs_rel": float(r / n), "log_ratio": float(g / n)}
                for a, b, (n, h, r, g) in zip(lo, hi, acc, strict=True) if n]

    row_lo = [r * ROW_BAND for r in range(n_rows)]
    row_hi = [min(size, r + ROW_BAND) - 1 for r in row_lo]
    return {w: {"depth": table(by_depth[w], edges[:-1], edges[1:]),
                "rows": table(by_row[w], row_lo, row_hi)}
            for w in data.worlds if by_depth[w][:, 0].sum()}


def format_depth_bands(bands: dict[str, dict[str, list[dict[str, float]]]]) -> str:
    lines = ["depth by true depth and by image row (0.3-10 m pixels; log ratio > 0: too far):",
             f"  {'world':<8} {'band':<14} {'share':>6} {'delta1':>7} {'abs_rel':>8} "
             f"{'log_ratio':>9}"]
    for w, kinds in bands.items():
        for kind, unit in (("depth", "m"), ("rows", "")):
            for b in kinds[kind]:
                band = (f"{b['lo']:g}-{b['hi']:g} {unit}" if unit
                        else f"rows {b['lo']:g}-{b['hi']:g}")
                lines.append(f"  {w:<8} {band:<14} {b['share']:6.3f} {b['delta1']:7.3f} "
                             f"{b['abs_rel']:8.3f} {b['log_ratio']:+9.3f}")
    return "\n".join(lines)


def format_sweep(sweep: dict[float, dict[str, dict[str, float]]]) -> str:
    lines = ["detection threshold sweep (heatmap figures per world):",
             f"  {'threshold':>9} {'world':<8} " + " ".join(f"{k[:12]:>12}" for k in SWEEP_KEYS)]
    for t, per in sweep.items():
        for w, f in per.items():
            lines.append(f"  {t:9.2f} {w:<8} " + " ".join(f"{f[k]:12.4f}" for k in SWEEP_KEYS))
    return "\n".join(lines)


def heldout(data_dir: Path = DEFAULT_DATA_DIR, frames: int = HELDOUT_FRAMES,
            worlds: Sequence[str] = WORLDS, split: str = "heldout",
            pedestrian_mode: str = DatasetConfig.pedestrian_mode,
            n_pedestrians: int | None = None) -> Dataset:
    """The held-out split, or with ``split="validation"`` the validation split (driving
    frames only; rendered on first use, then reused from ``data_dir``), with the
    pedestrians walking by ``pedestrian_mode``, ``n_pedestrians`` of them (None: the
    world's 3); a setting other than the 3 pacers is cached under its own file name."""
    if split not in SPLIT_SEEDS:
        raise ValueError(f"split {split!r}: give one of {', '.join(SPLIT_SEEDS)}")
    cfg = DatasetConfig(frames=frames, seed=SPLIT_SEEDS[split], worlds=tuple(worlds),
                        drive_fraction=1.0, pedestrian_mode=pedestrian_mode,
                        n_pedestrians=n_pedestrians)
    return Dataset.load(build(data_dir, cfg))


def format_metrics(m: Metrics) -> str:
    ok = m.meets_targets()
    lines = [f"frames {m.frames}, pedestrians >= {MIN_PEDESTRIAN_PX} px: "
             f"{m.pedestrians}, frames without pedestrians: {m.empty_frames}",
             f"  {'':<20} {'all':>7} {'worst':>7}   target (worst world)"]
    s, worst = m.summary(), m.worst()
    for k, t in TARGETS.items():
        cmp = "<=" if k in _LOWER_IS_BETTER else ">="
        lines.append(f"  {k:<20} {s[k]:7.4f} {worst[k]:7.4f}   {cmp} {t}  "
                     f"{'ok' if ok[k] else 'MISSED'}")
    lines.append(f"  {'abs_rel_near':<20} {m.abs_rel_near:7.4f}           "
                 f"(true depth < {NEAR_DEPTH_M} m; no target)")
    keys = (*TARGETS, "abs_rel_near")
    lines.append(f"  {'world':<8} " + " ".join(f"{k[:12]:>12}" for k in keys)
                 + "  frames pedestrians")
    for w, f in m.per_world.items():
        lines.append(f"  {w:<8} " + " ".join(f"{f[k]:12.4f}" for k in keys)
                     + f"  {f['frames']:6.0f} {f['pedestrians']:11.0f}")
    if m.intervals:
        lines.append("  90 % intervals over bootstrap draws of whole episodes:")
        lines.append(f"  {'world':<8} " + " ".join(f"{k[:11]:>11}" for k in TARGETS))
        for w, iv in m.intervals.items():
            lines.append(f"  {w:<8} " + " ".join(
                f"{iv[k][0]:5.3f}-{iv[k][1]:5.3f}" for k in TARGETS))
    return "\n".join(lines)


def _json_safe(obj: object) -> object:
    """NaN (a figure with nothing to measure) as null, so the line is strict JSON."""
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float) and obj != obj:
        return None
    return obj


def _thresholds(text: str) -> list[float]:
    """``--sweep``'s comma-separated thresholds, each in (0, 1)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of numbers (e.g. 0.5,0.3,0.1)"
        ) from None
    if not values or not all(0.0 < v < 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"thresholds must be in (0, 1), got {text!r}")
    return values


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m active_vision.training.evaluate",
                                description="Heatmap and depth quality on the held-out split.")
    p.add_argument("--weights", type=Path, default=None, help="default: the shipped weights")
    p.add_argument("--data", type=Path, default=None,
                   help="a dataset .npz (default: render/reuse the held-out split)")
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR)
    p.add_argument("--frames", type=int, default=HELDOUT_FRAMES,
                   help="held-out frames to render when --data is not given")
    p.add_argument("--split", choices=tuple(SPLIT_SEEDS), default="heldout",
                   help="driving frames to evaluate on when --data is not given: the "
                   "held-out split (the figures reported) or the validation split (to choose "
                   "between networks on)")
    p.add_argument("--pedestrian-mode", default=DatasetConfig.pedestrian_mode,
                   choices=PEDESTRIAN_MODES,
                   help="how the split's pedestrians walk when --data is not given (a mode "
                   "other than pacing, or --pedestrians, renders and caches its own file)")
    p.add_argument("--pedestrians", type=int, default=None, metavar="N",
                   help="pedestrians in each world of the split (default: the world's 3)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="fp32: the torch network; int8: its int8 ONNX model (made by "
                   "active_vision.training.quantize; an error when it does not run here)")
    p.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    p.add_argument("--heatmap", choices=("detect", "predict"), default="detect",
                   help="predict: also evaluate the predictive heatmap (future occupancy)")
    p.add_argument("--predict-weights", type=Path, default=None,
                   help="predictor weights (default: the shipped predict.pt)")
    p.add_argument("--sweep", type=_thresholds, default=None, metavar="T1,T2,...",
                   help="also print IoU, recall and false-positive frames per world at each "
                   "of these detection thresholds (in (0, 1))")
    p.add_argument("--depth-bands", action="store_true",
                   help="also print delta1, AbsRel and the mean log ratio per world by true "
                   "depth and by image row: where the depth channel goes wrong")
    p.add_argument("--log-level", default="WARNING")
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    data = (Dataset.load(args.data) if args.data
            else heldout(args.data_dir, args.frames, split=args.split,
                         pedestrian_mode=args.pedestrian_mode, n_pedestrians=args.pedestrians))
    model = load_model(args.weights)
    m = evaluate(model, data, threads=args.threads, precision=args.precision,
                 weights=args.weights)
    print(format_metrics(m))
    if args.sweep:
        print(format_sweep(threshold_sweep(model, data, args.sweep, threads=args.threads)))
    if args.depth_bands:
        print(format_depth_bands(depth_bands(model, data, threads=args.threads)))
    out: dict[str, object] = {**m.summary(), "precision": args.precision,
                              "pedestrian_mode": args.pedestrian_mode,
                              "n_pedestrians": args.pedestrians,
                              "frames": m.frames, "pedestrians": m.pedestrians,
                              "empty_frames": m.empty_frames, "abs_rel_near": m.abs_rel_near,
                              "worst": m.worst(),
                              "per_world": {w: dict(f) for w, f in m.per_world.items()},
                              "intervals": m.intervals}
    if args.heatmap == "predict":
        from active_vision.training.predict_train import evaluate_heldout, figure_rows

        pm = evaluate_heldout(args.predict_weights, args.weights, args.data_dir,
                              threads=args.threads, split=args.split,
                              pedestrian_mode=args.pedestrian_mode,
                              n_pedestrians=args.pedestrians)
        keys = ("predict_iou", "detect_baseline_iou", "oracle_now_iou")
        print(f"predictive heatmap, {pm['targets']} held-out targets (IoU with the 1.5 s "
              "future-occupancy mask):")
        print("\n".join("  " + row for row in figure_rows(pm)))
        per = pm["per_world"]
        assert isinstance(per, dict)
        out.update({k: pm[k] for k in (*keys, "margin_interval")})
        pw = out["per_world"]
        assert isinstance(pw, dict)
        for w, f in per.items():
            pw.setdefault(w, {}).update(f)
    if args.json:
        print(json.dumps(_json_safe(out)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
