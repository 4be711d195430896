"""Data, training and evaluation of the predictive heatmap (:mod:`active_vision.predict`).

    python -m active_vision.training.predict_train [--episodes 900] [--epochs 10] [--threads 2]
    python -m active_vision.training.predict_train --evaluate-only [--split validation] [--json]

Data: driving episodes (:meth:`active_vision.training.driving.DriveRecorder.record_sequence`, the
same drivers, lighting and random pedestrian appearance as the detection data) with every
control step's camera frame (0.05 s apart, the env's cadence, so the window is what the
daemon sees) and, every 3rd step from step 4 on, the future-occupancy mask (1.5 s, rover
held still) and the current mask. Training episodes come from ``TRAIN_SEED``, held-out ones
from ``HELDOUT_SEED`` (different paths, appearances and lighting), and validation ones, to
choose between predictors on, from ``VALIDATION_SEED``. Files are cached in
``--data-dir`` (``pred_<worlds>_s<seed>_e<episodes>_v<version>.npz``).

The detection network (the shipped :class:`~active_vision.models.AVNet`, or ``--weights``)
runs over every frame through :class:`~active_vision.perception.Perception`, exactly as in
the daemon; each target's window is its last ``K`` fused frames within the episode, the
oldest repeated at the start (:class:`~active_vision.history.SlotHistory`'s rule).

Loss: binary cross-entropy plus a soft Dice term on the future mask. Augmentation: the
whole window flipped left-right.

Evaluation, per world and overall, IoU at 0.5 against the future mask (summed over all
target pixels, like ``evaluate``'s IoU) of:

- ``predict_iou``: the predictor;
- ``detect_baseline_iou``: this frame's detection heatmap used as the prediction;
- ``oracle_now_iou``: this frame's true pedestrian mask used as the prediction.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from active_vision.predict import (
    DEFAULT_PREDICT_WEIGHTS,
    HORIZON_S,
    K,
    PredictNet,
    Predictor,
    save_predictor,
)
from active_vision.training.dataset import (
    DEFAULT_DATA_DIR,
    SPLIT_SEEDS,
    WORLDS,
    DatasetConfig,
    FrameRenderer,
    crowd_shares,
    crowd_tag,
    parse_crowds,
)
from active_vision.training.driving import DriveRecorder
from fused_image import CHANNEL_HEATMAP, FUSED_SIZE
from rover_env.pedestrians import PEDESTRIAN_MODES
from rover_train.cli import parse_recipe_command, recipe_dict, recipe_from_dict

logger = logging.getLogger(__name__)

PRED_DATA_VERSION = 3  # 2: the moon's ground texture (DATASET_VERSION 5); 3: its roughness (6)
THRESHOLD = 0.5
HELDOUT_EPISODES = 180
"""Held-out (and validation) episodes: 60 per world, 24 targets each at most. At 20 per world
a few episodes of a pedestrian standing in front of the rover decide the maze's predict -
detect margin (docs/decisions.md, "Perception network and int8")."""
BOOTSTRAP_RESAMPLES = 2000
"""Bootstrap draws of episodes behind ``margin_interval``."""


@dataclass
class SequenceData:
    """Driving episodes for the predictor, flattened: ``rgb`` every step of every episode;
    per target, its row in ``rgb`` (``target_row``), its episode's first row
    (``episode_row``), its world, and its ``future`` and ``now`` masks."""

    rgb: np.ndarray
    target_row: np.ndarray
    episode_row: np.ndarray
    world: np.ndarray
    future: np.ndarray
    now: np.ndarray
    worlds: tuple[str, ...]

    def save(self, path: Path) -> Path:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, rgb=self.rgb, target_row=self.target_row,
                            episode_row=self.episode_row, world=self.world.astype(np.int8),
                            future=self.future, now=self.now, worlds=np.array(self.worlds))
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: Path) -> SequenceData:
        with np.load(path) as z:
            return cls(z["rgb"], z["target_row"].astype(np.int64),
                       z["episode_row"].astype(np.int64), z["world"].astype(np.int64),
                       z["future"].astype(bool), z["now"].astype(bool),
                       tuple(str(w) for w in z["worlds"]))


    @classmethod
    def concatenate(cls, parts: Sequence[SequenceData]) -> SequenceData:
        """One file's worth of ``parts`` in order (same worlds), rows renumbered."""
        worlds = parts[0].worlds
        if any(p.worlds != worlds for p in parts):
            raise ValueError(f"sequences of different worlds: {[p.worlds for p in parts]}")
        offsets = np.cumsum([0] + [len(p.rgb) for p in parts[:-1]])
        return cls(np.concatenate([p.rgb for p in parts]),
                   np.concatenate([p.target_row + o for p, o in zip(parts, offsets, strict=True)]),
                   np.concatenate([p.episode_row + o for p, o in zip(parts, offsets, strict=True)]),
                   np.concatenate([p.world for p in parts]),
                   np.concatenate([p.future for p in parts]),
                   np.concatenate([p.now for p in parts]), worlds)


