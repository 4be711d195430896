"""A collision shield on the camera scan: the table actions whose next half second keeps the
rover's body off what its own camera has seen.

A learnt policy that sees part of the world touches things it has seen: the camera agents'
touches are mostly scenery at a front corner while turning (docs/decisions.md, "RL"), and the
camera scan knows 82-88 % of the scenery within 1 m. Robot stacks keep a last line of defence
beside the planner for this (Nav2's collision monitor slows or stops on the sensor's points,
whatever the controller asked). :class:`CollisionShield` is that line for a policy over the
relative table (``rover-train --relative-table``): it rolls each table action forward for
``horizon_s`` on the rover's kinematics (the heading PID's yaw rate, the commanded speed) and
forbids those that bring the rover's outline within ``margin_m`` of a scan reading, unless the
rover is already that close and the action does not bring it closer. Standing still is always
allowed. :class:`rover_train.algos.ModelAgent` draws from the policy restricted to the allowed
actions (``shield=``), so a learnt policy keeps its choice wherever it was safe.

It reads only the observation (the ``camera_scan`` key: ranges and bearings in the rover's
frame), never the simulator. On RoverEnvDiscrete, whose ``Discrete(60)`` is the same table, it
reads the LIDAR instead (``source="lidar"``): 360 degrees, every step, but with no telling a
person from a wall, so one margin for every return; for the LIDAR RL entries that margin is
their ``EntrySpec.shield_settings``; with ``lidar_map`` the world's map tells walls from
people, each kept its own margin (docs/decisions.md, "A shield on the LIDAR").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rover_env import constants as c
from rover_env import rover
from rover_env.camera_scan import SCAN_KEY, SCAN_ROWS, sector_centres
from rover_env.discrete_env import N_SEED_ACTIONS, SPEED_LEVELS
from rover_env.gaze_discrete_env import PAN_WINDOWS
from rover_train.wrappers import relative_action

HALF_LENGTH = max(rover.CHASSIS_HALF[0], rover.WHEEL_X + rover.WHEEL_RADIUS)
"""Metres from the rover's centre to its front (the chassis; the wheels end 0.01 m short)."""
HALF_WIDTH = max(rover.CHASSIS_HALF[1], rover.WHEEL_Y + rover.WHEEL_WIDTH / 2)
"""Metres from the rover's centre to its side (the wheels' outer faces)."""


@dataclass(frozen=True)
class ShieldConfig:
    """How far ahead the shield looks and how close it lets the rover come."""

    horizon_s: float = 0.5
    """Seconds each action is rolled forward (held, as the table's commands are)."""
    margin_m: float = 0.05
    """Metres between the rover's outline and a scan reading that an action may not cross."""
    people: bool = True
    """Check the scan's person readings as well as its scenery."""
    person_margin_m: float = 0.3
    """Metres kept from a person reading: a wider berth than from the scenery, since people
    walk (on the zoo's episodes 0.3 m cut inspect's person touches from 8 to 6 of 200, the
    maze's stayed at 11; docs/decisions.md, "RL")."""
    person_speed_mps: float = 0.0
    """Metres per second a person may close in at: a person reading's margin grows by it over
    each rolled-forward step's time (0: people held where they were seen). Walkers close at
    1.2-1.8 m/s, and most touches behind the shield come while the rover moves."""
    lidar_map: bool = False
    """On the LIDAR: tell people from walls by the world's map (a return the map does not
    explain, ``rover_train.zoo.agent.unmapped_scan``, is a person's), each kept its own margin;
    False: every return kept ``person_margin_m`` off."""

    def __post_init__(self) -> None:
        if not self.horizon_s >= c.CONTROL_DT:
            raise ValueError(f"horizon_s must be at least one control step ({c.CONTROL_DT} s), "
                             f"got {self.horizon_s}")  # fmt: skip
        if not (self.margin_m >= 0 and self.person_margin_m >= 0):
            raise ValueError(f"margin_m and person_margin_m must be >= 0 m, got "
                             f"{self.margin_m}, {self.person_margin_m}")  # fmt: skip
        if not self.person_speed_mps >= 0:
            raise ValueError(f"person_speed_mps must be >= 0, got {self.person_speed_mps}")


