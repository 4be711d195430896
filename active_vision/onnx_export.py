"""ONNX export of the perception network, cached and versioned with its weights.

The ONNX backend (:mod:`active_vision.backends`) runs the network in ONNX Runtime from an
``.onnx`` file made from the torch weights. The file maps camera frames straight to fused
frames, so a frame costs one ONNX Runtime call and no other array operation:

- input ``frames``: uint8 ``(batch, S, S, 3)`` RGB, as the camera segment holds them;
- output ``fused``: float32 ``(batch, S, S, 3)``, the fused image (:mod:`fused_image`):
  luminance, the heatmap (sigmoid of the network's logit) and the depth channel (of its log
  depth), each in [0, 1].

:func:`fuse_pre_post` wraps the network's own graph (float32 ``(batch, 3, S, S)`` in [0, 1]
to its raw ``(batch, 2, S, S)`` maps) in those conversions, as ONNX nodes named ``fused/...``;
the int8 model (:mod:`active_vision.training.quantize`) is the quantized network wrapped the
same way, so the conversions stay float32 in both. The file's name carries what it was made
from::

    <weights stem>-<sha256 of the weights file, 16 hex>-s<frame side>-x<EXPORT_VERSION>.onnx

so a retrained weights file, another frame size or a change to how the export is done
never reuses a stale file. :func:`onnx_file_for` looks for it first next to the weights (the
package ships the file for its own weights, so a plain install needs neither ``onnx`` nor
``onnxscript``), then in the user cache (``$XDG_CACHE_HOME/roverav/active_vision/onnx``),
and otherwise exports it there on first use.

The export of the network (:func:`export_onnx`) is generic over the model: it takes any
``nn.Module`` and its example inputs, and marks dimension 0 of every input and output as a
dynamic batch axis (the daemon batches over its slots). It uses the default dynamo exporter
(``torch.onnx.export(..., dynamo=True)``); the legacy TorchScript exporter writes float64
initializers that ONNX Runtime's CPU convolution rejects. Exporting needs the ``onnx`` and
``onnxscript`` packages (the ``onnx`` extra: ``pip install 'roverav[onnx]'``).

``python -m active_vision.training.train`` writes the export beside the weights it trains; re-make
the shipped file by hand with::

    python -m active_vision.onnx_export            # writes next to the shipped weights
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import logging
import math
import os
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from active_vision.models import DEFAULT_WEIGHTS, HEAD_DEPTH, HEAD_HEATMAP, load_model
from fused_image import (
    CHANNEL_DEPTH,
    CHANNEL_GRAY,
    CHANNEL_HEATMAP,
    DEPTH_MAX_M,
    FUSED_SIZE,
    LUMA_WEIGHTS,
)

logger = logging.getLogger(__name__)

EXPORT_VERSION = 2
"""Part of the file name: bump it when the export changes, so cached files are remade.
2: uint8 frames in, fused frames out (1: the network's float input and raw maps)."""
OPSET = 18
"""ONNX opset of the export (the dynamo exporter's default range; ORT >= 1.16 runs it)."""
MAX_EXPORT_BATCH = 256
"""Upper bound the exporter is told for the dynamic batch axis."""
INPUT_NAME = "frames"
OUTPUT_NAME = "raw"
FUSED_OUTPUT_NAME = "fused"
"""The output of a file made by :func:`fuse_pre_post` (its input keeps ``INPUT_NAME``)."""
FUSED_NODE_PREFIX = "fused/"
"""Names of the nodes and tensors :func:`fuse_pre_post` adds start with this."""
ONNX_CACHE_DIR = (
    Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    / "roverav" / "active_vision" / "onnx"
)
"""Where exports of weights other than the shipped ones are cached."""
_CHATTY_LOGGERS = ("onnx_ir", "onnxscript", "torch.onnx")
"""Loggers of the exporter that report every graph pass at INFO (kept at WARNING)."""
EXPORT_EXTRA_HINT = (
    "Install the export tools with `pip install onnx onnxscript` (the `onnx` extra of "
    "roverav), or run with --backend torch."
)


class OnnxExportError(RuntimeError):
    """The ONNX file for a weights file is not there and cannot be made here."""


def weights_digest(path: Path) -> str:
    """First 16 hex digits of the sha256 of the file at ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def onnx_file_name(weights: Path, size: int) -> str:
    """The versioned file name of the export of ``weights`` at frame side ``size``."""
    return f"{weights.stem}-{weights_digest(weights)}-s{size}-x{EXPORT_VERSION}.onnx"


INT8_SUFFIX = ".int8.onnx"
"""Ending of the int8 (quantized) model's file name in place of ``.onnx``."""


def int8_file_name(weights: Path, size: int) -> str:
    """The file name of the int8 model quantized from the export of ``weights``
    (``<export name without .onnx>.int8.onnx``; made by ``python -m
    active_vision.training.quantize``)."""
    return onnx_file_name(weights, size).removesuffix(".onnx") + INT8_SUFFIX


def int8_file_for(weights: Path | None = None, size: int = 96,
                  cache_dir: Path | None = None) -> Path | None:
    """The int8 model of ``weights`` (default: the shipped ones) next to them or in
    ``cache_dir`` (default :data:`ONNX_CACHE_DIR`), or None: it is never made on the fly
    (its calibration needs rendered validation frames)."""
    weights = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not weights.is_file():
        return None
    name = int8_file_name(weights, size)
    cache_dir = Path(cache_dir) if cache_dir is not None else ONNX_CACHE_DIR
    for candidate in (weights.parent / name, cache_dir / name):
        if candidate.is_file():
            return candidate
    return None


def _output_names(model: nn.Module, n_out: int) -> list[str]:
    names = getattr(model, "onnx_output_names", None)
    if names:
        return list(names)
    return [OUTPUT_NAME] if n_out == 1 else [f"{OUTPUT_NAME}{i}" for i in range(n_out)]


def export_onnx(model: nn.Module, example_inputs: Sequence[torch.Tensor], path: Path,
                input_names: Sequence[str] | None = None) -> Path:
    """Export ``model`` (eval mode) to ``path`` with a dynamic batch axis on every input.

    :param example_inputs: one tensor per ``forward`` argument; their shapes, except
        dimension 0, are fixed in the graph.
    :param input_names: names of the graph's inputs (default ``frames``, ``frames1``, ...).
    :raises OnnxExportError: ``onnx``/``onnxscript`` are missing, or the export failed.
    """
    try:
        import onnx  # noqa: F401
        import onnxscript  # noqa: F401
    except ImportError as exc:
        raise OnnxExportError(
            f"exporting the perception network to ONNX needs the onnx and onnxscript "
            f"packages ({exc}). {EXPORT_EXTRA_HINT}"
        ) from exc
    inputs = tuple(example_inputs)
    if input_names is None:
        input_names = [INPUT_NAME] + [f"{INPUT_NAME}{i}" for i in range(1, len(inputs))]
    batch = torch.export.Dim("batch", min=1, max=MAX_EXPORT_BATCH)
    model.eval()
    with torch.no_grad():
        outs = model(*inputs)
    n_out = len(outs) if isinstance(outs, tuple | list) else 1
    output_names = _output_names(model, n_out)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    # The exporter prints its progress on stdout, where the daemon's peers read its ready
    # line: keep it off stdout and put it in the log instead.
    chatter = io.StringIO()
    quiet = [logging.getLogger(n) for n in _CHATTY_LOGGERS]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.WARNING)
    try:
        with contextlib.redirect_stdout(chatter):
            program = torch.onnx.export(
                model, inputs, dynamo=True, opset_version=OPSET,
                input_names=list(input_names), output_names=output_names,
                dynamic_shapes=tuple({0: batch} for _ in inputs),
            )  # fmt: skip
            program.save(str(tmp))
        tmp.replace(path)
    except Exception as exc:  # the exporter raises many types
        tmp.unlink(missing_ok=True)
        raise OnnxExportError(
            f"exporting {type(model).__name__} to ONNX failed ({type(exc).__name__}: {exc}). "
            "Run with --backend torch meanwhile."
        ) from exc
    finally:
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
    logger.debug("exporter output:\n%s", chatter.getvalue())
    logger.info("exported %s to %s", type(model).__name__, path)
    return path


