"""Train the perception network on frames rendered from our worlds.

    python -m active_vision.training.train [--data FILE] [--frames N] [--epochs E] [--threads 2]
    python -m active_vision.training.train --init active_vision/weights/avnet.pt \
        --epochs 2 --lr 1e-3
    (the second: a fine-tune of the shipped weights)

One network (:class:`~active_vision.models.AVNet`) serves both fused channels (the daemon
needs both heads from one file), so it is trained on the sum of the two losses.

Without ``--data`` the training split (``dataset.TRAIN_SEED``, 40,000 frames, 70 % recorded
while driving, random pedestrian appearance, half of them in inspect) is rendered into
``--data-dir`` on first use (about two minutes) and reused afterwards. On the CPU by
default, ``--threads`` torch threads (default 2); a from-scratch run of the default recipe is
about an hour on two CPU cores. ``--device cuda`` trains on a GPU with the same batches (the
random draws stay on the CPU generator); there the step is bound by the augmentation's
per-frame work on the CPU, not by the network. The training state is written after every epoch
(``--checkpoint``, default ``OUT.ckpt``); ``--resume`` continues an interrupted run. With
``--calibrate`` the heatmap head is then calibrated on the validation split
(:mod:`active_vision.training.calibrate`: the detection threshold that serves recall best
within the false-positive budget becomes the head's 0.5). Writes
``active_vision/weights/avnet.pt`` (or ``--out``) with the held-out figures (driving split) of
the result stored in its ``meta``.

Losses:

- heatmap: binary cross-entropy on the logits (pedestrian pixels weighted
  ``POSITIVE_WEIGHT``, and a small figure's pixels up to ``SMALL_FIGURE_MAX_BOOST`` times
  more: ``sqrt(SMALL_FIGURE_PX / its pixels)``, so that a figure 4-5 m away, which recall
  counts as one pedestrian like a near one, is not worth a tenth of it), plus a soft Dice
  term over the batch (keeps small pedestrians from drowning in background pixels), plus a
  hard-negative term: the ``HARD_NEGATIVES`` highest background logits of each frame pushed
  towards 0 (false detections are a few confident pixels that the mean cross-entropy
  barely sees);
- depth: the head predicts log metric depth; L1 on ``log d`` for pixels nearer than the far
  limit (for small errors that is AbsRel, and it is symmetric in the depth ratio that
  delta1 tests), and a hinge ``max(0, log DEPTH_MAX_M - log_d)`` for far/sky pixels, which
  only need to read as "at or beyond the limit" (channel 0); pedestrian pixels count
  ``1 + PEDESTRIAN_DEPTH_WEIGHT`` times.

Augmentation: copy-paste of pedestrians between the frames of a batch, occluded by what
is nearer (:func:`paste_figures`, half of the frames), distractors that are not people
(``--clutter``: façades, poles, cones and texture drawn in the frame's geometry,
:mod:`active_vision.training.clutter`), horizontal flip (image, mask and depth together),
brightness, contrast, per-channel gain and pixel noise.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from active_vision.models import (
    DEFAULT_WEIGHTS,
    HEAD_DEPTH,
    HEAD_HEATMAP,
    MIN_DEPTH_M,
    AVNet,
    AVNetConfig,
    load_model,
    weights_meta,
)
from active_vision.models import save_weights as _save
from active_vision.training.clutter import clutter_batch
from active_vision.training.dataset import (
    DEFAULT_DATA_DIR,
    Dataset,
    DatasetConfig,
    build,
    crowd_shares,
    parse_crowds,
)
from fused_image import DEPTH_MAX_M
from rover_train.cli import parse_recipe_command, recipe_dict, recipe_from_dict

logger = logging.getLogger(__name__)

HARD_NEGATIVES = 32
HARD_NEGATIVE_WEIGHT = 0.2
POSITIVE_WEIGHT = 3.0
"""Weight of pedestrian pixels in the heatmap's cross-entropy: a pedestrian of 30-60 px
among 9,216 background pixels otherwise costs too little to miss."""
PEDESTRIAN_DEPTH_WEIGHT = 4.0
SMALL_FIGURE_PX = 200
"""A pedestrian (8-connected mask component) smaller than this gets its pixels' heatmap weight
raised by ``sqrt(SMALL_FIGURE_PX / pixels)``, at most ``SMALL_FIGURE_MAX_BOOST`` times
(400 with a cap of 4, tried with edge pastes, did not raise inspect's recall on the
validation split: docs/decisions.md, "Perception network and int8")."""
SMALL_FIGURE_MAX_BOOST = 3.0
DEPTH_WORLD_WEIGHTS: dict[str, float] = {}
"""Depth-loss weight of a world's frames by name (a world not named: 1). None by default; the
shipped recipe weights the moon's frames 4 times (``--depth-world-weight moon=4``), which
raised the moon's delta1 on validation in fine-tunes. No from-scratch run without it was
made, so the default stays (docs/decisions.md, "Perception network and int8")."""
PASTE_PROB = 0.5
"""Share of training frames that receive another frame's pedestrians (:func:`paste_figures`)."""
PASTE_MAX_SHIFT = 40
"""Most columns a pasted figure is moved sideways (a paste that is not to a frame edge)."""
TRAIN_WORLDS: tuple[str, ...] = ("inspect", "moon", "maze", "inspect")
"""The training split's world cycle: inspect twice, as the world with the most pedestrians
missed (its panel rows hide and shade them; recall 0.84 there against 0.96-0.98 elsewhere
with an even split)."""


