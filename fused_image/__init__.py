"""fused_image: what the fused image means, shared by its maker and its readers.

The av-daemon (``active_vision``) makes the fused image from the forward camera's frame;
the fused envs (``rover_env``) read it as ``obs["fused_image"]``, the reward reads its
heatmap, and the zoo's fused students read its depth. Neither side imports the other, and
the wire format (``shm_protocol``) carries bytes of any ``(H, W, C)`` shape without knowing
this one: the meaning lives here, imported by all of them. Needs numpy only.

The image is ``FUSED_SHAPE`` = ``(96, 96, 3)`` float32 (the seed's ``RoverEnvFused(size=(96,
96))`` and ``96 * 96 * 3 float32`` segment), every channel in [0, 1]:

    channel 0  CHANNEL_GRAY     luminance of the camera frame
    channel 1  CHANNEL_HEATMAP  pedestrian heatmap (the reward reads it)
    channel 2  CHANNEL_DEPTH    depth, near is bright: depth_to_channel(metres)

Other sizes are allowed (an env's ``size=``, the daemon's ``--size``, a multiple of 16 and
square for the daemon); ``FUSED_SIZE`` is the default everywhere.
"""

from __future__ import annotations

from typing import Any

import numpy as np

FUSED_SIZE: tuple[int, int] = (96, 96)
"""Default (height, width) of the fused image and of the camera frame it is made from.
Seed: ``RoverEnvFused(size=(96, 96))``."""
FUSED_SHAPE: tuple[int, int, int] = (*FUSED_SIZE, 3)
"""``(H, W, C)`` of the default fused image. Seed: ``96 * 96 * 3 float32`` at offset 12 of
the fused segment."""
FUSED_DTYPE: np.dtype[Any] = np.dtype("<f4")
"""The fused image's dtype: little-endian float32."""

CHANNEL_GRAY = 0
"""Luminance of the camera frame, in [0, 1]: ``LUMA_WEIGHTS`` over its RGB, divided by 255."""
LUMA_WEIGHTS: tuple[float, float, float] = (0.299, 0.587, 0.114)
"""ITU-R BT.601 luminance weights of R, G, B (what OpenCV's ``COLOR_RGB2GRAY`` uses)."""
CHANNEL_HEATMAP = 1
"""Pedestrian heatmap, in [0, 1] (the reward reads this channel). Seed 001 calls channel 1
depth; seeds 000 and 002 and the reward's use of it as the heatmap settle it."""
CHANNEL_DEPTH = 2
"""Depth as ``depth_to_channel(metres)``: near is bright, see below."""

DEPTH_MAX_M = 10.0
"""Far limit of the depth channel in metres: depth at or beyond it encodes as 0.0."""


def depth_to_channel(metres: Any) -> np.ndarray:
    """Metric depth to the depth channel: ``clip(1 - d / DEPTH_MAX_M, 0, 1)`` as float32.

    1.0 is at the camera, 0.0 at or beyond ``DEPTH_MAX_M`` (10 m); negative depths clip to
    1.0. NaN (no return) and +inf encode as 0.0, "far", so no NaN reaches an observation.
    Vectorised: returns an array of the input's shape (0-d for a scalar).
    """
    d = np.asarray(metres, dtype=np.float32)
    out = np.clip(np.float32(1.0) - d / np.float32(DEPTH_MAX_M), 0.0, 1.0)
    return np.asarray(np.where(np.isnan(out), np.float32(0.0), out), dtype=np.float32)


def channel_to_depth(value: Any) -> np.ndarray:
    """Depth channel back to metres: ``(1 - v) * DEPTH_MAX_M`` as float32.

    Values are clipped to [0, 1] first, so 0.0 reads as ``DEPTH_MAX_M`` ("at or beyond the
    far limit"): the encoding cannot tell 10 m from 50 m.
    """
    v = np.clip(np.asarray(value, dtype=np.float32), 0.0, 1.0)
    return np.asarray((np.float32(1.0) - v) * np.float32(DEPTH_MAX_M), dtype=np.float32)


__all__ = [
    "CHANNEL_DEPTH",
    "CHANNEL_GRAY",
    "CHANNEL_HEATMAP",
    "DEPTH_MAX_M",
    "FUSED_DTYPE",
    "FUSED_SHAPE",
    "FUSED_SIZE",
    "LUMA_WEIGHTS",
    "channel_to_depth",
    "depth_to_channel",
]
