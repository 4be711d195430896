"""Camera frames in, fused observations out: grayscale, pedestrian heatmap, depth.

:class:`Perception` turns a batch of uint8 camera frames ``(N, H, W, 3)`` (RGB) or
``(N, H, W, 4)`` (RGB + the renderer's depth channel, see the camera segment convention in
``docs/architecture.md``) into fused frames ``(N, S, S, 3)`` float32 in [0, 1], channels
indexed by ``shm_protocol.CHANNEL_GRAY`` / ``CHANNEL_HEATMAP`` / ``CHANNEL_DEPTH``:

- gray: ITU-R BT.601 luminance ``0.299 R + 0.587 G + 0.114 B`` (what OpenCV's
  ``COLOR_RGB2GRAY`` computes), divided by 255;
- heatmap: the :class:`~active_vision.models.AVNet` heatmap head (sigmoid);
- depth: the AVNet depth head (default), or with ``depth="render"`` the frame's fourth
  channel divided by 255 (the renderer's true depth, already in the depth convention).

All N frames go through the network in one forward pass, under ``torch.inference_mode``,
with buffers allocated once and reused (they grow if a larger batch arrives).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch

from active_vision.models import (
    HEAD_DEPTH,
    HEAD_HEATMAP,
    AVNet,
    load_model,
    log_depth_to_channel,
)
from shm_protocol import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP

logger = logging.getLogger(__name__)

DepthSource = Literal["model", "render"]
#: BT.601 luma weights, scaled so uint8 RGB maps to gray in [0, 1].
_LUMA = (0.299 / 255.0, 0.587 / 255.0, 0.114 / 255.0)


@dataclass
class PerceptionConfig:
    """How :class:`Perception` runs."""

    size: int = 96
    """Side of the fused frame; input frames of another size are resized (INTER_AREA)."""
    depth: DepthSource = "model"
    """``model``: depth from the network; ``render``: from the input frame's 4th channel."""
    threads: int | None = 1
    """``torch.set_num_threads`` value (process-wide); None leaves torch's setting alone."""
    weights: Path | None = None
    """Weights file; None means the shipped ``active_vision/weights/avnet.pt``."""
    max_batch: int = 8
    """Batch size the buffers are first allocated for (they grow when needed)."""


@dataclass
class StageTimes:
    """Accumulated wall time per stage (seconds) and the number of frames processed."""

    gray: float = 0.0
    network: float = 0.0
    frames: int = 0
    batches: int = 0
    extra: dict[str, float] = field(default_factory=dict)

    def reset(self) -> None:
        self.gray = self.network = 0.0
        self.frames = self.batches = 0
        self.extra.clear()

    def per_frame_ms(self) -> dict[str, float]:
        """Milliseconds per frame for each stage (``gray``, ``heatmap+depth``, extras)."""
        n = max(self.frames, 1)
        out = {"gray": 1e3 * self.gray / n, "heatmap+depth": 1e3 * self.network / n}
        out.update({k: 1e3 * v / n for k, v in self.extra.items()})
        return out


