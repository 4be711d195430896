"""Inference backends for the perception network: eager torch or ONNX Runtime.

:class:`~active_vision.perception.Perception` runs its network through one of these; the
rest of the system sees only ``Perception``. A backend maps camera frames to fused frames
(:mod:`fused_image`: luminance, heatmap, depth from the network). Both own preallocated
input and output buffers (grown when a larger batch arrives, views cached per batch size),
so a frame costs no new array:

- write the batch into :meth:`Network.input` (``(n, S, S, 3)`` uint8 RGB),
- call :meth:`Network.run` and read the fused frames ``(n, S, S, 3)`` float32 it returns (a
  view of the backend's output buffer, overwritten by the next call).

``torch`` (:class:`TorchNetwork`) runs the module in eager mode on a channels-last input,
with the conversions around it in torch. ``onnx`` (:class:`OnnxNetwork`) runs the ONNX
export (:mod:`active_vision.onnx_export`), which holds the conversions as graph nodes, in
ONNX Runtime's CPU provider with I/O bound to the buffers (``run_with_iobinding``): one
call a batch and no other array operation (cheaper than the same conversions in torch
around the network: benchmarks/RESULTS.md, "Precision: int8 against fp32");
``intra_op_num_threads`` is the thread count, and the pool waits passively (no spinning),
for the same reason ``active_vision`` sets ``OMP_WAIT_POLICY=PASSIVE`` for torch.
``auto`` (:func:`resolve_backend`) is ``onnx`` when ``onnxruntime`` imports and the export is
available, else ``torch`` with one log line saying why.

Precision (``PerceptionConfig.precision``, ``av-daemon --precision``): the int8 model is
quantized from the export (static QDQ quantization, 7-bit weights per channel, made by
``python -m active_vision.training.quantize`` and shipped beside the export as
``<export>.int8.onnx``). ``auto`` (the default) runs it where the ONNX backend runs, the file
is there, it agrees with fp32 on this CPU and is faster here, as measured once per machine
(:mod:`active_vision.precision`), else the fp32 export, with one log line saying which and
why. ``int8`` runs it where it agrees with fp32 on this CPU and refuses to start
(:class:`BackendError`) where it does not. ``fp32`` always runs the fp32 export, unchecked.
Where the int8 file is missing or ONNX Runtime fails to load it, ``auto`` and ``int8`` run
the fp32 export with one log line. The torch backend runs fp32 whatever is asked.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
import torch
from torch import nn

from active_vision.choices import BACKENDS, DEFAULT_PRECISION, PRECISION_CHOICES, PRECISIONS
from active_vision.models import HEAD_DEPTH, HEAD_HEATMAP, log_depth_to_channel
from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP, LUMA_WEIGHTS

logger = logging.getLogger(__name__)

BackendName = Literal["auto", "onnx", "torch"]
Precision = Literal["fp32", "int8"]
"""What a network computes in (the values of ``PRECISIONS``)."""
_INT8_DISABLED_OPTIMIZERS = ("NchwcTransformer",)
"""ONNX Runtime graph passes left out for the int8 model (see :class:`OnnxNetwork`)."""


class BackendError(RuntimeError):
    """The requested inference backend cannot run here (the message says what to do)."""


class Network(Protocol):
    """What :class:`~active_vision.perception.Perception` needs from a backend."""

    name: str
    precision: str
    """``fp32`` or ``int8``: what the network computes in."""

    def input(self, n: int) -> np.ndarray:
        """Writable ``(n, S, S, 3)`` uint8 input buffer (RGB frames) for a batch of ``n``."""
        ...

    def run(self, n: int) -> np.ndarray:
        """Run on the first ``n`` inputs; fused frames ``(n, S, S, 3)`` float32 in [0, 1]
        (a view of a reused buffer)."""
        ...


def onnxruntime_available() -> bool:
    """True when ``onnxruntime`` imports."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


