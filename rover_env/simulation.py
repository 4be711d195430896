"""RoverSim: one MuJoCo world with the rover and its pedestrians, read out by name.

Used by every env and by ``active_vision.training.dataset`` to render training frames. The
OpenGL renderer (:mod:`rover_env.rendering`) is created on the first render call, in the
process that renders, so a sim (or an env holding one) can be built in a subprocess
vector-env worker.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import mujoco
import numpy as np

from fused_image import DEPTH_MAX_M, FUSED_SIZE
from rover_env import rover
from rover_env.pedestrians import (
    DEFAULT_MODE,
    GROUP_PROXY,
    Appearance,
    Pedestrians,
    pedestrian_count,
    pedestrians_xml,
)
from rover_env.pedestrians import (
    pedestrian_mode as canonical_mode,
)
from rover_env.rendering import CameraFrame, GLRenderer
from rover_env.worlds import WorldSpec, make_world
from rover_env.worlds.spec import (
    CONAFFINITY_WORLD,
    CONTYPE_WORLD,
    GROUP_MARKER,
    GROUP_PEDESTRIAN,
    GROUP_ROVER_VISUAL,
    OBSTACLE_FRICTION,
    OBSTACLE_PRIORITY,
)

log = logging.getLogger(__name__)


# s; implicitfast keeps wheel servos and contacts stable here (0.01 behaves the same:
# drive speed, turn rates, flips; tested), and two steps per 0.05 s control period are cheap.
PHYSICS_DT = 0.025
SOLVER_ITERATIONS = 20
SOLVER_LS_ITERATIONS = 8
CHASE_MAX_SIZE = (640, 480)  # (width, height): the largest render_chase frame
# Clip planes relative to the model extent (fixed at _EXTENT): near 2 cm, far 120 m.
_EXTENT = 10.0
_ZNEAR, _ZFAR = 0.002, 12.0
_CHASE_DISTANCE = 3.6
_CHASE_ELEVATION = -22.0
_CHASE_LEAD = 1.0
_GOAL_BODY = "goal_marker"
# The chase view's gaze cone: where the forward camera looks, drawn on the ground.
VIEW_CONE_LENGTH = 4.0  # m from the camera along each edge of the field of view
_VIEW_CONE_WIDTH = 0.04  # m, radius of the drawn lines
_VIEW_CONE_RGBA = np.array([1.0, 0.85, 0.1, 0.9], dtype=np.float32)
_VIEW_CONE_LIFT = 0.05  # m above the ground below the rover
_OBSTACLE, _PEDESTRIAN = 1, 2  # contact codes of geoms (0: ground or the rover itself)


class Lighting(NamedTuple):
    """The model's lights: per-light diffuse/ambient/specular ``(L, 3)`` and the headlight's
    diffuse/ambient ``(3,)`` (RGB in [0, 1])."""

    diffuse: np.ndarray
    ambient: np.ndarray
    specular: np.ndarray
    head_diffuse: np.ndarray
    head_ambient: np.ndarray


class Contacts(NamedTuple):
    """What the rover touches: scenery other than the ground, and pedestrians."""

    obstacle: bool
    pedestrian: bool


_NO_CONTACT = Contacts(False, False)


def build_mjcf(
    world: WorldSpec,
    camera_size: tuple[int, int],
    physics_dt: float,
    n_pedestrians: int | None = None,
    pedestrian_mode: str = DEFAULT_MODE,
) -> str:
    """The complete MJCF of ``world`` with the rover, ``n_pedestrians`` pedestrians (the
    world's own count by default) and a goal marker."""
    if n_pedestrians is None:
        n_pedestrians = world.n_pedestrians
    height, width = camera_size
    offwidth = max(width, CHASE_MAX_SIZE[0])
    offheight = max(height, CHASE_MAX_SIZE[1])
    sx = 0.5 * (world.spawn.x[0] + world.spawn.x[1])
    sy = 0.5 * (world.spawn.y[0] + world.spawn.y[1])
    rover_body, actuators = rover.rover_xml(sx, sy, rover.REST_HEIGHT + world.ground_height(sx, sy))
    goal = (
        f'<body name="{_GOAL_BODY}" mocap="true" pos="{sx} {sy} 0">'
        f'<geom type="cylinder" size="0.5 0.005" pos="0 0 0.005" group="{GROUP_MARKER}" '
        'contype="0" conaffinity="0" rgba="0.1 0.9 0.2 0.5"/>'
        f'<geom type="cylinder" size="0.02 0.5" pos="0 0 0.5" group="{GROUP_MARKER}" '
        'contype="0" conaffinity="0" rgba="0.1 0.9 0.2 0.9"/>'
        "</body>"
    )
    return (
        f'<mujoco model="roverav_{world.name}">'
        '<compiler angle="degree" autolimits="true"/>'
        f'<option timestep="{physics_dt}" integrator="implicitfast" cone="pyramidal" '
        f'iterations="{SOLVER_ITERATIONS}" ls_iterations="{SOLVER_LS_ITERATIONS}"/>'
        f'<statistic extent="{_EXTENT}" center="{sx} {sy} 0"/>'
        "<visual>"
        '<quality offsamples="0" shadowsize="0" numslices="12" numstacks="8" numquads="1"/>'
        f'<global offwidth="{offwidth}" offheight="{offheight}"/>'
        f'<map znear="{_ZNEAR}" zfar="{_ZFAR}"/>'
        '<headlight ambient="0.35 0.35 0.35" diffuse="0.45 0.45 0.45" specular="0 0 0"/>'
        "</visual>"
        "<default>"
        f'<geom contype="{CONTYPE_WORLD}" conaffinity="{CONAFFINITY_WORLD}" condim="3" '
        f'friction="{OBSTACLE_FRICTION}" priority="{OBSTACLE_PRIORITY}"/>'
        "</default>"
        f"<asset>{world.asset_xml}</asset>"
        "<worldbody>"
        '<light name="sun" directional="true" pos="0 0 20" dir="-0.3 -0.5 -1" '
        'diffuse="0.55 0.55 0.55" specular="0 0 0" castshadow="false"/>'
        + world.worldbody_xml
        + rover_body
        + pedestrians_xml(n_pedestrians, proxy=pedestrian_mode != "pacing")
        + goal
        + "</worldbody>"
        + f"<actuator>{actuators}</actuator>"
        + "</mujoco>"
    )


class RoverSim:
    """One MuJoCo world with the rover and its pedestrians, with named readouts.

    :param world: ``inspect``, ``moon`` (alias ``island``) or ``maze``.
    :param camera_size: forward camera frame (height, width) in pixels.
    :param physics_dt: physics time step (s); ``advance`` runs whole steps.
    :param seed_rng: generator for the initial state; the sim is reset from it (or from
        a fixed seed) at construction so it is usable before the first ``reset``.
    :param pedestrian_appearance: ``"fixed"`` (default: the palette figures) or ``"random"``
        (colours, height, girth and gait phase drawn per episode from the reset generator;
        see :mod:`rover_env.pedestrians`).
    :param n_pedestrians: walking figures, 0 to 20 (None: the world's own count, 3); the
        model has exactly this many pedestrian bodies.
    :param pedestrian_mode: how they walk: ``crowd`` (default), ``pacing``, ``oblivious``,
        ``crossing`` or ``groups`` (see :mod:`rover_env.pedestrians`).
    """

    def __init__(
        self,
        world: str = "inspect",
        camera_size: tuple[int, int] = FUSED_SIZE,
        physics_dt: float = PHYSICS_DT,
        seed_rng: np.random.Generator | None = None,
        pedestrian_appearance: str = "fixed",
        n_pedestrians: int | None = None,
        pedestrian_mode: str = DEFAULT_MODE,
    ) -> None:
        if not physics_dt > 0:
            raise ValueError(f"physics_dt must be > 0, got {physics_dt}")
        if len(camera_size) != 2 or min(camera_size) < 1:
            raise ValueError(f"camera_size must be (height, width) >= 1, got {camera_size}")
        self.world: WorldSpec = make_world(world)
        n_pedestrians = pedestrian_count(n_pedestrians, self.world)
        pedestrian_mode = canonical_mode(pedestrian_mode)
        self._scan_group = GROUP_PEDESTRIAN if pedestrian_mode == "pacing" else GROUP_PROXY
        self.camera_size = (int(camera_size[0]), int(camera_size[1]))
        self.physics_dt = float(physics_dt)
        self.model = mujoco.MjModel.from_xml_string(
            build_mjcf(self.world, self.camera_size, self.physics_dt, n_pedestrians,
                       pedestrian_mode)  # fmt: skip
        )
        self.data = mujoco.MjData(self.model)
        m, d = self.model, self.data
        obj = mujoco.mjtObj
        self._body = mujoco.mj_name2id(m, obj.mjOBJ_BODY, rover.BODY_NAME)
        free = m.body_jntadr[self._body]
        self._qpos = m.jnt_qposadr[free]
        self._qvel = m.jnt_dofadr[free]
        wheel_joints = [mujoco.mj_name2id(m, obj.mjOBJ_JOINT, n) for n in rover.WHEEL_NAMES]
        self._wheel_dofs = np.array([m.jnt_dofadr[j] for j in wheel_joints], dtype=np.intp)
        self._actuators = np.array(
            [mujoco.mj_name2id(m, obj.mjOBJ_ACTUATOR, n) for n in rover.WHEEL_NAMES],
            dtype=np.intp,
        )
        self._wheel_cmd = np.zeros(4)
        self._wheel_speeds = np.zeros(4)
        self._camera_id = mujoco.mj_name2id(m, obj.mjOBJ_CAMERA, rover.CAMERA_NAME)
        self._head = mujoco.mj_name2id(m, obj.mjOBJ_BODY, rover.CAMERA_HEAD_NAME)
        self._camera_pan = 0.0
        height, width = self.camera_size
        half_fovy = math.radians(rover.CAMERA_FOVY) / 2
        self.camera_half_fov = math.atan(math.tan(half_fovy) * width / height)
        """Half the forward camera's horizontal field of view (rad): 45 deg on square frames."""
        # the frustum's side planes pass through the camera: a sphere of radius r at (x, z)
        # is wholly outside the right one when x > z tan(h) + r / cos(h)
        self._tan_half_fovx = math.tan(self.camera_half_fov)
        self._sec_half_fovx = 1.0 / math.cos(self.camera_half_fov)
        self._tan_half_fovy = math.tan(half_fovy)
        self._sec_half_fovy = 1.0 / math.cos(half_fovy)
        self._goal_mocap = m.body_mocapid[mujoco.mj_name2id(m, obj.mjOBJ_BODY, _GOAL_BODY)]
        self.pedestrians = Pedestrians(
            m, d, self.world, appearance=pedestrian_appearance, mode=pedestrian_mode
        )
        # Geom classes for contacts: rover subtree, pedestrians, ground.
        rover_bodies = {self._body, self._head} | {
            mujoco.mj_name2id(m, obj.mjOBJ_BODY, n) for n in rover.WHEEL_NAMES
        }
        self._rover_geoms = np.isin(m.geom_bodyid, list(rover_bodies))
        self._pedestrian_geoms = self.pedestrians.geom_mask
        ground_types = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)
        # Geoms the forward camera leaves out of a frame it cannot show them in (the frames are
        # pixel-identical without them; llvmpipe's cost grows with the triangles drawn): the
        # rover's own body when the camera looks straight ahead, and any other bounded geom
        # (pedestrians, rocks, panels, walls; not the ground) wholly outside the view frustum.
        self._rover_visuals = np.flatnonzero(
            self._rover_geoms & (m.geom_group == GROUP_ROVER_VISUAL)
        )
        drawn = mujoco.MjvOption().geomgroup[m.geom_group].astype(bool)
        unbounded = np.isin(m.geom_type, ground_types) | (m.geom_rbound <= 0)
        self._cullable = np.flatnonzero(drawn & ~unbounded & ~self._rover_geoms)
        ground = np.isin(m.geom_type, ground_types) & (m.geom_bodyid == 0)
        codes = np.where(self._pedestrian_geoms, _PEDESTRIAN, _OBSTACLE)
        codes[ground | self._rover_geoms] = 0
        self._contact_codes: list[int] = codes.tolist()
        self._lidars: dict[tuple[int, float, bool], rover.Lidar] = {}
        self._contacts: Contacts | None = None
        self._renderer: GLRenderer | None = None
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = self._camera_id
        self._chase = mujoco.MjvCamera()
        self._chase.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._chase.distance = _CHASE_DISTANCE
        self._chase.elevation = _CHASE_ELEVATION
        self._lights0 = Lighting(
            m.light_diffuse.copy(), m.light_ambient.copy(), m.light_specular.copy(),
            m.vis.headlight.diffuse.copy(), m.vis.headlight.ambient.copy(),
        )
        self._scenery_group = np.zeros(6, np.uint8)
        self._scenery_group[0] = 1  # geom group 0: ground, terrain, rocks, walls
        self._ray_geom = np.zeros(1, np.int32)
        self.reset(seed_rng if seed_rng is not None else np.random.default_rng(0))

    # --- state ---------------------------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        """Fresh physics state: rover at a free spawn with random yaw, new pedestrian paths."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        x, y = self.world.sample_free(rng, self.world.spawn, rover.SPAWN_CLEARANCE)
        yaw = float(rng.uniform(-math.pi, math.pi))
        self.pedestrians.reset(rng, avoid=(x, y))
        self.set_rover_pose(x, y, yaw)

    def set_rover_pose(
        self,
        x: float,
        y: float,
        yaw: float,
        *,
        z: float | None = None,
        roll: float = 0.0,
        pitch: float = 0.0,
    ) -> None:
        """Teleport the rover (zero velocities, wheel servos stopped) and run mj_forward.

        :param z: chassis origin height; default rests the wheels on the ground below.
        :param roll: rotation about the body x axis (rad), e.g. ``math.pi`` upside down.
        :param pitch: rotation about the body y axis (rad).
        """
        m, d = self.model, self.data
        if z is None:
            z = self._rest_height(x, y, yaw)
        q = self._qpos
        d.qpos[q : q + 3] = (x, y, z)
        quat = np.empty(4)
        # R = Rz(yaw) Ry(pitch) Rx(roll): intrinsic z, y', x'' (lower case = intrinsic).
        mujoco.mju_euler2Quat(quat, np.array([yaw, pitch, roll]), "zyx")
        d.qpos[q + 3 : q + 7] = quat
        v = self._qvel
        d.qvel[v : v + 6] = 0.0
        d.qvel[self._wheel_dofs] = 0.0
        d.ctrl[self._actuators] = 0.0
        d.qacc_warmstart[:] = 0.0
        mujoco.mj_forward(m, d)
        self._contacts = None

    def _rest_height(self, x: float, y: float, yaw: float) -> float:
        world = self.world
        if world.heightfield is None:
            return rover.REST_HEIGHT
        c, s = math.cos(yaw), math.sin(yaw)
        ground = max(
            world.ground_height(x + c * wx - s * wy, y + s * wx + c * wy)
            for wx in (-rover.WHEEL_X, 0.0, rover.WHEEL_X)
            for wy in (-rover.WHEEL_Y, 0.0, rover.WHEEL_Y)
        )
        return ground + rover.REST_HEIGHT + 0.02

    def set_command(self, linear: float, angular: float) -> None:
        """Drive command: ``linear`` m/s forward, ``angular`` rad/s (left positive)."""
        rover.wheel_targets(linear, angular, self._wheel_cmd)
        self.data.ctrl[self._actuators] = self._wheel_cmd

    def advance(self, duration: float) -> None:
        """Run the physics for ``duration`` s of simulated time (whole physics steps).

        The pedestrians walk on to their poses for the end of the interval first (waiting
        if the rover is in their way), so their positions read during and after this call
        agree.
        """
        n = max(1, int(round(duration / self.physics_dt)))
        m, d = self.model, self.data
        q = self._qpos
        self.pedestrians.advance(n * self.physics_dt, (d.qpos[q], d.qpos[q + 1]))
        obstacle = pedestrian = False
        for _ in range(n):
            mujoco.mj_step(m, d)
            if d.ncon:
                touched = self._touching()
                obstacle |= touched.obstacle
                pedestrian |= touched.pedestrian
        self._contacts = Contacts(obstacle, pedestrian)

    def set_camera_pan(self, angle: float) -> None:
        """Turn the camera head to ``angle`` rad about the vertical (0 straight ahead, positive
        to the left, like yaw) and update the camera pose at once (for the next render).

        The head is a massless frame welded to the chassis: its pose is a model parameter
        (``body_quat``), so turning it changes what the camera sees and nothing else.
        """
        angle = float(angle)
        if not math.isfinite(angle):
            raise ValueError(f"camera pan must be a finite angle in rad, got {angle}")
        self._camera_pan = angle
        self.model.body_quat[self._head] = (math.cos(0.5 * angle), 0.0, 0.0, math.sin(0.5 * angle))
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    @property
    def camera_pan(self) -> float:
        """The camera head's pan angle (rad, 0 straight ahead, positive left)."""
        return self._camera_pan

    @property
    def camera_heading(self) -> float:
        """Where the forward camera looks on the ground plane: world heading (rad)."""
        look = self.data.cam_xmat[self._camera_id].reshape(3, 3)[:, 2]  # camera +z looks back
        return math.atan2(-look[1], -look[0])

    def pedestrians_in_view(self, max_range: float = DEPTH_MAX_M) -> np.ndarray:
        """(P,) bool: pedestrians whose ground position lies inside the forward camera's
        horizontal field of view and within ``max_range`` m of it (the depth channel's range
        by default). A geometric test: a pedestrian behind a wall still counts."""
        cam = self.data.cam_xpos[self._camera_id]
        peds = self.pedestrians.positions
        dx, dy = peds[:, 0] - cam[0], peds[:, 1] - cam[1]
        bearing = np.arctan2(dy, dx) - self.camera_heading
        bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
        return (np.abs(bearing) <= self.camera_half_fov) & (np.hypot(dx, dy) <= max_range)

    def set_goal_marker(self, x: float, y: float) -> None:
        """Move the goal marker (a green disc, drawn in the chase view only)."""
        self.data.mocap_pos[self._goal_mocap] = (x, y, self.world.ground_height(x, y))

    # --- readouts ------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time since the last reset (s)."""
        return float(self.data.time)

    @property
    def position(self) -> np.ndarray:
        """Rover chassis origin (x, y, z) in metres (new array)."""
        q = self._qpos
        return self.data.qpos[q : q + 3].copy()

    @property
    def orientation(self) -> np.ndarray:
        """(pitch, roll, yaw) in radians, the seed's IMU order (new array)."""
        w, x, y, z = self.data.qpos[self._qpos + 3 : self._qpos + 7]
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return np.array([pitch, roll, yaw])

    @property
    def yaw(self) -> float:
        """Heading (rad, counter-clockwise from +x)."""
        w, x, y, z = self.data.qpos[self._qpos + 3 : self._qpos + 7]
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    @property
    def velocities(self) -> np.ndarray:
        """Wheel-odometry (linear m/s, angular rad/s) (new array)."""
        np.take(self.data.qvel, self._wheel_dofs, out=self._wheel_speeds)
        return np.array(rover.wheel_odometry(self._wheel_speeds))

    def lidar(self, n_points: int, max_range: float, pedestrians: bool = True) -> np.ndarray:
        """Planar LIDAR scan: (n_points,) float32 in [0, max_range], min per segment.

        See :class:`rover_env.rover.Lidar` for the ray layout. ``pedestrians=False``: the
        same scan of the scenery alone (the pedestrians let the rays through), to tell
        which returns are the pedestrians'. Returns a new array.
        """
        key = (int(n_points), float(max_range), bool(pedestrians))
        lidar = self._lidars.get(key)
        if lidar is None:
            lidar = rover.Lidar(self.model, self.data, n_points, max_range, pedestrians,
                                self._scan_group)  # fmt: skip
            self._lidars[key] = lidar
        return lidar.scan().copy()

    @property
    def camera_up(self) -> np.ndarray:
        """The world's up direction in the forward camera's frame (x right, y up, z back:
        MuJoCo's camera axes), (3,) (new array): how the camera is tilted and rolled."""
        return self.data.cam_xmat[self._camera_id].reshape(3, 3)[2].copy()

    @property
    def camera_fov(self) -> float:
        """Vertical field of view of the forward camera (rad); equal to the horizontal one
        for square frames."""
        return math.radians(float(self.model.cam_fovy[self._camera_id]))

    @property
    def lighting(self) -> Lighting:
        """The lights as they are now (copies)."""
        m = self.model
        return Lighting(m.light_diffuse.copy(), m.light_ambient.copy(), m.light_specular.copy(),
                        m.vis.headlight.diffuse.copy(), m.vis.headlight.ambient.copy())

    @property
    def default_lighting(self) -> Lighting:
        """The lights as the world defines them (copies)."""
        return Lighting(*(a.copy() for a in self._lights0))

    def set_lighting(self, lighting: Lighting) -> None:
        """Set every light (values clipped to [0, 1]); ``set_lighting(default_lighting)``
        restores the world's."""
        m = self.model
        m.light_diffuse[:] = np.clip(lighting.diffuse, 0.0, 1.0)
        m.light_ambient[:] = np.clip(lighting.ambient, 0.0, 1.0)
        m.light_specular[:] = np.clip(lighting.specular, 0.0, 1.0)
        m.vis.headlight.diffuse[:] = np.clip(lighting.head_diffuse, 0.0, 1.0)
        m.vis.headlight.ambient[:] = np.clip(lighting.head_ambient, 0.0, 1.0)

    def terrain_height(self, x: float, y: float) -> float:
        """Height of the rendered scenery (ground, terrain, rocks, walls) at (x, y): a ray
        cast down from 100 m; ``WorldSpec.ground_height`` where the ray hits nothing."""
        dist = mujoco.mj_ray(self.model, self.data, np.array([x, y, 100.0]),
                             np.array([0.0, 0.0, -1.0]), self._scenery_group, 1, -1,
                             self._ray_geom)
        return 100.0 - dist if dist >= 0 else self.world.ground_height(x, y)

    @property
    def pedestrian_appearance(self) -> list[Appearance]:
        """This episode's look of every pedestrian (colours, height, girth, gait phase)."""
        return list(self.pedestrians.appearance)

    @property
    def pedestrian_positions(self) -> np.ndarray:
        """(P, 2) pedestrian ground positions (x, y) in metres (new array)."""
        return self.pedestrians.positions.copy()

    def place_pedestrian(self, i: int, x: float, y: float, heading: float) -> None:
        """Pin pedestrian ``i`` standing at (x, y) facing ``heading`` until the next reset."""
        self.pedestrians.place(i, x, y, heading)
        mujoco.mj_forward(self.model, self.data)
        self._contacts = None

    def rover_contacts(self) -> Contacts:
        """Whether the rover touched non-ground scenery and/or a pedestrian during the last
        :meth:`advance` (at any physics step: a rover pushing into a wall rocks, and its
        contact comes and goes within a control period), or now if it was posed since."""
        if self._contacts is None:
            self._contacts = self._touching()
        return self._contacts

    def _touching(self) -> Contacts:
        # Every contact pair involves the rover (the collision bits allow nothing else), so
        # OR-ing both geoms' codes says what it touches. Plain Python: a handful of pairs.
        d = self.data
        n = d.ncon
        if n == 0:
            return _NO_CONTACT
        codes = self._contact_codes
        flags = 0
        for a, b in d.contact.geom[:n].tolist():
            flags |= codes[a] | codes[b]
        return Contacts(bool(flags & _OBSTACLE), bool(flags & _PEDESTRIAN))

    # --- rendering -----------------------------------------------------------------------------
    def _gl(self) -> GLRenderer:
        if self._renderer is None:
            self._renderer = GLRenderer(self.model, self._pedestrian_geoms)
        return self._renderer

    def render_camera(self, depth: bool = False, segmentation: bool = False) -> CameraFrame:
        """Forward camera frame (camera_size), optionally with metric depth and the
        pedestrian mask."""
        height, width = self.camera_size
        r = self._gl()
        rgba, unseen = self.model.geom_rgba, self._unseen_geoms()
        alpha = rgba[unseen, 3]
        rgba[unseen, 3] = 0.0  # transparent geoms are left out of the scene
        try:
            return r.render(
                self.data, self._camera, r.camera_option, width, height, depth, segmentation
            )
        finally:
            rgba[unseen, 3] = alpha

    def _unseen_geoms(self) -> np.ndarray:
        """Indices of drawn geoms the forward camera cannot see now: bounded geoms (all but
        the ground and the rover) whose bounding sphere lies wholly outside one side of the
        view frustum, and, unless the camera is panned (then it may see a corner of the
        rover), the rover's own geoms."""
        d, cam = self.data, self._camera_id
        geoms = self._cullable
        radius = self.model.geom_rbound[geoms]  # live: random appearances resize pedestrians
        # centres in the camera frame: x right, y up, -z along the view
        v = (d.geom_xpos[geoms] - d.cam_xpos[cam]) @ d.cam_xmat[cam].reshape(3, 3)
        ahead = -v[:, 2]
        outside = (
            (ahead + radius <= 0.0)  # behind the camera
            | (np.abs(v[:, 0]) > ahead * self._tan_half_fovx + radius * self._sec_half_fovx)
            | (np.abs(v[:, 1]) > ahead * self._tan_half_fovy + radius * self._sec_half_fovy)
        )
        culled = geoms[outside]
        if self._camera_pan != 0.0:
            return culled
        return np.concatenate((self._rover_visuals, culled))

    def future_pedestrian_mask(self, horizon: float = 1.5, step: float = 0.1) -> np.ndarray:
        """bool (H, W): camera pixels a pedestrian covers at some moment in the next
        ``horizon`` seconds, seen from the current camera pose.

        The rover and camera are held still; only the pedestrians walk on along their own
        paths (waiting for the rover as they would), and their segmentation masks at
        ``0, step, 2 step, ..., horizon`` are OR-ed. The sim is left exactly as it was
        (pedestrian poses restored, no physics step taken).
        """
        if not horizon >= 0 or not step > 0:
            raise ValueError(f"horizon must be >= 0 and step > 0, got {horizon}, {step}")
        m, d = self.model, self.data
        q = self._qpos
        rover_xy = (float(d.qpos[q]), float(d.qpos[q + 1]))
        saved = self.pedestrians.walked_state()
        union = self.render_camera(segmentation=True).pedestrian_mask
        assert union is not None
        try:
            for _ in range(int(round(horizon / step))):
                self.pedestrians.advance(step, rover_xy)
                mujoco.mj_kinematics(m, d)
                mask = self.render_camera(segmentation=True).pedestrian_mask
                assert mask is not None
                union |= mask
        finally:
            self.pedestrians.restore_walked(saved)
            mujoco.mj_kinematics(m, d)
        return union

    def render_chase(
        self, width: int = 480, height: int = 360, *, view_cone: bool = False
    ) -> np.ndarray:
        """uint8 (height, width, 3) view from behind and above the rover (videos).

        :param view_cone: draw where the forward camera looks: its centre line and the two
            edges of its horizontal field of view, ``VIEW_CONE_LENGTH`` m on the ground.
        """
        cam = self._chase
        q = self._qpos
        yaw = self.yaw
        cam.lookat[:] = self.data.qpos[q : q + 3]
        cam.lookat[0] += _CHASE_LEAD * math.cos(yaw)  # look a little ahead of the rover
        cam.lookat[1] += _CHASE_LEAD * math.sin(yaw)
        cam.lookat[2] += 0.4
        cam.azimuth = math.degrees(yaw)
        r = self._gl()
        decorate = self._draw_view_cone if view_cone else None
        return r.render(self.data, cam, r.chase_option, width, height, decorate=decorate).rgb

    def _draw_view_cone(self, scene: mujoco.MjvScene) -> None:
        cam = self.data.cam_xpos[self._camera_id]
        q = self._qpos
        z = float(self.data.qpos[q + 2]) - rover.REST_HEIGHT + _VIEW_CONE_LIFT
        start = np.array([cam[0], cam[1], z])
        heading = self.camera_heading
        half = self.camera_half_fov
        for offset in (-half, 0.0, half):
            if scene.ngeom >= scene.maxgeom:
                log.debug("chase scene full: view cone not drawn completely")
                return
            a = heading + offset
            end = start + VIEW_CONE_LENGTH * np.array([math.cos(a), math.sin(a), 0.0])
            geom = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(
                geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.zeros(9),
                _VIEW_CONE_RGBA,
            )  # fmt: skip
            mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, _VIEW_CONE_WIDTH, start, end)
            scene.ngeom += 1

    def close(self) -> None:
        """Free the renderer (the sim stays usable; a later render makes a new one)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass
