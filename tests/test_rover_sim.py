"""RoverSim: driving, LIDAR, camera (depth, pedestrian mask), pedestrians, contacts."""

from __future__ import annotations

import math

import numpy as np
import pytest

import rover_env  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from rover_env import WORLD_NAMES, RoverSim, rover
from rover_env.pedestrians import SPEED_RANGE

# maze: outer walls are 0.2 m thick centred on +-6 m, so the inner face is at 5.9 m.
WALL_FACE = 5.9
CONTROL_DT = 0.05


@pytest.fixture(scope="module")
def maze() -> RoverSim:
    sim = RoverSim("maze", camera_size=(96, 96), pedestrian_mode="pacing")
    yield sim
    sim.close()


def _park_pedestrians(sim: RoverSim) -> None:
    """Stand every pedestrian in the maze's far corner, out of the way."""
    for i in range(sim.pedestrians.n):
        sim.place_pedestrian(i, -5.4 + 0.6 * i, -5.4, 0.0)


def test_rover_drives_1m_in_about_a_second(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(1))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)  # open corridor along +x
    start = maze.position
    maze.set_command(1.0, 0.0)
    steps = 0
    while np.linalg.norm(maze.position[:2] - start[:2]) < 1.0 and steps < 100:
        maze.advance(CONTROL_DT)
        steps += 1
    assert 0.95 <= steps * CONTROL_DT <= 1.4  # 1 s at 1 m/s plus a short spin-up
    lin, ang = maze.velocities
    assert lin == pytest.approx(1.0, abs=0.05)
    assert abs(ang) < 0.05
    assert abs(maze.orientation[2]) < 0.05  # straight


def test_rover_turns_in_place(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(2))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    start = maze.position
    maze.set_command(0.0, 1.0)
    yaws = []
    for _ in range(40):  # 2 s
        maze.advance(CONTROL_DT)
        yaws.append(maze.orientation[2])
    turned = np.unwrap(yaws)[-1]
    assert 1.4 < turned < 2.6  # about 1 rad/s, left (counter-clockwise) positive
    assert np.linalg.norm(maze.position[:2] - start[:2]) < 0.05


def test_lidar_reads_a_wall_at_a_known_distance(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(3))
    _park_pedestrians(maze)
    for x, yaw in ((3.2, 0.0), (4.7, 0.0)):
        maze.set_rover_pose(x, -4.8, yaw)  # facing the east wall, nothing in between
        scan = maze.lidar(32, 12.0)
        forward = scan[15:17]  # the two middle points straddle straight ahead
        assert scan.dtype == np.float32 and scan.shape == (32,)
        assert np.all(np.abs(forward - (WALL_FACE - x)) < 0.03)
    # Turned to face north, the same wall is now on the right (scan index 8 = -pi/2).
    maze.set_rover_pose(4.7, -4.0, math.pi / 2)
    right = maze.lidar(32, 12.0)[7:9]
    assert np.all(np.abs(right - (WALL_FACE - 4.7)) < 0.03)


def test_lidar_clips_misses_and_ignores_the_rover(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(4))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    scan = maze.lidar(16, 1.0)  # short range: most rays miss
    assert np.all(scan <= 1.0) and np.all(scan > 0.2)  # the rover's own body is never hit
    assert np.sum(scan == 1.0) >= 8


def test_lidar_sees_pedestrians(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(5))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    before = maze.lidar(32, 12.0)[15:17].min()
    maze.place_pedestrian(0, -1.0, -1.0, math.pi / 2)  # 2 m ahead, side-on
    after = maze.lidar(32, 12.0)[15:17].min()
    assert before > 2.8  # the wall at x = -0.1
    assert 1.8 < after < 2.0  # legs (0.07 m radius) at 2 m


def test_camera_mask_finds_a_pedestrian_in_front(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(6))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    empty = maze.render_camera(segmentation=True)
    assert empty.pedestrian_mask is not None and not empty.pedestrian_mask.any()
    maze.place_pedestrian(0, 0.0, -1.0, math.pi)  # 3 m ahead, facing the rover
    frame = maze.render_camera(depth=True, segmentation=True)
    assert frame.rgb.shape == (96, 96, 3) and frame.rgb.dtype == np.uint8
    mask = frame.pedestrian_mask
    assert mask.shape == (96, 96) and mask.dtype == bool
    assert mask.sum() > 50
    cols = np.flatnonzero(mask.any(axis=0))
    assert 38 <= cols.mean() <= 58  # centred
    # Metric depth on the pedestrian: ~3 m from the rover centre, camera 0.2 m ahead.
    ped_depth = np.median(frame.depth[mask])
    assert 2.4 < ped_depth < 2.9
    # Pedestrian pixels look different from the empty frame.
    assert np.abs(frame.rgb[mask].astype(int) - empty.rgb[mask].astype(int)).mean() > 20