class Perception:
    """Batched fused-frame perception (see the module docstring).

    :param config: a :class:`PerceptionConfig`; defaults when None.
    :param model: an already loaded network (for tests/training); loaded from
        ``config.weights`` when None.
    :raises active_vision.models.WeightsError: the weights file is missing or corrupt.
    """

    def __init__(self, config: PerceptionConfig | None = None, model: AVNet | None = None):
        self.config = config or PerceptionConfig()
        if self.config.depth not in ("model", "render"):
            raise ValueError(f"depth must be 'model' or 'render', got {self.config.depth!r}")
        if self.config.size % 16:
            raise ValueError(f"size must be a multiple of 16, got {self.config.size}")
        if self.config.threads is not None:
            torch.set_num_threads(int(self.config.threads))
        self.model = model if model is not None else load_model(self.config.weights)
        self.model.eval()
        self.model.to(memory_format=torch.channels_last)
        self.timings = StageTimes()
        self._luma = torch.tensor(_LUMA, dtype=torch.float32)
        self._capacity = 0
        self._allocate(max(1, self.config.max_batch))

    @property
    def size(self) -> int:
        return self.config.size

    def _allocate(self, n: int) -> None:
        s = self.config.size
        self._capacity = n
        self._resized = np.empty((n, s, s, 4), dtype=np.uint8)
        # float RGB, NHWC storage: permuted to NCHW it is a channels_last tensor for the net.
        self._rgb = torch.empty((n, s, s, 3), dtype=torch.float32)
        self._gray = torch.empty((n, s, s), dtype=torch.float32)
        self._out = np.empty((n, s, s, 3), dtype=np.float32)
        self._out_t = torch.from_numpy(self._out)

    def _input(self, frames: np.ndarray) -> np.ndarray:
        if frames.ndim == 3:
            frames = frames[None]
        if frames.ndim != 4 or frames.shape[-1] not in (3, 4) or frames.dtype != np.uint8:
            raise ValueError(
                "Perception expects uint8 frames shaped (N, H, W, 3) or (N, H, W, 4), got "
                f"{frames.dtype} {frames.shape}"
            )
        if self.config.depth == "render" and frames.shape[-1] != 4:
            raise ValueError(
                "depth='render' needs frames with the renderer's depth in channel 3 "
                f"(N, H, W, 4); got {frames.shape}"
            )
        n, h, w, c = frames.shape
        if n > self._capacity:
            logger.debug("growing perception buffers from %d to %d frames", self._capacity, n)
            self._allocate(n)
        s = self.config.size
        if (h, w) == (s, s):
            return frames
        out = self._resized[:n, :, :, :c]
        for i in range(n):
            out[i] = cv2.resize(frames[i], (s, s), interpolation=cv2.INTER_AREA).reshape(s, s, c)
        return out

    @torch.inference_mode()
    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """Fused frames ``(N, S, S, 3)`` float32 for uint8 ``frames`` ``(N, H, W, 3|4)``.

        The result is a view of a buffer this object reuses: the next call overwrites it.
        Copy it if you keep it.
        """
        t0 = time.perf_counter()
        frames = self._input(np.asarray(frames))
        n = frames.shape[0]
        u8 = torch.from_numpy(np.ascontiguousarray(frames))
        rgb = self._rgb[:n]
        rgb.copy_(u8[..., :3])
        out = self._out_t[:n]
        torch.matmul(rgb, self._luma, out=self._gray[:n])
        out[..., CHANNEL_GRAY] = self._gray[:n]
        if self.config.depth == "render":
            out[..., CHANNEL_DEPTH] = u8[..., 3]
            out[..., CHANNEL_DEPTH] *= 1.0 / 255.0
        rgb.mul_(1.0 / 255.0)
        t1 = time.perf_counter()
        raw = self.model(rgb.permute(0, 3, 1, 2))
        # straight into the (strided) channels of the output buffer: no temporaries
        torch.sigmoid(raw[:, HEAD_HEATMAP], out=out[..., CHANNEL_HEATMAP])
        if self.config.depth == "model":
            log_depth_to_channel(raw[:, HEAD_DEPTH], out=out[..., CHANNEL_DEPTH])
        t2 = time.perf_counter()
        self.timings.gray += t1 - t0
        self.timings.network += t2 - t1
        self.timings.frames += n
        self.timings.batches += 1
        return self._out[:n]


def gray_of(frames: np.ndarray) -> np.ndarray:
    """Reference grayscale (float32 in [0, 1]) of uint8 RGB frames ``(..., 3)``."""
    rgb = np.asarray(frames)[..., :3].astype(np.float32)
    return rgb @ np.asarray(_LUMA, dtype=np.float32)


__all__ = ["DepthSource", "Perception", "PerceptionConfig", "StageTimes", "gray_of"]
