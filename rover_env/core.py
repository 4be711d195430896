"""RoverEnvBase: what RoverEnv and the two fused envs share.

World and sim ownership, episode reset (spawn and goal sampled from the seed rectangles),
the PID heading controller, the target readout, goals (+100, new goal, episode goes on; or,
with ``goal_ends_episode=True``, +100 and the episode ends there),
the seed's safety checks (flip, stuck, stuck-in-collision, out of bounds) with per-env
thresholds from :class:`~rover_env.reward.RewardConfig`, the info dict, and the chase-camera
``render()``. Subclasses choose the observation and the action decoding through the hooks
listed in the class docstring.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from fused_image import FUSED_SIZE
from rover_env import constants as c
from rover_env import reward as rw
from rover_env.controller import HeadingPID, wrap_angle
from rover_env.errors import EnvClosedError, closed_env_message
from rover_env.pedestrians import CROSSING_MODES, DEFAULT_MODE, pedestrian_count, pedestrian_mode
from rover_env.reward import RewardConfig
from rover_env.simulation import PHYSICS_DT, RoverSim
from rover_env.worlds import canonical_world_name

log = logging.getLogger(__name__)

RENDER_SIZE = (480, 360)  # (width, height) of render_mode="rgb_array" frames
_F32 = np.float32


def float_box(low: tuple[float, ...], high: tuple[float, ...]) -> spaces.Box:
    """A float32 Box from per-dimension bounds."""
    return spaces.Box(low=np.array(low, dtype=_F32), high=np.array(high, dtype=_F32), dtype=_F32)


def state_spaces() -> dict[str, spaces.Box]:
    """The seed's ``pose``, ``imu``, ``target`` and ``velocities`` Boxes (shared by all envs)."""
    return {
        "pose": float_box(c.POSE_LOW, c.POSE_HIGH),
        "imu": float_box(c.IMU_LOW, c.IMU_HIGH),
        "target": float_box(c.TARGET_LOW, c.TARGET_HIGH),
        "velocities": float_box(c.VELOCITIES_LOW, c.VELOCITIES_HIGH),
    }


def _clamp(value: float, lo: float, hi: float) -> float:
    return lo if value < lo else hi if value > hi else value


