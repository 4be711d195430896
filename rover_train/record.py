"""Episodes as ROS 2 bags: one MCAP file per episode, in the seed's topics, on sim time.

    rover-eval --random --env lidar --episodes 2 --record runs/rec
    # then open runs/rec/episode_100000.mcap in Foxglove with docs/foxglove_layout.json

:class:`EpisodeRecorder` writes one episode of any roverav env (the LIDAR envs, the fused
envs, their discrete and gaze variants) to an MCAP file (:class:`RecordEpisodes` does it for
every episode of an env it wraps; ``rover-eval --record DIR`` writes
``DIR/episode_<seed>.mcap``). Every message is stamped with the simulated time
(``RoverSim.time``, 0 at the episode's reset, ``control_dt`` per step): the header stamp
and the MCAP log time are the same. The reset's observation and each step's are written:

Topics (standard ROS 2 types; frames ``odom`` = the world, ``base_link`` = the chassis):

- ``/camera/image_raw`` (sensor_msgs/Image rgb8): the forward camera's frame
  (``env.camera_frame()``, the frame a fused env sends the daemon);
- ``/chase/image_raw`` (sensor_msgs/Image rgb8): the chase view (``env.render()``), when the
  env has ``render_mode="rgb_array"``;
- ``/scan`` (sensor_msgs/LaserScan, LIDAR envs): ``obs["lidar"]``; point i covers
  [-pi + i 2pi/n, -pi + (i + 1) 2pi/n) in the rover's frame, so its angle is that segment's
  middle; a range at the LIDAR's maximum (no return) is written as +inf (REP 117);
- ``/imu/data`` (sensor_msgs/Imu): the orientation (``obs["imu"]``'s pitch, roll and yaw),
  the chassis' angular velocity and specific force (gravity included; the acceleration
  averaged over the step) in its own frame;
- ``/odom`` (nav_msgs/Odometry): the chassis' pose in ``odom`` and the wheel odometry
  (``obs["velocities"]``) in ``base_link``;
- ``/tf`` (tf2_msgs/TFMessage): ``odom`` -> ``base_link``; ``/tf_static`` once:
  ``base_link`` -> ``laser`` and ``camera_link`` (the camera head panned straight ahead);
- ``/cmd_vel`` (geometry_msgs/Twist): the command the step applied (forward speed, and the
  yaw rate the heading PID asked for, after the wheel limits), stamped when it was applied
  (the step's start): one fewer than the observations;
- ``/goal_pose`` (geometry_msgs/PoseStamped): the current goal, on the ground;
- ``/pedestrians`` (geometry_msgs/PoseArray): the pedestrians on the ground, each facing the
  way it last moved;
- ``/path`` (nav_msgs/Path): the path driven so far, a pose every ``path_every`` steps (and
  the last), written every ``path_every`` steps and at the end;
- ``/active_vision/gray``, ``/active_vision/heatmap``, ``/active_vision/depth``
  (sensor_msgs/Image 32FC1, fused envs): the fused image's channels, gray and heatmap in
  [0, 1], depth in metres.

Needs ``pip install 'roverav[ros]'`` (:mod:`active_vision.ros_formats`); without it
making a recorder raises ``RosExtraMissingError``. What it costs: ``benchmarks/record_cost.py``
(the forward camera is rendered once more per step on the LIDAR envs, the chase view once
per step where it is on).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from active_vision.ros_formats import COMPRESSIONS, McapWriter, fused_messages, image_message
from active_vision.ros_formats import header as ros_header
from active_vision.ros_formats import message as ros_message
from rover_env import rover
from rover_env.constants import CAMERA_TOPIC, CMD_VEL_TOPIC, IMU_TOPIC, SCAN_TOPIC
from rover_env.core import RoverEnvBase

logger = logging.getLogger(__name__)

ODOM_TOPIC = "/odom"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
GOAL_TOPIC = "/goal_pose"
PEDESTRIANS_TOPIC = "/pedestrians"
PATH_TOPIC = "/path"
CHASE_TOPIC = "/chase/image_raw"

ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
LASER_FRAME = "laser"
CAMERA_FRAME = "camera_link"
CHASE_FRAME = "chase_camera"

_NS = 1_000_000_000
_MOVED_M = 1e-4
"""A pedestrian that moved less than this in a step keeps its heading."""


@dataclass(frozen=True)
class RecordConfig:
    """What an :class:`EpisodeRecorder` writes besides the state topics."""

    camera: bool = True
    """``/camera/image_raw``: the forward camera (rendered once more per step on the LIDAR
    envs, which do not render it otherwise)."""
    chase: bool = True
    """``/chase/image_raw`` where the env has ``render_mode="rgb_array"``."""
    path_every: int = 10
    """Steps between ``/path`` messages and between the poses they hold (each holds the
    whole path so far, so its cost grows with the episode divided by this)."""
    compression: str = "zstd"
    """MCAP chunk compression: ``zstd``, ``lz4`` or ``none``."""

    def __post_init__(self) -> None:
        if self.path_every < 1:
            raise ValueError(f"path_every must be >= 1 step, got {self.path_every}")
        if self.compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {COMPRESSIONS}, got "
                             f"{self.compression!r}")


def _ns(seconds: float) -> int:
    return int(round(seconds * _NS))


def _vector(x: float, y: float, z: float) -> Any:
    return ros_message("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def _quaternion(x: float, y: float, z: float, w: float) -> Any:
    return ros_message("geometry_msgs/msg/Quaternion", x=float(x), y=float(y), z=float(z),
                       w=float(w))


def _yaw_quaternion(yaw: float) -> Any:
    return _quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def _pose(x: float, y: float, z: float, orientation: Any) -> Any:
    point = ros_message("geometry_msgs/msg/Point", x=float(x), y=float(y), z=float(z))
    return ros_message("geometry_msgs/msg/Pose", position=point, orientation=orientation)


def _transform(ns: int, parent: str, child: str, translation: Any, rotation: Any) -> Any:
    return ros_message("geometry_msgs/msg/TransformStamped", header=ros_header(ns, parent),
                       child_frame_id=child,
                       transform=ros_message("geometry_msgs/msg/Transform",
                                             translation=translation, rotation=rotation))


def _base_of(env: gym.Env) -> RoverEnvBase:
    base = env.unwrapped
    if not isinstance(base, RoverEnvBase):
        raise TypeError(f"expected a roverav env (rover_env.RoverEnvBase), got "
                        f"{type(base).__name__}")
    return base


class EpisodeRecorder:
    """One episode of ``env`` written to the MCAP file ``path`` (module docstring).

    Call :meth:`reset` with what ``env.reset()`` returned, :meth:`step` with what each
    ``env.step()`` returned, then :meth:`close` (or use it as a context manager, which
    closes it, or drops the file when the block raises). The file appears at ``path`` only
    when closed (``<path>.part`` until then).

    :param env: a roverav env, wrapped or not (its ``render()`` gives the chase view).
    :param path: the ``.mcap`` file to write.
    :param config: what to write (:class:`RecordConfig`).
    :raises active_vision.ros_formats.RosExtraMissingError: ``roverav[ros]`` is missing.
    """

    def __init__(self, env: gym.Env, path: Path | str,
                 config: RecordConfig | None = None) -> None:
        self.env = env
        self.base = _base_of(env)
        self.config = config or RecordConfig()
        self.path = Path(path)
        model = self.base.sim.model
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, rover.BODY_NAME)
        joint = int(model.body_jntadr[body])
        self._body = body
        self._qpos = int(model.jnt_qposadr[joint])
        self._dof = int(model.jnt_dofadr[joint])
        self._wheels = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n)
                                 for n in rover.WHEEL_NAMES], dtype=np.intp)
        self._gravity = np.array(model.opt.gravity, dtype=np.float64)
        self._writer = McapWriter(self.path, compression=self.config.compression)
        self._steps = 0
        self._last_ns = 0
        self._path: list[Any] = []  # a pose every path_every steps
        self._pose: Any = None  # this step's PoseStamped
        self._walkers: np.ndarray | None = None
        self._walker_yaw = np.zeros(0)
        self._scan_angles: tuple[float, float] | None = None
        self._velocity: np.ndarray | None = None

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        return dict(self._writer.counts)

    # --- the episode ------------------------------------------------------------------
    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None:
        """Write the static transforms and the reset's observation."""
        ns = self._now()
        down = math.radians(rover.CAMERA_PITCH)
        self._writer.write(TF_STATIC_TOPIC, ros_message("tf2_msgs/msg/TFMessage", transforms=[
            _transform(ns, BASE_FRAME, LASER_FRAME, _vector(0.0, 0.0, rover.LIDAR_Z),
                       _quaternion(0.0, 0.0, 0.0, 1.0)),
            _transform(ns, BASE_FRAME, CAMERA_FRAME,
                       _vector(rover.CAMERA_X, 0.0, rover.CAMERA_Z),
                       _quaternion(0.0, math.sin(down / 2), 0.0, math.cos(down / 2))),
        ]), ns)
        self._observation(obs, ns)

    def step(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None:
        """Write the command the step applied and its observation."""
        linear, angular = rover.wheel_odometry(self.base.sim.data.ctrl[self._wheels])
        twist = ros_message("geometry_msgs/msg/Twist", linear=_vector(linear, 0.0, 0.0),
                            angular=_vector(0.0, 0.0, angular))
        self._writer.write(CMD_VEL_TOPIC, twist, self._last_ns)
        self._steps += 1
        ns = self._now()
        self._observation(obs, ns)
        if self._steps % self.config.path_every == 0:
            self._path.append(self._pose)
            self._write_path(ns)

    def close(self) -> Path:
        """Write the last path, finish the file and return its path."""
        if not self._writer.closed:
            if self._pose is not None and self._path[-1] is not self._pose:
                self._path.append(self._pose)
                self._write_path(self._last_ns)
            self._writer.close()
            logger.info("recorded %d steps to %s", self._steps, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the file being written."""
        self._writer.abort()

    def __enter__(self) -> EpisodeRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # --- messages ---------------------------------------------------------------------
    def _now(self) -> int:
        self._last_ns = _ns(self.base.sim.time)
        return self._last_ns

    def _observation(self, obs: dict[str, np.ndarray], ns: int) -> None:
        base, write, cfg = self.base, self._writer.write, self.config
        if cfg.camera:
            write(CAMERA_TOPIC, image_message(base.camera_frame(), ns, CAMERA_FRAME), ns)
        if cfg.chase and base.render_mode == "rgb_array":
            chase = self.env.render()
            if chase is not None:
                write(CHASE_TOPIC, image_message(np.asarray(chase), ns, CHASE_FRAME), ns)
        if "lidar" in obs:
            write(SCAN_TOPIC, self._scan(np.asarray(obs["lidar"]), ns), ns)
        if "fused_image" in obs:
            for topic, msg in fused_messages(np.asarray(obs["fused_image"]), ns, CAMERA_FRAME):
                write(topic, msg, ns)
        data = base.sim.data
        qw, qx, qy, qz = (float(v) for v in data.qpos[self._qpos + 3: self._qpos + 7])
        x, y, z = (float(v) for v in data.qpos[self._qpos: self._qpos + 3])
        orientation = _quaternion(qx, qy, qz, qw)
        write(IMU_TOPIC, self._imu(orientation, ns), ns)
        pose = _pose(x, y, z, orientation)
        linear, angular = (float(v) for v in base.odometry)
        twist = ros_message("geometry_msgs/msg/Twist", linear=_vector(linear, 0.0, 0.0),
                            angular=_vector(0.0, 0.0, angular))
        zeros = np.zeros(36, dtype=np.float64)
        write(ODOM_TOPIC, ros_message(
            "nav_msgs/msg/Odometry", header=ros_header(ns, ODOM_FRAME), child_frame_id=BASE_FRAME,
            pose=ros_message("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=zeros),
            twist=ros_message("geometry_msgs/msg/TwistWithCovariance", twist=twist,
                              covariance=zeros)), ns)
        write(TF_TOPIC, ros_message("tf2_msgs/msg/TFMessage", transforms=[
            _transform(ns, ODOM_FRAME, BASE_FRAME, _vector(x, y, z), orientation)]), ns)
        self._pose = ros_message("geometry_msgs/msg/PoseStamped",
                                 header=ros_header(ns, ODOM_FRAME), pose=pose)
        if not self._path:  # the reset's pose starts the path
            self._path.append(self._pose)
        world = base.world
        gx, gy = (float(v) for v in base.goal)
        write(GOAL_TOPIC, ros_message(
            "geometry_msgs/msg/PoseStamped", header=ros_header(ns, ODOM_FRAME),
            pose=_pose(gx, gy, world.ground_height(gx, gy), _quaternion(0.0, 0.0, 0.0, 1.0))),
            ns)
        write(PEDESTRIANS_TOPIC, self._pedestrians(ns), ns)

    def _scan(self, ranges: np.ndarray, ns: int) -> Any:
        n = len(ranges)
        if self._scan_angles is None:
            angles, per_point = rover.lidar_ray_angles(n)
            middles = angles.reshape(n, per_point).mean(axis=1)
            self._scan_angles = (float(middles[0]), float(middles[1] - middles[0]) if n > 1
                                 else 2 * math.pi)
        first, step = self._scan_angles
        top = float(self.base.max_lidar_range)
        out = np.where(ranges >= top, np.float32(np.inf), ranges).astype(np.float32)
        return ros_message(
            "sensor_msgs/msg/LaserScan", header=ros_header(ns, LASER_FRAME), angle_min=first,
            angle_max=first + (n - 1) * step, angle_increment=step, time_increment=0.0,
            scan_time=float(self.base.control_dt), range_min=0.0, range_max=top, ranges=out,
            intensities=np.zeros(0, dtype=np.float32))

    def _imu(self, orientation: Any, ns: int) -> Any:
        data, dof = self.base.sim.data, self._dof
        to_body = np.asarray(data.xmat[self._body], dtype=np.float64).reshape(3, 3).T
        spin = data.qvel[dof + 3: dof + 6]  # a free joint's angular velocity: body frame
        velocity = np.array(data.qvel[dof: dof + 3], dtype=np.float64)  # world frame
        # the mean acceleration over the step (MuJoCo's instantaneous one chatters with the
        # wheels' contacts), as an IMU's low-pass filter gives it
        accel = (np.zeros(3) if self._velocity is None
                 else (velocity - self._velocity) / float(self.base.control_dt))
        self._velocity = velocity
        force = to_body @ (accel - self._gravity)
        unknown = np.zeros(9, dtype=np.float64)
        return ros_message(
            "sensor_msgs/msg/Imu", header=ros_header(ns, BASE_FRAME), orientation=orientation,
            orientation_covariance=unknown, angular_velocity=_vector(*spin),
            angular_velocity_covariance=unknown, linear_acceleration=_vector(*force),
            linear_acceleration_covariance=unknown)

    def _pedestrians(self, ns: int) -> Any:
        base = self.base
        walkers = np.asarray(base.sim.pedestrian_positions, dtype=np.float64)
        if self._walkers is not None and len(self._walkers) == len(walkers):
            delta = walkers - self._walkers
            moved = np.hypot(delta[:, 0], delta[:, 1]) > _MOVED_M
            self._walker_yaw = np.where(moved, np.arctan2(delta[:, 1], delta[:, 0]),
                                        self._walker_yaw)
        else:
            self._walker_yaw = np.zeros(len(walkers))
        self._walkers = walkers
        world = base.world
        poses = [_pose(px, py, world.ground_height(px, py), _yaw_quaternion(yaw))
                 for (px, py), yaw in zip(walkers.tolist(), self._walker_yaw.tolist(),
                                          strict=True)]
        return ros_message("geometry_msgs/msg/PoseArray", header=ros_header(ns, ODOM_FRAME),
                           poses=poses)

    def _write_path(self, ns: int) -> None:
        self._writer.write(PATH_TOPIC, ros_message(
            "nav_msgs/msg/Path", header=ros_header(ns, ODOM_FRAME), poses=list(self._path)), ns)


def episode_path(directory: Path | str, seed: int | None, index: int) -> Path:
    """``directory/episode_<seed>.mcap``; ``episode_n<index>.mcap`` for an unseeded reset."""
    name = f"episode_{seed}" if seed is not None else f"episode_n{index}"
    return Path(directory) / f"{name}.mcap"


class RecordEpisodes(gym.Wrapper):
    """Every episode of ``env`` written as ``directory/episode_<seed>.mcap``
    (:func:`episode_path`) by an :class:`EpisodeRecorder`. An episode's file is closed when
    it ends (terminated or truncated), at the next ``reset()`` or at ``close()``;
    :attr:`paths` lists the files written.

    :param env: a roverav env (``render_mode="rgb_array"`` adds the chase view).
    :param directory: where the files go (made when needed).
    :param config: what to write (:class:`RecordConfig`).
    """

    def __init__(self, env: gym.Env, directory: Path | str,
                 config: RecordConfig | None = None) -> None:
        super().__init__(env)
        _base_of(env)
        self.directory = Path(directory)
        self.config = config or RecordConfig()
        self.recorder: EpisodeRecorder | None = None
        self.paths: list[Path] = []
        self._episodes = 0

    def _finish(self) -> None:
        if self.recorder is not None:
            self.paths.append(self.recorder.close())
            self.recorder = None

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self._finish()
        obs, info = self.env.reset(seed=seed, options=options)
        path = episode_path(self.directory, seed, self._episodes)
        self._episodes += 1
        self.recorder = EpisodeRecorder(self.env, path, self.config)
        self.recorder.reset(obs, info)
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.recorder is not None:
            self.recorder.step(obs, info)
            if terminated or truncated:
                self._finish()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        try:
            self._finish()
        finally:
            super().close()


__all__ = [
    "CHASE_TOPIC",
    "GOAL_TOPIC",
    "ODOM_TOPIC",
    "PATH_TOPIC",
    "PEDESTRIANS_TOPIC",
    "TF_STATIC_TOPIC",
    "TF_TOPIC",
    "EpisodeRecorder",
    "RecordConfig",
    "RecordEpisodes",
    "episode_path",
]
