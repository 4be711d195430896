"""Where the planner expert looks: the gaze teacher's camera policy, and a pan head for envs
that have none.

:class:`GazePolicy` chooses a pan target (rad relative to the rover's heading, within the
gaze env's +-60 deg) from the true state, in this order:

1. **A pedestrian at risk.** Each pedestrian's position is extrapolated linearly (its
   estimated velocity) over ``horizon`` s, and the rover's along its planned path at
   ``cruise`` m/s (where it will be if it drives on, even while it waits). The pedestrian
   whose predicted distance first falls under ``risk_distance`` (personal space) is the
   riskiest; ties go to the closer approach. The camera turns as little as it must to hold
   it ``view_margin`` inside the field of view (its bearing taken from the camera, which
   sits ``CAMERA_X`` ahead of the rover's centre: 10 deg more than from the centre for a
   pedestrian 1 m beside it), and keeps the way the rover is heading in view too when both
   fit.
2. **The way the path turns.** With nobody at risk, it looks at the point of the planned
   path ``path_near`` to ``path_look`` m ahead that lies furthest off the heading, when that
   is more than ``path_turn`` (a corner, a turn towards the goal).
3. **A slow scan.** Otherwise it sweeps +-``scan_amplitude`` at ``scan_rate``, from where
   the camera is.

The camera's servo (180 deg/s, :data:`rover_env.constants.PAN_RATE`) limits how fast the
pan follows: 9 deg per 0.05 s step, so the policy's target is where the head is going, not
where it is. :class:`rover_train.wrappers.WithPanHead` gives an env without a pan action
(RoverEnv) the gaze env's action, ``gaze`` observation and view readouts, turning the sim's
camera with the same servo: the teachers are evaluated on it with no daemon (they do not
need the fused image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rover_env import constants as c
from rover_env.controller import wrap_angle
from rover_env.rover import CAMERA_FOVY, CAMERA_X

RISK_HORIZON = 3.0  # s of predicted motion in which an intrusion makes a pedestrian at risk
RISK_STEP = 0.25  # s between predicted positions
VIEW_MARGIN = math.radians(10.0)  # a watched pedestrian is held this far inside the view
PATH_NEAR = 1.0  # m along the planned path: from here (the first cells' bearings are noise) ...
PATH_LOOK = 2.5  # m: ... to here, the point furthest off the heading says where it turns
_PATH_SAMPLES = 7  # points between PATH_NEAR and PATH_LOOK
PATH_TURN = math.radians(20.0)  # that point this far off the heading: look at it
SCAN_AMPLITUDE = math.radians(40.0)  # the scan sweeps +-this (the view then covers +-85 deg)
SCAN_RATE = math.radians(40.0)  # rad/s: a sweep from one side to the other in 2 s
HALF_FOV = math.radians(CAMERA_FOVY) / 2  # rad: the forward camera's, square frames
REASONS = ("pedestrian", "path", "scan")
"""What a gaze target was chosen for (:attr:`GazePolicy.reason`)."""


@dataclass
class GazeConfig:
    """The gaze policy's parameters."""

    horizon: float = RISK_HORIZON
    """s over which pedestrian and rover positions are predicted."""
    step: float = RISK_STEP
    """s between predicted positions."""
    risk_distance: float = c.PERSONAL_SPACE_M
    """A pedestrian predicted closer than this (m) within ``horizon`` is at risk."""
    view_margin: float = VIEW_MARGIN
    """rad: a pedestrian at risk is held this far inside the field of view's edge."""
    path_near: float = PATH_NEAR
    """m along the planned path from which its points say where it turns ..."""
    path_look: float = PATH_LOOK
    """m: ... up to here."""
    path_turn: float = PATH_TURN
    """rad: the point furthest off the heading is looked at when it is further than this."""
    scan_amplitude: float = SCAN_AMPLITUDE
    """rad: the scan's sweep either side of the heading."""
    scan_rate: float = SCAN_RATE
    """rad/s: the scan's speed (below the servo's, so the camera keeps up)."""
    pan_limit: float = c.PAN_LIMIT
    """rad: targets are clipped to +-this (the gaze env's action bound)."""
    half_fov: float = HALF_FOV
    """rad: half the camera's horizontal field of view."""
    camera_ahead: float = CAMERA_X
    """m: the camera (the pan head's axis) sits this far ahead of the rover's centre."""


