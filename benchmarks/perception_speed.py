"""Perception speed: ms/frame per stage, batch 1 and 8, 1 and 2 torch threads; daemon fps;
and the original pipeline's detector (YOLO11n at 640x640, five frames per output).

    .venv/bin/python -m benchmarks.perception_speed [--quick] [--no-daemon]
        [--weights OTHER.pt ...]

What runs:

1. ``Perception`` (the daemon's code path, shipped weights, all three channels, depth from
   the network) on uint8 96x96 frames: the median over ``repeats`` runs of ``iters``
   calls (and the best run, which is what the code costs when the shared machine is quiet),
   split into the stages the daemon logs (input = checking the frames and copying them into
   the backend's buffer, network = the backend's call: uint8 frames to fused frames).
2. The daemon end to end: ``python -m active_vision`` in a subprocess; this process plays the
   env (publishes camera frames, waits for each fused frame by ``source_seq``), with 1 slot
   in lock step and with 8 slots (8 frames published, then 8 waited for).
3. The original pipeline's detector for comparison, at its own input size: YOLO11n at
   640x640, run on five frames per fused output. ``ultralytics`` cannot be a dependency (and
   its current release does not import without torchvision, which this CPU build has not),
   so this script builds a YOLO11n-shaped torch module itself, layer for layer from
   ``yolo11.yaml`` at scale n (depth 0.50, width 0.25): Conv/C3k2/C3k/SPPF/C2PSA backbone,
   FPN/PAN neck, Detect head with DFL decoding (no NMS), random weights, batch norm folded
   as ultralytics does for inference. Its parameter count is checked against the published
   2,624,080 of YOLO11n before it is timed. Latency only.

``--weights FILE`` (repeatable) adds rows for other weights files, timed in the same run
and in the same way (batch 1 and 8, one thread), so two networks are compared at the same
machine load: e.g. the previous network, ``git show REV:active_vision/weights/avnet.pt >
/tmp/old.pt``.

Targets: <= 2 ms/frame at batch 1 on one thread for all three channels; <= 1 ms/frame
at batch 8. The machine's other load is reported with the table: timings on a shared
2-core machine move by tens of percent.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from active_vision.launcher import spawn_daemon
from active_vision.perception import Perception, PerceptionConfig
from fused_image import FUSED_SHAPE, FUSED_SIZE

YOLO11N_PARAMS = 2_624_080  # ultralytics yolo11.yaml, scale n (80 classes)


@dataclass
class Args:
    """Benchmark options."""

    iters: int = 200
    """Calls per timed run (batch 1; batch 8 uses iters / 4)."""
    repeats: int = 5
    """Timed runs per configuration; the median is reported."""
    daemon_frames: int = 500
    """Round trips per daemon measurement."""
    daemon: bool = True
    """Measure the daemon end to end."""
    yolo: bool = True
    """Time the YOLO11n-shaped comparison."""
    backend: str = "auto"
    """Perception backend (``auto``, ``onnx``, ``torch``) for the Perception and daemon rows."""
    weights: tuple[Path, ...] = ()
    """Other weights files timed beside the shipped ones (one thread, batch 1 and 8)."""


# --- perception -----------------------------------------------------------------------------


def bench_perception(threads: int, batch: int, args: Args,
                     weights: Path | None = None) -> dict[str, float]:
    p = Perception(PerceptionConfig(threads=threads, max_batch=batch, backend=args.backend,
                                    weights=weights))
    frames = np.random.default_rng(0).integers(0, 256, (batch, *FUSED_SIZE, 3), dtype=np.uint8)
    iters = max(10, args.iters // (4 if batch > 1 else 1))
    for _ in range(20):
        p(frames)
    runs = []
    for _ in range(args.repeats):
        p.timings.reset()
        t0 = time.perf_counter()
        for _ in range(iters):
            p(frames)
        total = 1e3 * (time.perf_counter() - t0) / (iters * batch)
        runs.append({**p.timings.per_frame_ms(), "total": total})
    out = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    out["best"] = min(r["total"] for r in runs)
    return out


# --- daemon end to end ----------------------------------------------------------------------


def bench_daemon(slots: int, args: Args) -> dict[str, float]:
    from shm_protocol import FrameReader, FrameWriter, camera_name, slot_name

    name = f"bench_av_{uuid.uuid4().hex[:8]}"
    with spawn_daemon(name, slots, extra_args=["--threads", "1", "--backend", args.backend,
                                               "--log-level", "WARNING"]):
        cams = [FrameWriter(camera_name(slot_name(name, i)), create=False) for i in range(slots)]
        fused = [FrameReader(slot_name(name, i)) for i in range(slots)]
        frame = np.random.default_rng(1).integers(0, 256, (*FUSED_SIZE, 3), dtype=np.uint8)
        out = np.empty(FUSED_SHAPE, np.float32)
        rounds = max(20, args.daemon_frames // slots)
        lat = []
        for k in range(rounds + 10):
            t0 = time.perf_counter()
            seqs = [c.publish(frame) for c in cams]
            for r, s in zip(fused, seqs, strict=True):
                r.wait_for(source_seq=s, timeout=10.0, out=out)
            if k >= 10:
                lat.append(time.perf_counter() - t0)
        for c in cams:
            c.close()
        for r in fused:
            r.close()
        total = sum(lat)
        return {"fps": rounds * slots / total, "round_ms_p50": 1e3 * statistics.median(lat)}


# --- YOLO11n-shaped comparison --------------------------------------------------------------


class ConvBNAct(nn.Module):
    """Conv (no bias) + BatchNorm + SiLU, 'same' padding: ultralytics' ``Conv``."""

    def __init__(self, c_in: int, c_out: int, k: int = 1, s: int = 1, groups: int = 1,
                 act: bool = True) -> None:
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, s, k // 2, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(c_out)
        self.act = nn.SiLU() if act else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(self.conv(x)))


