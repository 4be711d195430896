"""What rover-train may put between a fused env and the policy, and how an agent trained so
drives the plain env.

- :class:`RelativeTable` (``rover-train --relative-table``): ``Discrete(60)`` over a
  continuous env's ``[speed, relative heading]`` action, the seed's 5 speeds x 12 headings
  relative to the yaw, exactly ``RoverEnvDiscrete``'s table (on a gaze env ``Discrete(300)``:
  each of them with each of the 5 pan windows as the camera's target; or, with
  ``pan_head=True`` (``--pan-head``), ``MultiDiscrete([60, 5])``: the drive and the pan
  window as two heads of the policy). PPO from scratch learns the
  nav task on that table where Gaussian noise on the box, filtered out by the rover's
  inertia, did not (the LIDAR RL entries); the fused discrete env's table steers to
  absolute compass headings, which a policy must then learn at every yaw.
- :class:`DropImage` (``rover-train --drop-image``): the observation without
  ``fused_image``, so the policy reads the camera scan and the state (an MLP) and not the
  pixels (a CNN): the daemon still perceives every frame, and the scan is made from it.

And what gives RoverEnv (no daemon) the action interface of the gaze and discrete envs, so
that an agent or teacher made for those drives it (the lab's DAgger stage 1, benchmarks):

- :class:`WithPanHead`: RoverEnvFusedGaze's ``[speed, relative heading, pan target]``, the
  sim's camera turned by the gaze env's servo;
- :class:`WithSeedTable`: the seed's table of the fused discrete envs, ``Discrete(60)``, or
  ``Discrete(180)`` over :class:`WithPanHead`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env.controller import wrap_angle
from rover_env.core import float_box
from rover_env.discrete_env import (
    DIRECTION_ANGLES,
    N_DIRECTIONS,
    N_SEED_ACTIONS,
    SPEED_LEVELS,
    action_index,
    decode_action,
)
from rover_env.gaze_discrete_env import (
    CENTRE_WINDOW,
    N_GAZE_ACTIONS,
    PAN_WINDOWS,
    decode_gaze_action,
    moved_window,
)
from rover_env.gaze_env import servo_step

IMAGE_KEY = "fused_image"
RELATIVE_ANGLES = np.linspace(-np.pi, np.pi, N_DIRECTIONS, endpoint=False)
"""Heading k of the relative table: ``-pi + k * pi / 6`` rad from the yaw (k = 6 straight on)."""


N_LOOKING_ACTIONS = N_SEED_ACTIONS * len(PAN_WINDOWS)
"""The relative table with a pan target: 60 drives x the 5 pan windows (-60 to +60 deg)."""


def relative_action(action: Any) -> np.ndarray:
    """The ``[speed, relative heading]`` float32 command of a table action in ``0..59``."""
    speed_idx, direction_idx = decode_action(action)
    return np.array([SPEED_LEVELS[speed_idx], RELATIVE_ANGLES[direction_idx]], dtype=np.float32)


def relative_head_action(action: Any) -> np.ndarray:
    """The ``[speed, relative heading, pan target]`` float32 command of a two-head action
    ``[drive, window]`` (``MultiDiscrete([60, 5])``: the relative table's action and the pan
    window, ``PAN_WINDOWS`` index); the same command as :func:`relative_looking_action` of
    ``drive * 5 + window``."""
    drive, window = (int(a) for a in np.asarray(action).reshape(-1))
    if not (0 <= drive < N_SEED_ACTIONS and 0 <= window < len(PAN_WINDOWS)):
        raise ValueError(f"a two-head action is [drive 0..{N_SEED_ACTIONS - 1}, pan window "
                         f"0..{len(PAN_WINDOWS) - 1}], got {action!r}")  # fmt: skip
    return np.array([*relative_action(drive), PAN_WINDOWS[window]], dtype=np.float32)


def relative_looking_action(action: Any) -> np.ndarray:
    """The ``[speed, relative heading, pan target]`` float32 command of an action in
    ``0..299`` of the relative table with a pan target: ``action // 5`` is the drive (the
    relative table's action), ``action % 5`` the pan window (``PAN_WINDOWS``, index 0 =
    -60 deg, right of the heading; 2 = straight ahead)."""
    index = action_index(action, N_LOOKING_ACTIONS)
    drive, window = divmod(index, len(PAN_WINDOWS))
    return np.array([*relative_action(drive), PAN_WINDOWS[window]], dtype=np.float32)


class RelativeTable(gym.ActionWrapper):
    """The relative table over an env whose actions are ``[speed, relative heading]``:
    ``Discrete(60)`` (see the module docstring); over a gaze env's ``[speed, relative heading,
    pan target]``: ``Discrete(300)``, each drive with each of the 5 pan windows as the pan
    target (:func:`relative_looking_action`), so that one policy chooses how to drive and
    where to look, each step, with no state in between; with ``pan_head=True``,
    ``MultiDiscrete([60, 5])`` (:func:`relative_head_action`): the drive and the window are
    two heads, each of 60 and 5 choices, so what the reward teaches of one is not spread over
    the other's 5 or 60 copies of it."""

    def __init__(self, env: gym.Env, pan_head: bool = False) -> None:
        super().__init__(env)
        box = env.action_space
        if not isinstance(box, spaces.Box) or box.shape[0] not in (2, 3):
            raise ValueError(
                f"the relative table drives a continuous [speed, relative heading] action (or "
                f"with a pan target); this env's action space is {box} (use --env fused or "
                f"fused-gaze)"
            )
        self.looking = box.shape[0] == 3
        if pan_head and not self.looking:
            raise ValueError("pan_head (--pan-head) splits a gaze env's table into a drive head "
                             "and a pan head; this env has no pan (use --env fused-gaze)")
        self.pan_head = pan_head
        self._command = table_command(self.looking, pan_head)
        table = N_LOOKING_ACTIONS if self.looking else N_SEED_ACTIONS
        self.action_space: spaces.Space[Any] = (
            spaces.MultiDiscrete([N_SEED_ACTIONS, len(PAN_WINDOWS)]) if pan_head
            else spaces.Discrete(table))  # fmt: skip

    def action(self, action: Any) -> np.ndarray:
        return self._command(action)