def sequence_path(data_dir: Path, seed: int, episodes: int, worlds: Sequence[str] = WORLDS,
                  pedestrian_mode: str = "pacing", n_pedestrians: int | None = None) -> Path:
    return Path(data_dir) / (f"pred_{'-'.join(worlds)}_s{seed}_e{episodes}"
                             f"{crowd_tag(pedestrian_mode, n_pedestrians)}"
                             f"_v{PRED_DATA_VERSION}.npz")


def render_sequences(seed: int, episodes: int, worlds: Sequence[str] = WORLDS,
                     size: int = FUSED_SIZE[0], pedestrian_mode: str = "pacing",
                     n_pedestrians: int | None = None) -> SequenceData:
    """Record ``episodes`` episodes (episode e in world ``e % W``, generator
    ``default_rng([seed, 2, e])``) among pedestrians walking by ``pedestrian_mode``,
    ``n_pedestrians`` of them (None: the world's 3)."""
    cfg = DatasetConfig(size=size, worlds=tuple(worlds), pedestrian_mode=pedestrian_mode,
                        n_pedestrians=n_pedestrians)
    recorders: dict[str, DriveRecorder] = {}
    rgb, trow, erow, world, future, now = [], [], [], [], [], []
    rows = 0
    t0 = time.perf_counter()
    try:
        for e in range(episodes):
            w = e % len(worlds)
            if worlds[w] not in recorders:
                recorders[worlds[w]] = DriveRecorder(FrameRenderer(worlds[w], cfg))
            seq = recorders[worlds[w]].record_sequence(np.random.default_rng([seed, 2, e]),
                                                        HORIZON_S)
            if not len(seq.targets):
                continue
            rgb.append(seq.rgb)
            trow.append(rows + seq.targets)
            erow.append(np.full(len(seq.targets), rows))
            world.append(np.full(len(seq.targets), w))
            future.append(seq.future)
            now.append(seq.now)
            rows += len(seq.rgb)
            if (e + 1) % 10 == 0:
                logger.info("sequences: %d/%d episodes (%.0f s)", e + 1, episodes,
                            time.perf_counter() - t0)
    finally:
        for rec in recorders.values():
            rec.r.close()
    return SequenceData(np.concatenate(rgb), np.concatenate(trow), np.concatenate(erow),
                        np.concatenate(world), np.concatenate(future), np.concatenate(now),
                        tuple(worlds))


def build_sequences(data_dir: Path, seed: int, episodes: int, worlds: Sequence[str] = WORLDS,
                    pedestrian_mode: str = "pacing", n_pedestrians: int | None = None
                    ) -> SequenceData:  # fmt: skip
    """Render (or reuse from ``data_dir``) a sequence file."""
    path = sequence_path(data_dir, seed, episodes, worlds, pedestrian_mode, n_pedestrians)
    if path.is_file():
        logger.info("reusing %s", path)
        return SequenceData.load(path)
    data = render_sequences(seed, episodes, worlds, pedestrian_mode=pedestrian_mode,
                            n_pedestrians=n_pedestrians)
    data.save(path)
    logger.info("wrote %s (%d frames, %d targets)", path, len(data.rgb), len(data.target_row))
    return data


def fused_frames(data: SequenceData, weights: Path | None = None, threads: int = 2
                 ) -> np.ndarray:
    """``(rows, S, S, 3)`` float16: every recorded frame through the detection network
    (:class:`~active_vision.perception.Perception`, as the daemon runs it)."""
    from active_vision.perception import Perception, PerceptionConfig

    perception = Perception(PerceptionConfig(size=data.rgb.shape[1], threads=threads,
                                             weights=weights, max_batch=64))
    fused = np.empty(data.rgb.shape, np.float16)
    for i in range(0, len(data.rgb), 64):
        fused[i:i + 64] = perception(data.rgb[i:i + 64])
    return fused


