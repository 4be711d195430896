"""A privileged planner expert: the teacher the zoo's students are distilled from.

It knows what no policy observes: the world's obstacle footprints (from the
:class:`~rover_env.worlds.WorldSpec`) and the pedestrians' true positions (from the sim).

- **Map.** An occupancy grid of the world's goal square plus a margin (``GRID_RES`` m
  cells). Each cell's cost grows as its clearance from the nearest footprint falls below
  ``PREFERRED_CLEARANCE``, and is prohibitive below ``HARD_CLEARANCE`` (the seed's collision
  test is a LIDAR return under 0.3 m from the rover's centre).
- **Plan.** A cost-to-go field from the goal (8-connected Dijkstra, done as vectorised
  relaxation sweeps), computed once per goal and cached.
- **Track.** Pure pursuit: walk the field's steepest descent ``LOOKAHEAD`` m ahead and
  steer at the farthest point of that path the rover can see in a straight line.
- **Pedestrians.** With a pedestrian within ``PED_RANGE``, a small local planner scores
  candidate (speed, heading) pairs, reverse included, by the progress they make on the
  cost-to-go field over the next second against how far they bring the rover inside
  ``PERSONAL_SPACE`` of each pedestrian's predicted position (linear extrapolation of its
  last motion) and how close they come to obstacles. Standing still inside someone's
  personal space scores badly too, so a pedestrian that stopped for the rover gets room.

- **Gaze.** With ``sees="camera"`` it reacts only to the pedestrians inside the forward
  camera's view *as the camera points now*: the pan it is given (:meth:`PlannerExpert.act`'s
  ``pan``; :meth:`~PlannerExpert.act_env` reads the sim's camera pan). ``gaze`` says where it
  points the camera when it is asked for a gaze env's action: ``fixed``, straight ahead, or
  ``active``, the gaze policy of :mod:`rover_train.imitation.gaze` (a pedestrian at risk,
  else where the planned path turns, else a slow scan), chosen from the true state.

The expert's action is ``[speed m/s, heading relative to the rover's yaw rad]``, the
action of every continuous roverav env, from :meth:`PlannerExpert.act`; for a gaze env
(RoverEnvFusedGaze, or any env whose action space is the gaze env's ``Box`` of 3)
``[speed, heading, pan target rad]``, from :meth:`PlannerExpert.act_gaze`.
:meth:`PlannerExpert.act_env` gives whichever the env's action space takes. Three teachers
come of this on the same episodes: the fixed teacher (``sees="camera"``, ``gaze="fixed"``),
the gaze teacher (``sees="camera"``, ``gaze="active"``) and the all-seeing teacher
(``sees="all"``); ``benchmarks/gaze_value.py`` compares them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gymnasium import spaces

from rover_env.controller import wrap_angle
from rover_env.discrete_env import N_SEED_ACTIONS, nearest_action
from rover_env.gaze_discrete_env import N_GAZE_ACTIONS, nearest_gaze_action
from rover_env.lidar_discrete_env import RoverEnvDiscrete
from rover_env.rover import CAMERA_FOVY
from rover_env.worlds import WorldSpec, make_world
from rover_train.imitation.gaze import GazeConfig, GazePolicy
from rover_train.navgrid import (
    GRID_RES,
    HARD_CLEARANCE,
    CostToGo,
    FieldCache,
    OccupancyGrid,
    goal_key,
)
from rover_train.wrappers import takes_pan

LOOKAHEAD = 1.2  # m of planned path the pursuit point may be taken from
SIGHT_CLEARANCE = 0.3  # m: the straight segment to the pursuit point keeps this clearance
PERSONAL_SPACE = 1.2  # m (the evaluation's personal-space radius)
PED_RANGE = 2.6  # m: pedestrians farther than this are ignored
PED_HORIZON = 0.8  # s: how far ahead pedestrian positions are extrapolated
STALL_TIME = 2.0  # s without progress near a pedestrian before a detour is planned
STALL_PROGRESS = 0.3  # m of planned path that counts as progress
DETOUR_TIME = 4.0  # s a detour plan is followed
DETOUR_COST = 40.0  # extra cost per cell inside a blocking pedestrian's personal space
CAMERA_HALF_FOV = math.radians(CAMERA_FOVY) / 2  # rad; square frames: horizontal = vertical
PEDESTRIAN_RADIUS = 0.25  # m: a pedestrian this far off the view's edge still shows in it
SEES = ("all", "camera")
GAZES = ("fixed", "active")
VELOCITY_FROM = ("updates", "steps")
MANNERS = {
    "polite": {"personal_weight": 6.0, "zone": PERSONAL_SPACE + 0.15,
               "contact_distance": 0.6, "contact_cost": 5.0},
    "firm": {"personal_weight": 2.0, "zone": 1.0, "contact_distance": 0.7, "contact_cost": 15.0},
}  # fmt: skip
"""The local planner's pedestrian terms (:class:`ExpertConfig` fields) by name. ``polite``
keeps 1.35 m from everyone and pays dearly for intrusion; ``firm`` keeps 1 m, pays a third
as much for intrusion and three times as much for a predicted near-contact, counted from
0.7 m. In corridors the polite expert dithers: it cannot pass a pedestrian without
intruding, so it waits, detours and times out. Firm reaches more goals with fewer collided
episodes on the diagnostic seeds and intrudes more; the terms were chosen there
(docs/decisions.md, "Imitation and the zoo"; benchmarks/RESULTS.md, "The planner
expert")."""

_SIGHT_SAMPLES = 14  # points checked along a line of sight (every <= 0.1 m at LOOKAHEAD)
_CANDIDATE_HEADINGS = np.linspace(-math.pi, math.pi, 16, endpoint=False)
_CANDIDATE_SPEEDS = (0.0, 0.35, 0.7, 1.0)
_HORIZON_TIMES = np.array([0.25, 0.5, 0.75, 1.0]) * PED_HORIZON / 0.8 * 1.0


@dataclass
class ExpertConfig:
    """The expert's driving parameters."""

    max_speed: float = 1.0
    """m/s on a clear straight."""
    min_speed: float = -0.6
    """m/s, the most reverse it ever commands (the fused envs' action floor)."""
    pedestrian_aware: bool = True
    """Steer around and yield to pedestrians using their true positions."""
    personal_weight: float = MANNERS["polite"]["personal_weight"]
    """Local planner: cost per squared metre of predicted personal-space intrusion."""
    zone: float = MANNERS["polite"]["zone"]
    """Local planner: the radius (m) kept from predicted pedestrian positions."""
    contact_distance: float = MANNERS["polite"]["contact_distance"]
    """Local planner: a predicted rover-pedestrian centre distance under this (m) is a
    near-contact (the seed's collision test fires on a LIDAR return under 0.3 m from the
    rover's centre, so about 0.55 m centre to centre)."""
    contact_cost: float = MANNERS["polite"]["contact_cost"]
    """Local planner: cost per predicted near-contact sample."""
    velocity_from: str = "updates"
    """How pedestrian velocities are estimated (:meth:`PlannerExpert._pedestrian_velocities`):
    ``updates``, over the last change of their positions, or ``steps``, between consecutive
    calls (what the shipped students' teacher did; their recipes say so)."""
    trigger: float = PED_RANGE
    """The local planner takes over when a pedestrian is closer than this (m)."""
    sees: str = "all"
    """Which pedestrians it reacts to: ``all`` (their true positions all round), or
    ``camera``, only those inside the forward camera's horizontal field of view
    (:func:`in_camera_view`): what a fused student can see. A teacher that yields to a
    pedestrian behind the rover gives its image student labels it cannot explain; the
    student learns to back off at places and moments instead, where nothing is there."""
    gaze: str = "fixed"
    """Where it points the camera when asked for a gaze env's action (:meth:`PlannerExpert.
    act_gaze`): ``fixed``, straight ahead (pan target 0), or ``active``, the gaze policy
    (:class:`~rover_train.imitation.gaze.GazePolicy`)."""
    gaze_config: GazeConfig = field(default_factory=GazeConfig)
    """The gaze policy's parameters (``gaze="active"``)."""

    def __post_init__(self) -> None:
        if self.sees not in SEES:
            raise ValueError(f"ExpertConfig.sees must be one of {SEES}, got {self.sees!r}")
        if self.gaze not in GAZES:
            raise ValueError(f"ExpertConfig.gaze must be one of {GAZES}, got {self.gaze!r}")
        if self.velocity_from not in VELOCITY_FROM:
            raise ValueError(f"ExpertConfig.velocity_from must be one of {VELOCITY_FROM}, "
                             f"got {self.velocity_from!r}")  # fmt: skip

    @classmethod
    def with_manners(cls, manners: str, **kwargs: object) -> ExpertConfig:
        """A config with the local planner's pedestrian terms of ``MANNERS[manners]``
        (``kwargs`` set the other fields)."""
        if manners not in MANNERS:
            raise ValueError(f"manners must be one of {sorted(MANNERS)}, got {manners!r}")
        return cls(**MANNERS[manners], **kwargs)  # type: ignore[arg-type]


def in_camera_view(
    x: float,
    y: float,
    yaw: float,
    pedestrians: np.ndarray,
    half_fov: float = CAMERA_HALF_FOV,
    pan: float = 0.0,
) -> np.ndarray:
    """(P,) bool: pedestrians any part of which (a disc of ``PEDESTRIAN_RADIUS``) lies inside
    the horizontal field of view of the camera of a rover at (x, y) facing ``yaw``, its
    camera turned ``pan`` rad (positive left) on its pan head. The sim's
    ``pedestrians_in_view`` tests the camera's actual pose instead; this one needs only the
    rover's pose and the pan, so it also serves states drawn without driving (the sim's
    camera is not updated there)."""
    dx, dy = pedestrians[:, 0] - x, pedestrians[:, 1] - y
    dist = np.hypot(dx, dy)
    off = np.abs((np.arctan2(dy, dx) - (yaw + pan) + math.pi) % (2 * math.pi) - math.pi)
    margin = np.arcsin(np.clip(PEDESTRIAN_RADIUS / np.maximum(dist, 1e-6), 0.0, 1.0))
    return off <= half_fov + margin


class PlannerExpert:
    """The privileged expert for one world.

    Use :meth:`act_env` with a roverav env (reads the rover's pose, the goal, the
    pedestrians and the camera's pan from the env, and answers in the env's action layout),
    or :meth:`act` / :meth:`act_gaze` with those values directly. Call :meth:`reset` at each
    episode start (it forgets pedestrian motion history and the gaze policy's scan).
    """

    def __init__(self, world: str | WorldSpec, config: ExpertConfig | None = None) -> None:
        self.world = make_world(world) if isinstance(world, str) else world
        self.config = config if config is not None else ExpertConfig()
        self.grid = OccupancyGrid(self.world)
        self._fields = FieldCache(self.grid)
        self._last_peds: np.ndarray | None = None
        self._last_time: float | None = None
        self._velocities: np.ndarray | None = None
        """The velocity estimate this step's plan used (None with no pedestrian in view)."""
        self._held_velocities = np.zeros((0, 2))
        self.gaze = GazePolicy(self.config.gaze_config)
        """The gaze policy (``config.gaze="active"``); its ``reason`` and ``focus`` say why it
        chose the last pan target."""
        self.reset()

    def reset(self) -> None:
        self._last_peds = None
        self._last_time = None
        self._velocities = None
        self._held_velocities = np.zeros((0, 2))
        self.gaze.reset()
        self._detour: CostToGo | None = None
        self._detour_until = -1.0
        self._progress_log: list[tuple[float, float]] = []

    def field(self, goal: tuple[float, float]) -> CostToGo:
        if self._detour is not None and self._detour.goal == goal_key(goal):
            return self._detour
        return self._fields.get(goal)

    def pursuit_point(self, x: float, y: float, goal: tuple[float, float]) -> tuple[float, float]:
        """The point the rover steers at: the goal when in plain sight and near, else the
        farthest visible point of the planned path within ``LOOKAHEAD``."""
        return self.field(goal).pursuit_point(x, y, LOOKAHEAD, SIGHT_CLEARANCE, _SIGHT_SAMPLES)

    def act(
        self,
        position: tuple[float, float],
        yaw: float,
        goal: tuple[float, float],
        pedestrians: np.ndarray | None = None,
        time: float | None = None,
        pan: float = 0.0,
    ) -> np.ndarray:
        """``[speed, relative heading]`` for a rover at ``position`` facing ``yaw``.

        :param pedestrians: (P, 2) true pedestrian positions (ignored unless
            ``config.pedestrian_aware``).
        :param time: simulated time (s), to estimate pedestrian velocities between calls.
        :param pan: where the camera looks now (rad relative to ``yaw``, positive left):
            with ``config.sees="camera"`` the pedestrians inside that view are the ones it
            reacts to.
        """
        cfg = self.config
        x, y = float(position[0]), float(position[1])
        px, py = self.pursuit_point(x, y, goal)
        heading = wrap_angle(math.atan2(py - y, px - x) - yaw)
        speed = cfg.max_speed * max(0.0, math.cos(heading)) ** 3
        # slower where the corridor is tight
        clear = float(self.grid.clearance_at(x, y))
        clear_factor = float(np.clip((clear - 0.2) / 0.5, 0.35, 1.0))
        speed *= clear_factor
        self._velocities = None
        if cfg.pedestrian_aware and pedestrians is not None and len(pedestrians):
            peds = np.asarray(pedestrians, dtype=np.float64)[:, :2]
            vel = self._pedestrian_velocities(peds, time)
            self._velocities = vel
            near = np.hypot(peds[:, 0] - x, peds[:, 1] - y) < cfg.trigger
            if cfg.sees == "camera":
                near &= in_camera_view(x, y, yaw, peds, pan=pan)
            self._watch_stall(x, y, goal, peds, near, time)
            if near.any():
                speed, heading = self._local_plan(
                    x, y, yaw, goal, peds[near], vel[near], heading, speed
                )
                if speed > 0:  # the pursuit's caps: slow while turning and where it is tight
                    speed *= max(0.0, math.cos(heading)) ** 3 * clear_factor
        speed = float(np.clip(speed, cfg.min_speed, cfg.max_speed))
        return np.array([speed, heading], dtype=np.float32)

    def _pedestrian_velocities(self, peds: np.ndarray, time: float | None) -> np.ndarray:
        """Velocities (P, 2) of ``peds`` by finite differences. The crowd moves at its own
        rate (10 Hz against the env's 20 Hz control): with ``config.velocity_from="updates"``
        the difference spans the last change of the positions and the estimate is held
        between changes; ``"steps"`` differences consecutive calls, which reads 0 and twice
        the speed on alternate steps."""
        last, when = self._last_peds, self._last_time
        if (last is None or time is None or when is None or time <= when
                or last.shape != peds.shape):  # fmt: skip
            self._last_peds, self._last_time = peds.copy(), time
            self._held_velocities = np.zeros_like(peds)
            return self._held_velocities
        if self.config.velocity_from == "steps" or np.any(peds != last):
            self._last_peds, self._last_time = peds.copy(), time
            self._held_velocities = (peds - last) / (time - when)
        # held since the positions last changed (set with _last_peds, so of their shape)
        return self._held_velocities

    def _watch_stall(
        self,
        x: float,
        y: float,
        goal: tuple[float, float],
        peds: np.ndarray,
        near: np.ndarray,
        time: float | None,
    ) -> None:
        """Detour around pedestrians that block the way: when the planned cost-to-go has
        not dropped by ``STALL_PROGRESS`` over ``STALL_TIME`` s with a pedestrian near,
        plan once more with the pedestrians' discs made expensive, and follow that plan for
        ``DETOUR_TIME`` s."""
        if time is None:
            return
        if self._detour is not None and time > self._detour_until:
            self._detour = None
        plain = self._fields.peek(goal)
        value = (plain if plain is not None else self.field(goal)).value(x, y)
        log = self._progress_log
        log.append((time, value))
        while log and log[0][0] < time - STALL_TIME:
            log.pop(0)
        if self._detour is None and near.any() and log[0][0] <= time - STALL_TIME + 0.1:
            if log[0][1] - value < STALL_PROGRESS / self.grid.res:
                extra = self.grid.discs_cost(peds[near], PERSONAL_SPACE, DETOUR_COST)
                self._detour = CostToGo(self.grid, goal_key(goal), extra)
                self._detour_until = time + DETOUR_TIME
                log.clear()

    def _local_plan(
        self,
        x: float,
        y: float,
        yaw: float,
        goal: tuple[float, float],
        peds: np.ndarray,
        vel: np.ndarray,
        pursuit_heading: float,
        pursuit_speed: float,
    ) -> tuple[float, float]:
        """Pick (speed, relative heading) among candidates by predicted progress on the
        cost-to-go field minus a personal-space penalty over the next ``PED_HORIZON`` s."""
        rel = np.concatenate([_CANDIDATE_HEADINGS, [pursuit_heading]])
        speeds = np.array(_CANDIDATE_SPEEDS)
        h, v = np.meshgrid(rel, speeds, indexing="ij")
        h, v = h.ravel(), v.ravel()
        # reverse straight back
        h = np.concatenate([h, [0.0]])
        v = np.concatenate([v, [self.config.min_speed * 0.6]])
        align = np.where(v >= 0, np.maximum(np.cos(h), 0.0) ** 2, 1.0)
        eff = v * align
        theta = yaw + h
        ts = _HORIZON_TIMES
        # rover positions (C, T)
        rx = x + eff[:, None] * ts[None, :] * np.cos(theta)[:, None]
        ry = y + eff[:, None] * ts[None, :] * np.sin(theta)[:, None]
        # pedestrian positions (P, T)
        qx = peds[:, 0, None] + vel[:, 0, None] * ts[None, :]
        qy = peds[:, 1, None] + vel[:, 1, None] * ts[None, :]
        d = np.hypot(rx[:, None, :] - qx[None], ry[:, None, :] - qy[None])  # (C, P, T)
        intrude = np.clip(self.config.zone - d, 0.0, None)
        ped_cost = (intrude**2).sum(axis=(1, 2)) * self.config.personal_weight
        ped_cost += (d < self.config.contact_distance).sum(axis=(1, 2)) * self.config.contact_cost
        field = self.field(goal)
        grid = field.grid
        fi = np.clip(((rx[:, -1] - grid.x0) / grid.res).astype(int), 0, grid.shape[0] - 1)
        fj = np.clip(((ry[:, -1] - grid.y0) / grid.res).astype(int), 0, grid.shape[1] - 1)
        here = field.value(x, y)
        with np.errstate(invalid="ignore"):  # inf - inf inside an obstacle: no progress
            progress = (here - field.field[fi, fj]) * grid.res
        progress = np.where(np.isfinite(progress), progress, -100.0)
        clear = grid.clearance_at(rx, ry).min(axis=1)
        wall = np.where(clear < HARD_CLEARANCE, 20.0 + 50.0 * (HARD_CLEARANCE - clear), 0.0)
        score = 2.0 * progress - ped_cost - wall - 0.05 * np.abs(h)
        best = int(np.argmax(score))
        return float(v[best]), float(h[best])

    def act_gaze(
        self,
        position: tuple[float, float],
        yaw: float,
        goal: tuple[float, float],
        pedestrians: np.ndarray | None = None,
        time: float | None = None,
        pan: float = 0.0,
    ) -> np.ndarray:
        """``[speed, relative heading, pan target]``: the gaze env's action. The driving is
        :meth:`act`'s (reacting to what the camera at ``pan`` shows when ``config.sees`` is
        ``camera``); the pan target (rad relative to ``yaw``) is 0 with ``config.gaze=
        "fixed"``, else the gaze policy's (:attr:`gaze`), which follows the plan at
        ``config.max_speed``."""
        speed, heading = self.act(position, yaw, goal, pedestrians, time, pan)
        target = 0.0
        if self.config.gaze == "active":
            x, y = float(position[0]), float(position[1])
            look = self.gaze.config
            length = max(self.config.max_speed * look.horizon, look.path_look) + GRID_RES
            path = np.asarray(self.field(goal).descent(x, y, length)).reshape(-1, 2)
            peds = None if pedestrians is None else np.asarray(pedestrians)[:, :2]
            target = self.gaze.target((x, y), yaw, pan, path, peds, self._velocities, time,
                                      self.config.max_speed, float(heading))  # fmt: skip
        return np.array([speed, heading, target], dtype=np.float32)

    def act_env(self, env: Any) -> np.ndarray:
        """The expert action for the current state of a roverav env (or a wrapper of one),
        in the layout of ``env.action_space``: :meth:`act_gaze`'s 3 values for the gaze env's
        ``Box`` of 3, :meth:`act`'s 2 for a ``Box`` of 2, and for the seed's discrete tables
        the nearest table action (a 0-d integer array, as a discrete student acts):
        ``Discrete(180)`` from :meth:`act_gaze` and the env's ``pan_window``, ``Discrete(60)``
        from :meth:`act` (absolute headings, relative in RoverEnvDiscrete). The camera's pan
        is read from the env's sim."""
        base = getattr(env, "unwrapped", env)
        pos = base.position
        state = (
            (pos[0], pos[1]),
            float(base.orientation[2]),
            base.goal,
            base.sim.pedestrian_positions,
            base.sim.time,
            float(base.sim.camera_pan),
        )
        if takes_pan(env):
            return self.act_gaze(*state)
        space = getattr(env, "action_space", None)
        if isinstance(space, spaces.Discrete):
            return self._table_action(env, space, state)
        return self.act(*state)

    def _table_action(self, env: Any, space: spaces.Discrete, state: tuple[Any, ...]
                      ) -> np.ndarray:  # fmt: skip
        if space.n == N_GAZE_ACTIONS:
            window = int(env.get_wrapper_attr("pan_window"))
            return table_action(self.act_gaze(*state), state[1], window)
        if space.n == N_SEED_ACTIONS:
            relative = isinstance(getattr(env, "unwrapped", env), RoverEnvDiscrete)
            return table_action(self.act(*state), 0.0 if relative else state[1])
        raise ValueError(f"the expert labels the seed's tables (Discrete({N_SEED_ACTIONS}) "
                         f"or Discrete({N_GAZE_ACTIONS})), not {space}")


def table_action(action: np.ndarray, yaw: float, window: int | None = None) -> np.ndarray:
    """The seed's table action nearest the expert's ``[speed, relative heading]`` (the
    ``Discrete(60)`` cell, headings made absolute with ``yaw``) or, with the camera's
    ``window``, ``[speed, relative heading, pan target]`` (the ``Discrete(180)`` action): a
    0-d integer array, as a discrete student acts."""
    speed, heading = float(action[0]), yaw + float(action[1])
    if window is None:
        return np.asarray(nearest_action(speed, heading), dtype=np.int64)
    return np.asarray(nearest_gaze_action(speed, heading, float(action[2]), window),
                      dtype=np.int64)  # fmt: skip