def box_distance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed distance (m) from rover-frame points ``(x, y)`` (arrays of one shape) to the
    rover's outline: positive outside, negative inside."""
    dx = np.abs(x) - HALF_LENGTH
    dy = np.abs(y) - HALF_WIDTH
    return np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0)) + np.minimum(np.maximum(dx, dy), 0.0)


def outline_distance(points: np.ndarray) -> np.ndarray:
    """:func:`box_distance` of rover-frame points (..., 2)."""
    return box_distance(points[..., 0], points[..., 1])


def command_trajectories(commands: np.ndarray, horizon_s: float) -> np.ndarray:
    """Poses (N, steps, 3) ``x, y, yaw`` in the rover's frame after each control step of each
    ``[speed, relative heading]`` command (N, 2) held for ``horizon_s``: the commanded speed,
    and the yaw rate the heading PID commands for a constant relative heading (``kp`` times
    it, clamped)."""
    steps = max(1, round(horizon_s / c.CONTROL_DT))
    commands = np.asarray(commands, dtype=np.float64).reshape(-1, 2)
    speed = commands[:, 0]
    rate = np.clip(c.PID_KP * commands[:, 1], -c.MAX_ANGULAR_VELOCITY, c.MAX_ANGULAR_VELOCITY)
    poses = np.zeros((len(commands), steps, 3))
    x = y = yaw = np.zeros(len(commands))
    for k in range(steps):
        mid = yaw + 0.5 * rate * c.CONTROL_DT
        x = x + speed * np.cos(mid) * c.CONTROL_DT
        y = y + speed * np.sin(mid) * c.CONTROL_DT
        yaw = yaw + rate * c.CONTROL_DT
        poses[:, k] = np.stack([x, y, yaw], axis=1)
    return poses


TABLE_COMMANDS = np.stack([relative_action(a) for a in range(N_SEED_ACTIONS)])
"""The relative table's ``[speed, relative heading]`` command of each of its 60 actions."""
TABLE_COMMANDS.setflags(write=False)


def table_trajectories(horizon_s: float) -> np.ndarray:
    """Poses (60, N, 3) ``x, y, yaw`` in the rover's frame after each of the N control steps
    of each relative-table action held (:func:`command_trajectories` of the table)."""
    return command_trajectories(TABLE_COMMANDS, horizon_s)


LIDAR_KEY = "lidar"
"""RoverEnv's observation key of the planar LIDAR's ranges (m), point i the minimum over the
i-th of equal sectors from straight behind, counter-clockwise (``rover_env.rover.Lidar``)."""
SOURCES = ("camera_scan", "lidar")


