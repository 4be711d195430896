"""Active Vision: the perception process of the two-process pipeline.

Camera frames (from the env's camera segment, a video, or a camera device) become fused
96x96x3 float32 observations - grayscale, pedestrian heatmap, depth - published over shared
memory by the ``av-daemon`` (:mod:`active_vision.daemon`).

- :class:`Perception` / :class:`PerceptionConfig`: batched frames -> fused frames.
- ``BACKENDS`` / :class:`BackendError`: the network runs in ONNX Runtime or eager torch
  (``PerceptionConfig.backend``, ``av-daemon --backend``; :mod:`active_vision.backends`).
- :class:`AVNet`, :func:`load_model`, :class:`WeightsError`: the network and its weights.
- :func:`spawn_daemon` / :func:`start_daemon` / :class:`ChildProcess`: run an av-daemon from
  another process (:mod:`active_vision.launcher`; standard library only, no torch).
- :class:`SlotHistory`: the daemon's per-slot K-frame history, cut at episode starts.
- :class:`Predictor`, :class:`PredictNet`, :func:`load_predictor`: ``--heatmap predict``
  (occupancy over the next 1.5 s from the last K frames).
- ``python -m active_vision.training.dataset | train | predict_train | evaluate``: data, training,
  quality figures.

The torch-backed names load on first use, so ``from active_vision import spawn_daemon``
(a supervisor, a test) does not import torch.
"""

import os as _os

# torch's OpenMP worker threads spin while they wait. On a machine shared with other work
# that spinning makes a 2-thread training step many times slower than a 1-thread one; with
# passive waiting 2 threads are as fast as 1 or faster. Only a default: an OMP_WAIT_POLICY
# set by the user wins. It must be set before OpenMP starts, hence here, before torch is
# imported through the modules below.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import importlib as _importlib
from typing import Any as _Any

from active_vision.launcher import (
    READY_MARKER,
    ChildProcess,
    DaemonStartError,
    spawn_daemon,
    start_daemon,
)

_LAZY = {
    "BACKENDS": "active_vision.choices",
    "BackendError": "active_vision.backends",
    "AVNet": "active_vision.models",
    "AVNetConfig": "active_vision.models",
    "WeightsError": "active_vision.models",
    "load_model": "active_vision.models",
    "save_weights": "active_vision.models",
    "Perception": "active_vision.perception",
    "PerceptionConfig": "active_vision.perception",
    "StageTimes": "active_vision.perception",
    "SlotHistory": "active_vision.history",
    "PredictNet": "active_vision.predict",
    "Predictor": "active_vision.predict",
    "load_predictor": "active_vision.predict",
}


def __getattr__(name: str) -> _Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'active_vision' has no attribute {name!r}")
    return getattr(_importlib.import_module(module), name)


__all__ = [
    "BACKENDS",
    "READY_MARKER",
    "AVNet",
    "AVNetConfig",
    "BackendError",
    "ChildProcess",
    "DaemonStartError",
    "Perception",
    "PerceptionConfig",
    "PredictNet",
    "Predictor",
    "SlotHistory",
    "StageTimes",
    "WeightsError",
    "load_model",
    "load_predictor",
    "save_weights",
    "spawn_daemon",
    "start_daemon",
]
