"""The int8 model of the perception network: static quantization of its ONNX export.

``python -m active_vision.training.quantize [--weights PATH]`` exports the network of the
weights (:func:`active_vision.onnx_export.export_network`), quantizes it with ONNX Runtime's
``quantize_static``, wraps it in the same float32 frame-to-fused-frame conversions as the
fp32 export (:func:`active_vision.onnx_export.fuse_pre_post`) and writes it beside the
export as ``<weights stem>-<sha256, 16 hex>-s<side>-x<version>.int8.onnx``
(:func:`active_vision.onnx_export.int8_file_name`), removing older int8 files of the same
stem and side there. The daemon runs it with ``--precision int8``
(:mod:`active_vision.backends`).

The recipe (:class:`QuantizeRecipe`, stored in the int8 file's ONNX metadata under
``RECIPE_KEY``; ``--recipe FILE`` remakes a file from it), each choice made on the
validation split (the figures: benchmarks/RESULTS.md, "Precision: int8 against fp32"):

- **QDQ format**, uint8 activations, int8 weights **per output channel**: ONNX Runtime fuses
  the QuantizeLinear/DequantizeLinear pairs into its int8 convolution kernels. The QOperator
  format is slower; int8 activations are slower than fp32 (the CPU's u8s8 kernels want
  uint8 activations); per-tensor weights double the depth error.
- **the head stays fp32**: the last convolution (the heatmap logit and the log depth) and
  what follows it up to the output. An 8-bit log-depth output costs AbsRel in every world;
  in fp32 the head costs no measurable speed (a 1x1 convolution to 2 channels).
- **Percentile calibration** (99.999) on ``calibration_frames`` validation frames: against
  MinMax, the same heatmap figures and AbsRel nearer fp32's; Entropy gives MinMax's model.
- **7-bit weights** (``reduce_range``): on a CPU with AVX2 and no VNNI, ONNX Runtime's u8s8
  kernels add pairs of products in 16 bits, which saturates with full 8-bit weights and
  wrecks the model; with 7-bit weights it stays near fp32 in every world. With VNNI both
  run the same kernels. The daemon checks the model against fp32 on each CPU
  (:mod:`active_vision.precision`).
- No ``quant_pre_process``: ORT's symbolic shape inference does not complete on this graph,
  and with ONNX shape inference alone it changes neither speed nor quality.

Calibration frames come from the validation split (``evaluate.heldout(split="validation")``,
rendered on first use), never from the held-out split the figures are reported on.
``python -m active_vision.training.evaluate --precision int8`` gives the held-out figures.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from active_vision.models import DEFAULT_WEIGHTS
from active_vision.onnx_export import (
    INPUT_NAME,
    INT8_SUFFIX,
    export_network,
    fuse_file,
    int8_file_name,
)
from active_vision.training.dataset import DEFAULT_DATA_DIR
from fused_image import FUSED_SIZE
from rover_train.cli import parse_recipe_command, recipe_dict, recipe_from_dict

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class QuantizeRecipe:
    """How the int8 model is made (see the module docstring for why each value); stored in
    the file it makes, and the command line is generated from these fields."""

    calibration_frames: int = 256
    """Validation frames the activation ranges are measured on (drawn without replacement)."""
    batch: int = 8
    """Frames per calibration batch."""
    method: str = field(default="percentile",
                        metadata={"choices": ("minmax", "entropy", "percentile")})
    """ONNX Runtime's calibration method."""
    percentile: float = 99.999
    """For ``percentile``: the share of each activation's values its range covers."""
    reduce_range: bool = True
    """7-bit weights (CPUs without VNNI saturate on 8-bit ones in their u8s8 kernels)."""
    seed: int = 0
    """Seed of the draw of calibration frames."""

    def problem(self) -> str | None:
        """What is wrong with this recipe (named by its option), or None."""
        if self.calibration_frames < 1:
            return f"--calibration-frames must be at least 1, got {self.calibration_frames}"
        if self.batch < 1:
            return f"--batch must be at least 1, got {self.batch}"
        if not 50.0 < self.percentile <= 100.0:
            return f"--percentile must be in (50, 100], got {self.percentile}"
        return None


