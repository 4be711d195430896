"""rover_env.readouts: what a policy may know besides its observation matches the sim."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rover_env import (
    FORWARD_CAMERA,
    LIDAR_SCAN_LAG,
    RoverEnv,
    RoverSim,
    lidar_ray_angles,
    make_world,
    obstacle_map,
)


def test_forward_camera_matches_the_sim() -> None:
    sim = RoverSim("maze")
    try:
        assert math.radians(FORWARD_CAMERA.fovy_deg) == pytest.approx(sim.camera_fov)
        # the camera's height above the ground under the rover, at rest on flat ground
        cam_z = float(sim.data.cam_xpos[sim.model.camera("front_camera").id][2])
        assert cam_z == pytest.approx(FORWARD_CAMERA.height_m, abs=0.01)
    finally:
        sim.close()


def test_lidar_scan_lag_is_the_envs_physics_step() -> None:
    env = RoverEnv(world_n="maze")
    try:
        assert env.control_dt / env.physics_substeps == pytest.approx(LIDAR_SCAN_LAG)
    finally:
        env.close()


def test_obstacle_map_casts_the_worlds_footprints() -> None:
    angles, _ = lidar_ray_angles(32)
    for world in ("maze", "island"):
        got = obstacle_map(world).ray_distances(0.5, -1.0, angles, 6.0)
        np.testing.assert_array_equal(got, make_world(world).ray_distances(0.5, -1.0, angles, 6.0))
    assert obstacle_map("maze") is obstacle_map("maze")
    with pytest.raises(ValueError, match="unknown world"):
        obstacle_map("mars")
