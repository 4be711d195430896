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
default, ``--threads`` torch threads (default 2): the default network (24/48/96/128) for the
default 15 epochs took 65 min on a 2-core machine with two runs side by side on one thread
each (255-265 s an epoch, 2026-11-26; the 16/32/64/96 network before it: 125-150 s).
``--device cuda`` trains on a GPU with the same batches (the random draws stay on the CPU
generator); the step is bound by the augmentation's per-frame work, so an H200 with 16 CPU
cores took about 25 s an epoch for the 16/32/64/96 network with two runs sharing it. The
training state is written after every epoch (``--checkpoint``, default ``OUT.ckpt``);
``--resume`` continues an interrupted run. With ``--calibrate`` the heatmap head is then
calibrated on the validation split (:mod:`active_vision.training.calibrate`: the detection
threshold that serves recall best within the false-positive budget becomes the head's
0.5). Writes ``active_vision/weights/avnet.pt`` (or ``--out``)
with the held-out figures (driving split) of the result stored in its ``meta``.

Losses:

- heatmap: binary cross-entropy on the logits (pedestrian pixels weighted
  ``POSITIVE_WEIGHT``, and a small figure's pixels up to ``SMALL_FIGURE_MAX_BOOST`` times
  more: ``sqrt(SMALL_FIGURE_PX / its pixels)``, so that a figure 4-5 m away, which recall
  counts as one pedestrian like a near one, is not worth a tenth of it), plus a soft Dice
  term over the batch (keeps small pedestrians from drowning in background pixels), plus a
  hard-negative term: the ``HARD_NEGATIVES`` highest background logits of each frame pushed
  towards 0 (false detections are a few confident pixels that the mean cross-entropy
  barely sees), and, with ``--hard-positive-weight`` (off by default), its counterpart:
  each counted pedestrian's ``HARD_POSITIVES`` highest logits pushed above 0;
- depth: the head predicts log metric depth; L1 on ``log d`` for pixels nearer than the far
  limit (for small errors that is AbsRel, and it is symmetric in the depth ratio that
  delta1 tests), and a hinge ``max(0, log DEPTH_MAX_M - log_d)`` for far/sky pixels, which
  only need to read as "at or beyond the limit" (channel 0); pedestrian pixels count
  ``1 + PEDESTRIAN_DEPTH_WEIGHT`` times.

Augmentation: copy-paste of pedestrians between the frames of a batch, occluded by what
is nearer (:func:`paste_figures`, half of the frames; ``--edge-paste-share`` puts a share
of those pastes at a side edge, cut by it), horizontal flip (image, mask and
depth together), brightness, contrast, per-channel gain and pixel noise.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

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
)
from active_vision.models import save_weights as _save
from active_vision.training.dataset import (
    DEFAULT_DATA_DIR,
    TRAIN_SEED,
    Dataset,
    DatasetConfig,
    build,
)
from active_vision.training.evaluate import MIN_BLOB_PX, MIN_PEDESTRIAN_PX
from shm_protocol import DEPTH_MAX_M

logger = logging.getLogger(__name__)

