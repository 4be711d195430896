"""The perception network: one shared encoder, two heads (pedestrian heatmap, depth).

``AVNet`` is a small fully-convolutional network. Input: a batch of camera frames at the
fused resolution (``(N, 3, 96, 96)`` float32 RGB in [0, 1]). Output: two maps of the same
size, the pedestrian heatmap (sigmoid, 1 = pedestrian) and the depth channel in the
``shm_protocol`` depth convention (``1 - d / DEPTH_MAX_M`` clipped to [0, 1]: near is bright,
0 at or beyond the far limit).

Layout (widths ``w1, w2, w3, w4``, default 24/48/96/128; optional full-resolution stage
``f``, default none)::

    RGB + row coordinate (4 ch, 96²)
    stem   3×3 s2 -> w1 (48²)  ───────────────────────────────────────┐ skip
    enc2   3×3 s2 -> w2, 3×3 (24²)  ─────────────────────────┐ skip    │
    enc3   3×3 s2 -> w3, 3×3 dil 2, 3×3 (12²)  ───┐ skip      │         │
    enc4   3×3 s2 -> w4, 3×3 dil 2 (6²), + 1×1(global mean)   │         │
    up     1×1 -> w3, ×2 nearest, + skip, 3×3 (12²)           │         │
    up     1×1 -> w2, ×2 nearest, + skip, 3×3 (24²)  ─────────┘         │
    up     1×1 -> w1, ×2 nearest, + skip, 3×3 (48²)  ───────────────────┘
    full   1×1 -> f, ×2 bilinear, + 3×3 of the input (96²), 3×3 (96²)
    heads  1×1 -> 2 maps (heatmap logit, log depth) (96²)

With ``full_res=0`` (the version-2 layout) there is no full-resolution stage and the heads
run at 48² and are upsampled ×2 bilinear. The full-resolution stage exists for edges that a
48² output blurs: the moon's skyline, where the true depth falls from 2 m to 10 m within a
few rows and a blurred head reads the far terrain as near, and the legs and outline of a
figure 4-5 m away (40-60 pixels).

The 1/16 level and the global context give the depth head a view of the whole frame (the
horizon, a figure's full height), which a pedestrian's distance and a tilted rover's ground
plane need.

The depth head predicts the natural log of metric depth; :meth:`AVNet.predict` turns it into
the depth channel (``1 - exp(log_d) / DEPTH_MAX_M`` clipped to [0, 1]). Log depth keeps
relative precision everywhere: 25 % of 0.3 m is 0.0075 in channel units, which a sigmoid on
the channel hardly resolves. The row coordinate channel lets the depth head learn the
ground plane's depth-by-row prior. Batch norm is used while training and folded into the
convolutions for inference (:meth:`AVNet.fuse_for_inference`).

Weights are a plain dict of tensors and primitives (see :func:`save_weights`) and load
with ``torch.load(..., weights_only=True)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from fused_image import DEPTH_MAX_M

logger = logging.getLogger(__name__)

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "avnet.pt"
REGENERATE_COMMAND = "python -m active_vision.training.train"
WEIGHTS_FORMAT = "roverav.avnet"
WEIGHTS_VERSION = 3  # 3: optional full-resolution stage (config "full_res")
READABLE_VERSIONS = (2, 3)  # 2: four encoder levels + global context, log-depth head

#: Index of each head in the output of :meth:`AVNet.forward` / :meth:`AVNet.predict`.
HEAD_HEATMAP = 0
HEAD_DEPTH = 1
MIN_DEPTH_M = 0.05
"""Smallest metric depth the depth head is trained on and scored against (metres)."""


def log_depth_to_channel(log_d: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """Depth channel ``clip(1 - exp(log_d) / DEPTH_MAX_M, 0, 1)`` of log metric depth.

    :param out: tensor of ``log_d``'s shape (any strides) to write into instead of a new one.
    """
    out = torch.clamp(log_d, max=math.log(DEPTH_MAX_M), out=out)
    out.exp_().mul_(-1.0 / DEPTH_MAX_M).add_(1.0)
    return out.clamp_(0.0, 1.0)


class WeightsError(RuntimeError):
    """The network's weights file is missing, unreadable, or does not match the network."""


