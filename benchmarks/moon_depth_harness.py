"""What limits the moon's depth? A harness that tries one change at a time (quality, not speed).

The moon's monocular depth misses its target (delta1 0.74 against 0.85), and the network
fits its own training frames no better than held-out ones. A 40-minute training on all
worlds is too slow to test each suspect, so this script trains a network of the shipped
shape on moon driving frames only and compares runs that differ in one thing:

1. render moon driving frames (training seed ``TRAIN_SEED``, validation seed
   ``VALIDATION_SEED``, the dataset's own driving episodes) and record with each frame the
   world's up vector in camera coordinates (from the simulator, exact);
2. train one network (8,000 frames, 10 epochs, one thread) whose fourth input channel is
   - ``--mode row``: the row coordinate, as shipped;
   - ``--mode gravity``: the sine of each pixel's ray elevation above the true horizon,
     from the up vector (the row coordinate made tilt-aware; it follows the horizontal
     flip): what an IMU in the camera segment's trailer would give;
   ``--full-res N`` adds the network's full-resolution stage and ``--widths`` sets its
   four widths;
3. print the validation moon delta1 (0.3-10 m) after every epoch, overall and by bands of
   16 image rows.

    MUJOCO_GL=egl PYTHONPATH=. python benchmarks/moon_depth_harness.py --mode row
    MUJOCO_GL=egl PYTHONPATH=. python benchmarks/moon_depth_harness.py --mode gravity

The frames are rendered once into ``--cache`` (the first run renders; start a second one
after it has). To try a change to the world (its texture, shading or terrain), run the
script with ``PYTHONPATH`` set to a copy of the tree whose ``rover_env/worlds/moon.py`` has
the change and a ``--cache`` of its own. Results: benchmarks/RESULTS.md, "What limits the
moon's depth".
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch

from active_vision.models import HEAD_DEPTH, AVNet, AVNetConfig
from active_vision.training.dataset import TRAIN_SEED, VALIDATION_SEED, DatasetConfig, FrameRenderer
from active_vision.training.driving import DriveRecorder
from active_vision.training.train import augment_batch, figure_weights, losses, parse_widths
from fused_image import FUSED_SIZE
from rover_env import FORWARD_CAMERA

SIZE = FUSED_SIZE[0]
ROW_BAND = 16


def render(seed: int, frames: int, path: Path) -> None:
    """Moon driving frames of ``seed`` (episode e from ``default_rng([seed, 1, e])``) with the
    world's up vector in camera coordinates, into ``path``."""
    renderer = FrameRenderer("moon", DatasetConfig(frames=frames, seed=seed, worlds=("moon",),
                                                   drive_fraction=1.0))
    sim = renderer.sim
    ups: list[np.ndarray] = []
    plain = sim.render_camera

    def render_camera(depth: bool = False, segmentation: bool = False):  # noqa: ANN202
        if depth:  # the recorder's kept frames are the ones rendered with depth
            ups.append(sim.camera_up)
        return plain(depth=depth, segmentation=segmentation)

    sim.render_camera = render_camera
    recorder = DriveRecorder(renderer)
    rgb, depth, mask = [], [], []
    e = 0
    while sum(len(r) for r in rgb) < frames:
        got = recorder.record(np.random.default_rng([seed, 1, e]))
        rgb.append(got.rgb)
        depth.append(got.depth)
        mask.append(got.mask)
        e += 1
    renderer.close()
    np.savez(path, rgb=np.concatenate(rgb)[:frames], depth=np.concatenate(depth)[:frames],
             mask=np.concatenate(mask)[:frames], up=np.stack(ups)[:frames].astype(np.float32))


def ray_elevation(up: torch.Tensor) -> torch.Tensor:
    """``(N, 1, S, S)`` sine of each pixel's ray elevation for up vectors ``(N, 3)`` in camera
    coordinates (x right, y up, looking along -z)."""
    f = (SIZE / 2) / math.tan(math.radians(FORWARD_CAMERA.fovy_deg) / 2)
    u = (torch.arange(SIZE, dtype=torch.float32) + 0.5 - SIZE / 2) / f
    rx, ry = u.view(1, SIZE).expand(SIZE, SIZE), -u.view(SIZE, 1).expand(SIZE, SIZE)
    norm = torch.sqrt(rx**2 + ry**2 + 1.0)
    up = up.view(-1, 3, 1, 1)
    return ((rx * up[:, 0] + ry * up[:, 1] - up[:, 2]) / norm).unsqueeze(1)


