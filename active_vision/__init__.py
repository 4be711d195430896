"""Active Vision: the perception process of the two-process pipeline.

Camera frames (from the env's camera segment, a video, or a camera device) become fused
96x96x3 float32 observations - grayscale, pedestrian heatmap, depth - published over shared
memory by the ``av-daemon`` (:mod:`active_vision.daemon`).

- :class:`Perception` / :class:`PerceptionConfig`: batched frames -> fused frames.
- ``BACKENDS`` / :class:`BackendError`: the network runs in ONNX Runtime or eager torch
  (``PerceptionConfig.backend``, ``av-daemon --backend``; :mod:`active_vision.backends`).
- :class:`AVNet`, :func:`load_model`, :class:`WeightsError`: the network and its weights.
- ``python -m active_vision.dataset | train | evaluate``: data, training, quality figures.
"""

import os as _os

# torch's OpenMP worker threads spin while they wait. On a machine shared with other work
# (2 cores, another busy process) a 2-thread training step measured 10x slower than a
# 1-thread one because of that spinning; with passive waiting 2 threads were as fast as 1
# or faster. Only a default: an OMP_WAIT_POLICY set by the user wins. It must be set before
# OpenMP starts, hence here, before torch is imported through the modules below.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from active_vision.backends import BACKENDS, BackendError
from active_vision.models import AVNet, AVNetConfig, WeightsError, load_model, save_weights
from active_vision.perception import Perception, PerceptionConfig, StageTimes

__all__ = [
    "BACKENDS",
    "AVNet",
    "AVNetConfig",
    "BackendError",
    "Perception",
    "PerceptionConfig",
    "StageTimes",
    "WeightsError",
    "load_model",
    "save_weights",
]