@dataclass(frozen=True)
class AVNetConfig:
    """Shape of the network (stored inside the weights file)."""

    widths: tuple[int, int, int, int] = (24, 48, 96, 128)
    """Channels at 1/2, 1/4, 1/8 and 1/16 of the input resolution (a weights file stores its
    own, so files made at 16/32/64/96 load as such). 24/48/96/128 finds more of inspect's
    pedestrians and reads the moon's depth better than 16/32/64/96, at about twice the cost
    a frame, within the daemon's 2 ms budget (docs/decisions.md, "Perception network and
    int8"; benchmarks/RESULTS.md, "Perception speed")."""
    full_res: int = 0
    """Channels of the full-resolution stage (0: none, the heads run at 1/2 resolution)."""


def _conv_bn(c_in: int, c_out: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class AVNet(nn.Module):
    """Shared-encoder network with a pedestrian-heatmap head and a depth head."""

    def __init__(self, config: AVNetConfig | None = None) -> None:
        super().__init__()
        self.config = config or AVNetConfig()
        w1, w2, w3, w4 = self.config.widths
        self.stem = _conv_bn(4, w1, stride=2)
        self.enc2 = nn.Sequential(_conv_bn(w1, w2, stride=2), _conv_bn(w2, w2))
        self.enc3 = nn.Sequential(
            _conv_bn(w2, w3, stride=2), _conv_bn(w3, w3, dilation=2), _conv_bn(w3, w3)
        )
        self.enc4 = nn.Sequential(_conv_bn(w3, w4, stride=2), _conv_bn(w4, w4, dilation=2))
        self.context = nn.Sequential(nn.Conv2d(w4, w4, 1), nn.ReLU(inplace=True))
        self.lat4 = nn.Conv2d(w4, w3, 1)
        self.dec3 = _conv_bn(w3, w3)
        self.lat3 = nn.Conv2d(w3, w2, 1)
        self.dec2 = _conv_bn(w2, w2)
        self.lat2 = nn.Conv2d(w2, w1, 1)
        self.dec1 = _conv_bn(w1, w1)
        f = self.config.full_res
        if f:
            self.full_in = _conv_bn(4, f)
            self.lat1 = nn.Conv2d(w1, f, 1)
            self.dec0 = _conv_bn(f, f)
        self.head = nn.Conv2d(f or w1, 2, 1)
        with torch.no_grad():
            self.head.bias[HEAD_DEPTH] = math.log(2.0)  # start near a typical depth
        self._coord_cache: dict[tuple[int, int, torch.device], torch.Tensor] = {}

    def _coords(self, x: torch.Tensor) -> torch.Tensor:
        n, _, h, w = x.shape
        key = (h, w, x.device)
        coord = self._coord_cache.get(key)
        if coord is None:
            rows = torch.linspace(-1.0, 1.0, h, device=x.device, dtype=x.dtype)
            coord = rows.view(1, 1, h, 1).expand(1, 1, h, w).contiguous()
            self._coord_cache[key] = coord
        return coord.expand(n, 1, h, w)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Raw maps ``(N, 2, H, W)``: heatmap logit (``HEAD_HEATMAP``) and log metric depth
        (``HEAD_DEPTH``).

        :param x: ``(N, 3, H, W)`` float RGB in [0, 1]; H and W divisible by 16.
        """
        if x.shape[-1] % 16 or x.shape[-2] % 16:
            raise ValueError(f"AVNet needs H and W divisible by 16, got {tuple(x.shape[-2:])}")
        x0 = torch.cat((x, self._coords(x)), dim=1)
        x1 = self.stem(x0)
        x2 = self.enc2(x1)
        x3 = self.enc3(x2)
        x4 = self.enc4(x3)
        x4 = x4 + self.context(x4.mean(dim=(2, 3), keepdim=True))
        y = self.dec3(F.interpolate(self.lat4(x4), scale_factor=2.0, mode="nearest") + x3)
        y = self.dec2(F.interpolate(self.lat3(y), scale_factor=2.0, mode="nearest") + x2)
        y = self.dec1(F.interpolate(self.lat2(y), scale_factor=2.0, mode="nearest") + x1)
        if self.config.full_res:
            y = F.interpolate(self.lat1(y), scale_factor=2.0, mode="bilinear",
                              align_corners=False)
            return self.head(self.dec0(y + self.full_in(x0)))
        # two channels: bilinear is 3x faster on a contiguous (NCHW) tensor than channels_last
        head = self.head(y).contiguous()
        return F.interpolate(head, scale_factor=2.0, mode="bilinear", align_corners=False)

    def predict(self, x: torch.Tensor) -> torch.Tensor:
        """Heatmap and depth channel in [0, 1], ``(N, 2, H, W)``."""
        raw = self.forward(x)
        heat = torch.sigmoid(raw[:, HEAD_HEATMAP:HEAD_HEATMAP + 1])
        depth = log_depth_to_channel(raw[:, HEAD_DEPTH:HEAD_DEPTH + 1])
        return torch.cat((heat, depth), dim=1)  # HEAD_HEATMAP, HEAD_DEPTH

    @torch.no_grad()
    def fuse_for_inference(self) -> AVNet:
        """Fold every BatchNorm into its convolution (eval mode, in place); returns self."""
        fold_batch_norm(self)
        return self


@torch.no_grad()
def fold_batch_norm(model: nn.Module) -> nn.Module:
    """Put ``model`` in eval mode and fold each (Conv2d, BatchNorm2d, act) ``Sequential``'s
    batch norm into its convolution, in place (inference only)."""
    model.eval()
    for module in model.modules():
        if not isinstance(module, nn.Sequential):
            continue
        layers = list(module)
        if (
            len(layers) == 3
            and isinstance(layers[0], nn.Conv2d)
            and isinstance(layers[1], nn.BatchNorm2d)
        ):
            module[0] = torch.nn.utils.fusion.fuse_conv_bn_eval(layers[0], layers[1])
            module[1] = nn.Identity()
    return model


def half_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """``model``'s state dict with floating tensors in fp16 (halves a weights file; loading
    casts them back to float32)."""
    return {k: v.detach().to(torch.float16 if v.is_floating_point() else v.dtype)
            for k, v in model.state_dict().items()}


def save_weights(model: AVNet, path: Path, meta: dict[str, Any] | None = None) -> Path:
    """Write ``model`` (unfused) to ``path`` as a ``weights_only``-loadable dict."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": WEIGHTS_FORMAT,
        "version": WEIGHTS_VERSION,
        "config": {"widths": list(model.config.widths), "full_res": model.config.full_res},
        "meta": dict(meta or {}),
        "state_dict": half_state_dict(model),
    }
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def _fail(path: Path, what: str) -> WeightsError:
    return WeightsError(
        f"active_vision weights file {path}: {what}. Regenerate it with "
        f"`{REGENERATE_COMMAND}` (writes {DEFAULT_WEIGHTS}), or pass the path of a "
        "weights file written by that command."
    )