class TorchNetwork:
    """Eager torch backend: uint8 -> float and the luminance into planes, the module on a
    channels-last view, sigmoid and the depth conversion into the planes, one interleaving
    copy into the fused frames (elementwise ops on strided outputs cost twice as much)."""

    name = "torch"
    precision = "fp32"

    def __init__(self, model: nn.Module, size: int, capacity: int = 1) -> None:
        self.model = model.eval().to(memory_format=torch.channels_last)
        self.size = size
        self._views: dict[int, tuple[torch.Tensor, ...]] = {}
        self._allocate(max(1, capacity))

    def _allocate(self, n: int) -> None:
        s = self.size
        self._capacity = n
        self._frames = np.empty((n, s, s, 3), dtype=np.uint8)
        # NHWC storage: permuted to NCHW it is a channels_last tensor for the convolutions.
        self._nhwc = torch.empty((n, s, s, 3), dtype=torch.float32)
        self._planes = torch.empty((n, 3, s, s), dtype=torch.float32)
        self._out = np.empty((n, s, s, 3), dtype=np.float32)
        self._views = {}

    def input(self, n: int) -> np.ndarray:
        if n > self._capacity:
            self._allocate(n)
        return self._frames[:n]

    def _views_for(self, n: int) -> tuple[torch.Tensor, ...]:
        v = self._views.get(n)
        if v is None:
            planes = self._planes[:n]
            v = self._views[n] = (
                torch.from_numpy(self._frames[:n]).permute(0, 3, 1, 2),
                self._nhwc[:n].permute(0, 3, 1, 2), planes, planes.permute(0, 2, 3, 1),
                torch.from_numpy(self._out[:n]))
        return v

    @torch.inference_mode()
    def run(self, n: int) -> np.ndarray:
        self.input(n)
        u8, x, planes, planes_nhwc, out = self._views_for(n)
        x.copy_(u8)
        gray = planes[:, CHANNEL_GRAY]
        torch.mul(x[:, 0], LUMA_WEIGHTS[0] / 255.0, out=gray)
        gray.add_(x[:, 1], alpha=LUMA_WEIGHTS[1] / 255.0)
        gray.add_(x[:, 2], alpha=LUMA_WEIGHTS[2] / 255.0)
        x.mul_(1.0 / 255.0)
        raw = self.model(x)
        torch.sigmoid(raw[:, HEAD_HEATMAP], out=planes[:, CHANNEL_HEATMAP])
        log_depth_to_channel(raw[:, HEAD_DEPTH], out=planes[:, CHANNEL_DEPTH])
        out.copy_(planes_nhwc)
        return self._out[:n]


class OnnxNetwork:
    """ONNX Runtime backend (CPU provider) with inputs and outputs bound to numpy buffers.

    :param path: the ``.onnx`` file (:mod:`active_vision.onnx_export`): one uint8 input
        ``(batch, S, S, 3)``, one float32 output ``(batch, S, S, 3)``; an int8 model
        quantizes and dequantizes inside, so its input and output are the same.
    :param threads: ``intra_op_num_threads``.
    :param precision: what the file holds (``fp32`` or ``int8``), for the log and readers.
    :raises BackendError: ``onnxruntime`` is missing or the file cannot be loaded.
    """

    name = "onnx"

    def __init__(self, path: Path, size: int, threads: int = 1, capacity: int = 1,
                 precision: Precision = "fp32") -> None:
        self.precision: str = precision
        try:
            import onnxruntime as ort
        except ImportError as exc:
            raise BackendError(
                f"--backend onnx needs onnxruntime ({exc}). Install it with "
                "`pip install onnxruntime`, or use --backend torch (or auto)."
            ) from exc
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = max(1, int(threads))
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        opts.log_severity_level = 3
        # The int8 model runs its quantized convolutions in ORT's NHWC int8 kernels; the
        # NCHWc layout pass only re-lays out the fp32 head and the Resizes around them, with
        # a reorder each way, a cost the int8 model runs faster without (fp32 keeps it).
        disabled = list(_INT8_DISABLED_OPTIMIZERS) if precision == "int8" else []
        try:
            self.session = ort.InferenceSession(str(path), opts,
                                                providers=["CPUExecutionProvider"],
                                                disabled_optimizers=disabled)
        except Exception as exc:  # ORT raises its own Fail/InvalidGraph types
            raise BackendError(
                f"ONNX Runtime cannot load {path} ({type(exc).__name__}: {exc}). Delete the "
                "file so it is exported again, or use --backend torch."
            ) from exc
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise BackendError(
                f"{path}: expected one input and one output, found {len(inputs)} inputs "
                f"({[i.name for i in inputs]}) and {len(outputs)} outputs; this backend "
                "feeds one frame batch. Re-export it with active_vision.onnx_export."
            )
        shape = [inputs[0].type, outputs[0].type, *inputs[0].shape[1:], *outputs[0].shape[1:]]
        if shape != ["tensor(uint8)", "tensor(float)", size, size, 3, size, size, 3]:
            raise BackendError(
                f"{path}: expected uint8 frames (batch, {size}, {size}, 3) in and fused frames "
                f"out, found {inputs[0].type} {inputs[0].shape} -> {outputs[0].type} "
                f"{outputs[0].shape} (an export of another version or size). Delete it so it "
                "is exported again (python -m active_vision.onnx_export), or use --backend "
                "torch.")
        self._in_name, self._out_name = inputs[0].name, outputs[0].name
        self.path = Path(path)
        self.size = size
        self.threads = opts.intra_op_num_threads
        self._ort = ort
        self._allocate(max(1, capacity))

    def _allocate(self, n: int) -> None:
        s = self.size
        self._capacity = n
        self._in = np.empty((n, s, s, 3), dtype=np.uint8)
        self._out = np.empty((n, s, s, 3), dtype=np.float32)
        self._bound: dict[int, tuple[object, np.ndarray, np.ndarray]] = {}

    def _binding(self, n: int) -> tuple[object, np.ndarray, np.ndarray]:
        if n > self._capacity:
            self._allocate(n)
        entry = self._bound.get(n)
        if entry is None:
            s = self.size
            binding = self.session.io_binding()
            binding.bind_input(self._in_name, "cpu", 0, np.uint8, (n, s, s, 3),
                               self._in.ctypes.data)
            binding.bind_output(self._out_name, "cpu", 0, np.float32, (n, s, s, 3),
                                self._out.ctypes.data)
            entry = self._bound[n] = (binding, self._in[:n], self._out[:n])
        return entry

    def input(self, n: int) -> np.ndarray:
        return self._binding(n)[1]

    def run(self, n: int) -> np.ndarray:
        binding, _, out = self._binding(n)
        self.session.run_with_iobinding(binding)
        return out