HARD_NEGATIVES = 32
HARD_NEGATIVE_WEIGHT = 0.2
HARD_POSITIVES = 2 * MIN_BLOB_PX
"""Pixels of each pedestrian whose logits the hard-positive term pushes above 0: twice the
smallest blob the evaluation counts as a detection."""
HARD_POSITIVE_WEIGHT = 0.0
"""Weight of the hard-positive term (:func:`hard_positive_loss`; ``--hard-positive-weight``).
Off: a run of the shipped recipe with 0.2 did not raise inspect's recall on the validation
split at 0.5 (0.939 against 0.941) and gave false detections (0.46 % of inspect's empty
frames against 0); it moves the network's operating point (recall 0.955 at 0.4) rather than
what it can see (benchmarks/RESULTS.md, 2026-11-26)."""
POSITIVE_WEIGHT = 3.0
"""Weight of pedestrian pixels in the heatmap's cross-entropy: a pedestrian of 30-60 px
among 9,216 background pixels otherwise costs too little to miss (recall on driving frames
was 0.59 in inspect without it)."""
PEDESTRIAN_DEPTH_WEIGHT = 4.0
SMALL_FIGURE_PX = 200
"""A pedestrian (8-connected mask component) smaller than this gets its pixels' heatmap weight
raised by ``sqrt(SMALL_FIGURE_PX / pixels)``, at most ``SMALL_FIGURE_MAX_BOOST`` times.
(400 with a cap of 4, together with edge pastes, did not raise inspect's recall on the
validation split: 0.935 against 0.941 at 0.5; benchmarks/RESULTS.md, 2026-11-26.)"""
SMALL_FIGURE_MAX_BOOST = 3.0
DEPTH_WORLD_WEIGHTS: dict[str, float] = {}
"""Depth-loss weight of a world's frames by name (a world not named: 1). None by default. On
the moon's old rough ground, weighting its frames 3 times moved its delta1 by less than
run-to-run noise in a fine-tune. On the gentler ground of 2026-11-26, fine-tunes with the
moon weighted 2 and then 4 times gained +0.010 and +0.016 on validation, and the shipped
weights were made so (``--depth-world-weight moon=4``). Four trainings from scratch with it
(seeds 0-3) read the moon's delta1 at 0.879-0.889 on validation. None was run without it,
so its share in that is not known, and the default stays (benchmarks/RESULTS.md)."""
PASTE_PROB = 0.5
"""Share of training frames that receive another frame's pedestrians (:func:`paste_figures`)."""
PASTE_MAX_SHIFT = 40
"""Most columns a pasted figure is moved sideways (a paste that is not to a frame edge)."""
EDGE_PASTE_SHARE = 0.0
"""Share of the pastes that put the figures at a side edge of the frame, a quarter to three
quarters of them cut off (:func:`paste_figures`; ``--edge-paste-share``). Half of inspect's
missed figures are at the frame's side edges, and a shift of at most ``PASTE_MAX_SHIFT``
columns cuts few; but a run with 0.5 (and small figures weighted more) did not raise
inspect's recall on the validation split (benchmarks/RESULTS.md, 2026-11-26), so it is off."""
DISTILL_WEIGHT = 0.5
"""Share of the heatmap loss given to the teachers' mean heatmap in a distillation
(``--teacher``; :func:`losses`), the rest to the mask."""
TRAIN_WORLDS: tuple[str, ...] = ("inspect", "moon", "maze", "inspect")
"""The training split's world cycle: inspect twice, as the world with the most pedestrians
missed (its panel rows hide and shade them; recall 0.84 there against 0.96-0.98 elsewhere
with an even split)."""


