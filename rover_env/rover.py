"""The Leo-like rover: MJCF, skid-steer command mapping, wheel odometry, and the 2D LIDAR.

Leo Rover: about 0.45 x 0.43 m, 6.5 kg, four 0.13 m wheels, skid-steered. The chassis body
origin sits at wheel-axle height; the wheels collide as spheres (cheap, robust on height
fields), the visuals are cylinders. Collision shapes are in group 3 (invisible), visuals in
group 2 (no collision), so the LIDAR (groups 0 and 1) never sees the rover itself.
"""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np

from rover_env.worlds.spec import (
    CONAFFINITY_ROVER,
    CONTYPE_ROVER,
    GROUND_FRICTION,
    GROUP_ROVER_COLLISION,
    GROUP_ROVER_VISUAL,
)

# --- geometry (Leo-like) --------------------------------------------------------------------
WHEEL_RADIUS = 0.065  # m (0.13 m wheels)
WHEEL_WIDTH = 0.07
WHEEL_MASS = 0.3  # kg each
CHASSIS_MASS = 6.5 - 4 * WHEEL_MASS  # kg, so the rover weighs 6.5 kg
WHEEL_X = 0.15  # front/rear axle offset from the centre (wheelbase 0.30 m)
WHEEL_Y = 0.18  # left/right wheel centre offset (track 0.36 m, outer width 0.43 m)
CHASSIS_HALF = (0.225, 0.125, 0.05)  # 0.45 m long
CHASSIS_Z = 0.055  # chassis box centre above the axle
LIDAR_Z = 0.235  # above the axle: 0.30 m above flat ground
CAMERA_X = 0.20
CAMERA_Z = 0.285  # above the axle: 0.35 m above flat ground
CAMERA_FOVY = 90.0  # deg; square frames, so 90 deg horizontally too
CAMERA_PITCH = 8.0  # deg down
# The camera sits in its own body, the pan head, whose frame turns about the vertical
# through the camera (gaze envs set it; the seed envs leave it straight ahead). A massless
# welded frame: turning it moves only the camera and the head's visual, never the physics.
CAMERA_HEAD_NAME = "camera_head"
SPAWN_CLEARANCE = 0.4  # m from obstacle footprints (half-diagonal 0.31 m plus margin)
# Height of the chassis origin above the ground when resting on flat ground.
REST_HEIGHT = WHEEL_RADIUS

# --- drive ----------------------------------------------------------------------------------
MAX_WHEEL_SPEED = 50.0  # rad/s (3.25 m/s at the rim), actuator ctrlrange
# N m per wheel, actuator forcerange: enough to slip the wheels and to turn in place at
# the PID's 7 rad/s clamp, little enough that pushing into a wall does not rock the rover.
WHEEL_TORQUE = 1.5
WHEEL_KV = 2.0  # N m s / rad, velocity servo gain
WHEEL_ARMATURE = 0.005  # kg m^2, motor and gearbox inertia seen at the wheel
WHEEL_FRICTIONLOSS = 0.15  # N m of gearbox friction: a stopped rover holds on ~8 deg slopes
# Skid-steer: wheels slip sideways while turning, so the body turns slower than the
# wheel speed difference suggests. Commands use an effective track wider than the real
# one (measured on flat ground: commanded angular rate ~ achieved), odometry the same.
EFFECTIVE_TRACK = 2 * WHEEL_Y * 3.0
WHEEL_NAMES = ("front_left", "rear_left", "front_right", "rear_right")
_LEFT = np.array([1.0, 1.0, 0.0, 0.0])
_RIGHT = np.array([0.0, 0.0, 1.0, 1.0])

# --- LIDAR ----------------------------------------------------------------------------------
LIDAR_RAW_RAYS = 360  # about one ray per degree, rounded up to a multiple of lidar_points

BODY_NAME = "rover"
LIDAR_SITE = "lidar"
CAMERA_NAME = "front_camera"

_ROVER_RGBA = "0.82 0.84 0.86 1"
_ACCENT_RGBA = "0.95 0.55 0.1 1"
_WHEEL_RGBA = "0.12 0.12 0.12 1"