def parse_widths(text: str) -> tuple[int, int, int, int]:
    """The network's four widths from ``"24,48,96,128"`` (an argparse ``type``)."""
    try:
        w = tuple(int(v) for v in text.split(","))
    except ValueError:
        w = ()
    if len(w) != 4 or min(w) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give four positive integers, "
                                         "e.g. 24,48,96,128")
    return w  # type: ignore[return-value]


def parse_worlds(text: str) -> tuple[str, ...]:
    """World names from ``"inspect,moon,maze"`` (an argparse ``type``)."""
    worlds = tuple(w.strip() for w in text.split(",") if w.strip())
    if not worlds:
        raise argparse.ArgumentTypeError(f"{text!r}: give world names, e.g. inspect,moon,maze")
    return worlds


def training_split(cfg: AVNetRecipe, data_dir: Path) -> Dataset:
    """The training frames of recipe ``cfg``: ``cfg.frames`` split evenly over ``cfg.crowds``,
    scene k rendered (and cached in ``data_dir``) from seed ``TRAIN_SEED + k``; a recipe with
    only ``pacing`` reads the pacers' split of seed ``TRAIN_SEED``."""
    parts = [Dataset.load(build(data_dir, DatasetConfig(
        frames=frames, seed=seed, worlds=cfg.worlds, pedestrian_mode=mode, n_pedestrians=count)))
        for seed, mode, count, frames in crowd_shares(cfg.frames, cfg.crowds)]
    return parts[0] if len(parts) == 1 else Dataset.concatenate(parts)


def parse_world_weights(text: str) -> dict[str, float]:
    """Per-world weights from ``"moon=4,maze=1"`` (an argparse ``type``; ``""``: none)."""
    weights: dict[str, float] = {}
    for item in (s for s in text.split(",") if s.strip()):
        world, _, value = item.partition("=")
        try:
            weights[world.strip()] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{item!r}: give WORLD=WEIGHT, e.g. moon=4") from None
    return weights