@dataclass(frozen=True)
class EnvOptions:
    """The keyword-only options every roverav env accepts, declared once.

    Each env takes them as keywords (``RoverEnv(world_n="maze", control_dt=0.1)``) beside
    its seed arguments; an unknown keyword raises ``TypeError`` naming the accepted ones.
    The env keeps the validated set as ``env.options``.
    """

    control_dt: float = c.CONTROL_DT
    """Simulated seconds per step (the PID's dt)."""
    physics_dt: float = PHYSICS_DT
    """Largest physics step (s); the one used divides ``control_dt`` evenly."""
    reward_config: RewardConfig | None = None
    """Reward and termination constants; None: the env's own (``RewardConfig()`` for
    RoverEnv, ``RewardConfig.fused()`` for the fused envs)."""
    render_mode: str | None = None
    """None or ``"rgb_array"``: ``render()`` returns a chase-camera frame."""
    render_size: tuple[int, int] = RENDER_SIZE
    """(width, height) of ``render()`` frames."""
    pedestrian_mode: str = DEFAULT_MODE
    """How the pedestrians walk: ``crowd`` (the default: a social-force crowd walking to
    goals, routing around the scenery, keeping apart and making room for the rover),
    ``pacing`` (straight out-and-back paths, waiting when the rover is in the way),
    ``oblivious``
    (the same crowd, blind to the rover), ``crossing`` (the crowd walking across the line
    from the rover's start to its first goal, from the side: see
    ``Pedestrians.lay_crossings``) or ``groups`` (the crowd in groups of 2-3). ``walk``, the
    old name of ``pacing``, is accepted with a ``FutureWarning`` for one release."""
    n_pedestrians: int | None = None
    """Walking figures, 0 to 20; None: the world's own count (3)."""
    pedestrian_appearance: str = "fixed"
    """``"fixed"`` (the seed's look) or ``"random"`` (clothing colours, height, girth and
    gait phase drawn per episode, deterministic from the reset seed)."""
    goal_ends_episode: bool = False
    """False (the seed's): a reached goal pays ``goal_reward``, a new goal is drawn and the
    episode goes on. True (an RL task like CrowdNav's, and what the evaluators count): the
    step that reaches the goal pays its reward and ends the episode, ``terminated`` with
    ``info["termination_reason"] == "goal"`` and ``info["is_success"]`` True; the goal is
    not replaced, so ``info["goal"]`` and ``distance_to_goal`` are the reached one's."""

    def __post_init__(self) -> None:
        if not self.control_dt > 0:
            raise ValueError(f"control_dt must be > 0 s, got {self.control_dt}")
        if not self.physics_dt > 0:
            raise ValueError(f"physics_dt must be > 0 s, got {self.physics_dt}")
        if not isinstance(self.goal_ends_episode, bool | np.bool_):
            raise TypeError(
                f"goal_ends_episode must be True or False, got {self.goal_ends_episode!r}: "
                "True ends the episode at the first goal, False (the default) draws a new one"
            )
        object.__setattr__(self, "goal_ends_episode", bool(self.goal_ends_episode))
        object.__setattr__(self, "pedestrian_mode", pedestrian_mode(self.pedestrian_mode))
        if self.n_pedestrians is not None:
            object.__setattr__(self, "n_pedestrians", pedestrian_count(self.n_pedestrians))

    @classmethod
    def of(cls, owner: str, options: dict[str, Any]) -> EnvOptions:
        """The options from an env's keywords; ``TypeError`` naming ``owner`` and the accepted
        keywords for an unknown one."""
        unknown = sorted(set(options) - {f.name for f in dataclasses.fields(cls)})
        if "camera_scan" in unknown:
            raise TypeError(
                f"{owner}() has no fused image, so it takes no camera_scan: the scan is built "
                "from the fused image's depth and heatmap. The fused envs take it "
                "(RoverEnvFused, DiscreteRoverEnvFused, RoverEnvFusedGaze, "
                "DiscreteRoverEnvFusedGaze: roverav/RoverEnvFused-v0, "
                "roverav/RoverEnvFusedDiscrete-v0, roverav/RoverEnvFusedGaze-v0, "
                "roverav/RoverEnvFusedGazeDiscrete-v0); the LIDAR envs have their lidar key"
            )
        if unknown:
            accepted = ", ".join(f.name for f in dataclasses.fields(cls))
            raise TypeError(
                f"{owner}() got unexpected keyword argument(s) {', '.join(unknown)}; the "
                f"options common to the roverav envs are {accepted} (its docstring lists "
                "its own arguments)"
            )
        return cls(**options)