def test_camera_depth_is_metric(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(7))
    _park_pedestrians(maze)
    x = 4.5
    maze.set_rover_pose(x, -4.8, 0.0)
    frame = maze.render_camera(depth=True)
    assert frame.depth.dtype == np.float32 and frame.depth.shape == (96, 96)
    # The optical axis (8 deg down) meets the wall at this depth.
    expected = (WALL_FACE - x - rover.CAMERA_X) / math.cos(math.radians(rover.CAMERA_PITCH))
    assert frame.depth[47:49, 47:49].mean() == pytest.approx(expected, abs=0.01)


def test_chase_view_renders(maze: RoverSim) -> None:
    img = maze.render_chase(160, 120)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert img.std() > 5


def test_pedestrians_walk_at_walking_speed() -> None:
    sim = RoverSim("inspect", pedestrian_mode="pacing")
    for seed in range(3):
        sim.reset(np.random.default_rng(seed))
        assert sim.pedestrians.n >= 2
        sim.set_rover_pose(-28.5, -28.5, 0.0)  # out of their way, so none waits
        speeds = []
        for _ in range(20):
            before = sim.pedestrian_positions
            sim.advance(CONTROL_DT)
            speeds.append(np.linalg.norm(sim.pedestrian_positions - before, axis=1) / CONTROL_DT)
        median = np.median(np.array(speeds), axis=0)  # robust to a turn-around step
        assert np.all(median >= SPEED_RANGE[0] - 1e-6) and np.all(median <= SPEED_RANGE[1] + 1e-6)
    sim.close()


@pytest.mark.parametrize("world", WORLD_NAMES)
def test_pedestrians_are_randomised_per_episode_and_reproducible(world: str) -> None:
    sim = RoverSim(world)
    assert sim.pedestrians.n >= 2
    sim.reset(np.random.default_rng(10))
    first = sim.pedestrian_positions
    sim.reset(np.random.default_rng(11))
    other = sim.pedestrian_positions
    sim.reset(np.random.default_rng(10))
    again = sim.pedestrian_positions
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, other)
    # Paths keep clear of obstacles and start away from the rover.
    clearance = sim.world.clearance_many(first[:, 0], first[:, 1])
    assert np.all(clearance > 0.4)
    sim.close()


def test_pedestrian_wait_for_the_rover_in_their_way(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(8))
    _park_pedestrians(maze)
    maze.set_rover_pose(-1.0, -1.0, 0.0)
    # Walk pedestrian 0 straight at the rover from 3 m away.
    peds = maze.pedestrians
    peds._paths[0] = peds._paths[0]._replace(
        ax=-4.0, ay=-1.0, ux=1.0, uy=0.0, length=3.0, speed=1.2
    )
    peds._walked[0] = 0.0
    for _ in range(60):
        maze.advance(CONTROL_DT)
    gap = np.linalg.norm(maze.pedestrian_positions[0] - maze.position[:2])
    assert 0.8 < gap < 1.2
    assert not maze.rover_contacts().pedestrian


def test_contacts(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(9))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    maze.advance(0.2)
    assert maze.rover_contacts() == (False, False)  # the ground does not count
    maze.set_rover_pose(5.62, -4.8, 0.0)  # nose 5 cm from the east wall
    maze.set_command(0.5, 0.0)
    maze.advance(0.5)
    assert maze.rover_contacts().obstacle
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    maze.place_pedestrian(0, -2.62, -1.0, math.pi / 2)  # legs touching the nose
    maze.set_command(0.3, 0.0)
    maze.advance(0.2)
    assert maze.rover_contacts().pedestrian


def test_set_rover_pose_upside_down(maze: RoverSim) -> None:
    maze.set_rover_pose(-3.0, -1.0, 0.5, z=0.3, roll=math.pi)
    pitch, roll, yaw = maze.orientation
    assert abs(abs(roll) - math.pi) < 1e-6
    assert abs(pitch) < 1e-6
    assert maze.position[2] == pytest.approx(0.3)