def fuse_pre_post(model: Any, size: int) -> Any:
    """The ``onnx.ModelProto`` ``model`` of the network (float32 ``(batch, 3, S, S)`` in
    [0, 1] to raw ``(batch, 2, S, S)``: heatmap logit, log depth), wrapped to take uint8
    ``(batch, S, S, 3)`` frames and give the fused frames (see the module docstring). The
    network's nodes are kept as they are (fp32 or quantized); ``model`` is changed in place
    and returned.

    The conversions are built from ops ONNX Runtime runs fast on these shapes: the
    luminance is a MatMul of the three planes, the depth channel ``clip(1 - exp(min(log_d,
    log DEPTH_MAX_M)) / DEPTH_MAX_M, 0, 1)``, and one Transpose interleaves the channels.
    (A 1x1 Conv, a broadcast Mul over the channel axis, or per-element ops on NHWC
    tensors each cost more than the network's pre- and post-processing in torch.)
    """
    from onnx import TensorProto, helper, numpy_helper

    graph = model.graph
    if len(graph.input) != 1 or len(graph.output) != 1:
        raise OnnxExportError(f"expected a network with one input and one output, found "
                              f"{len(graph.input)} and {len(graph.output)}")
    net_in, net_out = graph.input[0].name, graph.output[0].name
    x = f"{FUSED_NODE_PREFIX}x"
    for node in graph.node:
        for i, name in enumerate(node.input):
            if name == net_in:
                node.input[i] = x

    def t(name: str) -> str:
        return FUSED_NODE_PREFIX + name

    def const(name: str, value: Any, dtype: Any = np.float32) -> None:
        graph.initializer.append(numpy_helper.from_array(np.asarray(value, dtype), t(name)))

    def node(op: str, inputs: list[str], outputs: list[str], **attrs: Any) -> Any:
        return helper.make_node(op, inputs, outputs, name=t(outputs[0].removeprefix(
            FUSED_NODE_PREFIX)), **attrs)

    const("inv255", 1.0 / 255.0)
    const("luma", np.asarray(LUMA_WEIGHTS).reshape(1, 3))
    const("flat", [0, 3, -1], np.int64)
    const("plane", [0, 1, size, size], np.int64)
    const("split", [1, 1], np.int64)
    const("log_max", math.log(DEPTH_MAX_M))
    const("neg_inv_max", -1.0 / DEPTH_MAX_M)
    const("zero", 0.0)
    const("one", 1.0)
    heads = ["", ""]
    heads[HEAD_HEATMAP], heads[HEAD_DEPTH] = t("logit"), t("log_depth")
    channels = ["", "", ""]
    channels[CHANNEL_GRAY], channels[CHANNEL_HEATMAP] = t("gray"), t("heat")
    channels[CHANNEL_DEPTH] = t("depth")
    pre = [
        node("Cast", [INPUT_NAME], [t("frames_f")], to=TensorProto.FLOAT),
        node("Transpose", [t("frames_f")], [t("nchw")], perm=[0, 3, 1, 2]),
        node("Mul", [t("nchw"), t("inv255")], [x]),
        node("Reshape", [x, t("flat")], [t("x_flat")]),
        node("MatMul", [t("luma"), t("x_flat")], [t("gray_flat")]),
        node("Reshape", [t("gray_flat"), t("plane")], [t("gray")]),
    ]
    post = [
        node("Split", [net_out, t("split")], heads, axis=1),
        node("Sigmoid", [t("logit")], [t("heat")]),
        node("Min", [t("log_depth"), t("log_max")], [t("log_depth_max")]),
        node("Exp", [t("log_depth_max")], [t("metres")]),
        node("Mul", [t("metres"), t("neg_inv_max")], [t("neg_scaled")]),
        node("Add", [t("neg_scaled"), t("one")], [t("near")]),
        node("Clip", [t("near"), t("zero"), t("one")], [t("depth")]),
        node("Concat", channels, [t("planes")], axis=1),
        node("Transpose", [t("planes")], [FUSED_OUTPUT_NAME], perm=[0, 2, 3, 1]),
    ]
    nodes = [*pre, *graph.node, *post]
    del graph.node[:]
    graph.node.extend(nodes)
    del graph.input[:], graph.output[:]
    graph.input.append(helper.make_tensor_value_info(
        INPUT_NAME, TensorProto.UINT8, ["batch", size, size, 3]))
    graph.output.append(helper.make_tensor_value_info(
        FUSED_OUTPUT_NAME, TensorProto.FLOAT, ["batch", size, size, 3]))
    # shapes recorded for the network's old input/output names would now be stale
    keep = [v for v in graph.value_info if v.name not in (net_in, net_out)]
    del graph.value_info[:]
    graph.value_info.extend(keep)
    return model