class RoverEnvBase(gym.Env):
    """Base class of the roverav envs (not registered itself).

    A step: decode the action into (speed, absolute desired heading) → PID yaw rate on
    simulated dt → drive command → ``control_dt`` seconds of physics → goal handling →
    observation → collision test → reward → safety checks → info.

    Override points (all have working defaults except ``_observe``):

    ``_decode_action(action) -> (speed m/s, absolute desired heading rad)``
        Default: a Box ``[speed, relative heading]`` clipped to ``action_space``, desired
        heading = current yaw + relative heading (the seed's continuous envs). Non-finite
        actions raise ``ValueError``. The discrete env maps an index to a speed level and
        an absolute compass heading.
    ``_observe() -> dict``
        The observation after the physics step (and at reset). Must return new arrays.
        :meth:`_state_observation` gives the shared ``pose``/``imu``/``target``/
        ``velocities`` entries.
    ``_collision() -> bool``
        Whether this step counts as a collision (penalty, and the stuck-in-collision
        count). Default: LIDAR minimum (kept as ``nearest_range``) below
        ``reward_config.collision_distance``.
    ``_task_reward(obs) -> float``
        The non-terminal reward. Default: goal + progress + velocity bonus + turn penalty +
        collision penalty (the seed's table) + clearance penalty + personal-space penalty
        (both off in the seed). Record
        each extra term with :meth:`_add_reward_term` so it shows in ``info``.
    ``_on_reset() -> None``
        Called after the sim and the goal are reset, before the first ``_observe`` (e.g. to
        drop stale shared-memory frames). Default: nothing.
    ``_default_reward_config() -> RewardConfig`` (classmethod)
        The constants used when ``reward_config`` is None. Default: ``RewardConfig()``.

    Readable per-step state for hooks: ``self.sim``, ``self.goal`` (x, y),
    ``self.distance_to_goal``, ``self.distance_delta`` (m closer to this step's goal),
    ``self.goal_reached`` (this step), ``self.collided``
    (this step), ``self.contact`` (the rover's body touched a pedestrian or the scenery this
    step), ``self.nearest_pedestrian`` (m), ``self.position`` (3,), ``self.orientation``
    (pitch, roll, yaw),
    ``self.odometry`` (linear, angular), ``self.reward_config``.

    Episode end: ``terminated`` for flip, stuck, stuck-in-collision and out of bounds
    (reward = that penalty alone, as in the seed), and with ``goal_ends_episode`` for the
    goal (reward = the step's task reward, goal reward included; a goal reached on the step
    of a failure counts as the goal, as the evaluators count it); ``truncated`` after
    ``length`` steps.
    The checks run after the physics step, so the step that causes a failure reports it
    (the seed checked at the top of the next step).

    :param world_n: ``inspect``, ``moon`` (``island``) or ``maze``.
    :param length: steps before ``truncated``.
    :param lidar_points: LIDAR points (also used by the default ``_collision``).
    :param max_lidar_range: LIDAR range in metres.
    :param camera_size: forward camera (height, width).
    :param options: the keyword-only options of :class:`EnvOptions` (``control_dt``,
        ``physics_dt``, ``reward_config``, ``render_mode``, ``render_size``,
        ``pedestrian_mode``, ``n_pedestrians``, ``pedestrian_appearance``,
        ``goal_ends_episode``); subclasses forward theirs here.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / c.CONTROL_DT))}

    def __init__(
        self,
        *,
        world_n: str = c.DEFAULT_WORLD,
        length: int = c.LENGTH,
        lidar_points: int = c.LIDAR_POINTS,
        max_lidar_range: float = c.MAX_LIDAR_RANGE,
        camera_size: tuple[int, int] = FUSED_SIZE,
        **options: Any,
    ) -> None:
        opts = EnvOptions.of(type(self).__name__, options)
        render_mode = opts.render_mode
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode {render_mode!r} is not supported; use one of "
                f"{self.metadata['render_modes']} or None"
            )
        if length < 1:
            raise ValueError(f"length must be >= 1 step, got {length}")
        self.options = opts
        self.pedestrian_mode = opts.pedestrian_mode
        self.goal_ends_episode = opts.goal_ends_episode
        self.world_name = canonical_world_name(world_n)
        self.length = int(length)
        self.lidar_points = int(lidar_points)
        self.max_lidar_range = float(max_lidar_range)
        self.control_dt = float(opts.control_dt)
        self.reward_config = (
            opts.reward_config if opts.reward_config is not None else self._default_reward_config()
        )
        self.render_mode = render_mode
        self.render_size = (int(opts.render_size[0]), int(opts.render_size[1]))
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.control_dt))}
        # physics_dt is the largest physics step: the one used divides control_dt evenly.
        self.physics_substeps = max(1, math.ceil(self.control_dt / opts.physics_dt - 1e-9))
        self.sim = RoverSim(
            self.world_name,
            camera_size=camera_size,
            physics_dt=self.control_dt / self.physics_substeps,
            pedestrian_appearance=opts.pedestrian_appearance,
            n_pedestrians=opts.n_pedestrians,
            pedestrian_mode=opts.pedestrian_mode,
        )
        self.world = self.sim.world
        self.pid = HeadingPID(dt=self.control_dt)
        # Episode state (set properly by reset()).
        self.goal = (0.0, 0.0)
        self.position = np.zeros(3)
        self.orientation = np.zeros(3)
        self.odometry = np.zeros(2)
        self.distance_to_goal = 0.0
        self._previous_distance = 0.0
        self._total_steps = 0
        self._positions: deque[tuple[float, float]] = deque(
            maxlen=self.reward_config.stuck_window + 1
        )
        self._clear_episode()
        self._needs_reset = True
        self._closed = False

    # --- hooks --------------------------------------------------------------------------------
    @classmethod
    def _default_reward_config(cls) -> RewardConfig:
        """The reward constants when ``reward_config`` is None: ``RewardConfig()``."""
        return RewardConfig()

    def _decode_action(self, action: Any) -> tuple[float, float]:
        """(speed m/s, absolute desired heading rad) from a ``[speed, relative heading]``."""
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (2,):
            raise ValueError(f"action must have 2 values [speed, heading], got shape {a.shape}")
        speed, heading = float(a[0]), float(a[1])
        if not (math.isfinite(speed) and math.isfinite(heading)):
            raise ValueError(f"action must be finite, got {a.tolist()}")
        box = cast(spaces.Box, self.action_space)  # the discrete envs override this method
        low, high = box.low, box.high
        speed = _clamp(speed, float(low[0]), float(high[0]))
        heading = _clamp(heading, float(low[1]), float(high[1]))
        return speed, float(self.orientation[2]) + heading

    def _observe(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def _collision(self) -> bool:
        self.nearest_range = float(self.sim.lidar(self.lidar_points, self.max_lidar_range).min())
        return self.nearest_range < self.reward_config.collision_distance

    def _task_reward(self, obs: dict[str, np.ndarray]) -> float:
        cfg = self.reward_config
        terms = self._reward_terms
        terms["reward_goal"] = rw.goal_reward(self.goal_reached, cfg)
        terms["reward_progress"] = rw.progress_reward(self.distance_delta, cfg)
        terms["reward_velocity"] = rw.velocity_bonus(float(self.odometry[0]), cfg)
        terms["reward_turn"] = rw.turn_penalty(float(self.odometry[1]), cfg)
        terms["reward_collision"] = rw.collision_penalty(self.collided, cfg)
        terms["reward_clearance"] = (rw.clearance_penalty(self.clearance_range(self.nearest_range),
                                                          cfg) if cfg.clearance_penalty else 0.0)
        terms["reward_personal_space"] = rw.personal_space_penalty(self.nearest_pedestrian, cfg)
        return (
            terms["reward_goal"]
            + terms["reward_progress"]
            + terms["reward_velocity"]
            + terms["reward_turn"]
            + terms["reward_collision"]
            + terms["reward_clearance"]
            + terms["reward_personal_space"]
        )

    def _on_reset(self) -> None:
        return None

    # --- helpers for subclasses ---------------------------------------------------------------
    def _add_reward_term(self, name: str, value: float) -> float:
        """Record a reward component for ``info`` (``reward_<name>``) and return it."""
        self._reward_terms[f"reward_{name}"] = value
        return value

    def _state_observation(self) -> dict[str, np.ndarray]:
        """New float32 arrays for ``pose``, ``imu``, ``target``, ``velocities``, clipped to
        the seed's bounds."""
        x, y, z = self.position
        pitch, roll, yaw = self.orientation
        lin, ang = self.odometry
        pose_hi, vel_hi = c.POSE_HIGH, c.VELOCITIES_HIGH
        return {
            "pose": np.array(
                (
                    _clamp(x, -pose_hi[0], pose_hi[0]),
                    _clamp(y, -pose_hi[1], pose_hi[1]),
                    _clamp(z, -pose_hi[2], pose_hi[2]),
                ),
                dtype=_F32,
            ),
            "imu": np.array((pitch, roll, yaw), dtype=_F32),
            "target": np.array(
                (min(self.distance_to_goal, c.TARGET_HIGH[0]), self.relative_goal_angle()),
                dtype=_F32,
            ),
            "velocities": np.array(
                (_clamp(lin, -vel_hi[0], vel_hi[0]), _clamp(ang, -vel_hi[1], vel_hi[1])),
                dtype=_F32,
            ),
        }

    def relative_goal_angle(self) -> float:
        """Bearing of the goal relative to the rover's heading, in [-pi, pi]."""
        bearing = math.atan2(self.goal[1] - self.position[1], self.goal[0] - self.position[0])
        return wrap_angle(bearing - self.orientation[2])

    def min_pedestrian_distance(self) -> float:
        """Distance (m) from the rover to the nearest pedestrian (inf with none)."""
        peds = self.sim.pedestrians.positions
        if len(peds) == 0:
            return math.inf
        return float(np.hypot(peds[:, 0] - self.position[0], peds[:, 1] - self.position[1]).min())

    def nearest_pedestrian_index(self) -> int:
        """Index of the pedestrian nearest the rover (-1 with none)."""
        peds = self.sim.pedestrians.positions
        if len(peds) == 0:
            return -1
        d = np.hypot(peds[:, 0] - self.position[0], peds[:, 1] - self.position[1])
        return int(np.argmin(d))

    # --- state --------------------------------------------------------------------------------
    def _clear_episode(self) -> None:
        """Zero the per-episode counters (construction and every reset)."""
        self.goals_reached = 0
        self.collision_count = 0
        self.goal_reached = False
        self.collided = False
        self.nearest_range = float(self.max_lidar_range)
        self.pedestrian_contact = False
        self.contact = False
        self.nearest_pedestrian = math.inf
        self.distance_delta = 0.0
        self._steps = 0
        self._episode_reward = 0.0
        self._positions.clear()
        self._reward_terms: dict[str, float] = {}

    def _read_state(self) -> None:
        sim = self.sim
        self.position = sim.position
        self.orientation = sim.orientation
        self.odometry = sim.velocities
        self.distance_to_goal = math.hypot(
            self.goal[0] - self.position[0], self.goal[1] - self.position[1]
        )

    def _sample_goal(self) -> None:
        cfg, world, rng = self.reward_config, self.world, self.np_random
        for _ in range(100):
            gx, gy = world.sample_free(rng, world.goal, 0.3)
            if math.hypot(gx - self.position[0], gy - self.position[1]) >= cfg.min_goal_distance:
                break
        self.goal = (gx, gy)
        self.sim.set_goal_marker(gx, gy)
        self.distance_to_goal = math.hypot(gx - self.position[0], gy - self.position[1])
        self._previous_distance = self.distance_to_goal

    def set_goal(self, x: float, y: float) -> None:
        """Put the current goal at (x, y) (evaluation scripts, tests)."""
        self.goal = (float(x), float(y))
        self.sim.set_goal_marker(self.goal[0], self.goal[1])
        self.distance_to_goal = math.hypot(x - self.position[0], y - self.position[1])
        self._previous_distance = self.distance_to_goal

    def _flip_direction(self) -> str:
        """The seed's is_robot_flipped(): '' or roll_left/roll_right/pitch_forward/
        pitch_backward."""
        pitch, roll = self.orientation[0], self.orientation[1]
        threshold = self.reward_config.flip_threshold
        if abs(roll) > threshold:
            return "roll_left" if roll > 0 else "roll_right"
        if abs(pitch) > threshold:
            return "pitch_forward" if pitch > 0 else "pitch_backward"
        return ""

    def _termination(self) -> str:
        """The first failure this step, in the seed's order ('' if none)."""
        cfg = self.reward_config
        if self._flip_direction():
            return rw.FLIPPED
        if self.collision_count > cfg.collision_limit:
            return rw.STUCK_IN_COLLISION
        history = self._positions
        if len(history) == history.maxlen:
            (x0, y0), (x1, y1) = history[0], history[-1]
            if math.hypot(x1 - x0, y1 - y0) < cfg.stuck_threshold:
                return rw.STUCK
        if not self.world.in_bounds(self.position[0], self.position[1]):
            return rw.OUT_OF_BOUNDS
        return ""

    # --- gymnasium API ---------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode: free spawn with random yaw, new goal, new pedestrian paths.

        ``options`` (all optional): ``rover_pose`` (x, y, yaw) places the rover there;
        ``goal`` (x, y) places the goal there.
        """
        self._check_open("reset")
        super().reset(seed=seed)
        if seed is not None:
            self._total_steps = 0  # a seeded reset starts a reproducible run
        options = options or {}
        self.sim.reset(self.np_random)
        if "rover_pose" in options:
            x, y, yaw = options["rover_pose"]
            self.sim.set_rover_pose(float(x), float(y), float(yaw))
        self.pid.reset()
        self._read_state()
        if "goal" in options:
            self.set_goal(*options["goal"])
        else:
            self._sample_goal()
        if self.pedestrian_mode in CROSSING_MODES:
            start = (float(self.position[0]), float(self.position[1]))
            self.sim.pedestrians.lay_crossings(self.np_random, start, self.goal)
        self._clear_episode()
        self._positions.append((float(self.position[0]), float(self.position[1])))
        self._needs_reset = False
        self._on_reset()
        obs = self._observe()
        return obs, self._info(0.0, "")

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self._check_open("step")
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode ends)")
        speed, desired_heading = self._decode_action(action)
        angular = self.pid.update(desired_heading, float(self.orientation[2]))
        self.sim.set_command(speed, angular)
        self.sim.advance(self.control_dt)
        self._steps += 1
        self._total_steps += 1
        self._read_state()
        self._positions.append((float(self.position[0]), float(self.position[1])))
        contacts = self.sim.rover_contacts()
        self.pedestrian_contact = contacts.pedestrian or self.sim.pedestrians.touching_rover
        self.contact = contacts.obstacle or self.pedestrian_contact
        self.nearest_pedestrian = self.min_pedestrian_distance()

        # Progress is measured against the goal of this step, even if it was just reached.
        self.distance_delta = self._previous_distance - self.distance_to_goal
        self.goal_reached = self.distance_to_goal < self.reward_config.success_distance
        if self.goal_reached:  # +100, and a new goal unless the goal ends the episode
            self.goals_reached += 1
            log.debug("goal %d reached at step %d", self.goals_reached, self._steps)
            if not self.goal_ends_episode:
                self._sample_goal()
        self._previous_distance = self.distance_to_goal
        obs = self._observe()
        self.collided = self._collision() or (
            self.reward_config.contact_is_collision and self.contact
        )
        if self.collided:
            self.collision_count += 1
        self._reward_terms = {}
        reward = self._task_reward(obs)

        if self.goal_reached and self.goal_ends_episode:
            reason = rw.GOAL  # the task reward stands: goal reward and this step's terms
        else:
            reason = self._termination()
        terminated = bool(reason)
        failed = terminated and reason != rw.GOAL
        if failed:
            # The seed returns the penalty alone on a failing step.
            reward = rw.termination_penalty(reason, self.reward_config)
            for key in self._reward_terms:
                self._reward_terms[key] = 0.0
        if terminated:
            self._needs_reset = True
        self._reward_terms["reward_termination"] = reward if failed else 0.0
        truncated = not terminated and self._steps >= self.length
        if truncated:
            reason = rw.TIME_LIMIT
            self._needs_reset = True
        self._episode_reward += reward
        info = self._info(reward, reason)
        if terminated and reason == rw.FLIPPED:
            info["flip_direction"] = self._flip_direction()
        return obs, float(reward), terminated, truncated, info

    def _info(self, reward: float, reason: str) -> dict[str, Any]:
        scenery = self.sim.rover_contacts().obstacle
        info: dict[str, Any] = {
            "steps": self._steps,
            "total_steps": self._total_steps,
            "reward": reward,
            "episode_reward": self._episode_reward,
            "goals_reached": self.goals_reached,
            "is_success": self.goals_reached > 0,
            "collision": self.collided,
            "collision_count": self.collision_count,
            "scenery_contact": scenery,
            "contact": scenery or self.pedestrian_contact,
            "termination_reason": reason,
            "distance_to_goal": self.distance_to_goal,
            **self._social_info(),
            "x_position": float(self.position[0]),
            "y_position": float(self.position[1]),
            "goal": self.goal,
        }
        info.update(self._reward_terms)
        return info

    def _social_info(self) -> dict[str, Any]:
        """The social metrics of this step (every env's ``info``)."""
        d_ped = self.min_pedestrian_distance()
        contact = self.pedestrian_contact
        rover_moving = abs(float(self.odometry[0])) >= c.ROVER_STOPPED_SPEED
        return {
            "min_pedestrian_distance": d_ped,
            "personal_space_intrusion": bool(d_ped < c.PERSONAL_SPACE_M),
            "intimate_space_intrusion": bool(d_ped < c.INTIMATE_SPACE_M),
            "pedestrian_collision": contact,
            "rover_hit_pedestrian": contact and rover_moving,
            "pedestrian_hit_rover": contact and not rover_moving,
        }

    def render(self) -> np.ndarray | None:
        """``rgb_array``: a chase-camera frame (``render_size`` = (width, height))."""
        self._check_open("render")
        if self.render_mode != "rgb_array":
            if self.render_mode is None:
                gym.logger.warn(
                    "render() called with render_mode=None; construct the env with "
                    'render_mode="rgb_array" to get frames'
                )
            return None
        return self.sim.render_chase(*self.render_size)

    @property
    def camera_size(self) -> tuple[int, int]:
        """(height, width) of the forward camera's frames (the ``camera_size`` keyword)."""
        return self.sim.camera_size

    def camera_frame(self) -> np.ndarray:
        """The forward camera's RGB frame now: (height, width, 3) uint8, a new array. The
        frame a fused env hands the av-daemon; for perception run in this process
        (``rover_train.imitation.dagger.FusedView``)."""
        self._check_open("camera_frame")
        return self.sim.render_camera().rgb

    def clearance_range(self, lidar_min: float) -> float:
        """The range the clearance term charges: the LIDAR minimum ``lidar_min``, or with
        ``reward_config.clearance_footprints`` the rover centre's distance to the nearest
        obstacle footprint where that is nearer."""
        if not self.reward_config.clearance_footprints:
            return lidar_min
        x, y = float(self.position[0]), float(self.position[1])
        return min(lidar_min, self.world.clearance(x, y))

    def set_reward_config(self, reward_config: RewardConfig) -> None:
        """Replace the reward constants from the next step on (a curriculum's switch, e.g.
        ``rover-train --clearance-from``; through a vector env:
        ``venv.env_method("set_reward_config", cfg)``). ``stuck_window`` sizes the episode's
        position history, so it must stay as it was."""
        if not isinstance(reward_config, RewardConfig):
            raise TypeError(f"set_reward_config takes a RewardConfig, got {type(reward_config)!r}")
        if reward_config.stuck_window != self.reward_config.stuck_window:
            raise ValueError(
                f"set_reward_config cannot change stuck_window ({self.reward_config.stuck_window} "
                f"-> {reward_config.stuck_window}) on a built env: pass it as reward_config "
                "when the env is made"
            )
        self.reward_config = reward_config

    @property
    def closed(self) -> bool:
        """True after :meth:`close` (then reset/step/render raise :class:`EnvClosedError`)."""
        return self._closed

    def _check_open(self, method: str) -> None:
        if self._closed:
            raise EnvClosedError(closed_env_message(type(self).__name__, method))

    def close(self) -> None:
        """Free the renderer. Idempotent; afterwards reset/step/render raise
        :class:`~rover_env.errors.EnvClosedError`."""
        self._closed = True
        self.sim.close()
        super().close()
