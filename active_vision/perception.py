"""Camera frames in, fused observations out: grayscale, pedestrian heatmap, depth.

:class:`Perception` turns a batch of uint8 camera frames ``(N, H, W, 3)`` (RGB) or
``(N, H, W, 4)`` (RGB + the renderer's depth channel, see the camera segment convention in
``docs/architecture.md``) into fused frames ``(N, S, S, 3)`` float32 in [0, 1], channels
indexed by ``fused_image.CHANNEL_GRAY`` / ``CHANNEL_HEATMAP`` / ``CHANNEL_DEPTH``:

- gray: ITU-R BT.601 luminance ``0.299 R + 0.587 G + 0.114 B`` (``fused_image.LUMA_WEIGHTS``,
  what OpenCV's ``COLOR_RGB2GRAY`` computes), divided by 255;
- heatmap: the :class:`~active_vision.models.AVNet` heatmap head (sigmoid);
- depth: the AVNet depth head (default), or with ``depth="render"`` the frame's fourth
  channel divided by 255 (the renderer's true depth, already in the depth convention).

All N frames go through the backend in one call, eager torch or ONNX Runtime (``backend``,
see :mod:`active_vision.backends`): it turns uint8 frames into fused frames, conversions
included (in ONNX Runtime they are nodes of the exported graph). Buffers are allocated once
and reused (they grow if a larger batch arrives).
"""

from __future__ import annotations

import copy
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch

from active_vision.backends import (
    DEFAULT_PRECISION,
    BackendError,
    Network,
    OnnxNetwork,
    Precision,
    TorchNetwork,
    resolve_backend,
)
from active_vision.models import AVNet, load_model
from active_vision.precision import choose_precision
from fused_image import CHANNEL_DEPTH, FUSED_SIZE, LUMA_WEIGHTS

logger = logging.getLogger(__name__)

DepthSource = Literal["model", "render"]
_INV255 = np.float32(1.0 / 255.0)


@dataclass
class PerceptionConfig:
    """How :class:`Perception` runs."""

    size: int = FUSED_SIZE[0]
    """Side of the fused frame; input frames of another size are resized (INTER_AREA)."""
    depth: DepthSource = "model"
    """``model``: depth from the network; ``render``: from the input frame's 4th channel."""
    threads: int | None = 1
    """Threads for the network: ``torch.set_num_threads`` (process-wide) and ONNX Runtime's
    ``intra_op_num_threads``; None leaves torch's setting alone (ONNX Runtime then uses 1)."""
    weights: Path | None = None
    """Weights file; None means the shipped ``active_vision/weights/avnet.pt``."""
    max_batch: int = 8
    """Batch size the buffers are first allocated for (they grow when needed)."""
    backend: str = "auto"
    """``auto`` | ``onnx`` | ``torch`` (:mod:`active_vision.backends`): ``auto`` is ONNX
    Runtime when it imports (and the export is available), else torch. A ``model`` passed to
    :class:`Perception` runs in torch unless ``onnx`` is asked for explicitly."""
    precision: str = DEFAULT_PRECISION
    """``auto`` | ``int8`` | ``fp32`` (:mod:`active_vision.backends`): ``auto`` runs the int8
    model in ONNX Runtime where it agrees with fp32 on this CPU and is faster, else the fp32
    export (one log line says which and why); ``int8`` runs it where it agrees and is
    refused where it does not; the torch backend always runs fp32."""
    int8_check: bool = True
    """False: ``int8`` runs the int8 model without checking it against fp32 on this CPU
    (what the evaluator does, to measure the model itself)."""


@dataclass
class StageTimes:
    """Accumulated wall time per stage (seconds) and the number of frames processed."""

    input: float = 0.0
    """Checking the frames and writing them into the backend's input (resized if needed)."""
    network: float = 0.0
    """The backend's call: uint8 frames to fused frames (conversions and the network)."""
    frames: int = 0
    batches: int = 0
    extra: dict[str, float] = field(default_factory=dict)

    def reset(self) -> None:
        self.input = self.network = 0.0
        self.frames = self.batches = 0
        self.extra.clear()

    def per_frame_ms(self) -> dict[str, float]:
        """Milliseconds per frame for each stage (``input``, ``network``, extras)."""
        n = max(self.frames, 1)
        out = {"input": 1e3 * self.input / n, "network": 1e3 * self.network / n}
        out.update({k: 1e3 * v / n for k, v in self.extra.items()})
        return out