@dataclass(frozen=True)
class AVNetRecipe:
    """Everything that decides what a perception weights file holds. The weights file stores
    it (``meta["recipe"]``); ``--recipe FILE`` remakes the file from it, and the command line
    is generated from these fields."""

    frames: int = 40000
    """Training frames to render (70 % driving, 30 % posed) when no ``--data`` file is given.
    40,000 frames for 15 epochs beat 20,000 for 30 (the same optimiser steps) and 60,000 for
    10 on the validation split (docs/decisions.md, "Perception network and int8")."""
    worlds: tuple[str, ...] = field(default=TRAIN_WORLDS, metadata={"parse": parse_worlds})
    """Worlds to render the training split from, cycled episode by episode and frame by
    frame (a name twice gets twice the frames), comma-separated."""
    crowds: tuple[str, ...] = field(default=("pacing",), metadata={"parse": parse_crowds})
    """Pedestrian scenes the training split is rendered among, comma-separated: a
    pedestrian mode (``pacing``, ``crowd``, ``oblivious``, ``crossing``, ``groups``), with
    ``:N`` for N pedestrians per world (e.g. ``pacing,crowd:3,crowd:10``); the frames are
    split evenly between them."""
    epochs: int = 15
    """Passes over the training data."""
    batch: int = 32
    """Frames per optimiser step."""
    lr: float = 4e-3
    """Peak learning rate (one-cycle schedule)."""
    threads: int = 2
    """torch threads (the float order of the kernels, so the weights, depend on it)."""
    device: str = "cpu"
    """torch device to train on (``cpu``, ``cuda``, ``cuda:1``). The random draws (batch order,
    augmentation) are made on the CPU generator either way, so a run on a GPU sees the same
    batches as on the CPU; its weights differ by the float order of the kernels."""
    seed: int = 0
    """torch seed (initial weights, batch order, augmentation)."""
    max_minutes: float = 90.0
    """Stop early (keeping the schedule's shape) when training takes longer than this."""
    widths: tuple[int, int, int, int] = field(default=AVNetConfig.widths,
                                              metadata={"parse": parse_widths})
    """The network's four widths, comma-separated."""
    full_res: int = AVNetConfig.full_res
    """Channels of the network's full-resolution stage (0: none)."""
    small_figure_boost: bool = True
    """Weight small figures' pixels up (``SMALL_FIGURE_PX``) in the heatmap loss."""
    paste_prob: float = PASTE_PROB
    """Copy-paste augmentation: share of frames that receive another frame's pedestrians
    (:func:`paste_figures`; 0 turns it off)."""
    depth_world_weights: dict[str, float] = field(
        default_factory=dict, metadata={"parse": parse_world_weights, "metavar": "W=X,..."})
    """Depth-loss weight of each world's frames, e.g. ``moon=4`` (a world not named: 1)."""
    clutter: float = 0.0
    """Share of training frames that get distractors drawn in (façades, poles, cones,
    texture: :mod:`active_vision.training.clutter`), so that real scenery is not read as a
    person."""
    clutter_worlds: tuple[str, ...] = field(default=(), metadata={"parse": parse_worlds})
    """Worlds whose frames may get distractors (none named: every world)."""
    init: Path | None = None
    """Start from these AVNet weights (same widths) instead of random ones: a fine-tune."""
    calibrate: bool = False
    """Fold the heatmap threshold chosen on the validation splits of ``crowds`` into the
    head (:mod:`active_vision.training.calibrate`) before the held-out evaluation (it
    changes channel 1 for whatever reads it)."""

    def problem(self) -> str | None:
        """What is wrong with this recipe (named by its option), or None."""
        if not 0.0 <= self.paste_prob <= 1.0:
            return f"--paste-prob {self.paste_prob}: give a share in [0, 1]"
        if not 0.0 <= self.clutter <= 1.0:
            return f"--clutter {self.clutter}: give a share in [0, 1]"
        if any(w < 0 for w in self.depth_world_weights.values()):
            return f"--depth-world-weights {self.depth_world_weights}: a weight cannot be negative"
        if self.init is not None and not self.init.is_file():
            return f"--init {self.init}: no such weights file"
        if self.full_res < 0:
            return f"--full-res {self.full_res}: give 0 (no full-resolution stage) or a count"
        try:
            device = torch.device(self.device)
        except RuntimeError:
            device = None
        if device is None or device.type not in ("cpu", "cuda"):
            return f"--device {self.device!r}: give cpu, cuda or cuda:N"
        if device.type == "cuda" and not torch.cuda.is_available():
            return f"--device {self.device}: this torch sees no CUDA GPU; train with --device cpu"
        return None