def resolve_backend(requested: str, weights: Path | None, size: int,
                    precision: str = "fp32") -> tuple[str, Path | None, Precision]:
    """The backend to run, for ``onnx`` its ``.onnx`` file, and the precision of that file.

    ``auto``: ``onnx`` when onnxruntime imports and the export is shipped, cached or can be
    made; otherwise ``torch``, with one log line saying why. ``onnx``: the same, but a
    missing piece is a :class:`BackendError` (or ``OnnxExportError``, ``WeightsError``).
    ``precision`` ``auto`` or ``int8`` on ``onnx``: the int8 file when it is there, else the
    fp32 export with one log line saying why. Whether the int8 file then runs is
    :func:`active_vision.precision.choose_precision`'s call
    (:class:`~active_vision.perception.Perception` asks it).
    """
    if requested not in BACKENDS:
        raise BackendError(f"backend must be one of {', '.join(BACKENDS)}, got {requested!r}")
    if precision not in PRECISION_CHOICES:
        raise BackendError(
            f"precision must be one of {', '.join(PRECISION_CHOICES)}, got {precision!r}")
    if requested == "torch":
        return "torch", None, "fp32"
    from active_vision.onnx_export import (
        INT8_SUFFIX,
        OnnxExportError,
        int8_file_for,
        onnx_file_for,
    )

    if not onnxruntime_available():
        if requested == "onnx":
            raise BackendError(
                "--backend onnx needs onnxruntime, which does not import here. Install it "
                "with `pip install onnxruntime`, or use --backend torch (or auto)."
            )
        logger.warning("onnxruntime is not installed: perception runs in torch "
                       "(pip install onnxruntime for the faster ONNX backend)")
        return "torch", None, "fp32"
    try:
        fp32 = onnx_file_for(weights, size)
    except OnnxExportError as exc:
        if requested == "onnx":
            raise
        logger.warning("perception runs in torch: %s", exc)
        return "torch", None, "fp32"
    if precision == "fp32":
        return "onnx", fp32, "fp32"
    int8 = int8_file_for(weights, size)
    if int8 is None:
        logger.warning("no int8 model %s%s here or in the cache: perception runs the fp32 "
                       "export; make it with `python -m active_vision.training.quantize`",
                       fp32.name.removesuffix(".onnx"), INT8_SUFFIX)
        return "onnx", fp32, "fp32"
    return "onnx", int8, "int8"


__all__ = [
    "BACKENDS",
    "DEFAULT_PRECISION",
    "PRECISIONS",
    "PRECISION_CHOICES",
    "BackendError",
    "BackendName",
    "Network",
    "OnnxNetwork",
    "Precision",
    "TorchNetwork",
    "onnxruntime_available",
    "resolve_backend",
]
