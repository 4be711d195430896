"""Pedestrian appearance option, lighting/terrain readouts and the future-occupancy mask."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rover_env.simulation import RoverSim


@pytest.fixture(scope="module")
def fixed() -> RoverSim:
    return RoverSim("inspect", pedestrian_mode="pacing")


@pytest.fixture(scope="module")
def random() -> RoverSim:
    return RoverSim("inspect", pedestrian_appearance="random", pedestrian_mode="pacing")


def test_fixed_appearance_is_the_palette_and_the_default_figure(fixed: RoverSim) -> None:
    from rover_env.pedestrians import SHIRTS

    for seed in range(3):
        fixed.reset(np.random.default_rng(seed))
        for look in fixed.pedestrian_appearance:
            assert np.min(np.abs(np.array(SHIRTS) - look.shirt).max(axis=1)) < 1e-6
            assert (look.height, look.girth, look.gait_phase) == (1.0, 1.0, 0.0)


def test_random_appearance_is_deterministic_per_seed_and_varies(random: RoverSim) -> None:
    random.reset(np.random.default_rng(1))
    first = random.pedestrian_appearance
    size1 = random.model.geom_size.copy()
    random.reset(np.random.default_rng(2))
    assert random.pedestrian_appearance != first
    assert not np.array_equal(random.model.geom_size, size1)  # girth and height applied
    random.reset(np.random.default_rng(1))
    assert random.pedestrian_appearance == first
    np.testing.assert_array_equal(random.model.geom_size, size1)
    heights = [a.height for s in range(5) for a in (random.reset(np.random.default_rng(s)) or
                                                    random.pedestrian_appearance)]
    assert min(heights) < 0.95 < 1.05 < max(heights)


def test_taller_figures_are_taller_in_the_image(random: RoverSim) -> None:
    rows = {}
    for seed in range(12):
        random.reset(np.random.default_rng(seed))
        look = random.pedestrian_appearance[0]
        px, py = random.pedestrian_positions[0]
        random.place_pedestrian(0, px, py, 0.0)
        for i in range(1, len(random.pedestrian_appearance)):
            random.place_pedestrian(i, px + 40.0, py + 40.0, 0.0)  # out of view
        random.set_rover_pose(px - 3.0, py, 0.0)
        mask = random.render_camera(segmentation=True).pedestrian_mask
        assert mask is not None and mask.any()
        rows[look.height] = np.flatnonzero(mask.any(axis=1))[0]  # top row of the figure
    low, high = min(rows), max(rows)
    assert high - low > 0.1
    assert rows[high] < rows[low]  # a taller figure's head is higher in the frame


def test_readouts_without_reaching_into_the_model(fixed: RoverSim) -> None:
    assert fixed.camera_fov == pytest.approx(math.radians(90.0))
    lights = fixed.default_lighting
    dim = lights._replace(diffuse=lights.diffuse * 0.2, head_diffuse=lights.head_diffuse * 0.2)
    fixed.reset(np.random.default_rng(0))
    bright = fixed.render_camera().rgb.astype(int).sum()
    fixed.set_lighting(dim)
    try:
        np.testing.assert_allclose(fixed.lighting.diffuse, lights.diffuse * 0.2)
        assert fixed.render_camera().rgb.astype(int).sum() < bright
    finally:
        fixed.set_lighting(fixed.default_lighting)
    assert fixed.render_camera().rgb.astype(int).sum() == bright
    assert fixed.terrain_height(*fixed.position[:2]) == pytest.approx(0.0, abs=1e-6)


def test_future_mask_covers_the_walk_and_leaves_the_sim_as_it_was(fixed: RoverSim) -> None:
    fixed.reset(np.random.default_rng(5))
    px, py = fixed.pedestrian_positions[0]
    fixed.set_rover_pose(px - 4.0, py, 0.0)
    fixed.advance(0.5)
    before = fixed.render_camera(depth=True, segmentation=True)
    positions = fixed.pedestrian_positions
    future = fixed.future_pedestrian_mask(1.5)
    after = fixed.render_camera(depth=True, segmentation=True)
    np.testing.assert_array_equal(after.rgb, before.rgb)
    np.testing.assert_array_equal(after.depth, before.depth)
    np.testing.assert_array_equal(fixed.pedestrian_positions, positions)
    assert np.all(future[before.pedestrian_mask])  # now is part of the next 1.5 s
    assert future.sum() > 1.5 * before.pedestrian_mask.sum()  # and the walk adds to it
    np.testing.assert_array_equal(fixed.future_pedestrian_mask(0.0), before.pedestrian_mask)