@dataclass
class TrainConfig:
    """Training options (CLI flags of the same names)."""

    data: Path | None = None
    """Training ``.npz``; None renders/reuses the training split in ``data_dir``."""
    data_dir: Path = DEFAULT_DATA_DIR
    """Where rendered datasets are cached."""
    frames: int = 40000
    """Training frames to render when ``data`` is None (70 % driving, 30 % posed). Twice the
    20,000 of 2026-11-25, in half the epochs (the same optimiser steps): on the validation
    split inspect's recall rose 0.915 -> 0.941 and its false-positive frames fell 2.05 -> 0 %
    (60,000 frames in 10 epochs: 0.931 and 1.4 %; benchmarks/RESULTS.md)."""
    worlds: tuple[str, ...] = TRAIN_WORLDS
    """Worlds to render the training split from, cycled episode by episode and frame by
    frame (a name twice gets twice the frames)."""
    epochs: int = 15
    """Passes over the training data."""
    batch: int = 32
    """Frames per optimiser step."""
    lr: float = 4e-3
    """Peak learning rate (one-cycle schedule)."""
    threads: int = 2
    """torch threads."""
    device: str = "cpu"
    """torch device to train on (``cpu``, ``cuda``, ``cuda:1``). The random draws (batch order,
    augmentation) are made on the CPU generator either way, so a run on a GPU sees the same
    batches as on the CPU; its weights differ by the float order of the kernels."""
    seed: int = 0
    """torch seed (initial weights, batch order, augmentation)."""
    max_minutes: float = 90.0
    """Stop early (keeping the schedule's shape) when training takes longer than this."""
    out: Path = DEFAULT_WEIGHTS
    """Weights file to write."""
    widths: tuple[int, int, int, int] = AVNetConfig.widths
    """Network widths."""
    full_res: int = AVNetConfig.full_res
    """Channels of the network's full-resolution stage (0: none)."""
    hard_positive_weight: float = HARD_POSITIVE_WEIGHT
    """Weight of the hard-positive term in the heatmap loss (0: off)."""
    small_figure_boost: bool = True
    """Weight small figures' pixels up (``SMALL_FIGURE_PX``) in the heatmap loss."""
    paste_prob: float = PASTE_PROB
    """Copy-paste augmentation: share of frames that receive another frame's pedestrians
    (:func:`paste_figures`; 0 turns it off)."""
    edge_paste_share: float = EDGE_PASTE_SHARE
    """Share of the pastes that put the figures at a side edge of the frame, cut by it
    (0: every paste is a shift of at most ``PASTE_MAX_SHIFT`` columns)."""
    depth_world_weights: dict[str, float] = field(
        default_factory=lambda: dict(DEPTH_WORLD_WEIGHTS))
    """Depth-loss weight of each world's frames (a world not named: 1)."""
    teachers: tuple[Path, ...] = ()
    """Distillation: AVNet weights files whose mean heatmap on each training frame is a soft
    heatmap target beside the mask (:func:`teacher_heatmaps`); none: no distillation."""
    distill_weight: float = DISTILL_WEIGHT
    """Share of the heatmap loss that goes to the teachers' target (with ``teachers``)."""
    init: Path | None = None
    """Start from these AVNet weights (same widths) instead of random ones: a fine-tune."""
    evaluate: bool = True
    """Evaluate on the held-out split after training and store the figures in the file."""
    calibrate: bool = False
    """Fold the heatmap threshold chosen on the validation split into the head
    (:mod:`active_vision.training.calibrate`) before the held-out evaluation. Off by default
    (it needs
    the validation split and changes channel 1 for whatever reads it); the shipped network
    was made with it (see that module for what it costs)."""
    checkpoint: Path | None = None
    """Write the training state here after every epoch (default: ``out`` + ``.ckpt``);
    with ``resume`` a run picks up from it after an interruption."""
    resume: bool = False
    """Continue from ``checkpoint`` if it exists (same data and options)."""


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
                  gen: torch.Generator, prob: float = PASTE_PROB,
                  edge_share: float = EDGE_PASTE_SHARE, soft: torch.Tensor | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Copy-paste augmentation: with probability ``prob`` a frame receives the pedestrians
    of another frame of the batch, moved sideways by up to ``PASTE_MAX_SHIFT`` columns, or
    (``edge_share`` of the pastes) moved so that the middle of their columns lands within a
    quarter of their width of the left or right edge: figures cut by the frame's edge.

    A pasted pixel replaces the frame's pixel only where the figure is nearer than what the
    frame shows there (its true depth), so nearer panels and walls still hide it, and the
    mask and the depth take the figure's values: the image, the mask and the depth stay
    consistent. Rows are kept, so a figure stands on the same image row (about the same
    ground distance) as in its own frame. A ``soft`` heatmap target (the teachers' of a
    distillation, ``(N, 1, H, W)``) is pasted like the mask. Returns new tensors (``soft``:
    None without one); the inputs are unchanged.

    Why: on driving frames the network missed figures standing in front of inspect's
    structures (a grey figure before a pink wall, a dark one before a green box) while it
    found the same figures against the ground or the sky; pasting puts figures in front of
    every kind of background the worlds have.
    """
    n = x.shape[0]
    use = torch.rand(n, generator=gen) < prob
    donors = torch.randint(0, n, (n,), generator=gen)
    shifts = torch.randint(-PASTE_MAX_SHIFT, PASTE_MAX_SHIFT + 1, (n,), generator=gen)
    to_edge = torch.zeros(n, dtype=torch.bool)
    if edge_share > 0.0:  # no extra draws without it: the batches of earlier runs stay as they were
        to_edge = torch.rand(n, generator=gen) < edge_share
        right = torch.rand(n, generator=gen) < 0.5
        offset = torch.rand(n, generator=gen) - 0.5  # where the middle lands, in widths / 2
    x, mask, depth = x.clone(), mask.clone(), depth.clone()
    soft = None if soft is None else soft.clone()
    width = x.shape[-1]
    columns = mask.amax(dim=(1, 2)) > 0.5  # (N, W): columns with a pedestrian pixel
    has_figure = columns.any(dim=1)
    for i in torch.nonzero(use).flatten().tolist():
        j = int(donors[i])
        if j == i or not bool(has_figure[j]):
            continue
        s = int(shifts[i])
        if bool(to_edge[i]):
            cols = torch.nonzero(columns[j]).flatten()
            lo, hi = int(cols[0]), int(cols[-1])
            edge = width - 0.5 if bool(right[i]) else -0.5
            s = round(edge + float(offset[i]) * (hi - lo + 1) / 2 - (lo + hi) / 2)
        d_mask = _shift_columns(mask[j], s) > 0.5
        d_depth = _shift_columns(depth[j], s)
        put = d_mask & (d_depth < depth[i])
        if not bool(put.any()):
            continue
        x[i] = torch.where(put, _shift_columns(x[j], s), x[i])
        mask[i] = torch.where(put, torch.ones_like(mask[i]), mask[i])
        depth[i] = torch.where(put, d_depth, depth[i])
        if soft is not None:
            soft[i] = torch.where(put, _shift_columns(soft[j], s), soft[i])
    return x, mask, depth, soft


def _augment(x: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor,
             gen: torch.Generator, paste_prob: float = 0.0,
             edge_share: float = EDGE_PASTE_SHARE, soft: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """The training augmentation of a batch; ``soft`` (a distillation's heatmap target, or
    None) follows the geometry (pastes, flips) like the mask. Draws the same random numbers
    with or without ``soft``."""
    n, dev = x.shape[0], x.device
    if paste_prob > 0.0:
        x, mask, depth, soft = paste_figures(x, mask, depth, gen, paste_prob, edge_share, soft)
    flip = (torch.rand(n, generator=gen) < 0.5).to(dev)
    x = torch.where(flip.view(n, 1, 1, 1), x.flip(-1), x)
    mask = torch.where(flip.view(n, 1, 1, 1), mask.flip(-1), mask)
    depth = torch.where(flip.view(n, 1, 1, 1), depth.flip(-1), depth)
    if soft is not None:
        soft = torch.where(flip.view(n, 1, 1, 1), soft.flip(-1), soft)
    bright = ((torch.rand(n, 1, 1, 1, generator=gen) - 0.5) * 0.3).to(dev)
    contrast = (0.7 + 0.6 * torch.rand(n, 1, 1, 1, generator=gen)).to(dev)
    gain = (0.9 + 0.2 * torch.rand(n, 3, 1, 1, generator=gen)).to(dev)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * contrast + mean + bright
    x = x * gain + 0.02 * torch.randn(x.shape, generator=gen).to(dev)
    # the daemon sees uint8 frames: quantise like them
    x = torch.round(x.clamp(0.0, 1.0) * 255.0) / 255.0
    return x, mask, depth, soft


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


def hard_positive_loss(heat_logit: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over the pedestrians of ``mask`` ``(N, 1, H, W)`` of ``softplus(-logit)`` over each
    one's ``HARD_POSITIVES`` highest heatmap logits.

    A pedestrian here is what the evaluation's recall counts: an 8-connected mask component
    of at least ``MIN_PEDESTRIAN_PX`` pixels. The cross-entropy is a mean over pixels, so a
    sliver of a figure beside a panel or at the frame's edge can stay just under 0.5 at a
    small cost; this term stays small only when every such figure has a core of
    ``HARD_POSITIVES`` confident pixels, which the evaluation would count as a detection. It
    is the counterpart of the hard negatives. Zero (with a gradient) for a batch without
    pedestrians."""
    flat = heat_logit[:, 0].flatten(1)
    terms = []
    for i, labels, area in figure_components(mask):
        labels = labels.reshape(-1)
        for k in np.flatnonzero(area[1:] >= MIN_PEDESTRIAN_PX) + 1:  # label 0: background
            px = torch.from_numpy(np.flatnonzero(labels == k)).to(flat.device)
            terms.append(F.softplus(-flat[i, px].topk(HARD_POSITIVES).values).mean())
    return torch.stack(terms).mean() if terms else flat.sum() * 0.0