class Residual3x3(nn.Module):
    """Two 3x3 convs with a shortcut (ultralytics ``Bottleneck``; hidden = c * e)."""

    def __init__(self, c: int, e: float) -> None:
        super().__init__()
        hidden = int(c * e)
        self.a = ConvBNAct(c, hidden, 3)
        self.b = ConvBNAct(hidden, c, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.b(self.a(x))


class CSP3(nn.Module):
    """Three-conv CSP block with two inner residual pairs (ultralytics ``C3k``, n=2)."""

    def __init__(self, c: int) -> None:
        super().__init__()
        h = c // 2
        self.left = ConvBNAct(c, h)
        self.right = ConvBNAct(c, h)
        self.inner = nn.Sequential(Residual3x3(h, 1.0), Residual3x3(h, 1.0))
        self.out = ConvBNAct(2 * h, c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(torch.cat((self.inner(self.left(x)), self.right(x)), 1))


class C3k2Block(nn.Module):
    """Split-and-grow CSP block with one inner unit (ultralytics ``C3k2`` at depth 0.5)."""

    def __init__(self, c_in: int, c_out: int, deep: bool, e: float = 0.5) -> None:
        super().__init__()
        self.c = int(c_out * e)
        self.split = ConvBNAct(c_in, 2 * self.c)
        self.unit = CSP3(self.c) if deep else Residual3x3(self.c, 0.5)
        self.merge = ConvBNAct(3 * self.c, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = self.split(x).chunk(2, 1)
        return self.merge(torch.cat((a, b, self.unit(b)), 1))


class SPPFBlock(nn.Module):
    """1x1 reduce, three chained 5x5 max-pools, concat, 1x1 (ultralytics ``SPPF``)."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.reduce = ConvBNAct(c, c // 2, act=False)
        self.merge = ConvBNAct(2 * c, c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = [self.reduce(x)]
        for _ in range(3):
            y.append(F.max_pool2d(y[-1], 5, 1, 2))
        return self.merge(torch.cat(y, 1))


class PositionAttention(nn.Module):
    """Multi-head self-attention over positions with a depthwise positional term."""

    def __init__(self, c: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.head_dim = c // heads
        self.key_dim = self.head_dim // 2
        self.qkv = ConvBNAct(c, c + 2 * self.key_dim * heads, act=False)
        self.proj = ConvBNAct(c, c, act=False)
        self.pos = ConvBNAct(c, c, 3, groups=c, act=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, h, w = x.shape
        q, k, v = self.qkv(x).view(b, self.heads, 2 * self.key_dim + self.head_dim, h * w).split(
            [self.key_dim, self.key_dim, self.head_dim], dim=2)
        att = ((q * self.key_dim ** -0.5).transpose(-2, -1) @ k).softmax(dim=-1)
        y = (v @ att.transpose(-2, -1)).view(b, c, h, w) + self.pos(v.reshape(b, c, h, w))
        return self.proj(y)


class C2PSABlock(nn.Module):
    """Half the channels through attention + feed-forward (ultralytics ``C2PSA``, n=1)."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.c = c // 2
        self.split = ConvBNAct(c, c)
        self.att = PositionAttention(self.c, max(self.c // 64, 1))
        self.ffn = nn.Sequential(ConvBNAct(self.c, 2 * self.c), ConvBNAct(2 * self.c, self.c,
                                                                         act=False))
        self.merge = ConvBNAct(c, c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = self.split(x).split((self.c, self.c), 1)
        b = b + self.att(b)
        b = b + self.ffn(b)
        return self.merge(torch.cat((a, b), 1))


class DetectHead(nn.Module):
    """Anchor-free decoupled head, box branch with DFL (16 bins), 80 classes; decoding to
    (B, 84, anchors) as at inference, without NMS."""

    def __init__(self, chs: tuple[int, int, int], nc: int = 80, bins: int = 16) -> None:
        super().__init__()
        self.nc, self.bins = nc, bins
        cb, cc = max(16, chs[0] // 4, 4 * bins), max(chs[0], min(nc, 100))
        self.box = nn.ModuleList(nn.Sequential(ConvBNAct(c, cb, 3), ConvBNAct(cb, cb, 3),
                                               nn.Conv2d(cb, 4 * bins, 1)) for c in chs)
        self.cls = nn.ModuleList(nn.Sequential(
            ConvBNAct(c, c, 3, groups=c), ConvBNAct(c, cc), ConvBNAct(cc, cc, 3, groups=cc),
            ConvBNAct(cc, cc), nn.Conv2d(cc, nc, 1)) for c in chs)
        # DFL: the expectation over the bins as a fixed 1x1 conv (16 untrained parameters)
        self.dfl = nn.Conv2d(bins, 1, 1, bias=False).requires_grad_(False)
        self.dfl.weight.data[:] = torch.arange(bins, dtype=torch.float32).view(1, bins, 1, 1)
        self.strides = (8, 16, 32)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        b = feats[0].shape[0]
        boxes, scores, anchors, strides = [], [], [], []
        for f, box, cls, s in zip(feats, self.box, self.cls, self.strides, strict=True):
            h, w = f.shape[-2:]
            boxes.append(box(f).view(b, 4 * self.bins, -1))
            scores.append(cls(f).view(b, self.nc, -1))
            ys, xs = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
            anchors.append(torch.stack((xs.reshape(-1), ys.reshape(-1))))
            strides.append(torch.full((h * w,), float(s)))
        dist = torch.cat(boxes, 2).view(b, 4, self.bins, -1).transpose(2, 1).softmax(1)
        dist = self.dfl(dist).view(b, 4, -1)  # (B, 4, A)
        anchor = torch.cat(anchors, 1).unsqueeze(0)
        stride = torch.cat(strides)
        lt, rb = dist[:, :2], dist[:, 2:]
        xy = (anchor + (rb - lt) / 2) * stride
        wh = (lt + rb) * stride
        return torch.cat((xy, wh, torch.cat(scores, 2).sigmoid()), 1)


class Yolo11nShaped(nn.Module):
    """YOLO11n's layer graph (yolo11.yaml, scale n) with random weights."""

    def __init__(self) -> None:
        super().__init__()
        self.b0 = ConvBNAct(3, 16, 3, 2)
        self.b1 = ConvBNAct(16, 32, 3, 2)
        self.b2 = C3k2Block(32, 64, deep=False, e=0.25)
        self.b3 = ConvBNAct(64, 64, 3, 2)
        self.b4 = C3k2Block(64, 128, deep=False, e=0.25)
        self.b5 = ConvBNAct(128, 128, 3, 2)
        self.b6 = C3k2Block(128, 128, deep=True)
        self.b7 = ConvBNAct(128, 256, 3, 2)
        self.b8 = C3k2Block(256, 256, deep=True)
        self.b9 = SPPFBlock(256)
        self.b10 = C2PSABlock(256)
        self.h13 = C3k2Block(256 + 128, 128, deep=False)
        self.h16 = C3k2Block(128 + 128, 64, deep=False)
        self.h17 = ConvBNAct(64, 64, 3, 2)
        self.h19 = C3k2Block(64 + 128, 128, deep=False)
        self.h20 = ConvBNAct(128, 128, 3, 2)
        self.h22 = C3k2Block(128 + 256, 256, deep=True)
        self.detect = DetectHead((64, 128, 256))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        p4 = self.b4(self.b3(self.b2(self.b1(self.b0(x)))))
        p6 = self.b6(self.b5(p4))
        p10 = self.b10(self.b9(self.b8(self.b7(p6))))
        up = F.interpolate(p10, scale_factor=2.0, mode="nearest")
        h13 = self.h13(torch.cat((up, p6), 1))
        up = F.interpolate(h13, scale_factor=2.0, mode="nearest")
        h16 = self.h16(torch.cat((up, p4), 1))
        h19 = self.h19(torch.cat((self.h17(h16), h13), 1))
        h22 = self.h22(torch.cat((self.h20(h19), p10), 1))
        return self.detect([h16, h19, h22])


def _fold_bn(model: nn.Module) -> nn.Module:
    for m in model.modules():
        if isinstance(m, ConvBNAct):
            m.conv = torch.nn.utils.fusion.fuse_conv_bn_eval(m.conv, m.bn)
            m.bn = nn.Identity()
    return model


def bench_yolo(threads: int, args: Args) -> dict[str, float] | str:
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    model = Yolo11nShaped().eval()
    n_params = sum(p.numel() for p in model.parameters())
    if n_params != YOLO11N_PARAMS:
        return f"YOLO11n-shaped module has {n_params} parameters, expected {YOLO11N_PARAMS}"
    _fold_bn(model)
    x = torch.rand(5, 3, 640, 640)  # five frames per fused output, as the original ran it
    runs = []
    with torch.inference_mode():
        model(x)
        for _ in range(max(2, args.repeats // 2)):
            t0 = time.perf_counter()
            model(x)
            runs.append(time.perf_counter() - t0)
    per_output = 1e3 * statistics.median(runs)
    return {"per_output": per_output, "per_frame": per_output / 5, "best": 1e3 * min(runs)}


# --- report ---------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer iterations (a smoke run)")
    p.add_argument("--no-daemon", action="store_true")
    p.add_argument("--no-yolo", action="store_true")
    p.add_argument("--backend", choices=("auto", "onnx", "torch"), default="auto",
                   help="perception backend (the daemon's default is auto: onnx if installed)")
    p.add_argument("--weights", type=Path, action="append", default=[],
                   help="another weights file to time beside the shipped one (repeatable)")
    a = p.parse_args(argv)
    for w in a.weights:
        if not w.is_file():
            p.error(f"--weights {w}: no such file")
    args = Args(daemon=not a.no_daemon, yolo=not a.no_yolo, backend=a.backend,
                weights=tuple(a.weights))
    if a.quick:
        args.iters, args.repeats, args.daemon_frames = 40, 3, 100
    load = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} CPUs, load average {load:.2f} at start; torch "
          f"{torch.__version__}")
    print(f"perception backend: {Perception(PerceptionConfig(backend=args.backend)).backend}")
    print()
    print("| configuration | input | network | total ms/frame (best run) | frames/s |")
    print("|---|---:|---:|---:|---:|")
    for threads in (1, 2):
        for batch in (1, 8):
            r = bench_perception(threads, batch, args)
            print(f"| Perception batch {batch}, {threads} thread{'s' if threads > 1 else ''} "
                  f"| {r['input']:.3f} | {r['network']:.3f} | {r['total']:.3f} "
                  f"({r['best']:.3f}) | {1e3 / r['total']:.0f} |")
    for w in args.weights:
        for batch in (1, 8):
            r = bench_perception(1, batch, args, weights=w)
            print(f"| {w.name}: Perception batch {batch}, 1 thread | {r['input']:.3f} | "
                  f"{r['network']:.3f} | {r['total']:.3f} ({r['best']:.3f}) | "
                  f"{1e3 / r['total']:.0f} |")
    if args.daemon:
        for slots in (1, 8):
            d = bench_daemon(slots, args)
            print(f"| daemon end to end, {slots} slot{'s' if slots > 1 else ''} (env round "
                  f"trip p50 {d['round_ms_p50']:.2f} ms), 1 thread | | | "
                  f"{1e3 / d['fps']:.3f} | {d['fps']:.0f} |")
    if args.yolo:
        for threads in (1, 2):
            y = bench_yolo(threads, args)
            if isinstance(y, str):
                print(f"| YOLO11n-shaped: skipped ({y}) | | | | |")
                continue
            print(f"| YOLO11n-shaped 640x640, 5 frames per output, {threads} thread"
                  f"{'s' if threads > 1 else ''} (heatmap only) | | | {y['per_output']:.1f} "
                  f"({y['best']:.1f}) per output, {y['per_frame']:.1f} per frame "
                  f"| {1e3 / y['per_output']:.1f} outputs |")
    print()
    print(f"load average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