@dataclass(frozen=True)
class TrainRun:
    """Where a training run reads and writes: not part of the recipe."""

    data: Path | None = None
    """Training ``.npz``; none renders/reuses the training split in ``data_dir``."""
    data_dir: Path = DEFAULT_DATA_DIR
    """Where rendered datasets are cached."""
    out: Path = DEFAULT_WEIGHTS
    """Weights file to write."""
    checkpoint: Path | None = None
    """Write the training state here after every epoch (default: ``out`` + ``.ckpt``);
    with ``resume`` a run picks up from it after an interruption."""
    resume: bool = False
    """Continue from ``checkpoint`` if it exists (same data and recipe)."""
    evaluate: bool = True
    """Evaluate on the held-out split after training and store the figures in the file."""


def _shift_columns(t: torch.Tensor, shift: int) -> torch.Tensor:
    """``t`` (``(..., W)``) moved ``shift`` columns right (left if negative), zero-filled."""
    if shift == 0:
        return t
    out = torch.zeros_like(t)
    if shift > 0:
        out[..., shift:] = t[..., :-shift]
    else:
        out[..., :shift] = t[..., -shift:]
    return out


def paste_figures(x: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor,
                  gen: torch.Generator, prob: float = PASTE_PROB
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Copy-paste augmentation: with probability ``prob`` a frame receives the pedestrians
    of another frame of the batch, moved sideways by up to ``PASTE_MAX_SHIFT`` columns.

    A pasted pixel replaces the frame's pixel only where the figure is nearer than what the
    frame shows there (its true depth), so nearer panels and walls still hide it, and the
    mask and the depth take the figure's values: the image, the mask and the depth stay
    consistent. Rows are kept, so a figure stands on the same image row (about the same
    ground distance) as in its own frame. Returns new tensors; the inputs are unchanged.

    Why: on driving frames the network missed figures standing in front of inspect's
    structures (a grey figure before a pink wall, a dark one before a green box) while it
    found the same figures against the ground or the sky; pasting puts figures in front of
    every kind of background the worlds have.
    """
    n = x.shape[0]
    use = torch.rand(n, generator=gen) < prob
    donors = torch.randint(0, n, (n,), generator=gen)
    shifts = torch.randint(-PASTE_MAX_SHIFT, PASTE_MAX_SHIFT + 1, (n,), generator=gen)
    x, mask, depth = x.clone(), mask.clone(), depth.clone()
    has_figure = (mask.amax(dim=(1, 2, 3)) > 0.5)
    for i in torch.nonzero(use).flatten().tolist():
        j = int(donors[i])
        if j == i or not bool(has_figure[j]):
            continue
        s = int(shifts[i])
        d_mask = _shift_columns(mask[j], s) > 0.5
        d_depth = _shift_columns(depth[j], s)
        put = d_mask & (d_depth < depth[i])
        if not bool(put.any()):
            continue
        x[i] = torch.where(put, _shift_columns(x[j], s), x[i])
        mask[i] = torch.where(put, torch.ones_like(mask[i]), mask[i])
        depth[i] = torch.where(put, d_depth, depth[i])
    return x, mask, depth


def augment_batch(x: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor,
                  gen: torch.Generator, paste_prob: float = 0.0, clutter: float = 0.0,
                  clutter_allowed: torch.Tensor | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The training augmentation of a batch: pastes (:func:`paste_figures`), distractors
    (:func:`~active_vision.training.clutter.clutter_batch`, in the frames ``clutter_allowed``
    marks), flips, and photometric changes; the mask and the depth follow the geometry."""
    n, dev = x.shape[0], x.device
    if paste_prob > 0.0:
        x, mask, depth = paste_figures(x, mask, depth, gen, paste_prob)
    if clutter > 0.0:
        x, mask, depth = clutter_batch(x, mask, depth, gen, clutter, clutter_allowed)
    flip = (torch.rand(n, generator=gen) < 0.5).to(dev)
    x = torch.where(flip.view(n, 1, 1, 1), x.flip(-1), x)
    mask = torch.where(flip.view(n, 1, 1, 1), mask.flip(-1), mask)
    depth = torch.where(flip.view(n, 1, 1, 1), depth.flip(-1), depth)
    bright = ((torch.rand(n, 1, 1, 1, generator=gen) - 0.5) * 0.3).to(dev)
    contrast = (0.7 + 0.6 * torch.rand(n, 1, 1, 1, generator=gen)).to(dev)
    gain = (0.9 + 0.2 * torch.rand(n, 3, 1, 1, generator=gen)).to(dev)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * contrast + mean + bright
    x = x * gain + 0.02 * torch.randn(x.shape, generator=gen).to(dev)
    # the daemon sees uint8 frames: quantise like them
    x = torch.round(x.clamp(0.0, 1.0) * 255.0) / 255.0
    return x, mask, depth


def figure_components(mask: torch.Tensor) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """For each frame of a float mask ``(N, 1, H, W)`` with pedestrian pixels: its index, its
    8-connected component labels ``(H, W)`` (0: background) and each label's pixel count."""
    m = mask[:, 0].detach().cpu().numpy() > 0.5
    for i in np.flatnonzero(m.reshape(len(m), -1).any(axis=1)):
        _, labels, stats, _ = cv2.connectedComponentsWithStats(m[i].astype(np.uint8),
                                                               connectivity=8)
        yield int(i), labels, stats[:, cv2.CC_STAT_AREA]


def figure_weights(mask: torch.Tensor, small_boost: bool = True) -> torch.Tensor:
    """Per-pixel heatmap weights ``(N, 1, H, W)`` for a float mask ``(N, 1, H, W)``: 1 on the
    background, ``POSITIVE_WEIGHT`` on pedestrian pixels, and with ``small_boost`` times
    ``min(SMALL_FIGURE_MAX_BOOST, sqrt(SMALL_FIGURE_PX / area))`` on a figure (8-connected
    component) of fewer than ``SMALL_FIGURE_PX`` pixels."""
    if not small_boost:
        return 1.0 + (POSITIVE_WEIGHT - 1.0) * mask
    w = np.ones((mask.shape[0], *mask.shape[2:]), np.float32)
    for i, labels, area in figure_components(mask):
        area = area.astype(np.float32)
        boost = np.clip(np.sqrt(SMALL_FIGURE_PX / np.maximum(area, 1.0)), 1.0,
                        SMALL_FIGURE_MAX_BOOST)
        boost[0] = 1.0 / POSITIVE_WEIGHT  # label 0: the background
        w[i] = POSITIVE_WEIGHT * boost[labels]
    return torch.from_numpy(w).unsqueeze(1).to(mask.device)


def losses(logits: torch.Tensor, mask: torch.Tensor, depth_m: torch.Tensor,
           heat_weight: torch.Tensor, depth_weight: torch.Tensor | None = None
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """(heatmap loss, depth loss) for logits ``(N, 2, H, W)``, mask and metres ``(N,1,H,W)``,
    with per-pixel cross-entropy weights ``heat_weight`` (:func:`figure_weights`) and
    optional per-frame depth-loss weights ``depth_weight`` ``(N,)``."""
    heat_logit = logits[:, HEAD_HEATMAP:HEAD_HEATMAP + 1]
    bce = F.binary_cross_entropy_with_logits(heat_logit, mask, weight=heat_weight)
    prob = torch.sigmoid(heat_logit)
    dice = 1.0 - (2.0 * (prob * mask).sum() + 1.0) / (prob.sum() + mask.sum() + 1.0)
    # hard negatives: the HARD_NEGATIVES highest background logits of each frame (pixels
    # more than 2 px from a pedestrian), pushed to 0 - what a false detection is made of
    near = F.max_pool2d(mask, 5, stride=1, padding=2) > 0
    bg_logits = heat_logit.masked_fill(near, float("-inf")).flatten(1)
    hard = F.softplus(bg_logits.topk(HARD_NEGATIVES, dim=1).values).mean()
    heat = bce + 0.5 * dice + HARD_NEGATIVE_WEIGHT * hard
    log_d = logits[:, HEAD_DEPTH:HEAD_DEPTH + 1]
    near = depth_m < DEPTH_MAX_M
    far_log = math.log(DEPTH_MAX_M)
    per_px = torch.where(near, (log_d - torch.log(depth_m.clamp(min=MIN_DEPTH_M))).abs(),
                         F.relu(far_log - log_d))
    # pedestrians are few pixels but the ones whose distance matters most
    per_px = per_px * (1.0 + PEDESTRIAN_DEPTH_WEIGHT * mask)
    if depth_weight is not None:
        per_px = per_px * depth_weight.view(-1, 1, 1, 1)
    return heat, per_px.mean()


def train(cfg: AVNetRecipe, run: TrainRun | None = None, data: Dataset | None = None
          ) -> tuple[AVNet, dict[str, float]]:  # fmt: skip
    """Train a network by recipe ``cfg`` on ``data`` (or ``run``'s dataset); returns it
    (eval mode, unfused) and a dict of training facts."""
    run = run or TrainRun()
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    if data is None:
        data = Dataset.load(run.data) if run.data else training_split(cfg, run.data_dir)
    dev = torch.device(cfg.device)
    rgb = torch.from_numpy(data.rgb).permute(0, 3, 1, 2).contiguous().to(dev)  # uint8 N,3,H,W
    mask = torch.from_numpy(data.mask).unsqueeze(1).float().to(dev)
    depth_m = torch.from_numpy(np.nan_to_num(data.depth, nan=1e3, posinf=1e3)).unsqueeze(1)
    depth_m = depth_m.clamp(min=1e-3).to(dev)
    n = rgb.shape[0]
    frame_depth_weight = torch.tensor(
        [cfg.depth_world_weights.get(w, 1.0) for w in data.worlds], dtype=torch.float32
    )[torch.from_numpy(data.world)].to(dev)
    unknown = sorted(set(cfg.clutter_worlds) - set(data.worlds))
    if unknown:
        raise ValueError(f"--clutter-worlds {','.join(unknown)}: not a world of the training "
                         f"data ({', '.join(data.worlds)})")
    frame_clutter = (torch.from_numpy(np.isin(np.asarray(data.worlds)[data.world],
                                              cfg.clutter_worlds))
                     if cfg.clutter_worlds else None)
    model = AVNet(AVNetConfig(widths=tuple(cfg.widths), full_res=cfg.full_res))
    if cfg.init is not None:
        start = load_model(cfg.init, fuse=False)
        if start.config != model.config:
            raise ValueError(f"--init {cfg.init} has widths {start.config.widths} and full_res "
                             f"{start.config.full_res}, this run {model.config.widths} and "
                             f"{model.config.full_res}: pass the same --widths/--full-res")
        model.load_state_dict(start.state_dict())
        logger.info("starting from %s", cfg.init)
    model.to(dev).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    steps_per_epoch = math.ceil(n / cfg.batch)
    total_steps = cfg.epochs * steps_per_epoch
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr, total_steps=total_steps,
                                                pct_start=0.15)
    gen = torch.Generator().manual_seed(cfg.seed)
    ckpt = run.checkpoint or Path(str(run.out) + ".ckpt")
    first = 0
    recipe = {k: v for k, v in recipe_dict(cfg).items() if k != "max_minutes"}
    if run.resume and ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        if state.get("frames") != n or state.get("recipe") != recipe:
            theirs = state.get("recipe") or {}
            differ = sorted(k for k in set(recipe) | set(theirs)
                            if recipe.get(k) != theirs.get(k))  # fmt: skip
            raise ValueError(f"checkpoint {ckpt} is of another run ({state.get('frames')} "
                             f"frames against {n}; recipe fields that differ: {differ}): run "
                             "with the same data and recipe, or without --resume")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        gen.set_state(state["gen"])
        first = int(state["epoch"])
        logger.info("resuming from %s after epoch %d", ckpt, first)
    t0 = time.perf_counter()
    step = 0
    hist = {"heat": 0.0, "depth": 0.0}
    epoch = first - 1
    for epoch in range(first, cfg.epochs):
        order = torch.randperm(n, generator=gen)
        sums = {"heat": 0.0, "depth": 0.0}
        for b in range(steps_per_epoch):
            idx = order[b * cfg.batch:(b + 1) * cfg.batch]
            x = rgb[idx].float() / 255.0
            x, m, d = augment_batch(x, mask[idx], depth_m[idx], gen, cfg.paste_prob, cfg.clutter,
                                    None if frame_clutter is None else frame_clutter[idx])
            heat, dep = losses(model(x), m, d, figure_weights(m, cfg.small_figure_boost),
                               frame_depth_weight[idx])
            loss = heat + dep
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            step += 1
            sums["heat"] += float(heat.detach())
            sums["depth"] += float(dep.detach())
        hist = {k: v / steps_per_epoch for k, v in sums.items()}
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"model": model.state_dict(), "opt": opt.state_dict(),
                    "sched": sched.state_dict(), "gen": gen.get_state(), "epoch": epoch + 1,
                    "frames": n, "recipe": recipe}, str(ckpt) + ".tmp")
        Path(str(ckpt) + ".tmp").replace(ckpt)
        elapsed = time.perf_counter() - t0
        logger.info("epoch %d/%d  heatmap loss %.4f  depth loss %.4f  (%.0f s)", epoch + 1,
                    cfg.epochs, hist["heat"], hist["depth"], elapsed)
        if elapsed > 60.0 * cfg.max_minutes and epoch + 1 < cfg.epochs:
            logger.warning("stopping after %d epochs: over --max-minutes %.1f", epoch + 1,
                           cfg.max_minutes)
            break
    model.to("cpu").eval()
    facts = {"epochs": float(epoch + 1), "seconds": time.perf_counter() - t0,
             "frames": float(n), "heat_loss": hist["heat"], "depth_loss": hist["depth"],
             "dataset_seed": float(data.seed)}
    return model, facts