def rover_xml(x: float = 0.0, y: float = 0.0, z: float = REST_HEIGHT) -> tuple[str, str]:
    """(worldbody fragment, actuator fragment) of the rover placed at (x, y, z)."""
    cx, cy, cz = CHASSIS_HALF
    vg, cg = GROUP_ROVER_VISUAL, GROUP_ROVER_COLLISION
    # The rover's collision bits meet the world's (scenery, pedestrians), never its own.
    col = (
        f'contype="{CONTYPE_ROVER}" conaffinity="{CONAFFINITY_ROVER}" priority="0" '
        f'friction="{GROUND_FRICTION}"'
    )
    wheels = []
    for name, sx, sy in (
        ("front_left", 1, 1),
        ("rear_left", -1, 1),
        ("front_right", 1, -1),
        ("rear_right", -1, -1),
    ):
        wheels.append(
            f'<body name="{name}" pos="{sx * WHEEL_X} {sy * WHEEL_Y} 0">'
            f'<joint name="{name}" type="hinge" axis="0 1 0" armature="{WHEEL_ARMATURE}" '
            f'damping="0.01" frictionloss="{WHEEL_FRICTIONLOSS}"/>'
            f'<geom name="{name}" type="sphere" size="{WHEEL_RADIUS}" mass="{WHEEL_MASS}" '
            f'group="{cg}" {col} condim="3" '
            f'rgba="0 0 0 0"/>'
            f'<geom type="cylinder" size="{WHEEL_RADIUS} {WHEEL_WIDTH / 2}" euler="90 0 0" '
            f'group="{vg}" contype="0" conaffinity="0" mass="0" rgba="{_WHEEL_RGBA}"/>'
            f"</body>"
        )
    pitch = math.radians(CAMERA_PITCH)
    body = (
        f'<body name="{BODY_NAME}" pos="{x} {y} {z}">'
        f'<freejoint name="{BODY_NAME}"/>'
        f'<geom name="chassis" type="box" size="{cx} {cy} {cz}" pos="0 0 {CHASSIS_Z}" '
        f'mass="{CHASSIS_MASS}" group="{cg}" {col} rgba="0 0 0 0"/>'
        f'<geom type="box" size="{cx} {cy} {cz}" pos="0 0 {CHASSIS_Z}" group="{vg}" '
        f'contype="0" conaffinity="0" mass="0" rgba="{_ROVER_RGBA}"/>'
        f'<geom type="box" size="0.06 0.1 0.012" pos="{cx - 0.05} 0 {CHASSIS_Z + cz}" '
        f'group="{vg}" contype="0" conaffinity="0" mass="0" rgba="{_ACCENT_RGBA}"/>'
        f'<geom type="cylinder" size="0.012 {(CAMERA_Z - CHASSIS_Z - cz) / 2}" '
        f'pos="{CAMERA_X - 0.03} 0 {(CAMERA_Z + CHASSIS_Z + cz) / 2}" group="{vg}" '
        f'contype="0" conaffinity="0" mass="0" rgba="{_WHEEL_RGBA}"/>'
        f'<geom type="cylinder" size="0.035 0.02" pos="0 0 {LIDAR_Z}" group="{vg}" '
        f'contype="0" conaffinity="0" mass="0" rgba="{_WHEEL_RGBA}"/>'
        f'<geom type="cylinder" size="0.01 {(LIDAR_Z - CHASSIS_Z - cz) / 2}" '
        f'pos="0 0 {(LIDAR_Z + CHASSIS_Z + cz) / 2}" group="{vg}" contype="0" '
        f'conaffinity="0" mass="0" rgba="{_WHEEL_RGBA}"/>'
        f'<site name="{LIDAR_SITE}" pos="0 0 {LIDAR_Z}" size="0.01" group="{vg}"/>'
        f'<body name="{CAMERA_HEAD_NAME}" pos="{CAMERA_X} 0 {CAMERA_Z}">'
        # The head's housing sits behind the lens, outside the camera's own view.
        f'<geom type="box" size="0.025 0.035 0.018" pos="-0.03 0 0" group="{vg}" '
        f'contype="0" conaffinity="0" mass="0" rgba="{_ACCENT_RGBA}"/>'
        # MuJoCo cameras look along -z with +y up: xyaxes turns that to look along +x.
        f'<camera name="{CAMERA_NAME}" pos="0 0 0" fovy="{CAMERA_FOVY}" '
        f'mode="fixed" xyaxes="0 -1 0 {math.sin(pitch):.6f} 0 {math.cos(pitch):.6f}"/>'
        "</body>" + "".join(wheels) + "</body>"
    )
    actuators = "".join(
        f'<velocity name="{name}" joint="{name}" kv="{WHEEL_KV}" ctrlrange="{-MAX_WHEEL_SPEED} '
        f'{MAX_WHEEL_SPEED}" forcerange="{-WHEEL_TORQUE} {WHEEL_TORQUE}"/>'
        for name in WHEEL_NAMES
    )
    return body, actuators