class CollisionShield:
    """The allowed relative-table actions for one observation (see the module docstring):
    ``shield(obs)`` -> a (60,) bool mask (see ``pan_windows`` and ``pan_head`` for the gaze
    env's tables).

    :param source: what it reads: ``camera_scan`` (the camera scan's obstacle and person
        rows, each with its margin) or ``lidar`` (RoverEnvDiscrete's 360-degree LIDAR, which
        does not tell people from scenery: every point is kept ``person_margin_m`` off).
    """

    def __init__(self, config: ShieldConfig | None = None, pan_windows: int = 1,
                 pan_head: bool = False, source: str = "camera_scan",
                 world: str | None = None) -> None:  # fmt: skip
        if source not in SOURCES:
            raise ValueError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
        self.source = source
        self.config = cfg = config or ShieldConfig()
        if source == "lidar" and cfg.lidar_map and world is None:
            raise ValueError("lidar_map tells people from walls by a world's map: give world")
        self.world = world
        self.pan_windows = int(pan_windows)
        """Actions per drive in the policy's table: 1 for the relative table, 5 for the gaze
        env's (``action // 5`` is the drive; the camera's target does not move the rover)."""
        self.pan_head = bool(pan_head)
        """The gaze env's table as two heads (``MultiDiscrete([60, 5])``, ``--pan-head``): the
        mask is sb3-contrib's for that space, the drive head's 60 then the pan head's 5, every
        window allowed (where the camera looks never moves the rover)."""
        if self.pan_head and self.pan_windows != 1:
            raise ValueError("pan_head masks a drive head and a pan head; pan_windows is for "
                             "the one-head table of drives x windows: give one of them")
        self._poses = table_trajectories(cfg.horizon_s)
        x, y, yaw = (self._poses[..., k, None] for k in range(3))
        self._cos, self._sin = np.cos(yaw), np.sin(yaw)
        # a reading p in the frame of pose (x, y, yaw): R(-yaw) (p - (x, y)), its offsets here
        self._u0 = self._cos * x + self._sin * y
        self._v0 = -self._sin * x + self._cos * y
        if source == "lidar" and cfg.lidar_map:  # walls and people apart, by the map
            self._rows = [0, 1]
            self._row_margins = np.array([[cfg.margin_m], [cfg.person_margin_m]])
            self._row_growth = np.array([[0.0], [cfg.person_speed_mps]])
        elif source == "lidar":  # one row of ranges; a return may be a person
            self._rows = [0]
            self._row_growth = np.array([[cfg.person_speed_mps if cfg.people else 0.0]])
            self._row_margins = np.array([[cfg.person_margin_m if cfg.people else cfg.margin_m]])
        else:
            self._rows = [SCAN_ROWS.index("obstacle")] + ([SCAN_ROWS.index("person")]
                                                          if cfg.people else [])  # fmt: skip
            self._row_margins = np.array([cfg.margin_m, cfg.person_margin_m])[
                :len(self._rows), None]  # fmt: skip
            self._row_growth = np.array([0.0, cfg.person_speed_mps])[:len(self._rows), None]
        self._bearings: np.ndarray | None = None
        horizon = self._poses.shape[1] * c.CONTROL_DT
        self._times = (np.arange(self._poses.shape[1]) + 1.0) * c.CONTROL_DT
        travel = float(np.abs(SPEED_LEVELS).max()) * horizon
        widest = float((self._row_margins + self._row_growth * horizon).max())
        self.reach = travel + math.hypot(HALF_LENGTH, HALF_WIDTH) + widest
        """Metres from the rover's centre beyond which no reading can come within its margin
        during the horizon (the farthest the table drives in it, plus the outline's
        half-diagonal and the wider margin); such readings are not checked."""

    @property
    def n_actions(self) -> int:
        return len(self._poses)

    def points(self, scan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rover-frame points (K, 2) of the scan's readings within :attr:`reach`, and the
        margin (K,) each is given now."""
        pts, margin, _ = self._points(scan)
        return pts, margin

    def _points(self, scan: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`points` and each point's margin growth (K,), metres a second."""
        if self._bearings is None or len(self._bearings) != scan.shape[1]:
            self._bearings = sector_centres(scan.shape[1])
        ranges = scan[self._rows].astype(np.float64)
        near = ranges < self.reach
        r = ranges[near]
        b = np.broadcast_to(self._bearings, ranges.shape)[near]
        margin = np.broadcast_to(self._row_margins, ranges.shape)[near]
        growth = np.broadcast_to(self._row_growth, ranges.shape)[near]
        return np.stack([r * np.cos(b), r * np.sin(b)], axis=1), margin, growth

    def allowed(self, scan: np.ndarray) -> np.ndarray:
        """The (60,) mask of actions whose rolled-forward outline keeps its margin from every
        reading, or, where the rover is inside a margin already, gets no deeper into one."""
        return self._clear(scan, self._cos, self._sin, self._u0, self._v0)

    def allowed_commands(self, scan: np.ndarray, commands: np.ndarray) -> np.ndarray:
        """:meth:`allowed` for any ``[speed, relative heading]`` commands (N, 2), held for the
        horizon: a (N,) mask (a continuous policy's own command, say)."""
        poses = command_trajectories(commands, self.config.horizon_s)
        x, y, yaw = (poses[..., k, None] for k in range(3))
        cos, sin = np.cos(yaw), np.sin(yaw)
        return self._clear(scan, cos, sin, cos * x + sin * y, -sin * x + cos * y)

    def _clear(self, scan: np.ndarray, cos: np.ndarray, sin: np.ndarray, u0: np.ndarray,
               v0: np.ndarray) -> np.ndarray:  # fmt: skip
        pts, margin, growth = self._points(np.asarray(scan))
        mask = np.ones(len(cos), dtype=bool)
        if not len(pts):
            return mask
        ahead = margin + growth * self._times[:, None]  # (N, K): a person may close in
        # standing still's clearance over the horizon: an action no worse is always allowed
        now = float((outline_distance(pts) - ahead).min())
        # each reading in the frame of each future pose, x and y apart: (A, N, K) each
        px, py = pts[:, 0], pts[:, 1]
        x = cos * px + sin * py - u0
        y = cos * py - sin * px - v0
        closest = (box_distance(x, y) - ahead).min(axis=(1, 2))
        return closest >= min(now, 0.0) - 1e-9

    def __call__(self, obs: Any) -> np.ndarray:
        allowed = self.allowed(self.scan_of(obs))
        if self.pan_head:
            return np.concatenate([allowed, np.ones(len(PAN_WINDOWS), dtype=bool)])
        return np.repeat(allowed, self.pan_windows) if self.pan_windows > 1 else allowed

    def scan_of(self, obs: Any) -> np.ndarray:
        """What the shield reads of an observation (a batch of one is taken as one); a
        ValueError naming the key and the fix where the observation lacks it."""
        if self.source == "lidar":
            if not isinstance(obs, dict) or LIDAR_KEY not in obs:
                raise ValueError(f"the LIDAR shield reads RoverEnv's {LIDAR_KEY!r} observation "
                                 f"key: give it RoverEnvDiscrete's observations")  # fmt: skip
            scan = np.asarray(obs[LIDAR_KEY], dtype=np.float32).reshape(1, -1)
            if self.config.lidar_map:
                scan = self._walls_and_people(obs, scan[0])
        else:
            if not isinstance(obs, dict) or SCAN_KEY not in obs:
                raise ValueError(f"the collision shield reads the {SCAN_KEY!r} observation key: "
                                 f"make the env with camera_scan=True")  # fmt: skip
            scan = np.asarray(obs[SCAN_KEY])
            if scan.ndim == 3:  # a batch of one, as a vector env gives it
                scan = scan[0]
        return scan

    def _walls_and_people(self, obs: dict[str, Any], lidar: np.ndarray) -> np.ndarray:
        """(2, points): the returns the world's map explains (walls), then the others
        (people), each row far where the other holds the return."""
        from rover_train.zoo.agent import LIDAR_CLIP, unmapped_scan

        one = {k: np.asarray(v).reshape(-1) for k, v in obs.items()}  # a batch of one too
        assert self.world is not None
        person = unmapped_scan(one, self.world) < 1.0
        far = np.float32(max(LIDAR_CLIP, self.reach + 1.0))
        return np.stack([np.where(person, far, lidar), np.where(person, lidar, far)])


def shield_for(recipe: dict[str, Any], what: str,
               config: ShieldConfig | None = None) -> CollisionShield:  # fmt: skip
    """The shield of a model trained with ``recipe`` (its stored rover-train arguments);
    ``ValueError`` naming ``what`` unless it drives the relative table on the camera scan, or
    RoverEnvDiscrete (the same table) on its LIDAR."""
    if recipe.get("env") == "lidar-discrete":
        return CollisionShield(config, source="lidar", world=recipe.get("world"))
    if not (recipe.get("relative_table") and recipe.get("camera_scan")):
        raise ValueError(f"the collision shield guards a policy over the relative table on the "
                         f"camera scan (rover-train --camera-scan --relative-table) or on the "
                         f"LIDAR (--env lidar-discrete); {what} is neither")  # fmt: skip
    if recipe.get("pan_head"):
        return CollisionShield(config, pan_head=True)
    looking = recipe.get("env") == "fused-gaze"
    return CollisionShield(config, pan_windows=len(PAN_WINDOWS) if looking else 1)


def shielded_vec_env(venv: Any, shield: CollisionShield) -> Any:
    """``venv`` (a Stable-Baselines3 VecEnv over camera-scan observations) answering
    ``env_method("action_masks")`` with the shield's mask for each env's newest observation:
    what sb3-contrib's ``MaskablePPO`` asks before each step (``rover-train --shield``). The
    masks are computed here, in the trainer's process, from the observations it already holds:
    no round trip to the env workers, and the same for subprocess, in-process and Ray envs."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class ShieldMasks(VecEnvWrapper):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(venv)
            self._obs: Any = None

        @property
        def reset_infos(self) -> Any:  # the envs' own (the checkpoints keep their episode RNGs)
            return self.venv.reset_infos

        @reset_infos.setter
        def reset_infos(self, _: Any) -> None:  # VecEnv.__init__ sets a blank list
            pass

        def reset(self) -> Any:
            self._obs = self.venv.reset()
            return self._obs

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            self._obs = obs  # after an episode's end, the next episode's first observation
            return obs, rewards, dones, infos

        def action_masks(self) -> list[np.ndarray]:
            if self._obs is None:
                raise RuntimeError("action masks asked for before the first reset")
            scans = np.asarray(self._obs[SCAN_KEY])
            return [shield({SCAN_KEY: scan}) for scan in scans]

        def has_attr(self, attr_name: str) -> bool:
            return attr_name == "action_masks" or bool(self.venv.has_attr(attr_name))

        def env_method(self, method_name: str, *args: Any, indices: Any = None,
                       **kwargs: Any) -> list[Any]:  # fmt: skip
            if method_name != "action_masks":
                return list(self.venv.env_method(method_name, *args, indices=indices, **kwargs))
            masks = self.action_masks()
            return masks if indices is None else [masks[i] for i in self._get_indices(indices)]

    return ShieldMasks()


__all__ = ["CollisionShield", "HALF_LENGTH", "HALF_WIDTH", "ShieldConfig", "box_distance",
           "outline_distance", "shield_for", "shielded_vec_env", "table_trajectories"]


SHIELDED_STUDENT_KINDS = ("fused", "fused-gaze")
"""The student kinds :class:`ShieldedAgent` guards: their actions are Box commands
``[speed, relative heading(, pan target)]``, which the shield can roll forward as they are."""
_SPEED_SPAN = float(c.FUSED_ACTION_HIGH[0] - c.FUSED_ACTION_LOW[0])


class ShieldedAgent:
    """A continuous-action agent behind the shield (a distilled camera student: RoverEnvFused's
    ``[speed, relative heading]`` or the gaze env's ``[speed, relative heading, pan target]``):
    its own command where the shield allows it, held for the horizon; otherwise the allowed
    relative-table drive nearest to it (speed over its range plus heading over pi), the rest
    of its action (where the camera looks) kept. A safety filter in the sense of Nav2's
    collision monitor: it changes the command only where the scan says it would touch.

    :param agent: an agent (``reset()``, ``act(obs)``) whose first two action values are the
        speed and relative heading; its attributes (a student's ``meta``, ``spec``) read
        through.
    :param shield: the shield (``source="camera_scan"``: the env needs ``camera_scan=True``).
    """

    def __init__(self, agent: Any, shield: CollisionShield) -> None:
        self.agent = agent
        self.shield = shield
        self.overridden = 0
        """Steps whose command the shield replaced, since this agent was made."""

    def reset(self) -> None:
        self.agent.reset()

    def act(self, obs: Any) -> np.ndarray:
        action = np.array(self.agent.act(obs), dtype=np.float32)
        scan = self.shield.scan_of(obs)
        command = np.clip(action[:2].astype(np.float64), c.FUSED_ACTION_LOW, c.FUSED_ACTION_HIGH)
        if self.shield.allowed_commands(scan, command[None])[0]:
            return action
        turn = np.angle(np.exp(1j * (TABLE_COMMANDS[:, 1] - command[1])))
        cost = np.abs(TABLE_COMMANDS[:, 0] - command[0]) / _SPEED_SPAN + np.abs(turn) / math.pi
        cost[~self.shield.allowed(scan)] = np.inf  # standing still is always allowed
        action[:2] = TABLE_COMMANDS[int(np.argmin(cost))]
        self.overridden += 1
        return action

    __call__ = act

    def __getattr__(self, name: str) -> Any:
        if name == "agent":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.agent, name)