@dataclass(frozen=True)
class QuantizeRun:
    """What ``python -m active_vision.training.quantize`` quantizes and where it writes."""

    weights: Path = DEFAULT_WEIGHTS
    """The AVNet weights whose ONNX export is quantized."""
    size: int = FUSED_SIZE[0]
    """Frame side (a multiple of 16)."""
    out_dir: Path | None = None
    """Directory to write to (default: the weights file's own)."""
    data_dir: Path = DEFAULT_DATA_DIR
    """Where the validation split is rendered or reused."""


RECIPE_KEY = "roverav.recipe"
"""The ONNX metadata key of an int8 file's :class:`QuantizeRecipe` (JSON)."""


def read_recipe(path: Path) -> QuantizeRecipe:
    """The recipe stored in the int8 ONNX file ``path``."""
    import onnx

    props = {p.key: p.value for p in onnx.load(str(path), load_external_data=False)
             .metadata_props}  # fmt: skip
    if RECIPE_KEY not in props:
        raise ValueError(f"{path} holds no recipe (an int8 file written before recipes were "
                         "stored)")  # fmt: skip
    return recipe_from_dict(QuantizeRecipe, json.loads(props[RECIPE_KEY]))


def _store_recipe(path: Path, recipe: QuantizeRecipe) -> None:
    import onnx

    model = onnx.load(str(path))
    for prop in list(model.metadata_props):
        if prop.key == RECIPE_KEY:
            model.metadata_props.remove(prop)
    onnx.helper.set_model_props(model, {RECIPE_KEY: json.dumps(recipe_dict(recipe))})
    onnx.save(model, str(path))


class QuantizeError(RuntimeError):
    """The int8 model cannot be made here (the message says what to do)."""


class _Frames:
    """``CalibrationDataReader`` over float32 NCHW frames, ``batch`` at a time."""

    def __init__(self, frames: np.ndarray, batch: int) -> None:
        self._it: Iterator[dict[str, np.ndarray]] = (
            {INPUT_NAME: frames[i:i + batch]} for i in range(0, len(frames), batch))

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._it, None)