class GravityNet(AVNet):
    """AVNet whose fourth input channel is set per batch (``elevation``) instead of rows."""

    elevation: torch.Tensor | None = None

    def _coords(self, x: torch.Tensor) -> torch.Tensor:
        return super()._coords(x) if self.elevation is None else self.elevation


def load(path: Path) -> tuple[torch.Tensor, ...]:
    d = np.load(path)
    depth = np.nan_to_num(d["depth"].astype(np.float32), nan=1e3, posinf=1e3)
    return (torch.from_numpy(d["rgb"]).permute(0, 3, 1, 2).contiguous(),
            torch.from_numpy(d["mask"]).unsqueeze(1).float(),
            torch.from_numpy(depth).unsqueeze(1).clamp(min=1e-3), torch.from_numpy(d["up"]))


@torch.no_grad()
def delta1(model: GravityNet, val: tuple[torch.Tensor, ...], gravity: bool
           ) -> tuple[float, np.ndarray]:
    rgb, _, depth, up = val
    model.eval()
    hits, total = np.zeros(SIZE // ROW_BAND), np.zeros(SIZE // ROW_BAND)
    for i in range(0, len(rgb), 64):
        model.elevation = ray_elevation(up[i:i + 64]) if gravity else None
        log_d = model(rgb[i:i + 64].float() / 255.0)[:, HEAD_DEPTH:HEAD_DEPTH + 1]
        gt = depth[i:i + 64]
        valid = (gt >= 0.3) & (gt < 10.0)
        hit = ((log_d - gt.log()).abs() < math.log(1.25)) & valid
        for b in range(len(hits)):
            rows = slice(b * ROW_BAND, (b + 1) * ROW_BAND)
            hits[b] += float(hit[..., rows, :].sum())
            total[b] += float(valid[..., rows, :].sum())
    model.train()
    return float(hits.sum() / total.sum()), hits / np.maximum(total, 1)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--mode", choices=("row", "gravity"), required=True)
    p.add_argument("--train-frames", type=int, default=8000)
    p.add_argument("--val-frames", type=int, default=1200)
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--full-res", type=int, default=0,
                   help="channels of the network's full-resolution stage (0: none, as shipped)")
    p.add_argument("--widths", type=parse_widths, default=AVNetConfig().widths,
                   help="channels at 1/2, 1/4, 1/8, 1/16 resolution, comma-separated "
                        "(default: the shipped 16,32,64,96)")
    p.add_argument("--cache", type=Path, default=Path("runs/moon_depth_harness"))
    a = p.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, seed, n in (("train", TRAIN_SEED, a.train_frames),
                          ("val", VALIDATION_SEED, a.val_frames)):
        paths[name] = a.cache / f"moon_{name}_s{seed}_n{n}.npz"
        if not paths[name].is_file():
            print(f"rendering {n} moon driving frames (seed {seed}) ...", flush=True)
            render(seed, n, paths[name])
    torch.set_num_threads(1)
    torch.manual_seed(a.seed)
    rgb, mask, depth, up = load(paths["train"])
    val = load(paths["val"])
    gravity = a.mode == "gravity"
    n, batch, lr = len(rgb), 32, 4e-3
    steps = math.ceil(n / batch)
    model = GravityNet(AVNetConfig(widths=a.widths, full_res=a.full_res))
    model.train()
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=a.epochs * steps,
                                                pct_start=0.15)
    gen = torch.Generator().manual_seed(a.seed)
    t0 = time.perf_counter()
    for epoch in range(a.epochs):
        order = torch.randperm(n, generator=gen)
        for b in range(steps):
            idx = order[b * batch:(b + 1) * batch]
            peek = torch.Generator()
            peek.set_state(gen.get_state())
            flip = torch.rand(len(idx), generator=peek) < 0.5  # augment_batch's first draw
            x, m, d = augment_batch(rgb[idx].float() / 255.0, mask[idx], depth[idx], gen)
            if gravity:
                e = ray_elevation(up[idx])
                model.elevation = torch.where(flip.view(-1, 1, 1, 1), e.flip(-1), e)
            heat, dep = losses(model(x), m, d, figure_weights(m))
            opt.zero_grad(set_to_none=True)
            (heat + dep).backward()
            opt.step()
            sched.step()
        d1, rows = delta1(model, val, gravity)
        print(f"{a.mode:8s} epoch {epoch + 1:2d} ({time.perf_counter() - t0:4.0f} s)  "
              f"validation moon delta1 {d1:.3f}  by 16-row band {np.round(rows, 3)}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