def window_rows(data: SequenceData) -> np.ndarray:
    """``(T, K)`` int64: the rows of :func:`fused_frames` that make each target's window,
    oldest first, by :class:`~active_vision.history.SlotHistory`'s rule (the episode's
    first frame repeated while fewer than ``K`` were seen); training gathers a batch's
    windows with it instead of holding every window in memory at once."""
    offsets = np.arange(K, dtype=np.int64) - (K - 1)
    return np.maximum(data.target_row[:, None] + offsets, data.episode_row[:, None])


def windows(data: SequenceData, weights: Path | None = None, threads: int = 2) -> np.ndarray:
    """``(T, K, S, S, 3)`` float16: each target's window of fused detection frames, as the
    daemon's :class:`~active_vision.history.SlotHistory` makes them
    (:func:`window_rows`), all held at once."""
    return fused_frames(data, weights, threads)[window_rows(data)]


@dataclass(frozen=True)
class PredictRecipe:
    """Everything that decides what a predictor weights file holds. The file stores it
    (``meta["recipe"]``); ``--recipe FILE`` remakes the file from it, and the command line
    is generated from these fields."""

    episodes: int = 900
    """Training driving episodes (split evenly over ``crowds``, scene k from seed
    ``TRAIN_SEED + k``): 900 give about 20,000 targets. Each batch's windows are gathered
    from the fused frames as it is drawn (:func:`window_rows`), so memory holds the frames,
    not every target's window. 900 episodes beat 450 in every world on the validation
    episodes (docs/decisions.md, "Perception network and int8")."""
    crowds: tuple[str, ...] = field(default=("pacing",), metadata={"parse": parse_crowds})
    """Pedestrian scenes the training episodes are rendered among, comma-separated, as
    ``active_vision.training.train --crowds`` (e.g. ``pacing,crowd:3,crowd:10``)."""
    epochs: int = 10
    """Passes over the training targets."""
    batch: int = 32
    """Targets per optimiser step."""
    lr: float = 3e-3
    """Peak learning rate (one-cycle schedule)."""
    threads: int = 2
    """torch threads (the float order of the kernels, so the weights, depend on it)."""
    seed: int = 0
    """torch seed (initial weights, batch order, flips)."""
    max_minutes: float = 60.0
    """Stop early when training takes longer than this."""
    weights: Path | None = None
    """Detection weights whose fused frames the predictor reads (default: the shipped
    AVNet)."""
    init: Path | None = None
    """Start from these predictor weights (fine-tuning) instead of random ones."""


@dataclass(frozen=True)
class PredictRun:
    """Where a predictor run reads and writes, and what it reports: not part of the
    recipe."""

    data_dir: Path = DEFAULT_DATA_DIR
    """Where rendered episodes are cached."""
    out: Path = DEFAULT_PREDICT_WEIGHTS
    """Predictor weights to write (or, with ``evaluate_only``, to evaluate)."""
    evaluate_only: bool = False
    """Evaluate ``out`` on the episodes of ``split``; no training."""
    split: str = field(default="heldout", metadata={"choices": tuple(sorted(SPLIT_SEEDS))})
    """Episodes to evaluate on: the reported held-out ones, or the validation ones to
    choose between predictors."""
    pedestrian_mode: str = field(default="pacing",
                                 metadata={"choices": PEDESTRIAN_MODES})
    """How the evaluation episodes' pedestrians walk (a mode other than pacing, or
    ``pedestrians``, renders and caches its own file)."""
    pedestrians: int | None = None
    """Pedestrians per world in the evaluation episodes (default: the world's 3)."""
    json: bool = False
    """End with one JSON line of the figures."""


