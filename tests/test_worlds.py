"""Worlds: the seed's rectangles to the metre, names and aliases, obstacle-free sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

import rover_env  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from rover_env import WORLD_NAMES, make_world
from rover_env.rover import SPAWN_CLEARANCE
from rover_env.worlds import Box, Circle, Rect, canonical_world_name

# The seed's "World-Specific Configuration", copied here independently of constants.py.
SEED_RECTANGLES = {
    "inspect": ((-27, -19), (-27, -19), (-27, -19), (-27, -19), (-29, -13), (-29, -17)),
    "moon": ((-4, 4), (-4, 4), (-4, 4), (-4, 4), (-20, 10), (-20, 20)),
    "maze": ((-4, 4), (-4, 4), (-4, 4), (-4, 4), (-30, 30), (-30, 30)),
}


def test_world_names_are_the_seeds() -> None:
    assert set(WORLD_NAMES) == {"inspect", "moon", "maze"}


@pytest.mark.parametrize("name", sorted(SEED_RECTANGLES))
def test_rectangles_equal_the_seed(name: str) -> None:
    sx, sy, gx, gy, bx, by = SEED_RECTANGLES[name]
    world = make_world(name)
    assert world.spawn == Rect(sx, sy)
    assert world.goal == Rect(gx, gy)
    assert world.bounds == Rect(bx, by)


def test_island_is_moon() -> None:
    assert canonical_world_name("island") == "moon"
    assert make_world("island") is make_world("moon")


def test_unknown_world_lists_the_choices() -> None:
    with pytest.raises(ValueError, match="inspect.*island.*maze.*moon"):
        make_world("mars")


@pytest.mark.parametrize("name", WORLD_NAMES)
def test_sampled_points_never_overlap_obstacles(name: str) -> None:
    world = make_world(name)
    rng = np.random.default_rng(0)
    points = np.array([world.sample_free(rng, world.spawn, SPAWN_CLEARANCE) for _ in range(500)])
    assert np.all(world.clearance_many(points[:, 0], points[:, 1]) > SPAWN_CLEARANCE)
    assert np.all(points >= [world.spawn.x[0], world.spawn.y[0]])
    assert np.all(points <= [world.spawn.x[1], world.spawn.y[1]])
    # Uniform over the free area: both halves of the rectangle get samples.
    mid = 0.5 * (world.spawn.x[0] + world.spawn.x[1])
    assert 100 < np.sum(points[:, 0] < mid) < 400


@pytest.mark.parametrize("name", WORLD_NAMES)
def test_every_world_has_obstacles_in_or_near_the_spawn_area(name: str) -> None:
    world = make_world(name)
    near = world.spawn.expanded(3.0)
    assert any(near.contains(o.x, o.y) for o in world.obstacles)


def test_footprint_distances() -> None:
    assert Circle(0.0, 0.0, 1.0).distance(3.0, 0.0) == pytest.approx(2.0)
    assert Circle(0.0, 0.0, 1.0).distance(0.0, 0.0) == pytest.approx(-1.0)
    box = Box(0.0, 0.0, 2.0, 1.0, yaw=math.pi / 2)  # long side along y after the turn
    assert box.distance(0.0, 3.0) == pytest.approx(1.0)
    assert box.distance(2.0, 0.0) == pytest.approx(1.0)
    world = make_world("maze")
    xs, ys = np.array([0.0, 3.0, 5.0]), np.array([0.0, 0.0, 5.0])
    vector = world.clearance_many(xs, ys)
    scalar = [min(o.distance(x, y) for o in world.obstacles) for x, y in zip(xs, ys, strict=True)]
    np.testing.assert_allclose(vector, scalar)


def test_ray_distances_cast_against_the_footprints_as_mujoco_casts_the_scenery() -> None:
    """``WorldSpec.ray_distances`` (the unmapped scan's map) against hand-worked rays, and
    against MuJoCo's own rays on the maze's scenery (groups 0 only: no pedestrians) from
    poses all over the maze."""
    import mujoco

    from rover_env.simulation import RoverSim

    world = make_world("maze")
    # from (-2, 0): the inner wall x = 0 (0.2 m thick) ahead, the outer wall x = -6 behind
    d = world.ray_distances(-2.0, 0.0, np.array([0.0, math.pi]), 12.0)
    np.testing.assert_allclose(d, [1.9, 3.9])
    # from (-3, 0) along +y: the wall y = 2, x in [-6, -2]
    assert world.ray_distances(-3.0, 0.0, np.array([math.pi / 2]), 12.0)[0] == pytest.approx(1.9)
    assert world.ray_distances(-3.0, 0.0, np.array([math.pi / 2]), 1.0)[0] == 1.0  # out of reach
    assert world.ray_distances(0.0, 0.0, np.array([1.0]), 12.0)[0] == 0.0  # inside the wall
    sim = RoverSim("maze")
    m, d_ = sim.model, sim.data
    scenery = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    geom = np.zeros(1, np.int32)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, y = world.sample_free(rng, world.goal, 0.4)
        angles = rng.uniform(-math.pi, math.pi, 8)
        ours = world.ray_distances(x, y, angles, 12.0)
        for a, expected in zip(angles, ours, strict=True):
            ray = np.array([math.cos(a), math.sin(a), 0.0])
            dist = mujoco.mj_ray(m, d_, np.array([x, y, 0.3]), ray, scenery, 1, -1, geom)
            assert (dist if 0 <= dist <= 12.0 else 12.0) == pytest.approx(expected, abs=1e-6)


def test_moon_has_terrain_steep_enough_to_flip() -> None:
    world = make_world("moon")
    hf = world.heightfield
    assert hf is not None
    cell = 2 * hf.radius_x / (hf.elevation.shape[1] - 1)
    heights = hf.elevation * hf.z_top
    slope = np.degrees(np.arctan(np.abs(np.diff(heights, axis=1)) / cell)).max()
    assert slope > 40.0
    # ... while the spawn square stays gentle.
    h = [world.ground_height(x, y) for x in np.linspace(-4, 4, 9) for y in np.linspace(-4, 4, 9)]
    assert max(h) - min(h) < 1.0


def test_moon_ground_between_its_hills_is_gentle_at_the_metre_scale() -> None:
    """Regolith slopes a few degrees from one metre to the next; a ground of facets each
    tilted differently (13 degrees median at 0.25 m of random height per cell) left the
    camera's depth nothing to read (docs/decisions.md, "The moon's roughness")."""
    hf = make_world("moon").heightfield
    assert hf is not None
    cell = 2 * hf.radius_x / (hf.elevation.shape[1] - 1)
    heights = hf.elevation * hf.z_top
    slopes = np.degrees(np.arctan(np.abs(np.diff(heights, axis=1)) / cell))
    assert np.median(slopes) < 8.0


def test_moon_ground_height_matches_the_terrain_mujoco_collides_with() -> None:
    """Spawn heights, rock placement and dataset poses use WorldSpec.ground_height: it must
    describe the same surface MuJoCo builds from the height field (rows were once mirrored
    in y, which put the rover up to half a metre inside the hills)."""
    import mujoco

    from rover_env.simulation import RoverSim

    sim = RoverSim("moon")
    m, d = sim.model, sim.data
    terrain = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
    rng = np.random.default_rng(0)
    errors = []
    geom = np.zeros(1, np.int32)
    for _ in range(200):
        x, y = rng.uniform(-15, 8), rng.uniform(-18, 18)
        dist = mujoco.mj_ray(m, d, np.array([x, y, 50.0]), np.array([0.0, 0.0, -1.0]),
                             None, 1, -1, geom)  # fmt: skip
        if geom[0] == terrain:
            errors.append(abs(sim.world.ground_height(x, y) - (50.0 - dist)))
    assert len(errors) > 150
    # bilinear lookup against MuJoCo's two triangles per 1 m cell: centimetres, not metres
    assert np.median(errors) < 0.05 and max(errors) < 0.3


def test_moon_ground_shows_texture_to_the_camera() -> None:
    """The camera must see grain on the moon's ground: with the plane floors' texrepeat one
    checker square was stretched over 17 m of height field and the ground right in front of
    the rover rendered as flat grey (mean |Laplacian| 0.1-0.4 grey levels on the bottom rows,
    against 3-6 with metre squares and grit), leaving monocular depth nothing to measure."""
    import cv2

    from rover_env.simulation import RoverSim

    sim = RoverSim("moon", camera_size=(96, 96))
    sim.reset(np.random.default_rng(0))
    grain = []
    for yaw in np.linspace(-3.0, 3.0, 7):
        sim.set_rover_pose(0.0, 0.0, float(yaw), z=sim.terrain_height(0.0, 0.0) + 0.3)
        sim.advance(0.3)
        gray = cv2.cvtColor(sim.render_camera().rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
        grain.append(float(np.abs(cv2.Laplacian(gray[-30:], cv2.CV_32F)).mean()))
    sim.close()
    assert min(grain) > 1.5, grain