def wheel_targets(linear: float, angular: float, out: np.ndarray) -> np.ndarray:
    """Wheel angular velocity targets (rad/s, order WHEEL_NAMES) for a body command.

    :param linear: forward speed, m/s.
    :param angular: yaw rate, rad/s (positive turns left).
    :param out: array of 4 floats to write into (returned).
    """
    half = 0.5 * EFFECTIVE_TRACK * angular
    left = (linear - half) / WHEEL_RADIUS
    right = (linear + half) / WHEEL_RADIUS
    out[0] = out[1] = min(max(left, -MAX_WHEEL_SPEED), MAX_WHEEL_SPEED)
    out[2] = out[3] = min(max(right, -MAX_WHEEL_SPEED), MAX_WHEEL_SPEED)
    return out


def wheel_odometry(wheel_speeds: np.ndarray) -> tuple[float, float]:
    """(linear m/s, angular rad/s) from the four wheel speeds (rad/s, order WHEEL_NAMES)."""
    left = 0.5 * (wheel_speeds[0] + wheel_speeds[1]) * WHEEL_RADIUS
    right = 0.5 * (wheel_speeds[2] + wheel_speeds[3]) * WHEEL_RADIUS
    return 0.5 * (left + right), (right - left) / EFFECTIVE_TRACK


@functools.cache
def lidar_ray_angles(n_points: int) -> tuple[np.ndarray, int]:
    """The LIDAR's raw rays for ``n_points`` points (see :class:`Lidar`): their angles in the
    rover's frame (rad, from -pi counter-clockwise) and how many consecutive rays each point
    is the minimum of. A read-only array, shared."""
    per_point = max(1, math.ceil(LIDAR_RAW_RAYS / n_points))
    n_rays = n_points * per_point
    angles = -math.pi + (np.arange(n_rays) + 0.5) * (2 * math.pi / n_rays)
    angles.setflags(write=False)
    return angles, per_point


class Lidar:
    """Planar LIDAR by ray casting from the ``lidar`` site, in the rover's frame.

    ``n_points * k`` raw rays (k chosen so there are at least ``LIDAR_RAW_RAYS``) cover
    [-pi, pi) counter-clockwise from straight behind (-pi) through straight ahead (0);
    point ``i`` is the minimum over its ``k`` consecutive rays, so the scan's middle
    point looks forward. Misses and ranges beyond ``max_range`` read ``max_range`` (the
    seed's handling of inf/NaN/out-of-range returns). Rays see geom groups 0 (scenery)
    and 1 (pedestrians; with ``pedestrians=False`` group 0 only, the scenery's scan); the
    rover's own geoms are in groups 2 and 3. All buffers are allocated once.
    """

    def __init__(
        self, model: mujoco.MjModel, data: mujoco.MjData, n_points: int, max_range: float,
        pedestrians: bool = True, pedestrian_group: int = 1,
    ) -> None:
        if n_points < 1:
            raise ValueError(f"lidar_points must be >= 1, got {n_points}")
        if not max_range > 0:
            raise ValueError(f"max_lidar_range must be > 0, got {max_range}")
        self._model, self._data = model, data
        self._geomgroup = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)
        self._geomgroup[pedestrian_group] = int(pedestrians)
        self.n_points = int(n_points)
        self.max_range = float(max_range)
        angles, self.rays_per_point = lidar_ray_angles(self.n_points)
        self.n_rays = len(angles)
        self._local = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
        self._vec = np.zeros((self.n_rays, 3))
        self._dist = np.zeros(self.n_rays)
        self._geomid = np.zeros(self.n_rays, dtype=np.int32)
        self._scan = np.zeros(self.n_points, dtype=np.float32)
        self._site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, LIDAR_SITE)
        self._pnt = data.site_xpos[self._site]
        self._rot = data.site_xmat[self._site].reshape(3, 3)

    def scan(self) -> np.ndarray:
        """Ranges (n_points,) float32 in [0, max_range]; a view reused by the next call."""
        np.matmul(self._local, self._rot.T, out=self._vec)
        mujoco.mj_multiRay(
            self._model,
            self._data,
            self._pnt,
            self._vec.reshape(-1),
            self._geomgroup,
            1,
            -1,
            self._geomid,
            self._dist,
            None,
            self.n_rays,
            self.max_range,
        )
        d = self._dist
        d[(d < 0) | (d > self.max_range)] = self.max_range
        np.min(d.reshape(self.n_points, self.rays_per_point), axis=1, out=self._scan)
        return self._scan