def losses(logits: torch.Tensor, mask: torch.Tensor, depth_m: torch.Tensor,
           heat_weight: torch.Tensor, depth_weight: torch.Tensor | None = None,
           hard_positive_weight: float = HARD_POSITIVE_WEIGHT,
           soft: torch.Tensor | None = None, distill_weight: float = 0.0
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """(heatmap loss, depth loss) for logits ``(N, 2, H, W)``, mask and metres ``(N,1,H,W)``,
    with per-pixel cross-entropy weights ``heat_weight`` (:func:`figure_weights`),
    optional per-frame depth-loss weights ``depth_weight`` ``(N,)`` and the weight of the
    hard-positive term (:func:`hard_positive_loss`). With a ``soft`` target (the teachers'
    mean heatmap, ``(N, 1, H, W)`` in [0, 1]) the heatmap loss is ``(1 - distill_weight)``
    times the loss against the mask plus ``distill_weight`` times the cross-entropy against
    ``soft``, pixels weighted alike."""
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
    if hard_positive_weight > 0.0:
        heat = heat + hard_positive_weight * hard_positive_loss(heat_logit, mask)
    if soft is not None and distill_weight > 0.0:
        to_teachers = F.binary_cross_entropy_with_logits(heat_logit, soft, weight=heat_weight)
        heat = (1.0 - distill_weight) * heat + distill_weight * to_teachers
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


@torch.no_grad()
def network_heatmaps(weights: Path, rgb: torch.Tensor, batch: int = 256) -> torch.Tensor:
    """The heatmap (sigmoid) of the AVNet in ``weights`` (any widths) on uint8 frames ``rgb``
    ``(N, 3, H, W)``: float32 ``(N, 1, H, W)`` on the CPU."""
    net = load_model(weights, fuse=True).eval()
    return torch.cat([torch.sigmoid(net(rgb[s:s + batch].cpu().float() / 255.0)
                                    [:, HEAD_HEATMAP:HEAD_HEATMAP + 1])
                      for s in range(0, rgb.shape[0], batch)])


def teacher_heatmaps(teachers: Sequence[Path], rgb: torch.Tensor, batch: int = 256
                     ) -> torch.Tensor:
    """The mean heatmap (:func:`network_heatmaps`) of the ``teachers`` on uint8 frames ``rgb``
    ``(N, 3, H, W)``, as uint8 ``(N, 1, H, W)`` (255: 1.0): the soft target of a
    distillation. The teachers see the frames unaugmented; the target then follows the
    batch's geometric augmentation (:func:`_augment`)."""
    out = torch.zeros((rgb.shape[0], 1, *rgb.shape[2:]), dtype=torch.float32)
    for path in teachers:
        out += network_heatmaps(path, rgb, batch)
        logger.info("teacher %s: heatmaps of %d frames", path, rgb.shape[0])
    return torch.round(out / len(teachers) * 255.0).to(torch.uint8)


def train(cfg: TrainConfig, data: Dataset | None = None) -> tuple[AVNet, dict[str, float]]:
    """Train a fresh network on ``data`` (or ``cfg``'s dataset); returns it (eval mode, unfused)
    and a dict of training facts."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    if data is None:
        path = cfg.data or build(cfg.data_dir, DatasetConfig(frames=cfg.frames, seed=TRAIN_SEED,
                                                            worlds=cfg.worlds))
        data = Dataset.load(path)
    dev = torch.device(cfg.device)
    rgb = torch.from_numpy(data.rgb).permute(0, 3, 1, 2).contiguous().to(dev)  # uint8 N,3,H,W
    mask = torch.from_numpy(data.mask).unsqueeze(1).float().to(dev)
    depth_m = torch.from_numpy(np.nan_to_num(data.depth, nan=1e3, posinf=1e3)).unsqueeze(1)
    depth_m = depth_m.clamp(min=1e-3).to(dev)
    n = rgb.shape[0]
    frame_depth_weight = torch.tensor(
        [cfg.depth_world_weights.get(w, 1.0) for w in data.worlds], dtype=torch.float32
    )[torch.from_numpy(data.world)].to(dev)
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
    ckpt = cfg.checkpoint or Path(str(cfg.out) + ".ckpt")
    first = 0
    teachers = [str(t) for t in cfg.teachers]
    if cfg.resume and ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        if (state.get("frames") != n or state.get("epochs") != cfg.epochs
                or state.get("teachers", []) != teachers):
            raise ValueError(f"checkpoint {ckpt} is for {state.get('frames')} frames, "
                             f"{state.get('epochs')} epochs and teachers "
                             f"{state.get('teachers', [])}, this run has {n}, {cfg.epochs} and "
                             f"{teachers}: run with the same options, or without --resume")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        gen.set_state(state["gen"])
        first = int(state["epoch"])
        logger.info("resuming from %s after epoch %d", ckpt, first)
    # after the checkpoint check: a resume with other teachers fails before minutes of work
    soft_all = teacher_heatmaps(cfg.teachers, rgb).to(dev) if cfg.teachers else None
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
            soft = None if soft_all is None else soft_all[idx].float() / 255.0
            x, m, d, soft = _augment(x, mask[idx], depth_m[idx], gen, cfg.paste_prob,
                                     cfg.edge_paste_share, soft)
            heat, dep = losses(model(x), m, d, figure_weights(m, cfg.small_figure_boost),
                               frame_depth_weight[idx], cfg.hard_positive_weight,
                               soft, cfg.distill_weight)
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
                    "frames": n, "epochs": cfg.epochs,
                    "teachers": teachers}, str(ckpt) + ".tmp")
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


def _parse(argv: Sequence[str] | None) -> TrainConfig:
    d = TrainConfig()
    p = argparse.ArgumentParser(prog="python -m active_vision.training.train",
                                description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, default=None, help="training .npz (default: render)")
    p.add_argument("--data-dir", type=Path, default=d.data_dir)
    p.add_argument("--frames", type=int, default=d.frames)
    p.add_argument("--worlds", default=",".join(d.worlds))
    p.add_argument("--epochs", type=int, default=d.epochs)
    p.add_argument("--batch", type=int, default=d.batch)
    p.add_argument("--lr", type=float, default=d.lr)
    p.add_argument("--threads", type=int, default=d.threads)
    p.add_argument("--device", default=d.device,
                   help="torch device to train on: cpu (default), cuda, cuda:N")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--max-minutes", type=float, default=d.max_minutes)
    p.add_argument("--out", type=Path, default=d.out)
    p.add_argument("--widths", type=parse_widths, default=d.widths,
                   help="the network's four widths, comma-separated")
    p.add_argument("--full-res", type=int, default=d.full_res,
                   help="channels of the full-resolution stage (0: none, the v2 layout)")
    p.add_argument("--no-small-figure-boost", action="store_true",
                   help="weigh every pedestrian pixel alike in the heatmap loss")
    p.add_argument("--hard-positive-weight", type=float, default=d.hard_positive_weight,
                   help="weight of the hard-positive term: each pedestrian's highest heatmap "
                   "logits pushed above 0 (0: off)")
    p.add_argument("--paste-prob", type=float, default=d.paste_prob,
                   help="share of frames that receive another frame's pedestrians (0: off)")
    p.add_argument("--edge-paste-share", type=float, default=d.edge_paste_share,
                   help="share of the pastes that put the figures at a side edge, cut by it "
                   "(0: none)")
    p.add_argument("--depth-world-weight", action="append", default=None, metavar="WORLD=W",
                   help="depth-loss weight of a world's frames, repeatable (default: "
                   + ",".join(f"{k}={v:g}" for k, v in DEPTH_WORLD_WEIGHTS.items())
                   + "; WORLD=1 to weigh it like the others)")
    p.add_argument("--teacher", type=Path, action="append", default=None, metavar="WEIGHTS",
                   help="distil: a network whose heatmaps (averaged over every --teacher) "
                   "are a soft target beside the mask; repeatable")
    p.add_argument("--distill-weight", type=float, default=d.distill_weight,
                   help="share of the heatmap loss given to the teachers' target")
    p.add_argument("--init", type=Path, default=None,
                   help="start from these weights (a fine-tune) instead of random ones")
    p.add_argument("--no-evaluate", action="store_true", help="skip the held-out evaluation")
    p.add_argument("--calibrate", action="store_true",
                   help="fold the detection threshold chosen on the validation split into the "
                   "heatmap head (active_vision.training.calibrate)")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="training state file, written every epoch (default: OUT.ckpt)")
    p.add_argument("--resume", action="store_true",
                   help="continue from --checkpoint after an interruption")
    p.add_argument("--log-level", default="INFO")
    a = p.parse_args(argv)
    if not 0.0 <= a.paste_prob <= 1.0:
        p.error(f"--paste-prob {a.paste_prob}: give a share in [0, 1]")
    if a.hard_positive_weight < 0:
        p.error(f"--hard-positive-weight {a.hard_positive_weight}: a weight cannot be negative")
    if not 0.0 <= a.edge_paste_share <= 1.0:
        p.error(f"--edge-paste-share {a.edge_paste_share}: give a share in [0, 1]")
    weights = dict(DEPTH_WORLD_WEIGHTS)
    for item in a.depth_world_weight or ():
        world, _, value = item.partition("=")
        try:
            weights[world.strip()] = float(value)
        except ValueError:
            p.error(f"--depth-world-weight {item!r}: give WORLD=WEIGHT, e.g. moon=3")
        if weights[world.strip()] < 0:
            p.error(f"--depth-world-weight {item!r}: a weight cannot be negative")
    if a.init is not None and not a.init.is_file():
        p.error(f"--init {a.init}: no such weights file")
    for t in a.teacher or ():
        if not t.is_file():
            p.error(f"--teacher {t}: no such weights file")
    if not 0.0 <= a.distill_weight <= 1.0:
        p.error(f"--distill-weight {a.distill_weight}: give a share in [0, 1]")
    try:
        device = torch.device(a.device)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        p.error(f"--device {a.device!r}: give cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        p.error(f"--device {a.device}: this torch sees no CUDA GPU; train with --device cpu")
    if a.full_res < 0:
        p.error(f"--full-res {a.full_res}: give 0 (no full-resolution stage) or a channel count")
    logging.basicConfig(level=a.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    return TrainConfig(data=a.data, data_dir=a.data_dir, frames=a.frames,
                       worlds=tuple(w for w in a.worlds.split(",") if w), epochs=a.epochs,
                       batch=a.batch, lr=a.lr, threads=a.threads, device=a.device,
                       seed=a.seed,
                       max_minutes=a.max_minutes, out=a.out,
                       widths=a.widths, full_res=a.full_res,
                       small_figure_boost=not a.no_small_figure_boost,
                       hard_positive_weight=a.hard_positive_weight,
                       paste_prob=a.paste_prob, edge_paste_share=a.edge_paste_share,
                       init=a.init, depth_world_weights=weights,
                       teachers=tuple(a.teacher or ()), distill_weight=a.distill_weight,
                       evaluate=not a.no_evaluate, calibrate=a.calibrate,
                       checkpoint=a.checkpoint, resume=a.resume)


def main(argv: Sequence[str] | None = None) -> int:
    cfg = _parse(argv)
    model, facts = train(cfg)
    meta: dict[str, float | str] = {**facts}
    if cfg.teachers:
        meta["teachers"] = ",".join(t.name if t.parent.name in ("", ".") else
                                    f"{t.parent.name}/{t.name}" for t in cfg.teachers)
        meta["distill_weight"] = cfg.distill_weight
    path = _save(model, cfg.out, meta)  # first without figures: evaluation may fail
    from active_vision.training.evaluate import evaluate, format_metrics, heldout

    if cfg.calibrate:
        from active_vision.training.calibrate import calibrate, calibrated_meta

        t, shift, table = calibrate(model, heldout(cfg.data_dir, split="validation"),
                                    threads=cfg.threads)
        print(table)
        meta = calibrated_meta(meta, t, shift)
        path = _save(model, cfg.out, meta)
    if cfg.evaluate:

        m = evaluate(model, heldout(cfg.data_dir), threads=cfg.threads)
        print(format_metrics(m))
        meta.update({f"heldout_{k}": float(v) for k, v in m.summary().items()})
        path = _save(model, cfg.out, meta)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB) after {facts['epochs']:.0f} "
          f"epochs in {facts['seconds']:.0f} s")
    # the ONNX backend's file, named for these exact weights (stale exports are removed)
    from active_vision.onnx_export import OnnxExportError, write_export_beside

    try:
        print(f"wrote {write_export_beside(path)}")
    except OnnxExportError as exc:
        print(f"no ONNX export written beside the weights ({exc}); the daemon exports it "
              "on first use, or run `python -m active_vision.onnx_export`", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
