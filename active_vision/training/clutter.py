"""Scenery that is not a person, drawn into training frames: façades, poles, cones, texture.

The worlds' scenery is flat-shaded: walls, panels and ground of one colour each, a black sky.
On real street footage the network trained on them fires on brick façades, windows, grass
and lamp posts (``benchmarks/real_footage.py``): texture and thin upright shapes are things it
never saw on anything but a pedestrian. :func:`clutter_batch` draws such things into a
training batch, in the frame's own geometry, so the image, the mask and the depth stay
consistent:

- a **façade** at a distance ``d`` replaces every pixel farther than ``d`` below a roof line
  (so it stands on the ground where the ground reaches ``d``, and what is nearer stays in
  front): brick or panel courses, a window grid, a colour from a street palette;
- **poles** (with a sign plate or a lamp arm now and then) and **cones**, each at its own
  distance, drawn where the frame shows something farther;
- **texture**: a multiplicative noise over the scenery, and over the pedestrians too in half
  the frames, so that texture itself does not mark a person.

A drawn pixel takes the distractor's distance as its depth target, and its mask becomes 0
(a pedestrian behind a pole or a façade is hidden by it). Sizes follow the camera's focal
length (``FOCAL_PX``): a pole 6-12 cm thick, a cone 0.3-0.7 m tall.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from rover_env.rover import CAMERA_FOVY

FOCAL_PX_PER_96 = 0.5 * 96 / math.tan(math.radians(CAMERA_FOVY) / 2)
"""Focal length of the rover camera in pixels at the fused size (96 px)."""

FACADE_PROB = 0.6
POLES_PROB = 0.6
CONES_PROB = 0.3
TEXTURE_PROB = 0.5
FIGURE_TEXTURE_PROB = 0.5
"""Of the textured frames, the share whose pedestrians are textured too."""

FACADE_COLOURS = np.array([
    (0.55, 0.33, 0.24), (0.62, 0.42, 0.30), (0.72, 0.66, 0.55), (0.80, 0.78, 0.72),
    (0.45, 0.45, 0.47), (0.30, 0.28, 0.27), (0.85, 0.85, 0.82), (0.50, 0.40, 0.33),
], np.float32)
POLE_COLOURS = np.array([
    (0.35, 0.36, 0.38), (0.15, 0.15, 0.16), (0.75, 0.75, 0.72), (0.20, 0.35, 0.22),
    (0.55, 0.55, 0.55), (0.60, 0.20, 0.15),
], np.float32)
SIGN_COLOURS = np.array([
    (0.9, 0.9, 0.9), (0.8, 0.15, 0.12), (0.15, 0.3, 0.75), (0.95, 0.8, 0.1), (0.1, 0.5, 0.25),
], np.float32)
CONE_COLOURS = np.array([(0.95, 0.45, 0.1), (0.9, 0.9, 0.9), (0.85, 0.2, 0.1)], np.float32)


def _uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def facade_texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A façade ``(3, h, w)`` in [0, 1]: brick or panel courses and a window grid."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    shear = _uniform(rng, -0.25, 0.25)  # a façade seen at an angle: courses slope
    yy = yy + shear * xx
    base = FACADE_COLOURS[rng.integers(len(FACADE_COLOURS))] * _uniform(rng, 0.8, 1.15)
    img = np.broadcast_to(base[:, None, None], (3, h, w)).copy()
    course = _uniform(rng, 1.2, 4.0)
    row = np.floor(yy / course)
    if rng.random() < 0.7:  # bricks: each its own shade, mortar lines between
        brick = course * _uniform(rng, 2.0, 3.0)
        col = np.floor((xx + (row % 2) * brick / 2) / brick)
        cells = rng.normal(0.0, 0.06, size=(int(row.max() - row.min()) + 2, int(col.max()) + 2))
        shade = cells[(row - row.min()).astype(int), col.astype(int)]
        mortar = ((yy % course) < 0.6) | (((xx + (row % 2) * brick / 2) % brick) < 0.6)
        img = img * (1.0 + shade)[None] + np.where(mortar, _uniform(rng, -0.12, 0.12), 0.0)[None]
    else:  # panels or render: faint horizontal courses
        img = img * (1.0 + np.where((yy % (course * 4)) < 0.8, -0.08, 0.0))[None]
    if rng.random() < 0.8:  # windows
        px, py = _uniform(rng, 7.0, 26.0), _uniform(rng, 9.0, 30.0)
        fx, fy = _uniform(rng, 0.35, 0.7), _uniform(rng, 0.35, 0.75)
        ox, oy = _uniform(rng, 0, px), _uniform(rng, 0, py)
        inside = (((xx + ox) % px) < fx * px) & (((yy + oy) % py) < fy * py)
        glass = np.array([_uniform(rng, 0.05, 0.35)] * 3, np.float32)
        if rng.random() < 0.3:  # a reflecting pane: the sky's colour
            glass = np.array([0.45, 0.55, 0.65], np.float32) * _uniform(rng, 0.7, 1.2)
        frame = (((xx + ox) % px) < fx * px + 1.0) & (((yy + oy) % py) < fy * py + 1.0) & ~inside
        img = np.where(inside[None], glass[:, None, None], img)
        if rng.random() < 0.6:
            img = np.where(frame[None], _uniform(rng, 0.6, 0.95), img)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def noise_texture(rng: np.random.Generator, h: int, w: int, scale: float) -> np.ndarray:
    """Smooth multiplicative noise ``(h, w)`` around 1: features of about ``scale`` pixels."""
    gh, gw = max(2, int(h / scale) + 2), max(2, int(w / scale) + 2)
    grid = rng.normal(0.0, 1.0, size=(gh, gw)).astype(np.float32)
    t = torch.from_numpy(grid)[None, None]
    up = torch.nn.functional.interpolate(t, size=(h, w), mode="bilinear", align_corners=False)
    return up[0, 0].numpy()


def _put(x: np.ndarray, mask: np.ndarray, depth: np.ndarray, where: np.ndarray,
         colour: np.ndarray, dist: float) -> None:
    """Draw ``colour`` (``(3,)`` or ``(3, H, W)``) at distance ``dist`` on the pixels of
    ``where`` that show something farther."""
    put = where & (depth > dist)
    if not put.any():
        return
    col = colour if colour.ndim == 3 else np.broadcast_to(colour[:, None, None], x.shape)
    x[:, put] = col[:, put]
    mask[put] = 0.0
    depth[put] = dist


def draw_facade(rng: np.random.Generator, x: np.ndarray, mask: np.ndarray,
                depth: np.ndarray) -> None:
    """A façade across part of the frame at 3-15 m, under a (sloping) roof line."""
    _, h, w = x.shape
    dist = _uniform(rng, 3.0, 15.0)
    x0 = int(rng.integers(0, w // 2)) if rng.random() < 0.5 else 0
    x1 = w if rng.random() < 0.6 else int(rng.integers(x0 + w // 4, w + 1))
    roof0 = _uniform(rng, -0.2, 0.5) * h
    roof = roof0 + _uniform(rng, -0.3, 0.3) * np.arange(w)
    yy, xx = np.mgrid[0:h, 0:w]
    where = (xx >= x0) & (xx < x1) & (yy >= roof[None, :])
    _put(x, mask, depth, where, facade_texture(rng, h, w), dist)


def draw_poles(rng: np.random.Generator, x: np.ndarray, mask: np.ndarray,
               depth: np.ndarray) -> None:
    """1-4 poles at 1.5-12 m, some with a sign plate or a lamp arm."""
    _, h, w = x.shape
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(rng.integers(1, 5))):
        dist = _uniform(rng, 1.5, 12.0)
        width = max(1.0, _uniform(rng, 0.06, 0.14) * FOCAL_PX_PER_96 / dist)
        cx = _uniform(rng, 0, w)
        top = _uniform(rng, -0.3, 0.4) * h
        colour = POLE_COLOURS[rng.integers(len(POLE_COLOURS))] * _uniform(rng, 0.8, 1.2)
        pole = (np.abs(xx + 0.5 - cx) <= width / 2) & (yy >= top)
        _put(x, mask, depth, pole, colour, dist)
        kind = rng.random()
        if kind < 0.35:  # a sign plate near the top
            sw = _uniform(rng, 0.3, 0.8) * FOCAL_PX_PER_96 / dist
            sh = sw * _uniform(rng, 0.6, 1.5)
            sy = top + _uniform(rng, 0.0, 0.2) * h
            plate = (np.abs(xx + 0.5 - cx) <= sw / 2) & (yy >= sy) & (yy < sy + sh)
            _put(x, mask, depth, plate, SIGN_COLOURS[rng.integers(len(SIGN_COLOURS))],
                 dist - 0.05)
        elif kind < 0.55:  # a lamp arm
            arm = _uniform(rng, 0.4, 1.2) * FOCAL_PX_PER_96 / dist * rng.choice([-1.0, 1.0])
            lo, hi = sorted((cx, cx + arm))
            bar = (xx + 0.5 >= lo) & (xx + 0.5 <= hi) & (np.abs(yy + 0.5 - top) <= width / 2)
            _put(x, mask, depth, bar, colour, dist)


def draw_cones(rng: np.random.Generator, x: np.ndarray, mask: np.ndarray,
               depth: np.ndarray) -> None:
    """1-3 cones or bollards standing on the ground at 1.5-8 m."""
    _, h, w = x.shape
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(rng.integers(1, 4))):
        dist = _uniform(rng, 1.5, 8.0)
        cx = int(rng.integers(0, w))
        column = depth[:, cx]
        ground = np.flatnonzero(column > dist)  # rows that show something beyond the cone
        if ground.size == 0:
            continue
        base = int(ground.max()) + 1  # the row where the ground reaches the cone
        tall = _uniform(rng, 0.3, 0.7) * FOCAL_PX_PER_96 / dist
        half = _uniform(rng, 0.3, 0.5) * tall
        frac = np.clip((yy + 0.5 - (base - tall)) / max(tall, 1.0), 0.0, 1.0)
        if rng.random() < 0.5:
            body = np.abs(xx + 0.5 - cx) <= np.maximum(0.5, half * frac)  # a cone
        else:
            body = np.abs(xx + 0.5 - cx) <= max(0.5, half * 0.5)  # a bollard
        body &= (yy + 0.5 >= base - tall) & (yy < base)
        _put(x, mask, depth, body, CONE_COLOURS[rng.integers(len(CONE_COLOURS))], dist)


def texture(rng: np.random.Generator, x: np.ndarray, mask: np.ndarray) -> None:
    """Multiplicative noise over the scenery (and in some frames the pedestrians)."""
    _, h, w = x.shape
    amp = _uniform(rng, 0.05, 0.3)
    tex = 1.0 + amp * noise_texture(rng, h, w, _uniform(rng, 1.0, 6.0))
    if rng.random() >= FIGURE_TEXTURE_PROB:
        tex = np.where(mask > 0.5, 1.0, tex)
    tint = 1.0 + rng.normal(0.0, 0.05, size=(3, 1, 1)).astype(np.float32)
    x *= tex[None] * tint


def clutter_frame(rng: np.random.Generator, x: np.ndarray, mask: np.ndarray,
                  depth: np.ndarray) -> None:
    """Draw distractors into one frame in place: ``x`` ``(3, H, W)`` in [0, 1], ``mask`` and
    ``depth`` (metres) ``(H, W)``."""
    if rng.random() < FACADE_PROB:
        draw_facade(rng, x, mask, depth)
    if rng.random() < POLES_PROB:
        draw_poles(rng, x, mask, depth)
    if rng.random() < CONES_PROB:
        draw_cones(rng, x, mask, depth)
    if rng.random() < TEXTURE_PROB:
        texture(rng, x, mask)
    np.clip(x, 0.0, 1.0, out=x)


def clutter_batch(x: torch.Tensor, mask: torch.Tensor, depth: torch.Tensor,
                  gen: torch.Generator, prob: float, allowed: torch.Tensor | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Distractors (:func:`clutter_frame`) in a share ``prob`` of the frames of a batch
    (``x`` ``(N, 3, H, W)``, ``mask`` and ``depth`` ``(N, 1, H, W)``); ``allowed`` ``(N,)``
    bool limits them to some frames. Returns new tensors; the inputs are unchanged."""
    n = x.shape[0]
    use = torch.rand(n, generator=gen) < prob
    if allowed is not None:
        use &= allowed.cpu()
    seeds = torch.randint(0, 2**31 - 1, (n,), generator=gen)
    if not bool(use.any()):
        return x, mask, depth
    x, mask, depth = x.clone(), mask.clone(), depth.clone()
    for i in torch.nonzero(use).flatten().tolist():
        rng = np.random.default_rng(int(seeds[i]))
        xi = x[i].cpu().numpy().copy()
        mi = mask[i, 0].cpu().numpy().copy()
        di = depth[i, 0].cpu().numpy().copy()
        clutter_frame(rng, xi, mi, di)
        x[i] = torch.from_numpy(xi).to(x.device)
        mask[i, 0] = torch.from_numpy(mi).to(mask.device)
        depth[i, 0] = torch.from_numpy(di).to(depth.device)
    return x, mask, depth