class GazePolicy:
    """The gaze teacher's camera policy (module docstring). Call :meth:`reset` at each
    episode start, then :meth:`target` once per step."""

    def __init__(self, config: GazeConfig | None = None) -> None:
        self.config = config if config is not None else GazeConfig()
        self.reset()

    def reset(self) -> None:
        self.reason = ""
        """Why the last target was chosen: one of :data:`REASONS` ("" before the first)."""
        self.focus = -1
        """The pedestrian at risk the last target watches (-1: none)."""
        self._scan: float | None = None
        self._scan_dir = 1.0
        self._last_time: float | None = None

    def target(
        self,
        position: tuple[float, float],
        yaw: float,
        pan: float,
        path: np.ndarray,
        pedestrians: np.ndarray | None,
        velocities: np.ndarray | None,
        time: float | None,
        cruise: float,
        way: float = 0.0,
    ) -> float:
        """The pan target (rad relative to ``yaw``, positive left) for this step.

        :param pan: the camera's pan now (rad).
        :param path: (K, 2) the planned path from the rover onwards (at least ``cruise *
            horizon`` and ``path_look`` m of it where the goal is that far).
        :param pedestrians: (P, 2) true positions; ``velocities`` (P, 2) their estimates
            (None: standing).
        :param time: simulated time (s), which paces the scan (None: one control step).
        :param cruise: m/s at which the rover is assumed to follow ``path``.
        :param way: relative heading (rad) the rover is about to drive in, kept in view
            beside a watched pedestrian when both fit.
        """
        cfg = self.config
        x, y = float(position[0]), float(position[1])
        dt = c.CONTROL_DT
        if time is not None and self._last_time is not None and time > self._last_time:
            dt = time - self._last_time
        self._last_time = time
        pts = np.vstack([[[x, y]], np.asarray(path, dtype=np.float64).reshape(-1, 2)])
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
        watched = self._riskiest(pts, arc, pedestrians, velocities, cruise)
        self.focus = watched
        if watched >= 0:
            assert pedestrians is not None
            px, py = np.asarray(pedestrians, dtype=np.float64)[watched, :2]
            cx = x + cfg.camera_ahead * math.cos(yaw)
            cy = y + cfg.camera_ahead * math.sin(yaw)
            self.reason = REASONS[0]
            self._scan = None
            return self._clip(self._keep_in_view(math.atan2(py - cy, px - cx) - yaw, way, pan))
        bearing = self._path_bearing(pts, arc, yaw)
        if abs(bearing) > cfg.path_turn:
            self.reason = REASONS[1]
            self._scan = None
            return self._clip(bearing)
        self.reason = REASONS[2]
        amp = cfg.scan_amplitude
        angle = min(max(pan, -amp), amp) if self._scan is None else self._scan
        angle += self._scan_dir * cfg.scan_rate * dt
        if abs(angle) >= amp:
            angle = math.copysign(amp, angle)
            self._scan_dir = -math.copysign(1.0, angle)
        self._scan = angle
        return self._clip(angle)

    def _path_bearing(self, pts: np.ndarray, arc: np.ndarray, yaw: float) -> float:
        """Bearing (rad relative to ``yaw``) of the point of the path ``path_near`` to
        ``path_look`` m ahead (of as much as there is) that lies furthest off the heading."""
        cfg = self.config
        end = min(cfg.path_look, float(arc[-1]))
        if end <= 0.0:
            return 0.0
        s = np.linspace(min(cfg.path_near, end), end, _PATH_SAMPLES)
        dx = np.interp(s, arc, pts[:, 0]) - pts[0, 0]
        dy = np.interp(s, arc, pts[:, 1]) - pts[0, 1]
        bearings = (np.arctan2(dy, dx) - yaw + math.pi) % (2 * math.pi) - math.pi
        return float(bearings[int(np.argmax(np.abs(bearings)))])

    def _riskiest(
        self,
        pts: np.ndarray,
        arc: np.ndarray,
        pedestrians: np.ndarray | None,
        velocities: np.ndarray | None,
        cruise: float,
    ) -> int:
        """Index of the pedestrian whose predicted distance first falls under
        ``risk_distance`` (ties: the closest approach), or -1."""
        if pedestrians is None or len(pedestrians) == 0:
            return -1
        cfg = self.config
        peds = np.asarray(pedestrians, dtype=np.float64)[:, :2]
        vel = np.zeros_like(peds) if velocities is None else np.asarray(velocities)[:, :2]
        times = np.arange(0.0, cfg.horizon + 1e-9, cfg.step)
        s = max(cruise, 0.0) * times
        rx, ry = np.interp(s, arc, pts[:, 0]), np.interp(s, arc, pts[:, 1])  # (T,)
        qx = peds[:, 0, None] + vel[:, 0, None] * times[None, :]
        qy = peds[:, 1, None] + vel[:, 1, None] * times[None, :]
        d = np.hypot(qx - rx[None, :], qy - ry[None, :])  # (P, T)
        inside = d < cfg.risk_distance
        at_risk = inside.any(axis=1)
        if not at_risk.any():
            return -1
        first = np.where(at_risk, inside.argmax(axis=1), len(times))
        order = np.lexsort((d.min(axis=1), first))
        return int(order[0])

    def _keep_in_view(self, bearing: float, way: float, pan: float) -> float:
        """The pan nearest ``pan`` that holds ``bearing`` ``view_margin`` inside the view and
        ``way`` in view too; when both do not fit, the one nearest ``way`` that holds
        ``bearing``."""
        half = self.config.half_fov - self.config.view_margin
        way = wrap_angle(way)
        bearing = way + wrap_angle(bearing - way)  # the same side of the way as seen
        lo, hi = max(bearing, way) - half, min(bearing, way) + half
        if lo <= hi:
            return min(max(pan, lo), hi)
        return min(max(way, bearing - half), bearing + half)

    def _clip(self, angle: float) -> float:
        limit = self.config.pan_limit
        return float(min(max(angle, -limit), limit))
