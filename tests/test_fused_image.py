"""fused_image: the fused image's size, channel meanings and depth encoding."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import fused_image
from fused_image import (
    CHANNEL_DEPTH,
    CHANNEL_GRAY,
    CHANNEL_HEATMAP,
    DEPTH_MAX_M,
    FUSED_DTYPE,
    FUSED_SHAPE,
    FUSED_SIZE,
    channel_to_depth,
    depth_to_channel,
)


def test_public_api_is_exported() -> None:
    for name in fused_image.__all__:
        assert hasattr(fused_image, name), name


def test_size_and_channels_are_the_seeds() -> None:
    assert FUSED_SIZE == (96, 96)  # seed: RoverEnvFused(size=(96, 96))
    assert FUSED_SHAPE == (96, 96, 3) and FUSED_DTYPE == np.dtype("<f4")
    assert (CHANNEL_GRAY, CHANNEL_HEATMAP, CHANNEL_DEPTH) == (0, 1, 2)


def test_depth_convention() -> None:
    d = np.array([0.0, 2.5, 5.0, 10.0, 25.0, -1.0, np.inf, np.nan], dtype=np.float32)
    c = depth_to_channel(d)
    assert c.dtype == np.float32
    np.testing.assert_allclose(c, [1.0, 0.75, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0])
    assert DEPTH_MAX_M == 10.0
    np.testing.assert_allclose(channel_to_depth([1.0, 0.5, 0.0]), [0.0, 5.0, 10.0])


@given(st.floats(min_value=0.0, max_value=10.0))
def test_depth_round_trip(metres: float) -> None:
    back = float(channel_to_depth(depth_to_channel(metres)))
    assert abs(back - metres) < 1e-5 * 10