def table_command(looking: bool, pan_head: bool = False) -> Callable[[Any], np.ndarray]:
    """What turns a relative-table action into the env's command (see
    :class:`RelativeTable`): on a gaze env (``looking``) with one head or two, else the
    table's own."""
    if pan_head:
        return relative_head_action
    return relative_looking_action if looking else relative_action


class DropImage(gym.ObservationWrapper):
    """The observation without ``fused_image`` (see the module docstring)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, spaces.Dict) or IMAGE_KEY not in space.spaces:
            raise ValueError(f"--drop-image takes {IMAGE_KEY!r} out of a fused env's "
                             f"observation; this env's has none ({space})")  # fmt: skip
        self.observation_space = spaces.Dict(
            {k: s for k, s in space.spaces.items() if k != IMAGE_KEY}
        )

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        return drop_image(observation)


def drop_image(observation: dict[str, Any]) -> dict[str, Any]:
    """``observation`` without ``fused_image`` (a new dict)."""
    return {k: v for k, v in observation.items() if k != IMAGE_KEY}


def agent_io(recipe: dict[str, Any]) -> tuple[Callable[[Any], Any] | None,
                                              Callable[[Any], Any] | None]:  # fmt: skip
    """What an agent trained with ``recipe`` (a rover-train model's stored arguments) does
    to the plain env's observations, and to its own actions, to drive that env as it was
    trained: (observe, act), each None when nothing is to be done."""
    steps: list[Callable[[Any], Any]] = []
    if recipe.get("waypoint"):
        from rover_train.waypoint import observer

        steps.append(observer(recipe["world"]))
    if recipe.get("drop_image"):
        steps.append(drop_image)

    def observe(obs: Any) -> Any:
        for step in steps:
            obs = step(obs)
        return obs

    act = None
    if recipe.get("relative_table"):
        act = table_command(recipe.get("env") == "fused-gaze", bool(recipe.get("pan_head")))
    return (observe if steps else None), act


def takes_pan(env: object) -> bool:
    """Whether ``env``'s actions are the gaze env's ``[speed, heading, pan target]`` (a
    ``Box`` of 3)."""
    space = getattr(env, "action_space", None)
    return isinstance(space, spaces.Box) and space.shape == (3,)


@dataclass(frozen=True)
class FirstContact:
    """An episode's first pedestrian contact, as :class:`WithPanHead` saw it."""

    step: int
    first_seen: tuple[float, float] | None
    """Where the person touched was when first inside the camera's view (within 10 m, a
    geometric test) this episode: (m from the rover, bearing in degrees from its heading,
    left positive); None when never before the contact."""

    @property
    def seen_before(self) -> bool:
        """Whether the person touched had been in the camera's view before the contact."""
        return self.first_seen is not None


class ViewLog:
    """Where each pedestrian was when first inside the camera's view this episode (a
    geometric test within 10 m: ``RoverSim.pedestrians_in_view``), and the episode's first
    pedestrian contact (:class:`FirstContact`): was the person touched seen before?"""

    def __init__(self) -> None:
        self.first_contact: FirstContact | None = None
        self._first_seen = np.zeros((0, 2))

    def reset(self, base: Any) -> None:
        """A new episode of ``base`` (an unwrapped rover env); call before its first
        :meth:`note`."""
        self.first_contact = None
        self._first_seen = np.full((len(base.sim.pedestrian_positions), 2), np.nan)

    def note(self, base: Any, in_view: np.ndarray) -> None:
        """Record where each pedestrian in view now (``in_view``, (P,) bool) was first seen
        from: (m from the rover, bearing in degrees from its heading, left positive)."""
        new = in_view & ~np.isfinite(self._first_seen[:, 0])
        if new.any():
            rel = base.sim.pedestrian_positions[new] - base.position[:2]
            bearing = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]) - base.orientation[2])
            self._first_seen[new, 0] = np.hypot(rel[:, 0], rel[:, 1])
            self._first_seen[new, 1] = (bearing + 180.0) % 360.0 - 180.0

    def contact(self, base: Any, step: int) -> None:
        """A pedestrian contact at ``step``: the episode's first is kept, with the nearest
        person (the one touched) and whether, and where, they had been seen before."""
        if self.first_contact is not None:
            return
        seen = self._first_seen[base.nearest_pedestrian_index()]
        self.first_contact = FirstContact(
            step, (float(seen[0]), float(seen[1])) if np.isfinite(seen[0]) else None)


