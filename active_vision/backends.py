"""Inference backends for the perception network: eager torch or ONNX Runtime.

:class:`~active_vision.perception.Perception` runs its network through one of these; the
rest of the system sees only ``Perception``. Both backends own preallocated input and output
buffers (grown when a larger batch arrives, views cached per batch size), so a frame costs
no new array:

- ``write`` the batch into :meth:`Network.input` (``(n, 3, S, S)`` float32, RGB in [0, 1]),
- call :meth:`Network.run` and read the raw maps ``(n, 2, S, S)`` it returns (a view of the
  backend's output buffer, overwritten by the next call).

``torch`` (:class:`TorchNetwork`) runs the module in eager mode on a channels-last input.
``onnx`` (:class:`OnnxNetwork`) runs the ONNX export (:mod:`active_vision.onnx_export`) in
ONNX Runtime's CPU provider with I/O bound to the buffers (``run_with_iobinding``):
``intra_op_num_threads`` is the thread count, and the pool waits passively (no spinning),
for the same reason ``active_vision`` sets ``OMP_WAIT_POLICY=PASSIVE`` for torch.
``auto`` (:func:`resolve_backend`) is ``onnx`` when ``onnxruntime`` imports and the export is
available, else ``torch`` with one log line saying why.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
import torch
from torch import nn

logger = logging.getLogger(__name__)

BackendName = Literal["auto", "onnx", "torch"]
BACKENDS: tuple[str, ...] = ("auto", "onnx", "torch")
RAW_CHANNELS = 2
"""Channels of the network's raw output (heatmap logit, log depth)."""


class BackendError(RuntimeError):
    """The requested inference backend cannot run here (the message says what to do)."""


class Network(Protocol):
    """What :class:`~active_vision.perception.Perception` needs from a backend."""

    name: str

    def input(self, n: int) -> torch.Tensor:
        """Writable ``(n, 3, S, S)`` float32 input buffer for a batch of ``n``."""
        ...

    def run(self, n: int) -> torch.Tensor:
        """Run on the first ``n`` inputs; raw maps ``(n, 2, S, S)`` (reused buffer)."""
        ...


def onnxruntime_available() -> bool:
    """True when ``onnxruntime`` imports."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


class TorchNetwork:
    """Eager torch backend: the module on a channels-last view of an NHWC buffer."""

    name = "torch"

    def __init__(self, model: nn.Module, size: int, capacity: int = 1) -> None:
        self.model = model.eval().to(memory_format=torch.channels_last)
        self.size = size
        self._views: dict[int, torch.Tensor] = {}
        self._allocate(max(1, capacity))

    def _allocate(self, n: int) -> None:
        s = self.size
        self._capacity = n
        # NHWC storage: permuted to NCHW it is a channels_last tensor for the convolutions.
        self._nhwc = torch.empty((n, s, s, 3), dtype=torch.float32)
        self._views = {}

    def input(self, n: int) -> torch.Tensor:
        if n > self._capacity:
            self._allocate(n)
        view = self._views.get(n)
        if view is None:
            view = self._views[n] = self._nhwc[:n].permute(0, 3, 1, 2)
        return view

    @torch.inference_mode()
    def run(self, n: int) -> torch.Tensor:
        return self.model(self.input(n))


class OnnxNetwork:
    """ONNX Runtime backend (CPU provider) with inputs and outputs bound to numpy buffers.

    :param path: the ``.onnx`` file (one float32 input ``(batch, 3, S, S)``, one output).
    :param threads: ``intra_op_num_threads``.
    :raises BackendError: ``onnxruntime`` is missing or the file cannot be loaded.
    """

    name = "onnx"

    def __init__(self, path: Path, size: int, threads: int = 1, capacity: int = 1) -> None:
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
        try:
            self.session = ort.InferenceSession(str(path), opts,
                                                providers=["CPUExecutionProvider"])
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
        self._in_name, self._out_name = inputs[0].name, outputs[0].name
        self.path = Path(path)
        self.size = size
        self.threads = opts.intra_op_num_threads
        self._ort = ort
        self._allocate(max(1, capacity))

    def _allocate(self, n: int) -> None:
        s = self.size
        self._capacity = n
        self._in = np.empty((n, 3, s, s), dtype=np.float32)
        self._out = np.empty((n, RAW_CHANNELS, s, s), dtype=np.float32)
        self._in_t = torch.from_numpy(self._in)
        self._out_t = torch.from_numpy(self._out)
        self._bound: dict[int, tuple[object, torch.Tensor, torch.Tensor]] = {}

    def _binding(self, n: int) -> tuple[object, torch.Tensor, torch.Tensor]:
        if n > self._capacity:
            self._allocate(n)
        entry = self._bound.get(n)
        if entry is None:
            s = self.size
            binding = self.session.io_binding()
            binding.bind_input(self._in_name, "cpu", 0, np.float32, (n, 3, s, s),
                               self._in.ctypes.data)
            binding.bind_output(self._out_name, "cpu", 0, np.float32,
                                (n, RAW_CHANNELS, s, s), self._out.ctypes.data)
            entry = self._bound[n] = (binding, self._in_t[:n], self._out_t[:n])
        return entry

    def input(self, n: int) -> torch.Tensor:
        return self._binding(n)[1]

    def run(self, n: int) -> torch.Tensor:
        binding, _, out = self._binding(n)
        self.session.run_with_iobinding(binding)
        return out


def resolve_backend(requested: str, weights: Path | None, size: int) -> tuple[str, Path | None]:
    """The backend to run and, for ``onnx``, its ``.onnx`` file.

    ``auto``: ``onnx`` when onnxruntime imports and the export is shipped, cached or can be
    made; otherwise ``torch``, with one log line saying why. ``onnx``: the same, but a
    missing piece is a :class:`BackendError` (or ``OnnxExportError``, ``WeightsError``).
    """
    if requested not in BACKENDS:
        raise BackendError(f"backend must be one of {', '.join(BACKENDS)}, got {requested!r}")
    if requested == "torch":
        return "torch", None
    from active_vision.onnx_export import OnnxExportError, onnx_file_for

    if not onnxruntime_available():
        if requested == "onnx":
            raise BackendError(
                "--backend onnx needs onnxruntime, which does not import here. Install it "
                "with `pip install onnxruntime`, or use --backend torch (or auto)."
            )
        logger.warning("onnxruntime is not installed: perception runs in torch "
                       "(pip install onnxruntime for the faster ONNX backend)")
        return "torch", None
    try:
        return "onnx", onnx_file_for(weights, size)
    except OnnxExportError as exc:
        if requested == "onnx":
            raise
        logger.warning("perception runs in torch: %s", exc)
        return "torch", None


__all__ = [
    "BACKENDS",
    "BackendError",
    "BackendName",
    "Network",
    "OnnxNetwork",
    "TorchNetwork",
    "onnxruntime_available",
    "resolve_backend",
]