RECIPE_KEY = "recipe"
"""The key of a weights file's ``meta`` that holds its :class:`AVNetRecipe` (as a dict)."""


def read_recipe(path: Path) -> AVNetRecipe:
    """The recipe stored in the weights file ``path``."""
    meta = weights_meta(path)
    if RECIPE_KEY not in meta:
        raise ValueError(f"{path} holds no recipe (weights written before recipes were "
                         "stored)")  # fmt: skip
    return recipe_from_dict(AVNetRecipe, meta[RECIPE_KEY])


def _parse(argv: Sequence[str] | None) -> tuple[AVNetRecipe, TrainRun]:
    recipe, run, _ = parse_recipe_command(
        AVNetRecipe, TrainRun, "python -m active_vision.training.train",
        __doc__.split("\n")[0], read_recipe, argv, "a weights file")
    return recipe, run


def main(argv: Sequence[str] | None = None) -> int:
    cfg, run = _parse(argv)
    model, facts = train(cfg, run)
    meta: dict[str, Any] = {**facts, RECIPE_KEY: recipe_dict(cfg)}
    path = _save(model, run.out, meta)  # first without figures: evaluation may fail
    from active_vision.training.evaluate import evaluate, format_metrics, heldout

    if cfg.calibrate:
        from active_vision.training.calibrate import (
            calibrate,
            calibrated_meta,
            validation_splits,
        )

        t, shift, table = calibrate(model, validation_splits(run.data_dir, cfg.crowds),
                                    threads=cfg.threads)
        print(table)
        meta = calibrated_meta(meta, t, shift)
        path = _save(model, run.out, meta)
    if run.evaluate:
        m = evaluate(model, heldout(run.data_dir), threads=cfg.threads)
        print(format_metrics(m))
        meta.update({f"heldout_{k}": float(v) for k, v in m.summary().items()})
        path = _save(model, run.out, meta)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB) after {facts['epochs']:.0f} "
          f"epochs in {facts['seconds']:.0f} s")
    from active_vision.training.quantize import write_exports_beside

    write_exports_beside(path, run.data_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
