"""The daemon's backend and precision choices, importable without torch.

av-daemon and ``active_vision.bag_fuse`` build their command lines from these before the
network loads, so that ``--help`` and a bad flag answer in about a second;
:mod:`active_vision.backends` re-exports them beside the engines that use them.
"""

from __future__ import annotations

BACKENDS: tuple[str, ...] = ("auto", "onnx", "torch")
"""Inference engines: ``auto`` (ONNX Runtime when installed, else torch), ``onnx``, ``torch``."""
PRECISIONS: tuple[str, ...] = ("fp32", "int8")
"""What a network computes in."""
PRECISION_CHOICES: tuple[str, ...] = ("auto", *PRECISIONS)
"""What may be asked for: a precision, or ``auto`` (the faster one that agrees with fp32)."""
DEFAULT_PRECISION = "auto"
"""int8 where the int8 model agrees with fp32 on this CPU and is faster, else fp32
(:mod:`active_vision.precision`; the ratios: benchmarks/RESULTS.md, "Precision: int8
against fp32")."""