def load_model(path: Path | str | None = None, *, fuse: bool = True) -> AVNet:
    """Load an :class:`AVNet` from ``path`` (default: the shipped weights), in eval mode.

    :param fuse: fold batch norm into the convolutions (for inference; not for training).
    :raises WeightsError: the file is missing, corrupt, or not an AVNet weights file.
    """
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise _fail(path, "not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a damaged file
        raise _fail(path, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not isinstance(payload, dict) or payload.get("format") != WEIGHTS_FORMAT:
        raise _fail(path, f"is not a {WEIGHTS_FORMAT} weights file")
    if payload.get("version") not in READABLE_VERSIONS:
        raise _fail(
            path, f"has version {payload.get('version')!r}, this code reads "
            f"{', '.join(map(str, READABLE_VERSIONS))}"
        )
    try:
        config = AVNetConfig(widths=tuple(int(w) for w in payload["config"]["widths"]),
                             full_res=int(payload["config"].get("full_res", 0)))
        model = AVNet(config)
        state = {k: v.float() if v.is_floating_point() else v
                 for k, v in payload["state_dict"].items()}
        model.load_state_dict(state)
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise _fail(path, f"does not match the network ({exc})") from exc
    model.eval()
    if fuse:
        model.fuse_for_inference()
    logger.debug("loaded %s (widths %s, full_res %d)", path, config.widths, config.full_res)
    return model


def weights_meta(path: Path | str | None = None) -> dict[str, Any]:
    """The ``meta`` dict stored with the weights (training figures, dataset seed)."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise _fail(path, "not found")
    payload = torch.load(path, map_location="cpu", weights_only=True)
    return dict(payload.get("meta", {}))


__all__ = [
    "AVNet",
    "AVNetConfig",
    "DEFAULT_WEIGHTS",
    "HEAD_DEPTH",
    "HEAD_HEATMAP",
    "REGENERATE_COMMAND",
    "WeightsError",
    "load_model",
    "save_weights",
    "weights_meta",
]
