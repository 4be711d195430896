"""Active Vision: the perception process of the two-process pipeline.

Camera frames (from the env's camera segment, a video, or a camera device) become fused
96x96x3 float32 observations - grayscale, pedestrian heatmap, depth - published over shared
memory by the ``av-daemon`` (:mod:`active_vision.daemon`).

- :class:`Perception` / :class:`PerceptionConfig`: batched frames -> fused frames.
- :class:`AVNet`, :func:`load_model`, :class:`WeightsError`: the network and its weights.
- ``python -m active_vision.dataset | train | evaluate``: data, training, quality figures.
"""

from active_vision.models import AVNet, AVNetConfig, WeightsError, load_model, save_weights
from active_vision.perception import Perception, PerceptionConfig, StageTimes

__all__ = [
    "AVNet",
    "AVNetConfig",
    "Perception",
    "PerceptionConfig",
    "StageTimes",
    "WeightsError",
    "load_model",
    "save_weights",
]
