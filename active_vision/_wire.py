"""The wire-format names active_vision uses, from their one home in ``shm_protocol``."""

from __future__ import annotations

from shm_protocol import (
    CHANNEL_DEPTH,
    CHANNEL_GRAY,
    CHANNEL_HEATMAP,
    DEPTH_MAX_M,
    FUSED_SHAPE,
    channel_to_depth,
    depth_to_channel,
)

__all__ = [
    "CHANNEL_DEPTH",
    "CHANNEL_GRAY",
    "CHANNEL_HEATMAP",
    "DEPTH_MAX_M",
    "FUSED_SHAPE",
    "channel_to_depth",
    "depth_to_channel",
]
