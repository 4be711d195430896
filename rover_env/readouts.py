"""What a policy may know besides its observation: sensor geometry and the worlds' maps.

A shipped policy (a zoo student) turns observations into features; some features need
facts that no observation carries: where the forward camera sits and how wide it sees (to
lift the fused image's depth to points), how the LIDAR's rays are laid out and when its
scan is taken (to cast a world's map the same way), and the map itself. They are read here,
from one public place, instead of from the simulator's modules; the values are the ones
the envs use, so features computed from them match the observations exactly.

    from rover_env import FORWARD_CAMERA, LIDAR_SCAN_LAG, lidar_ray_angles, obstacle_map
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from rover_env.rover import CAMERA_FOVY, CAMERA_PITCH, CAMERA_Z, WHEEL_RADIUS, lidar_ray_angles
from rover_env.simulation import PHYSICS_DT
from rover_env.worlds import WorldSpec, canonical_world_name, make_world


class CameraGeometry(NamedTuple):
    """Where a camera sits on the rover and how wide it sees."""

    fovy_deg: float
    """Vertical field of view (degrees); the horizontal one too on square frames."""
    pitch_deg: float
    """Pitch down from the horizontal (degrees), on a level rover."""
    height_m: float
    """Height of the optical centre above flat ground (m), rover at rest."""


FORWARD_CAMERA = CameraGeometry(
    fovy_deg=CAMERA_FOVY, pitch_deg=CAMERA_PITCH, height_m=WHEEL_RADIUS + CAMERA_Z
)
"""The forward camera (the fused image's source) with the head panned straight ahead."""

LIDAR_SCAN_LAG = PHYSICS_DT
"""Seconds by which the LIDAR's scan precedes ``obs["pose"]`` at the default physics step:
the scan is cast from the pose MuJoCo's kinematics computed at the start of the env step's
last physics step."""


class ObstacleMap:
    """A world's static obstacles as a policy's map: what a LIDAR would see with no
    pedestrians, on flat ground. Get one with :func:`obstacle_map`."""

    def __init__(self, world: WorldSpec) -> None:
        self._world = world

    def ray_distances(
        self, x: float, y: float, angles: np.ndarray, max_range: float
    ) -> np.ndarray:
        """Distance (m) along each world-frame heading in ``angles`` (rad) from (x, y) to the
        first obstacle footprint, ``max_range`` where none is nearer (0 from inside one): a
        level 2D cast, what a planar LIDAR sees of the scenery without the pedestrians."""
        return self._world.ray_distances(x, y, angles, max_range)


@functools.cache
def obstacle_map(world: str) -> ObstacleMap:
    """The :class:`ObstacleMap` of world ``world`` (a name or the seed's alias); one per
    world and process. ``ValueError`` names the worlds for an unknown one."""
    return ObstacleMap(make_world(canonical_world_name(world)))


__all__ = [
    "FORWARD_CAMERA",
    "LIDAR_SCAN_LAG",
    "CameraGeometry",
    "ObstacleMap",
    "lidar_ray_angles",
    "obstacle_map",
]