def fuse_file(network: Path, out: Path, size: int) -> Path:
    """Write the network ONNX file ``network`` wrapped by :func:`fuse_pre_post` to ``out``
    (atomically; the model's metadata, such as a quantization recipe, is kept)."""
    import onnx

    model = fuse_pre_post(onnx.load(str(network)), size)
    onnx.checker.check_model(model)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        onnx.save(model, str(tmp))
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


def export_network(weights: Path, size: int, path: Path) -> Path:
    """The AVNet of ``weights`` alone (float input, raw maps out: what the quantizer
    quantizes), exported to ``path``."""
    return export_onnx(load_model(weights), avnet_example_inputs(size), path)


def export_fused(weights: Path, size: int, path: Path) -> Path:
    """The fp32 file the ONNX backend runs: the network of ``weights`` exported and wrapped
    by :func:`fuse_pre_post`, written to ``path``."""
    with tempfile.TemporaryDirectory() as tmp:
        network = export_network(weights, size, Path(tmp) / "network.onnx")
        try:
            return fuse_file(network, path, size)
        except Exception as exc:  # onnx raises its own checker/validation types
            raise OnnxExportError(f"wrapping the export of {weights} failed "
                                  f"({type(exc).__name__}: {exc})") from exc


def avnet_example_inputs(size: int) -> tuple[torch.Tensor]:
    """Example input of :class:`~active_vision.models.AVNet` at frame side ``size``."""
    return (torch.rand(1, 3, size, size),)


