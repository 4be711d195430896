"""The predictive (spatiotemporal) pedestrian heatmap: ``av-daemon --heatmap predict``.

Seed 001 describes channel 1 as a spatiotemporal occupancy heatmap: from the last few
frames, where pedestrians will be. Here channel 1 in ``predict`` mode is the probability
that a pixel is covered by a pedestrian at some moment in the next ``HORIZON_S`` (1.5 s),
seen from the current camera pose, computed from the slot's last ``K`` (5) fused
detection frames (:class:`active_vision.history.SlotHistory`).

:class:`PredictNet` is a small fully-convolutional network on ``2 K + 1`` channels: the
``K`` detection heatmaps and ``K`` gray images (oldest first) and the current depth
channel, all at the fused resolution; its output is the occupancy logit. The detection
network (:class:`~active_vision.models.AVNet`) runs first, unchanged, and the predictor
reads its output, so ``detect`` and ``predict`` share one camera-to-fused pass.

Ground truth (:meth:`rover_env.simulation.RoverSim.future_pedestrian_mask`): hold the rover
and camera still, walk only the pedestrians on for 1.5 s, OR their masks.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from active_vision.models import WEIGHTS_DIR, WeightsError, fold_batch_norm, half_state_dict
from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP

logger = logging.getLogger(__name__)

K = 5
"""Frames of history the predictor sees (the original system's 5)."""
HORIZON_S = 1.5
"""Seconds ahead the predicted occupancy covers."""
DEFAULT_PREDICT_WEIGHTS = WEIGHTS_DIR / "predict.pt"
PREDICT_FORMAT = "roverav.predictnet"
PREDICT_VERSION = 1
REGENERATE_PREDICT = "python -m active_vision.training.predict_train"
HEATMAP_MODES = ("detect", "predict")


def _conv(c_in: int, c_out: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class PredictNet(nn.Module):
    """Window of fused detection frames -> future-occupancy logit ``(N, 1, H, W)``."""

    def __init__(self, k: int = K, widths: tuple[int, int, int] = (16, 32, 48)) -> None:
        super().__init__()
        self.k = k
        self.widths = tuple(widths)
        w1, w2, w3 = widths
        self.stem = _conv(2 * k + 1, w1, stride=2)                         # 1/2
        self.enc2 = nn.Sequential(_conv(w1, w2, stride=2), _conv(w2, w2))   # 1/4
        self.enc3 = nn.Sequential(_conv(w2, w3, stride=2), _conv(w3, w3, dilation=2),
                                  _conv(w3, w3, dilation=2))                # 1/8
        self.lat3 = nn.Conv2d(w3, w2, 1)
        self.dec2 = _conv(w2, w2)
        self.lat2 = nn.Conv2d(w2, w1, 1)
        self.dec1 = _conv(w1, w1)
        self.head = nn.Conv2d(w1, 1, 1)

    @staticmethod
    def inputs(window: torch.Tensor) -> torch.Tensor:
        """Network input ``(N, 2K+1, H, W)`` from windows ``(N, K, H, W, 3)`` (fused frames,
        oldest first)."""
        heat = window[..., CHANNEL_HEATMAP]
        gray = window[..., CHANNEL_GRAY]
        depth = window[:, -1:, :, :, CHANNEL_DEPTH]
        return torch.cat((heat, gray, depth), dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x1 = self.stem(x)
        x2 = self.enc2(x1)
        x3 = self.enc3(x2)
        y = self.dec2(F.interpolate(self.lat3(x3), scale_factor=2.0, mode="nearest") + x2)
        y = self.dec1(F.interpolate(self.lat2(y), scale_factor=2.0, mode="nearest") + x1)
        return F.interpolate(self.head(y), scale_factor=2.0, mode="bilinear",
                             align_corners=False)

    @torch.no_grad()
    def fuse_for_inference(self) -> PredictNet:
        """Fold batch norm into the convolutions (eval mode, in place)."""
        fold_batch_norm(self)
        return self


def save_predictor(model: PredictNet, path: Path, meta: dict[str, Any] | None = None) -> Path:
    """Write ``model`` (unfused) to ``path`` (``torch.load(weights_only=True)``-loadable)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": PREDICT_FORMAT, "version": PREDICT_VERSION,
        "config": {"k": model.k, "widths": list(model.widths)}, "meta": dict(meta or {}),
        "state_dict": half_state_dict(model),
    }
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_predictor(path: Path | str | None = None, *, fuse: bool = True) -> PredictNet:
    """Load a :class:`PredictNet` (default: the shipped ``weights/predict.pt``), eval mode.

    :raises WeightsError: missing, unreadable, or not a predictor weights file.
    """
    path = Path(path) if path is not None else DEFAULT_PREDICT_WEIGHTS

    def fail(what: str) -> WeightsError:
        return WeightsError(f"predictor weights file {path}: {what}. Regenerate it with "
                            f"`{REGENERATE_PREDICT}` (writes {DEFAULT_PREDICT_WEIGHTS}), or "
                            "pass --predict-weights with a file written by that command.")

    if not path.is_file():
        raise fail("not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a damaged file
        raise fail(f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not isinstance(payload, dict) or payload.get("format") != PREDICT_FORMAT:
        raise fail(f"is not a {PREDICT_FORMAT} weights file")
    if payload.get("version") != PREDICT_VERSION:
        raise fail(f"has version {payload.get('version')!r}, this code reads {PREDICT_VERSION}")
    try:
        cfg = payload["config"]
        model = PredictNet(int(cfg["k"]), tuple(int(w) for w in cfg["widths"]))  # type: ignore[arg-type]
        model.load_state_dict({k: v.float() if v.is_floating_point() else v
                               for k, v in payload["state_dict"].items()})
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise fail(f"does not match the network ({exc})") from exc
    model.eval()
    if fuse:
        model.fuse_for_inference()
    return model


class Predictor:
    """Runtime of ``predict`` mode: windows of fused detection frames in, channel 1 out.

    :param model: a loaded :class:`PredictNet` (default: the shipped weights).
    """

    def __init__(self, model: PredictNet | None = None, weights: Path | None = None) -> None:
        self.model = model if model is not None else load_predictor(weights)
        self.model.eval()
        self.k = self.model.k

    @torch.inference_mode()
    def __call__(self, windows: np.ndarray) -> np.ndarray:
        """Occupancy probability ``(N, H, W)`` float32 for windows ``(N, K, H, W, 3)``."""
        w = torch.from_numpy(np.ascontiguousarray(windows, dtype=np.float32))
        if w.ndim != 5 or w.shape[1] != self.k or w.shape[-1] != 3:
            raise ValueError(f"Predictor expects windows shaped (N, {self.k}, H, W, 3), got "
                             f"{tuple(w.shape)}")
        return torch.sigmoid(self.model(PredictNet.inputs(w)))[:, 0].numpy()


__all__ = [
    "DEFAULT_PREDICT_WEIGHTS",
    "HEATMAP_MODES",
    "HORIZON_S",
    "K",
    "PredictNet",
    "Predictor",
    "load_predictor",
    "save_predictor",
]