class ContactOrigins(gym.Wrapper):
    """Any rover env (LIDAR, fused or gaze), unchanged, with :attr:`first_contact`: the
    episode's first pedestrian contact and whether the person touched had been in the
    camera's view before it (:class:`ViewLog`, on the camera as it was each step: ahead for a
    fixed camera, turned for a gaze agent). What looking could ever win: a contact with a
    person never in a fixed camera's view."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.views = ViewLog()
        self.steps = 0

    @property
    def first_contact(self) -> FirstContact | None:
        return self.views.first_contact

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        base: Any = self.env.unwrapped
        self.steps = 0
        self.views.reset(base)
        self.views.note(base, base.sim.pedestrians_in_view())
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        base: Any = self.env.unwrapped
        self.steps += 1
        if info.get("pedestrian_collision"):
            self.views.contact(base, self.steps)
        self.views.note(base, base.sim.pedestrians_in_view())
        return obs, float(reward), terminated, truncated, info


class WithPanHead(gym.Wrapper):
    """An env without a pan action (RoverEnv) driven as RoverEnvFusedGaze is: the action is
    ``[speed, relative heading, pan target]``, after each step the sim's camera head turns
    towards the target at ``pan_rate`` (:func:`rover_env.gaze_env.servo_step`, the gaze env's
    servo), and it faces ahead again at every reset. The observation gains ``gaze`` (the pan,
    rad) and ``info`` the gaze env's ``pan``, ``pan_target``, ``pedestrian_in_view`` and
    ``nearest_pedestrian_in_view``. The episode's counts are :attr:`steps` and
    :attr:`nearest_in_view_steps`; :attr:`first_contact` says, for the episode's first
    pedestrian contact, whether the person touched had been in the camera's view before it
    and where (:class:`FirstContact`).

    The inner env must render nothing in ``step`` (RoverEnv): a fused env would render its
    frame before the head turns. For a fused image of the turned camera the lab wraps this
    one in ``rover_train.imitation.dagger.WithFusedView``.
    """

    def __init__(self, env: gym.Env, pan_rate: float | None = c.PAN_RATE) -> None:
        super().__init__(env)
        self.pan_rate = pan_rate
        self.pan_limit = c.PAN_LIMIT
        self.action_space = float_box(c.GAZE_ACTION_LOW, c.GAZE_ACTION_HIGH)
        self.observation_space = spaces.Dict(
            {**env.observation_space.spaces,  # type: ignore[attr-defined]
             "gaze": spaces.Box(-self.pan_limit, self.pan_limit, shape=(1,), dtype=np.float32)}
        )  # fmt: skip
        self.pan_target = 0.0
        self.steps = 0
        self.nearest_in_view_steps = 0
        self.views = ViewLog()
        self._in_view = np.zeros(0, dtype=bool)

    @property
    def first_contact(self) -> FirstContact | None:
        return self.views.first_contact

    def reset(self, **kwargs: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        base = self.env.unwrapped
        base.sim.set_camera_pan(0.0)  # type: ignore[attr-defined]
        self.pan_target = 0.0
        self.steps = self.nearest_in_view_steps = 0
        obs, info = self.env.reset(**kwargs)
        self.views.reset(base)
        info = self._info(info)
        self.views.note(base, self._in_view)
        return self._observation(obs), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(
                f"action {action!r}: expected 3 finite numbers [speed m/s, relative heading "
                "rad, pan target rad]"
            )
        obs, reward, terminated, truncated, info = self.env.step(a[:2].astype(np.float32))
        self.pan_target = min(max(float(a[2]), -self.pan_limit), self.pan_limit)
        sim = self.env.unwrapped.sim  # type: ignore[attr-defined]
        sim.set_camera_pan(servo_step(sim.camera_pan, self.pan_target, self.pan_rate,
                                      self.env.unwrapped.control_dt))  # type: ignore[attr-defined]  # fmt: skip
        info = self._info(info)
        self.steps += 1
        self.nearest_in_view_steps += info["nearest_pedestrian_in_view"]
        base: Any = self.env.unwrapped
        if info.get("pedestrian_collision"):
            self.views.contact(base, self.steps)
        self.views.note(base, self._in_view)
        return self._observation(obs), float(reward), terminated, truncated, info

    def _observation(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        pan = self.env.unwrapped.sim.camera_pan  # type: ignore[attr-defined]
        return {**obs, "gaze": np.array([pan], dtype=np.float32)}

    def _info(self, info: dict[str, Any]) -> dict[str, Any]:
        base: Any = self.env.unwrapped
        in_view = self._in_view = base.sim.pedestrians_in_view()
        nearest = base.nearest_pedestrian_index()
        return {
            **info,
            "pan": base.sim.camera_pan,
            "pan_target": self.pan_target,
            "pedestrian_in_view": bool(in_view.any()),
            "nearest_pedestrian_in_view": bool(nearest >= 0 and in_view[nearest]),
        }


class WithSeedTable(gym.Wrapper):
    """``env`` driven through the seed's table: ``Discrete(60)`` (5 speeds x 12 absolute
    compass headings, RoverEnvFusedDiscrete's) over an env of ``[speed, relative heading]``,
    ``Discrete(180)`` (with the 3 pan moves, RoverEnvFusedGazeDiscrete's) over one of
    ``[speed, relative heading, pan target]``. A pan move steps :attr:`pan_window` (centre at
    every reset), whose angle is the pan target the inner env's servo turns to; ``info``
    gains ``pan_window``. Everything else is the inner env's."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.gaze = takes_pan(env)
        if not self.gaze and getattr(env.action_space, "shape", None) != (2,):
            raise ValueError(f"the seed's table drives an env of [speed, relative heading] "
                             f"(or with a pan target); this one takes {env.action_space}")
        self.action_space = spaces.Discrete(N_GAZE_ACTIONS if self.gaze else N_SEED_ACTIONS)
        self.pan_window = CENTRE_WINDOW

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.pan_window = CENTRE_WINDOW
        obs, info = self.env.reset(**kwargs)
        return obs, self._info(info)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self.gaze:
            speed_idx, direction_idx, pan_move = decode_gaze_action(action)
            self.pan_window = moved_window(self.pan_window, pan_move)
            pan = [PAN_WINDOWS[self.pan_window]]
        else:
            speed_idx, direction_idx = decode_action(action)
            pan = []
        yaw = float(self.env.unwrapped.orientation[2])  # type: ignore[attr-defined]
        heading = wrap_angle(float(DIRECTION_ANGLES[direction_idx]) - yaw)
        command = np.array([SPEED_LEVELS[speed_idx], heading, *pan], dtype=np.float32)
        obs, reward, terminated, truncated, info = self.env.step(command)
        return obs, float(reward), terminated, truncated, self._info(info)

    def _info(self, info: dict[str, Any]) -> dict[str, Any]:
        return {**info, "pan_window": self.pan_window} if self.gaze else info