def calibration_frames(rgb: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """``n`` of the uint8 ``(N, S, S, 3)`` frames ``rgb`` (a seeded draw, in order) as the
    network's float32 ``(n, 3, S, S)`` input in [0, 1], as :class:`Perception` feeds it."""
    n = min(n, len(rgb))
    idx = np.sort(np.random.default_rng(seed).choice(len(rgb), n, replace=False))
    return np.ascontiguousarray(rgb[idx].transpose(0, 3, 1, 2), dtype=np.float32) / 255.0


def head_nodes(model_path: Path) -> list[str]:
    """Names of the last Conv feeding the graph's output and of every node after it on the
    way to the output (kept in fp32: quantizing the log-depth output costs AbsRel)."""
    import onnx

    graph = onnx.load(str(model_path)).graph
    producer = {out: node for node in graph.node for out in node.output}
    names: list[str] = []
    frontier = [o.name for o in graph.output]
    while frontier:
        node = producer.get(frontier.pop())
        if node is None or node.name in names:
            continue
        names.append(node.name)
        if node.op_type != "Conv":
            frontier.extend(i for i in node.input[:1] if i)
    return names


def quantize_file(fp32: Path, out: Path, frames: np.ndarray,
                  config: QuantizeRecipe | None = None) -> Path:
    """Quantize the fp32 ONNX file ``fp32`` of the network (float input, raw maps out: not
    the wrapped file the backend runs) into ``out`` (written atomically), calibrated on
    ``frames`` (float32 ``(n, 3, S, S)`` in [0, 1]), with the recipe in its metadata.

    :raises QuantizeError: onnxruntime's quantization tools are missing or failed.
    """
    cfg = config or QuantizeRecipe()
    try:
        from onnxruntime.quantization import (
            CalibrationMethod,
            QuantFormat,
            QuantType,
            quantize_static,
        )
    except ImportError as exc:
        raise QuantizeError(
            f"quantizing needs onnxruntime and onnx ({exc}): pip install onnxruntime onnx"
        ) from exc
    methods = {"minmax": CalibrationMethod.MinMax, "entropy": CalibrationMethod.Entropy,
               "percentile": CalibrationMethod.Percentile}
    if cfg.method not in methods:
        raise QuantizeError(f"method must be one of {', '.join(methods)}, got {cfg.method!r}")
    exclude = head_nodes(fp32)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        quantize_static(
            str(fp32), str(tmp), _Frames(frames, cfg.batch),
            quant_format=QuantFormat.QDQ, per_channel=True,
            reduce_range=cfg.reduce_range, activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8, calibrate_method=methods[cfg.method],
            nodes_to_exclude=exclude, extra_options={"CalibPercentile": cfg.percentile},
        )  # fmt: skip
        _store_recipe(tmp, cfg)
        tmp.replace(out)
    except Exception as exc:  # the quantizer raises many types
        tmp.unlink(missing_ok=True)
        raise QuantizeError(f"quantizing {fp32} failed ({type(exc).__name__}: {exc})") from exc
    logger.info("quantized %s to %s (%s; fp32: %s)", fp32.name, out, asdict(cfg), exclude)
    return out


def write_int8_beside(weights: Path = DEFAULT_WEIGHTS, size: int = FUSED_SIZE[0],
                      out_dir: Path | None = None, data_dir: Path = DEFAULT_DATA_DIR,
                      config: QuantizeRecipe | None = None) -> Path:
    """Quantize the network of ``weights``, calibrated on the validation split, wrap it
    (:func:`~active_vision.onnx_export.fuse_pre_post`) into ``out_dir`` (default: beside the
    weights) under its versioned name, and remove older int8 files of the same stem and side
    there."""
    from active_vision.training.evaluate import heldout

    cfg = config or QuantizeRecipe()
    weights = Path(weights)
    out_dir = Path(out_dir) if out_dir is not None else weights.parent
    val = heldout(data_dir, split="validation")
    if val.rgb.shape[1] != size:
        raise QuantizeError(f"validation frames are {val.rgb.shape[1]} px, the model {size} px")
    frames = calibration_frames(val.rgb, cfg.calibration_frames, cfg.seed)
    path = out_dir / int8_file_name(weights, size)
    with tempfile.TemporaryDirectory() as tmp:
        network = export_network(weights, size, Path(tmp) / "network.onnx")
        quantized = quantize_file(network, Path(tmp) / "network.int8.onnx", frames, cfg)
        fuse_file(quantized, path, size)
    for old in out_dir.glob(f"{weights.stem}-*-s{size}-x*{INT8_SUFFIX}"):
        if old != path:
            old.unlink()
            logger.info("removed stale int8 model %s", old)
    return path


def write_exports_beside(weights: Path, data_dir: Path = DEFAULT_DATA_DIR) -> None:
    """After a maker wrote ``weights``: the fp32 ONNX export and the int8 model beside it
    (stale ones of the same stem removed), each path printed, or why it was not written (the
    daemon then exports on first use, or runs fp32)."""
    from active_vision.onnx_export import OnnxExportError, write_export_beside

    try:
        print(f"wrote {write_export_beside(weights)}")
        print(f"wrote {write_int8_beside(weights, data_dir=data_dir)}")
    except OnnxExportError as exc:
        print(f"no ONNX export written beside the weights ({exc}); the daemon exports it on "
              "first use, or run `python -m active_vision.onnx_export`", file=sys.stderr)
    except QuantizeError as exc:
        print(f"no int8 model written beside the weights ({exc}); the daemon runs fp32 until "
              "`python -m active_vision.training.quantize` makes it", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    cfg, run, _ = parse_recipe_command(
        QuantizeRecipe, QuantizeRun, "python -m active_vision.training.quantize",
        "Make the int8 model of AVNet weights (static QDQ quantization of their ONNX export, "
        "calibrated on validation frames), named for the weights' sha256. Default: the "
        "shipped weights, written next to them.", read_recipe, argv, "an int8 file")
    from active_vision.onnx_export import OnnxExportError

    try:
        path = write_int8_beside(run.weights, run.size, run.out_dir, run.data_dir, cfg)
    except (QuantizeError, OnnxExportError) as exc:
        print(f"quantize: {exc}", file=sys.stderr)
        return 1
    print(path)
    return 0


__all__ = ["QuantizeError", "QuantizeRecipe", "QuantizeRun", "calibration_frames",
           "head_nodes", "quantize_file", "read_recipe", "write_exports_beside",
           "write_int8_beside"]


if __name__ == "__main__":
    raise SystemExit(main())
