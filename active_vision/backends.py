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

Precision (``PerceptionConfig.precision``, ``av-daemon --precision``): ``int8`` runs the
int8 model quantized from the export (static QDQ quantization, per-channel weights, made by
``python -m active_vision.training.quantize`` and shipped beside the export as
``<export>.int8.onnx``) where the ONNX backend runs, the file is there and the CPU has int8
dot-product instructions (:func:`cpu_int8_support`: AVX-512 VNNI or AVX-VNNI on x86, the
dot-product extension on Arm); otherwise, and when ONNX Runtime fails to load that file, the
fp32 export runs, with one log line saying why. ``fp32`` always runs the fp32 export. The
torch backend runs fp32 whatever is asked.
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
Precision = Literal["fp32", "int8"]
PRECISIONS: tuple[str, ...] = ("fp32", "int8")
DEFAULT_PRECISION: Precision = "int8"
"""int8: on the held-out split it is within 0.01 IoU/recall and 0.005 AbsRel/delta1 of fp32
in every world, and about 2x faster on one thread (benchmarks/precision_speed.py)."""
_INT8_CPU_FLAGS = ("avx512_vnni", "avx_vnni", "asimddp")
"""/proc/cpuinfo flags of int8 dot-product instructions (x86 VNNI, Arm dot product)."""
RAW_CHANNELS = 2
"""Channels of the network's raw output (heatmap logit, log depth)."""


class BackendError(RuntimeError):
    """The requested inference backend cannot run here (the message says what to do)."""


class Network(Protocol):
    """What :class:`~active_vision.perception.Perception` needs from a backend."""

    name: str
    precision: str
    """``fp32`` or ``int8``: what the network computes in."""

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


def cpu_int8_support(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[bool, str]:
    """Whether this CPU runs int8 convolutions fast (an int8 dot-product instruction), and
    the flag found or why not. Without one, ONNX Runtime's int8 kernels are no faster than
    fp32 and on AVX2 they can saturate (the reason for ``reduce_range``)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError as exc:
        return False, f"cannot read {cpuinfo} ({exc.strerror})"
    flags: set[str] = set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            flags.update(value.split())
            break
    for flag in _INT8_CPU_FLAGS:
        if flag in flags:
            return True, flag
    return False, f"no int8 dot-product instruction ({', '.join(_INT8_CPU_FLAGS)}) in {cpuinfo}"


class TorchNetwork:
    """Eager torch backend: the module on a channels-last view of an NHWC buffer."""

    name = "torch"
    precision = "fp32"

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

    :param path: the ``.onnx`` file (one float32 input ``(batch, 3, S, S)``, one output;
        an int8 model quantizes and dequantizes inside, so its input and output are float32
        too).
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


def resolve_backend(requested: str, weights: Path | None, size: int,
                    precision: str = "fp32") -> tuple[str, Path | None, Precision]:
    """The backend to run, for ``onnx`` its ``.onnx`` file, and the precision of that file.

    ``auto``: ``onnx`` when onnxruntime imports and the export is shipped, cached or can be
    made; otherwise ``torch``, with one log line saying why. ``onnx``: the same, but a
    missing piece is a :class:`BackendError` (or ``OnnxExportError``, ``WeightsError``).
    ``precision="int8"`` on ``onnx``: the int8 file when it is there and the CPU supports it
    (:func:`cpu_int8_support`), else the fp32 export with one log line saying why.
    """
    if requested not in BACKENDS:
        raise BackendError(f"backend must be one of {', '.join(BACKENDS)}, got {requested!r}")
    if precision not in PRECISIONS:
        raise BackendError(
            f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
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
    ok, why = cpu_int8_support()
    if not ok:
        logger.warning("this CPU has %s: perception runs the fp32 export, which is as fast "
                       "here (--precision fp32 says so without this line)", why)
        return "onnx", fp32, "fp32"
    return "onnx", int8, "int8"


__all__ = [
    "BACKENDS",
    "DEFAULT_PRECISION",
    "PRECISIONS",
    "BackendError",
    "BackendName",
    "Network",
    "OnnxNetwork",
    "Precision",
    "TorchNetwork",
    "cpu_int8_support",
    "onnxruntime_available",
    "resolve_backend",
]