def _loss(logit: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    bce = F.binary_cross_entropy_with_logits(logit, target)
    p = torch.sigmoid(logit)
    dice = 1.0 - (2.0 * (p * target).sum() + 1.0) / (p.sum() + target.sum() + 1.0)
    return bce + 0.5 * dice


def training_sequences(cfg: PredictRecipe, data_dir: Path = DEFAULT_DATA_DIR) -> SequenceData:
    """The training episodes of recipe ``cfg``: ``cfg.episodes`` split evenly over
    ``cfg.crowds``, scene k from seed ``TRAIN_SEED + k`` (a recipe of pacers alone reads the
    file it always read)."""
    parts = [build_sequences(data_dir, seed, episodes, pedestrian_mode=mode, n_pedestrians=count)
             for seed, mode, count, episodes in crowd_shares(cfg.episodes, cfg.crowds)]
    return parts[0] if len(parts) == 1 else SequenceData.concatenate(parts)


def train_predictor(cfg: PredictRecipe, data_dir: Path = DEFAULT_DATA_DIR
                    ) -> tuple[PredictNet, dict[str, float]]:  # fmt: skip
    """Train a :class:`PredictNet` by recipe ``cfg`` on the training episodes (rendered
    into, or reused from, ``data_dir``)."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    data = training_sequences(cfg, data_dir)
    # windows are gathered per batch: all of them at once took 5.6 GB for 900 episodes
    fused = torch.from_numpy(fused_frames(data, cfg.weights, cfg.threads))
    rows = torch.from_numpy(window_rows(data))
    y = torch.from_numpy(data.future).unsqueeze(1).float()
    n = len(y)
    model = PredictNet()
    if cfg.init is not None:
        from active_vision.predict import load_predictor

        model.load_state_dict(load_predictor(cfg.init, fuse=False).state_dict())
        logger.info("starting from %s", cfg.init)
    model.train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    steps = math.ceil(n / cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr,
                                                total_steps=cfg.epochs * steps, pct_start=0.15)
    gen = torch.Generator().manual_seed(cfg.seed)
    t0 = time.perf_counter()
    epoch, loss_sum = 0, 0.0
    for epoch in range(cfg.epochs):
        order = torch.randperm(n, generator=gen)
        loss_sum = 0.0
        for b in range(steps):
            idx = order[b * cfg.batch:(b + 1) * cfg.batch]
            xb = PredictNet.inputs(fused[rows[idx]].float())
            yb = y[idx]
            flip = (torch.rand(len(idx), generator=gen) < 0.5).view(-1, 1, 1, 1)
            xb = torch.where(flip, xb.flip(-1), xb)
            yb = torch.where(flip, yb.flip(-1), yb)
            loss = _loss(model(xb), yb)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            loss_sum += float(loss.detach())
        elapsed = time.perf_counter() - t0
        logger.info("epoch %d/%d  loss %.4f  (%.0f s)", epoch + 1, cfg.epochs,
                    loss_sum / steps, elapsed)
        if elapsed > 60.0 * cfg.max_minutes and epoch + 1 < cfg.epochs:
            logger.warning("stopping after %d epochs: over --max-minutes", epoch + 1)
            break
    model.eval()
    return model, {"epochs": float(epoch + 1), "seconds": time.perf_counter() - t0,
                   "targets": float(n), "loss": loss_sum / steps}


def evaluate_predictor(predictor: Predictor, data: SequenceData, win: np.ndarray
                       ) -> dict[str, object]:
    """``predict_iou``, ``detect_baseline_iou``, ``oracle_now_iou`` overall and per world,
    and ``margin_interval``: the 90 % interval of ``predict_iou - detect_baseline_iou`` over
    episodes (:func:`margin_interval`)."""
    episodes = np.unique(data.episode_row)
    index = {int(e): k for k, e in enumerate(episodes)}
    # per episode, rows: pred, det, now; columns: intersection, union
    counts = np.zeros((len(episodes), 3, 2), np.int64)
    episode_world = np.zeros(len(episodes), np.int64)
    for i in range(0, len(win), 64):
        prob = predictor(win[i:i + 64].astype(np.float32))
        det = win[i:i + 64, -1, :, :, :, ][..., CHANNEL_HEATMAP].astype(np.float32)
        for j in range(len(prob)):
            t = i + j
            fut = data.future[t]
            e = index[int(data.episode_row[t])]
            episode_world[e] = int(data.world[t])
            for row, guess in enumerate((prob[j] >= THRESHOLD, det[j] >= THRESHOLD,
                                         data.now[t])):
                counts[e, row, 0] += np.count_nonzero(guess & fut)
                counts[e, row, 1] += np.count_nonzero(guess | fut)

    def figures(c: np.ndarray) -> dict[str, object]:
        total = c.sum(axis=0)
        iou = [float(total[r, 0] / total[r, 1]) if total[r, 1] else float("nan")
               for r in range(3)]
        return {"predict_iou": iou[0], "detect_baseline_iou": iou[1], "oracle_now_iou": iou[2],
                "margin_interval": margin_interval(c)}

    out: dict[str, object] = dict(figures(counts))
    out["per_world"] = {w: figures(counts[episode_world == k]) for k, w in enumerate(data.worlds)}
    out["targets"] = int(len(win))
    return out


def margin_interval(counts: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES,
                    seed: int = 0) -> list[float]:
    """The 5th and 95th percentiles of ``predict_iou - detect_baseline_iou`` over
    ``resamples`` bootstrap draws of whole episodes: how sure a margin measured on these
    episodes is (an episode's frames are not independent, so episodes are the unit).

    :param counts: ``(episodes, 3, 2)`` intersections and unions per episode, rows
        predictor, detection, current ground truth.
    """
    n = len(counts)
    if n == 0:
        return [float("nan"), float("nan")]
    draws = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    total = counts[draws].sum(axis=1)  # (resamples, 3, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = total[:, :, 0] / total[:, :, 1]
    margin = iou[:, 0] - iou[:, 1]
    lo, hi = np.nanpercentile(margin, [5.0, 95.0])
    return [float(lo), float(hi)]


def figure_rows(m: dict[str, object]) -> list[str]:
    """:func:`evaluate_predictor`'s figures as table lines: a header, then overall and per
    world the three IoUs and the margin's interval."""
    per = m["per_world"]
    assert isinstance(per, dict)
    rows = [f"{'world':<8} {'predict':>8} {'detect':>8} {'now-GT':>8}  predict-detect, 90 % "
            "interval over episodes"]
    for w, f in [("all", m), *per.items()]:
        lo, hi = f["margin_interval"]  # type: ignore[index]
        rows.append(f"{w:<8} {f['predict_iou']:8.4f} {f['detect_baseline_iou']:8.4f} "  # type: ignore[index]
                    f"{f['oracle_now_iou']:8.4f}  {lo:+.3f} .. {hi:+.3f}")  # type: ignore[index]
    return rows


def evaluate_heldout(predict_weights: Path | None = None, weights: Path | None = None,
                     data_dir: Path = DEFAULT_DATA_DIR, episodes: int = HELDOUT_EPISODES,
                     threads: int = 2, split: str = "heldout", pedestrian_mode: str = "pacing",
                     n_pedestrians: int | None = None) -> dict[str, object]:
    """The three figures on the held-out (or ``split="validation"``) driving episodes
    (rendered on first use) among pedestrians walking by ``pedestrian_mode``,
    ``n_pedestrians`` of them (None: the world's 3)."""
    if split not in SPLIT_SEEDS:
        raise ValueError(f"split must be one of {sorted(SPLIT_SEEDS)}, got {split!r}")
    data = build_sequences(data_dir, SPLIT_SEEDS[split], episodes,
                           pedestrian_mode=pedestrian_mode, n_pedestrians=n_pedestrians)
    win = windows(data, weights, threads)
    return evaluate_predictor(Predictor(weights=predict_weights), data, win)


RECIPE_KEY = "recipe"
"""The key of a predictor file's ``meta`` that holds its :class:`PredictRecipe`."""


def read_recipe(path: Path) -> PredictRecipe:
    """The recipe stored in the predictor weights file ``path``."""
    meta = torch.load(path, map_location="cpu", weights_only=True).get("meta", {})
    if RECIPE_KEY not in meta:
        raise ValueError(f"{path} holds no recipe (weights written before recipes were "
                         "stored)")  # fmt: skip
    return recipe_from_dict(PredictRecipe, meta[RECIPE_KEY])


def main(argv: Sequence[str] | None = None) -> int:
    cfg, run, _ = parse_recipe_command(
        PredictRecipe, PredictRun, "python -m active_vision.training.predict_train",
        "Train/evaluate the predictive heatmap.", read_recipe, argv, "a predictor weights file")
    if not run.evaluate_only:
        model, facts = train_predictor(cfg, run.data_dir)
        save_predictor(model, run.out, {**facts, RECIPE_KEY: recipe_dict(cfg)})
        print(f"wrote {run.out} after {facts['epochs']:.0f} epochs in {facts['seconds']:.0f} s")
    m = evaluate_heldout(run.out, cfg.weights, run.data_dir, threads=cfg.threads,
                         split=run.split, pedestrian_mode=run.pedestrian_mode,
                         n_pedestrians=run.pedestrians)
    among = "" if run.pedestrian_mode == "pacing" and run.pedestrians is None else (
        f", {run.pedestrian_mode} of {run.pedestrians or 'the world'}")
    print(f"{run.split} episodes ({SPLIT_SEEDS[run.split]}{among}):")
    print("\n".join(figure_rows(m)))
    if run.json:
        print(json.dumps(m))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