def onnx_file_for(weights: Path | None = None, size: int = FUSED_SIZE[0], *, export: bool = True,
                  cache_dir: Path | None = None) -> Path:
    """The ONNX file of ``weights`` (default: the shipped ones) at frame side ``size``.

    Looks next to the weights, then in ``cache_dir`` (default :data:`ONNX_CACHE_DIR`);
    when neither holds it and ``export`` is True, exports it into ``cache_dir``.

    :raises OnnxExportError: not found and ``export`` is False or the export failed.
    :raises active_vision.models.WeightsError: the weights file is missing or corrupt.
    """
    weights = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not weights.is_file():
        load_model(weights)  # raises the named WeightsError with what to do
    name = onnx_file_name(weights, size)
    cache_dir = Path(cache_dir) if cache_dir is not None else ONNX_CACHE_DIR
    for candidate in (weights.parent / name, cache_dir / name):
        if candidate.is_file():
            return candidate
    if not export:
        raise OnnxExportError(
            f"no ONNX export of {weights} (looked for {name} next to it and in {cache_dir})."
        )
    logger.info("no ONNX export of %s yet: exporting it to %s (once)", weights, cache_dir)
    return export_fused(weights, size, cache_dir / name)


__all__ = [
    "EXPORT_VERSION",
    "FUSED_NODE_PREFIX",
    "FUSED_OUTPUT_NAME",
    "export_fused",
    "export_network",
    "fuse_file",
    "fuse_pre_post",
    "ONNX_CACHE_DIR",
    "OnnxExportError",
    "avnet_example_inputs",
    "INT8_SUFFIX",
    "export_onnx",
    "int8_file_for",
    "int8_file_name",
    "onnx_file_for",
    "onnx_file_name",
    "weights_digest",
    "write_export_beside",
]


def write_export_beside(weights: Path, size: int = FUSED_SIZE[0],
                        out_dir: Path | None = None) -> Path:
    """Export ``weights`` into ``out_dir`` (default: beside them) under its versioned name
    and remove older exports of the same stem and size there (what ships with the package).

    :raises OnnxExportError: the export tools are missing or the export failed.
    """
    weights = Path(weights)
    out_dir = Path(out_dir) if out_dir is not None else weights.parent
    path = out_dir / onnx_file_name(weights, size)
    export_fused(weights, size, path)
    for old in out_dir.glob(f"{weights.stem}-*-s{size}-x*.onnx"):
        if old != path and not old.name.endswith(INT8_SUFFIX):  # those: quantize's to tend
            old.unlink()
            logger.info("removed stale export %s", old)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m active_vision.onnx_export",
        description="Export AVNet weights to ONNX, named for the weights' sha256 (see the "
                    "module docstring). Default: the shipped weights, written next to them.")
    p.add_argument("--weights", type=Path, default=DEFAULT_WEIGHTS)
    p.add_argument("--size", type=int, default=FUSED_SIZE[0], help="frame side (a multiple of 16)")
    p.add_argument("--out-dir", type=Path, default=None,
                   help="directory (default: the weights file's own)")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        path = write_export_beside(a.weights, a.size, a.out_dir)
    except OnnxExportError as exc:
        print(f"onnx_export: {exc}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

