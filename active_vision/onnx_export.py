"""ONNX export of the perception network, cached and versioned with its weights.

The ONNX backend (:mod:`active_vision.backends`) runs the network in ONNX Runtime from an
``.onnx`` file made from the torch weights. The file's name carries what it was made from::

    <weights stem>-<sha256 of the weights file, 16 hex>-s<frame side>-x<EXPORT_VERSION>.onnx

so a retrained weights file, another frame size or a change to how the export is done
never reuses a stale file. :func:`onnx_file_for` looks for it first next to the weights (the
package ships the file for its own weights, so a plain install needs neither ``onnx`` nor
``onnxscript``), then in the user cache (``$XDG_CACHE_HOME/roverav/active_vision/onnx``),
and otherwise exports it there on first use.

The export is generic over the model: :func:`export_onnx` takes any ``nn.Module`` and its
example inputs, and marks dimension 0 of every input and output as a dynamic batch axis
(the daemon batches over its slots). It uses the default dynamo exporter
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
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from active_vision.models import DEFAULT_WEIGHTS, load_model
from fused_image import FUSED_SIZE

logger = logging.getLogger(__name__)

EXPORT_VERSION = 1
"""Part of the file name: bump it when the export changes, so cached files are remade."""
OPSET = 18
"""ONNX opset of the export (the dynamo exporter's default range; ORT >= 1.16 runs it)."""
MAX_EXPORT_BATCH = 256
"""Upper bound the exporter is told for the dynamic batch axis."""
INPUT_NAME = "frames"
OUTPUT_NAME = "raw"
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
    return export_onnx(load_model(weights), avnet_example_inputs(size), cache_dir / name)


__all__ = [
    "EXPORT_VERSION",
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
    export_onnx(load_model(weights), avnet_example_inputs(size), path)
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