class Perception:
    """Batched fused-frame perception (see the module docstring).

    :param config: a :class:`PerceptionConfig`; defaults when None.
    :param model: an already loaded network (for tests/training); loaded from
        ``config.weights`` when None.
    :raises active_vision.models.WeightsError: the weights file is missing or corrupt.
    :raises active_vision.backends.BackendError: the requested backend cannot run here.
    """

    def __init__(self, config: PerceptionConfig | None = None, model: AVNet | None = None):
        self.config = config or PerceptionConfig()
        if self.config.depth not in ("model", "render"):
            raise ValueError(f"depth must be 'model' or 'render', got {self.config.depth!r}")
        if self.config.size % 16:
            raise ValueError(f"size must be a multiple of 16, got {self.config.size}")
        if self.config.threads is not None:
            torch.set_num_threads(int(self.config.threads))
        requested = self.config.backend
        if model is not None and requested == "auto":
            requested = "torch"
        if model is not None and requested == "onnx":
            raise BackendError(
                "backend 'onnx' runs the ONNX export of a weights file, not a model object: "
                "save the model (active_vision.save_weights) and pass its path as "
                "PerceptionConfig.weights, or use backend 'torch' with model=."
            )
        backend, onnx_path, precision = resolve_backend(
            requested, self.config.weights, self.config.size, self.config.precision)
        if precision == "int8" and (self.config.int8_check or self.config.precision == "auto"):
            assert onnx_path is not None
            onnx_path, precision = self._checked_int8(onnx_path)
        capacity = max(1, self.config.max_batch)
        if backend == "onnx":
            assert onnx_path is not None
            self.model: AVNet | None = None
            onnx_net = self._onnx_network(onnx_path, precision, capacity)
            onnx_path = onnx_net.path
            self.net: Network = onnx_net
        else:
            self.model = model if model is not None else load_model(self.config.weights)
            self.net = TorchNetwork(self.model, self.config.size, capacity=capacity)
        logger.info("perception backend: %s, %s%s", backend, self.net.precision,
                    f" ({onnx_path.name})" if onnx_path is not None else "")
        self.timings = StageTimes()
        self._capacity = 0
        self._allocate(capacity)

    def _checked_int8(self, int8: Path) -> tuple[Path, Precision]:
        """The file and precision to run where ``auto`` or ``int8`` found the int8 model
        ``int8``: :func:`~active_vision.precision.choose_precision` against the fp32 export
        on this CPU (one log line; raises :class:`BackendError` where ``int8`` is refused)."""
        _, fp32, _ = resolve_backend("onnx", self.config.weights, self.config.size, "fp32")
        assert fp32 is not None
        chosen = choose_precision(self.config.precision, fp32, int8, self.config.size,
                                  self.config.threads or 1)
        return (int8 if chosen == "int8" else fp32), chosen

    def _onnx_network(self, path: Path, precision: str, capacity: int) -> OnnxNetwork:
        """The ONNX network of ``path``; an int8 file that ONNX Runtime cannot load (a build
        without its quantized kernels) falls back to the fp32 export with one log line."""
        threads = self.config.threads or 1
        try:
            return OnnxNetwork(path, self.config.size, threads=threads, capacity=capacity,
                               precision=precision)  # type: ignore[arg-type]
        except BackendError as exc:
            if precision != "int8":
                raise
            logger.warning("the int8 model does not load here, perception runs the fp32 "
                           "export: %s", exc)
        _, fp32, _ = resolve_backend("onnx", self.config.weights, self.config.size, "fp32")
        assert fp32 is not None
        return OnnxNetwork(fp32, self.config.size, threads=threads, capacity=capacity)

    def clone(self) -> Perception:
        """Another :class:`Perception` on the same network, backend and precision, with its
        own session (or module buffers) and input/output buffers, made without resolving or
        logging again: one per thread that runs perception (one object's buffers serve one
        caller at a time). The torch backend shares the module, whose forward pass does not
        write to it."""
        other = copy.copy(self)
        capacity = max(1, self._capacity)
        net = self.net
        if isinstance(net, OnnxNetwork):
            other.net = OnnxNetwork(net.path, self.config.size, threads=net.threads,
                                    capacity=capacity,
                                    precision=net.precision)  # type: ignore[arg-type]
        else:
            assert self.model is not None
            other.net = TorchNetwork(self.model, self.config.size, capacity=capacity)
        other.timings = StageTimes()
        other._allocate(capacity)
        return other

    @property
    def size(self) -> int:
        return self.config.size

    @property
    def backend(self) -> str:
        """The backend that runs the network: ``onnx`` or ``torch``."""
        return self.net.name

    @property
    def precision(self) -> str:
        """What the network computes in: ``fp32`` or ``int8`` (after any fallback)."""
        return self.net.precision

    def _allocate(self, n: int) -> None:
        self._capacity = n
        self.net.input(n)  # grows the backend's buffers

    def _input(self, frames: np.ndarray) -> tuple[int, np.ndarray | None]:
        """Write ``frames`` into the backend's input; the batch size, and the renderer's
        depth plane ``(n, S, S)`` uint8 when ``depth="render"``."""
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
        if (h, w) != (s, s):
            frames = np.stack([cv2.resize(f, (s, s), interpolation=cv2.INTER_AREA)
                               .reshape(s, s, c) for f in frames])
        self.net.input(n)[...] = frames[..., :3]
        return n, (frames[..., 3] if self.config.depth == "render" else None)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """Fused frames ``(N, S, S, 3)`` float32 for uint8 ``frames`` ``(N, H, W, 3|4)``.

        The result is a view of a buffer this object reuses: the next call overwrites it.
        Copy it if you keep it.
        """
        t0 = time.perf_counter()
        n, render_depth = self._input(np.asarray(frames))
        t1 = time.perf_counter()
        out = self.net.run(n)
        if render_depth is not None:
            np.multiply(render_depth, _INV255, out=out[..., CHANNEL_DEPTH])
        t2 = time.perf_counter()
        self.timings.input += t1 - t0
        self.timings.network += t2 - t1
        self.timings.frames += n
        self.timings.batches += 1
        return out


def gray_of(frames: np.ndarray) -> np.ndarray:
    """Reference grayscale (float32 in [0, 1]) of uint8 RGB frames ``(..., 3)``."""
    rgb = np.asarray(frames)[..., :3].astype(np.float32)
    return rgb @ (np.asarray(LUMA_WEIGHTS, dtype=np.float32) * _INV255)


__all__ = ["DepthSource", "Perception", "PerceptionConfig", "StageTimes", "gray_of"]