def test_moon_spawn_rests_on_the_terrain() -> None:
    sim = RoverSim("moon")
    for seed in range(5):
        sim.reset(np.random.default_rng(seed))
        x, y, z = sim.position
        sim.advance(1.0)
        # Resting on the terrain (the hfield's triangles differ from our bilinear
        # estimate by a few cm): neither sunk in nor hovering, upright, still.
        ground = sim.world.ground_height(x, y)
        assert abs(sim.position[2] - (ground + rover.REST_HEIGHT)) < 0.2
        assert max(abs(sim.orientation[0]), abs(sim.orientation[1])) < 0.5
        assert np.abs(sim.data.qvel[:3]).max() < 0.1
    sim.close()


def _frames_equal(a, b) -> bool:
    return (
        np.array_equal(a.rgb, b.rgb)
        and np.array_equal(a.depth, b.depth)
        and np.array_equal(a.pedestrian_mask, b.pedestrian_mask)
    )


@pytest.mark.parametrize(("world", "appearance"), [("maze", "fixed"), ("moon", "random")])
def test_camera_frames_are_identical_without_the_geoms_it_leaves_out(
    world: str, appearance: str
) -> None:
    """The forward camera skips geoms it cannot see (geoms outside the view frustum, the
    rover's own body when not panned); every frame must equal the one with all drawn
    (random appearances resize the pedestrians' geoms every episode)."""
    sim = RoverSim(world, camera_size=(96, 96), n_pedestrians=10,
                   pedestrian_appearance=appearance)  # fmt: skip
    rng = np.random.default_rng(3)
    sim.reset(rng)
    everything = np.zeros(0, dtype=np.intp)
    left_out = 0
    try:
        for k in range(40):
            if k == 20:
                sim.reset(rng)  # new appearances
            sim.set_command(float(rng.uniform(-0.3, 1.0)), float(rng.uniform(-2.0, 2.0)))
            sim.advance(CONTROL_DT * 4)
            sim.set_camera_pan(0.0 if k % 2 else float(rng.uniform(-1.0, 1.0)))
            left_out += len(sim._unseen_geoms())
            culled = sim.render_camera(depth=True, segmentation=True)
            sim._unseen_geoms = lambda: everything  # type: ignore[method-assign]
            try:
                full = sim.render_camera(depth=True, segmentation=True)
            finally:
                del sim._unseen_geoms
            assert _frames_equal(culled, full), f"frame {k} differs"
    finally:
        sim.close()
    assert left_out > 40 * 10  # most of ten people stand outside a 90 deg view


def test_camera_leaves_out_a_pedestrian_behind_and_keeps_one_at_the_edge(maze: RoverSim) -> None:
    maze.reset(np.random.default_rng(8))
    _park_pedestrians(maze)
    maze.set_rover_pose(-3.0, -1.0, 0.0)
    geoms = maze.pedestrians.geom_mask & (maze.model.geom_group <= 2)
    first_body = maze.model.geom_bodyid[np.flatnonzero(geoms)[0]]
    own = np.flatnonzero(geoms & (maze.model.geom_bodyid == first_body))  # pedestrian 0's
    rgba = maze.model.geom_rgba.copy()

    maze.place_pedestrian(0, -5.0, -1.0, 0.0)  # 2 m behind the rover
    assert set(own) <= set(maze._unseen_geoms())
    # at the left edge of the 90 deg view, 2.8 m ahead: the parts in view are drawn
    maze.place_pedestrian(0, -0.2, -1.0 + 2.7, 0.0)
    drawn = set(own) - set(maze._unseen_geoms())
    assert drawn and drawn != set(own)
    mask = maze.render_camera(segmentation=True).pedestrian_mask
    assert mask.any() and not mask[:, 16:].any()  # a sliver at the left edge
    # the rover's own body is left out looking ahead, drawn when the camera is panned
    body = set(maze._rover_visuals)
    assert body and body <= set(maze._unseen_geoms())
    maze.set_camera_pan(0.5)
    try:
        assert not body & set(maze._unseen_geoms())
    finally:
        maze.set_camera_pan(0.0)
    assert np.array_equal(maze.model.geom_rgba, rgba)  # restored after every frame
