"""Frames recorded while the rover drives: what the agent's camera actually sees.

:class:`DriveRecorder` runs short episodes in one world through the public
:class:`rover_env.simulation.RoverSim` calls (``reset``, ``set_command``, ``advance``,
``lidar``, ``render_camera``) and keeps every ``record_every``-th camera frame with its
metric depth and pedestrian mask. Each episode draws everything from its own generator
(so an episode is a pure function of its seed):

- the pedestrians' paths and, with ``appearance="random"``, their clothes, height, girth
  and gait phase (``RoverSim.reset``);
- the lighting (as the posed frames: :func:`active_vision.training.lighting.random_lighting`);
- the start: the world's spawn, or a free pose near the pedestrian area;
- the driver, one of :data:`DRIVERS`:

  ``wander``   smooth random speed and turn rate (an Ornstein-Uhlenbeck process each);
  ``approach`` steers at one pedestrian at 0.3-0.9 m/s (close approaches: the figures
               wait 1 m from the rover, so it ends up face to face with them);
  ``wall``     turns towards the nearest obstacle the LIDAR sees and drives into it slowly
               (walls and rocks at arm's length, the camera pressed against them);
  ``watch``    starts 3.5-9 m from a pedestrian, turns to keep it in view and creeps
               (distant pedestrians, small in the frame).

On the moon every driver meets slopes. An episode ends early if the rover tips past
``MAX_TILT_RAD`` or leaves the world.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from active_vision.training.lighting import random_lighting

logger = logging.getLogger(__name__)

DRIVERS = ("wander", "approach", "wall", "watch")
DRIVER_WEIGHTS = (0.3, 0.3, 0.2, 0.2)
CONTROL_DT = 0.05
"""Seconds per drive command (the envs' control period)."""
MAX_TILT_RAD = 1.0
_LIDAR_POINTS = 72
_LIDAR_RANGE = 6.0
_TURN_GAIN = 2.0
_MAX_TURN = 2.0


@dataclass
class DriveConfig:
    """How :class:`DriveRecorder` drives and records."""

    steps: int = 72
    """Control steps per episode (3.6 s at 0.05 s)."""
    record_every: int = 3
    """Keep every this many control steps' camera frame (0.15 s apart)."""
    near_start: float = 0.7
    """Probability of starting at a free pose near the pedestrian area instead of the spawn."""


@dataclass
class DrivenSequence:
    """One episode recorded at every control step, for the predictive heatmap.

    ``rgb`` holds every step's camera frame; ``targets`` the steps (rows of ``rgb``) that
    have ground truth: ``future`` (pedestrian pixels at some moment in the next
    ``horizon`` s, rover held still) and ``now`` (this frame's pedestrian mask).
    """

    rgb: np.ndarray
    targets: np.ndarray
    future: np.ndarray
    now: np.ndarray
    driver: str


@dataclass
class DrivenFrames:
    """Frames of one episode (arrays with one row per recorded frame)."""

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    step: np.ndarray
    driver: str


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class DriveRecorder:
    """Records driving episodes in one world (see the module docstring).

    :param renderer: the world's :class:`active_vision.training.dataset.FrameRenderer` (its sim and
        pose helpers are shared).
    """

    def __init__(self, renderer: Any, config: DriveConfig | None = None) -> None:
        self.r = renderer
        self.sim = renderer.sim
        self.config = config or DriveConfig()

    def _start(self, rng: np.random.Generator, driver: str) -> int:
        """Place the rover for ``driver``; the pedestrian it is about (or -1)."""
        r, sim = self.r, self.sim
        target = int(rng.integers(r.n_peds)) if r.n_peds else -1
        if driver == "watch" and target >= 0:
            px, py = sim.pedestrian_positions[target]
            for _ in range(20):
                dist = float(rng.uniform(3.5, 9.0))
                phi = float(rng.uniform(-math.pi, math.pi))
                x, y = px - dist * math.cos(phi), py - dist * math.sin(phi)
                if r.world.in_bounds(x, y) and r.world.is_free(x, y, r.clearance):
                    r._set_pose(x, y, phi + float(rng.uniform(-0.4, 0.4)))
                    return target
        if rng.random() < self.config.near_start:
            r._random_pose(rng)
        return target

    def _command(self, driver: str, target: int, state: np.ndarray,
                 rng: np.random.Generator) -> tuple[float, float]:
        sim = self.sim
        if driver == "wander" or target < 0 and driver in ("approach", "watch"):
            # Ornstein-Uhlenbeck: mean speed 0.5 m/s, turn rate around 0
            state[0] += 0.15 * (0.5 - state[0]) + 0.12 * rng.standard_normal()
            state[1] += 0.2 * (0.0 - state[1]) + 0.35 * rng.standard_normal()
            return float(np.clip(state[0], -0.3, 1.0)), float(np.clip(state[1], -1.5, 1.5))
        x, y, _ = sim.position
        yaw = sim.yaw
        if driver == "wall":
            scan = sim.lidar(_LIDAR_POINTS, _LIDAR_RANGE)
            i = int(np.argmin(scan))
            bearing = -math.pi + (i + 0.5) * 2.0 * math.pi / _LIDAR_POINTS
            err = _wrap(bearing + state[2])  # a fixed offset: hit walls at an angle too
            speed = state[3] if abs(err) < 0.6 else 0.1
            return speed, float(np.clip(_TURN_GAIN * err, -_MAX_TURN, _MAX_TURN))
        px, py = sim.pedestrian_positions[target]
        err = _wrap(math.atan2(py - y, px - x) - yaw + state[2])
        speed = state[3] if driver == "approach" else 0.1 * math.cos(err)
        return speed, float(np.clip(_TURN_GAIN * err, -_MAX_TURN, _MAX_TURN))

    def _drive(self, rng: np.random.Generator) -> tuple[str, Iterator[int]]:
        """Start an episode (reset, pick a driver and its target) and return the driver's
        name with the episode's steps: an iterator that sets random lighting, then yields
        ``k`` after step ``k``'s physics until the episode's ``steps`` or the rover tips
        over or leaves the world, and restores the lighting when it ends."""
        self.sim.reset(rng)
        driver = DRIVERS[int(rng.choice(len(DRIVERS), p=DRIVER_WEIGHTS))]
        target = self._start(rng, driver)
        return driver, self._steps(rng, driver, target)

    def _steps(self, rng: np.random.Generator, driver: str, target: int) -> Iterator[int]:
        cfg, sim, r = self.config, self.sim, self.r
        sim.set_lighting(random_lighting(sim, rng))
        # OU state (speed, turn), aim offset, cruise speed
        state = np.array([rng.uniform(0.0, 0.8), 0.0, rng.uniform(-0.35, 0.35),
                          rng.uniform(0.25, 0.9) if driver == "approach" else
                          rng.uniform(0.15, 0.45)])
        try:
            for k in range(cfg.steps):
                linear, angular = self._command(driver, target, state, rng)
                sim.set_command(linear, angular)
                sim.advance(CONTROL_DT)
                pitch, roll, _ = sim.orientation
                x, y, _ = sim.position
                if max(abs(pitch), abs(roll)) > MAX_TILT_RAD or not r.world.in_bounds(x, y):
                    return
                yield k
        finally:
            sim.set_lighting(sim.default_lighting)

    def record_sequence(self, rng: np.random.Generator, horizon: float = 1.5,
                        first_target: int = 4) -> DrivenSequence:
        """One episode with every step's frame kept and future-occupancy ground truth on
        every ``record_every``-th step from ``first_target`` on (see :class:`DrivenSequence`)."""
        cfg, sim = self.config, self.sim
        rgb, targets, future, now = [], [], [], []
        driver, steps_of_episode = self._drive(rng)
        for k in steps_of_episode:
            f = sim.render_camera(segmentation=True)
            rgb.append(f.rgb)
            if k >= first_target and (k - first_target) % cfg.record_every == 0:
                targets.append(k)
                now.append(f.pedestrian_mask)
                future.append(sim.future_pedestrian_mask(horizon))
        s = self.r.config.size
        empty = np.zeros((0, s, s), bool)
        return DrivenSequence(
            np.stack(rgb) if rgb else np.zeros((0, s, s, 3), np.uint8),
            np.asarray(targets, np.int64),
            np.stack(future) if future else empty,
            np.stack(now) if now else empty, driver)

    def record(self, rng: np.random.Generator) -> DrivenFrames:
        """One episode; its frames (possibly fewer than steps/record_every if it ended)."""
        cfg, sim = self.config, self.sim
        rgb, depth, mask, steps = [], [], [], []
        driver, steps_of_episode = self._drive(rng)
        for k in steps_of_episode:
            if k % cfg.record_every == cfg.record_every - 1:
                f = sim.render_camera(depth=True, segmentation=True)
                rgb.append(f.rgb)
                depth.append(f.depth.copy())
                mask.append(f.pedestrian_mask)
                steps.append(k)
        s = self.r.config.size
        if not rgb:
            return DrivenFrames(np.zeros((0, s, s, 3), np.uint8), np.zeros((0, s, s), np.float32),
                                np.zeros((0, s, s), bool), np.zeros(0, np.int64), driver)
        return DrivenFrames(np.stack(rgb), np.stack(depth), np.stack(mask),
                            np.asarray(steps, np.int64), driver)


__all__ = ["DRIVERS", "DriveConfig", "DriveRecorder", "DrivenFrames", "DrivenSequence"]
