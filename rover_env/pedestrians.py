"""Walking pedestrians: mocap figures (head, torso, arms, swinging legs) on back-and-forth paths.

Each pedestrian is three mocap bodies: the upper body (torso, arms, head) and two legs that
swing about the hip as it walks. Their geoms collide with the rover (not with the scenery:
mocap bodies cannot be pushed), are in geom group 1 (seen by the LIDAR and the cameras), and
get clothing colours from a palette kept apart from the rover's and the scenery's colours.

Every episode each pedestrian gets a new straight path (3-8 m, clear of obstacles, inside
the world's pedestrian area), a speed in [1.0, 1.5] m/s, a start point on the path and a
palette draw, all from the generator passed to :meth:`Pedestrians.reset` (the env's
``np_random``). Position at simulated time t is a closed form of t, so the figures move
identically whatever the step size.

Two modes (``PEDESTRIAN_MODES``): ``walk`` (the paths above, anywhere in the pedestrian
area) and ``crossing`` (:meth:`Pedestrians.lay_crossings`: paths across the straight line
from the rover to its goal, walked from the side, timed to meet the rover there), the
scenario where a camera fixed straight ahead sees pedestrians late.
Appearance (:data:`APPEARANCES`): ``"fixed"`` (the default, what the seed envs use) dresses
every figure from the small palettes below and keeps the one body shape. ``"random"`` draws,
per pedestrian and episode, continuous clothing and skin colours, a height scale
(:data:`HEIGHT_SCALE_RANGE`), a girth scale (:data:`GIRTH_SCALE_RANGE`) and a gait phase,
from the same generator after the paths: deterministic from the episode seed, so
``reset(seed=s)`` reproduces it. :attr:`Pedestrians.appearance` reads the result out.
"""

from __future__ import annotations

import logging
import math
import warnings
from typing import NamedTuple

import mujoco
import numpy as np

from rover_env import crowd_kernel
from rover_env.crowd import MAX_PEDESTRIANS, Crowd, CrowdState
from rover_env.worlds.spec import GROUP_PEDESTRIAN, GROUP_VISUAL, WorldSpec

log = logging.getLogger(__name__)

SPEED_RANGE = (1.0, 1.5)  # m/s, walking speed
PATH_LENGTH_RANGE = (3.0, 8.0)  # m
PATH_CLEARANCE = 0.45  # m from obstacle footprints
MIN_START_DISTANCE = 2.0  # m from the rover's spawn
HIP_HEIGHT = 0.9
HIP_HALF_WIDTH = 0.1
LEG_LENGTH = 0.85
STEP_LENGTH = 0.7  # m per step: one leg cycle is two steps
LEG_SWING = 0.45  # rad amplitude
YIELD_DISTANCE = 1.0  # m: a pedestrian waits rather than walk into the rover
PROXY_RADIUS = 0.2  # m: crowd modes: the capsule the LIDAR sees and the rover touches
GROUP_PROXY = 5  # its geom group: scanned by the LIDAR, not drawn
HEIGHT_SCALE_RANGE = (0.85, 1.12)  # "random" appearance: figure height factor
GIRTH_SCALE_RANGE = (0.8, 1.3)  # "random" appearance: torso/arm/leg thickness factor
APPEARANCES = ("fixed", "random")
_BATCH = 32  # candidate paths checked per batch
_MAX_BATCHES = 20
_PATH_SAMPLES = 33  # clearance checks along a path (every 0.25 m on an 8 m path)

PEDESTRIAN_MODES = ("pacing", "crowd", "oblivious", "crossing", "groups", "blind-crossing")
CROSSING_MODES = ("crossing", "blind-crossing")
"""Modes whose walkers cross the rover's start-goal line (:meth:`Pedestrians.lay_crossings`)."""
BLIND_MODES = ("oblivious", "blind-crossing")
"""Modes whose walkers do not see the rover: they neither give way nor stop for it."""
DEFAULT_MODE = "crowd"  # people who walk to goals and make room for the rover
RENAMED_MODES = {"walk": "pacing"}  # old name -> new, accepted with a warning for one release
# crossing mode: each pedestrian walks across the rover's start-goal line
CROSSING_FRACTION_RANGE = (0.3, 0.85)  # where along the line it crosses
CROSSING_HALF_LENGTH_RANGE = (2.5, 4.0)  # m walked on either side of the line
CROSSING_MIN_HALF_LENGTH = 1.5  # m: cluttered places settle for shorter crossings
CROSSING_ANGLE_JITTER = math.radians(20.0)  # from perpendicular to the line
CROSSING_ROVER_SPEED = 0.6  # m/s: a crossing is timed for a rover driving this fast
_CROSSING_TRIES = 48  # candidate crossings per pedestrian before a normal path

# Clothing and skin palettes (RGB). Shirts are saturated hues; the scenery is grey, sand,
# beige and dark blue, the rover light grey with an orange accent.
SHIRTS = (
    (0.85, 0.10, 0.12),
    (0.90, 0.20, 0.60),
    (0.95, 0.85, 0.10),
    (0.15, 0.70, 0.20),
    (0.55, 0.20, 0.75),
    (0.05, 0.75, 0.80),
    (0.98, 0.98, 0.98),
)
TROUSERS = ((0.10, 0.10, 0.25), (0.08, 0.08, 0.08), (0.35, 0.22, 0.12), (0.60, 0.55, 0.35))
SKIN = ((0.96, 0.80, 0.69), (0.80, 0.60, 0.45), (0.55, 0.37, 0.25), (0.36, 0.24, 0.16))


class Appearance(NamedTuple):
    """How one pedestrian looks this episode (readout; colours RGB in [0, 1])."""

    shirt: tuple[float, float, float]
    trousers: tuple[float, float, float]
    skin: tuple[float, float, float]
    height: float
    """Height factor (1 = the 1.71 m default figure)."""
    girth: float
    """Thickness factor of torso, arms and legs (1 = default)."""
    gait_phase: float
    """Leg-swing phase offset (rad)."""


def _hsv_rgb(h: float, s: float, v: float) -> tuple[float, float, float]:
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    r, g, b = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]
    return (float(r), float(g), float(b))


def random_appearance(rng: np.random.Generator) -> Appearance:
    """One ``"random"`` appearance: any shirt hue (some dull, some grey), trousers from dark
    to light, a skin tone between the palette's extremes, height, girth and gait phase."""
    shirt = _hsv_rgb(rng.random(), rng.uniform(0.0, 1.0), rng.uniform(0.25, 1.0))
    trousers = _hsv_rgb(rng.random(), rng.uniform(0.0, 0.7), rng.uniform(0.08, 0.75))
    a = rng.random()
    skin = tuple(float(x) for x in (1 - a) * np.array(SKIN[0]) + a * np.array(SKIN[-1]))
    return Appearance(
        shirt, trousers, skin,  # type: ignore[arg-type]
        float(rng.uniform(*HEIGHT_SCALE_RANGE)), float(rng.uniform(*GIRTH_SCALE_RANGE)),
        float(rng.uniform(0.0, 2.0 * math.pi)),
    )


class _Path(NamedTuple):
    """Out-and-back walk from (ax, ay) along unit (ux, uy) for ``length`` m at ``speed``
    m/s (a length of 0 stands still)."""

    ax: float
    ay: float
    ux: float
    uy: float
    length: float
    speed: float


def pedestrian_mode(mode: str) -> str:
    """The canonical name of pedestrian mode ``mode``: ``ValueError`` naming the modes for an
    unknown one; ``walk`` (the old name of ``pacing``) with a ``FutureWarning``."""
    if mode in RENAMED_MODES:
        new = RENAMED_MODES[mode]
        warnings.warn(
            f"pedestrian_mode={mode!r} is deprecated and will be removed in the next release; "
            f"it is now called {new!r}",
            FutureWarning,
            stacklevel=3,
        )
        return new
    if mode not in PEDESTRIAN_MODES:
        raise ValueError(
            f"pedestrian_mode must be one of {', '.join(PEDESTRIAN_MODES)}; got {mode!r}"
        )
    return mode


def pedestrian_count(n: object, world: WorldSpec | None = None) -> int:
    """``n`` checked: an int in 0..MAX_PEDESTRIANS (None: the world's own count)."""
    if n is None:
        return world.n_pedestrians if world is not None else 3
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise TypeError(
            f"n_pedestrians must be an int from 0 to {MAX_PEDESTRIANS}, got {n!r} "
            f"({type(n).__name__}); pass a whole number, e.g. n_pedestrians=10"
        )
    if not 0 <= n <= MAX_PEDESTRIANS:
        raise ValueError(
            f"n_pedestrians must be from 0 to {MAX_PEDESTRIANS}, got {n}; the worlds hold at "
            f"most {MAX_PEDESTRIANS} walking figures"
        )
    return int(n)


def body_name(i: int) -> str:
    return f"pedestrian{i}"


def pedestrians_xml(n: int, proxy: bool = False) -> str:
    """MJCF worldbody fragment with ``n`` pedestrians (parked far below the ground).

    ``proxy`` (the crowd modes): the six figure geoms are drawn only (group 2, no contacts)
    and one upright capsule per figure, :data:`PROXY_RADIUS` wide and invisible (group
    :data:`GROUP_PROXY`), is what the LIDAR sees and the rover touches: one geom instead of
    six to cast rays at and collide with, so ten people cost the LIDAR less than three
    figures do. The proxy is opaque: MuJoCo's ray casts skip geoms whose alpha is 0 (so
    a transparent proxy left the LIDAR blind to every crowd pedestrian); no renderer draws
    its group.
    """
    g = GROUP_PEDESTRIAN if not proxy else GROUP_VISUAL
    solid = "" if not proxy else ' contype="0" conaffinity="0"'
    parts = []
    for i in range(n):
        name = body_name(i)
        park = f"{10.0 * i} 0 -50"
        parts.append(
            f'<body name="{name}" mocap="true" pos="{park}">'
            f'<geom name="{name}_torso" type="capsule" fromto="0 0 {HIP_HEIGHT + 0.1} 0 0 1.35" '
            f'size="0.17" group="{g}"{solid} rgba="1 0 0 1"/>'
            f'<geom name="{name}_head" type="sphere" pos="0 0 1.6" size="0.11" group="{g}"{solid} '
            f'rgba="1 1 1 1"/>'
            f'<geom name="{name}_arm_l" type="capsule" fromto="0.02 0.24 1.38 0.06 0.26 0.92" '
            f'size="0.05" group="{g}"{solid} rgba="1 0 0 1"/>'
            f'<geom name="{name}_arm_r" type="capsule" fromto="0.02 -0.24 1.38 0.06 -0.26 0.92" '
            f'size="0.05" group="{g}"{solid} rgba="1 0 0 1"/>'
            + (
                f'<geom name="{name}_proxy" type="capsule" fromto="0 0 {PROXY_RADIUS} 0 0 1.5" '
                f'size="{PROXY_RADIUS}" group="{GROUP_PROXY}" rgba="0.5 0.5 0.5 1"/>'
                if proxy
                else ""
            )
            + "</body>"
        )
        for side in ("l", "r"):
            parts.append(
                f'<body name="{name}_leg_{side}" mocap="true" pos="{park}">'
                f'<geom name="{name}_leg_{side}" type="capsule" '
                f'fromto="0 0 0 0 0 {-(LEG_LENGTH - 0.07)}" size="0.07" group="{g}"{solid} '
                f'rgba="0 0 1 1"/>'
                "</body>"
            )
    return "".join(parts)


class Pedestrians:
    """The pedestrians of one MuJoCo model: their paths, and their mocap poses over time."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        world: WorldSpec,
        appearance: str = "fixed",
        mode: str = DEFAULT_MODE,
    ) -> None:
        """:param mode: one of :data:`PEDESTRIAN_MODES`: ``pacing`` walks the out-and-back
        paths below; the others are a :class:`~rover_env.crowd.Crowd` (``oblivious``: blind
        to the rover; ``groups``: in groups of 2-3; ``crossing``: across the rover's way,
        see :meth:`lay_crossings`; ``blind-crossing``: the same crossings, blind to the
        rover, so they come from outside a forward camera's view and do not give way). The
        model's bodies (``pedestrian<i>``) say how many."""
        mode = pedestrian_mode(mode)
        if appearance not in APPEARANCES:
            raise ValueError(
                f"pedestrian appearance must be one of {APPEARANCES}, got {appearance!r}"
            )
        self._model, self._data, self._world = model, data, world
        self.appearance_mode = appearance
        self.n = 0
        while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body_name(self.n)) >= 0:
            self.n += 1
        ids = [
            [
                mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body_name(i) + suffix)
                for i in range(self.n)
            ]
            for suffix in ("", "_leg_l", "_leg_r")
        ]
        self._mocap = np.array(
            [[model.body_mocapid[b] for b in row] for row in ids], dtype=np.intp
        )  # (3, n): upper body, left leg, right leg
        body_ids = np.array(ids, dtype=np.intp).reshape(-1)
        self.geom_mask = np.isin(model.geom_bodyid, body_ids)  # (ngeom,) pedestrian geoms
        self._geoms_by_part = {
            part: np.array(
                [
                    mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{body_name(i)}_{part}")
                    for i in range(self.n)
                ],
                dtype=np.intp,
            )
            for part in ("torso", "head", "arm_l", "arm_r", "leg_l", "leg_r")
        }
        parts = np.concatenate(list(self._geoms_by_part.values()))
        self._size0 = model.geom_size[parts].copy()
        self._pos0 = model.geom_pos[parts].copy()
        self._rbound0 = model.geom_rbound[parts].copy()
        self._parts = parts
        # Per pedestrian: a Path (plain floats: advance() runs every env step).
        self._paths = [_Path(0.0, 0.0, 1.0, 0.0, 0.0, SPEED_RANGE[0])] * self.n
        self._walked = [0.0] * self.n  # metres along each out-and-back cycle
        self.positions = np.zeros((self.n, 2))  # current (x, y), updated with the poses
        self.headings = np.zeros(self.n)
        # Mocap rows in _write_poses() order: per pedestrian, upper body, left leg, right leg.
        self._order = self._mocap.T.reshape(-1).copy()
        self._hip = [HIP_HEIGHT] * self.n
        self._gait = [0.0] * self.n
        self._hip_arr = np.full(self.n, HIP_HEIGHT)
        self._gait_arr = np.zeros(self.n)
        self.appearance: list[Appearance] = []
        self.mode = mode
        self._crowd: Crowd | None = None
        if mode != "pacing":
            self._crowd = Crowd(
                world, self.n, sees_rover=mode not in BLIND_MODES, groups=mode == "groups"
            )

    @property
    def crowd(self) -> Crowd | None:
        """The crowd model walking the figures (None in ``pacing`` mode)."""
        return self._crowd

    @property
    def touching_rover(self) -> bool:
        """Whether a crowd pedestrian's body was held at the rover's this step (it would
        have walked into it; never in ``pacing`` mode, whose figures wait instead)."""
        return self._crowd is not None and bool(self._crowd.touching.any())

    # --- episode set-up ------------------------------------------------------------------------
    def reset(self, rng: np.random.Generator, avoid: tuple[float, float] | None = None) -> None:
        """New paths, speeds, start points and clothes for every pedestrian, then pose them
        (a crowd: new starts, speeds and goals, then the clothes)."""
        if self._crowd is not None:
            self._crowd.reset(rng, avoid)
            for i in range(self.n):
                self._recolour(i, rng)
        for i in range(self.n if self._crowd is None else 0):
            (ax, ay), (ux, uy), length, phase = self._sample_path(rng, avoid)
            speed = float(rng.uniform(*SPEED_RANGE))
            self._paths[i] = _Path(ax, ay, ux, uy, length, speed)
            self._walked[i] = phase
            self._recolour(i, rng)
        self.appearance = [self._palette_appearance(i) for i in range(self.n)]
        if self.appearance_mode == "random":
            self.appearance = [random_appearance(rng) for _ in range(self.n)]
        self._apply_appearance()
        self._write_poses()

    def _palette_appearance(self, i: int) -> Appearance:
        rgba = self._model.geom_rgba
        part = self._geoms_by_part

        def colour(p: str) -> tuple[float, float, float]:
            r, g, b = rgba[part[p][i], :3]
            return (float(r), float(g), float(b))

        return Appearance(colour("torso"), colour("leg_l"), colour("head"), 1.0, 1.0, 0.0)

    def _apply_appearance(self) -> None:
        """Colours, body sizes and gait phases from :attr:`appearance` (sizes from the
        originals, so a "fixed" episode after a "random" one has the default figure)."""
        m = self._model
        size, pos, rbound = self._size0.copy(), self._pos0.copy(), self._rbound0.copy()
        for i, look in enumerate(self.appearance):
            h, g = look.height, look.girth
            self._hip[i] = HIP_HEIGHT * h
            self._gait[i] = look.gait_phase
            for j, name in enumerate(self._geoms_by_part):
                row = j * self.n + i
                if name == "head":
                    pos[row, 2] *= h
                    size[row, 0] *= 0.5 * (1.0 + h)
                else:  # capsules: radius x girth, half length and centre height x height
                    size[row, 0] *= g
                    size[row, 1] *= h
                    pos[row] *= h
                rbound[row] *= max(h, g)
            colours = {"torso": look.shirt, "arm_l": look.shirt, "arm_r": look.shirt,
                       "head": look.skin, "leg_l": look.trousers, "leg_r": look.trousers}
            for name, c in colours.items():
                m.geom_rgba[self._geoms_by_part[name][i], :3] = c
        self._hip_arr = np.array(self._hip)
        self._gait_arr = np.array(self._gait)
        m.geom_size[self._parts] = size
        m.geom_pos[self._parts] = pos
        m.geom_rbound[self._parts] = rbound

    def _sample_path(
        self, rng: np.random.Generator, avoid: tuple[float, float] | None
    ) -> tuple[tuple[float, float], tuple[float, float], float, float]:
        """(start, unit direction, length, phase): a free path inside the pedestrian area
        whose position at the sampled phase is at least MIN_START_DISTANCE from ``avoid``.

        Candidates are drawn and checked in batches (one clearance query per batch); the
        first valid candidate wins.
        """
        world = self._world
        area = world.pedestrian_area
        k = _BATCH
        t = np.linspace(0.0, 1.0, _PATH_SAMPLES)
        length_hi = PATH_LENGTH_RANGE[1]
        for attempt in range(_MAX_BATCHES):
            if attempt == _MAX_BATCHES // 2:
                length_hi = PATH_LENGTH_RANGE[0]  # crowded: settle for short paths
            ax = rng.uniform(area.x[0], area.x[1], k)
            ay = rng.uniform(area.y[0], area.y[1], k)
            heading = rng.uniform(-math.pi, math.pi, k)
            length = rng.uniform(PATH_LENGTH_RANGE[0], length_hi, k)
            phase = rng.uniform(0.0, 2.0, k) * length  # anywhere on the out-and-back cycle
            ux, uy = np.cos(heading), np.sin(heading)
            bx, by = ax + length * ux, ay + length * uy
            ok = (area.x[0] <= bx) & (bx <= area.x[1]) & (area.y[0] <= by) & (by <= area.y[1])
            if avoid is not None:
                along = np.where(phase <= length, phase, 2.0 * length - phase)
                px, py = ax + along * ux, ay + along * uy
                ok &= np.hypot(px - avoid[0], py - avoid[1]) >= MIN_START_DISTANCE
            cand = np.flatnonzero(ok)  # only paths that pass the cheap tests get walked
            xs = ax[cand, None] + (length * ux)[cand, None] * t
            ys = ay[cand, None] + (length * uy)[cand, None] * t
            free = np.all(world.clearance_many(xs, ys) > PATH_CLEARANCE, axis=1)
            good = cand[free]
            if len(good):
                i = good[0]
                return (
                    (float(ax[i]), float(ay[i])),
                    (float(ux[i]), float(uy[i])),
                    float(length[i]),
                    float(phase[i]),
                )
        # A crowded area: stand still at a free point rather than fail the reset.
        log.warning("world %s: no free pedestrian path found; one stands still", world.name)
        for _ in range(_MAX_BATCHES):
            sx, sy = world.sample_free(rng, area, PATH_CLEARANCE)
            if avoid is None or math.hypot(sx - avoid[0], sy - avoid[1]) >= MIN_START_DISTANCE:
                break
        return (sx, sy), (1.0, 0.0), 0.0, 0.0

    def lay_crossings(
        self, rng: np.random.Generator, start: tuple[float, float], goal: tuple[float, float]
    ) -> int:
        """Give every pedestrian a path across the line from ``start`` to ``goal``.

        Pedestrian i crosses the line at a random fraction of its length
        (``CROSSING_FRACTION_RANGE``), walking within ``CROSSING_ANGLE_JITTER`` of
        perpendicular to it from a random side, ``CROSSING_HALF_LENGTH_RANGE`` m either side
        of the line (``CROSSING_MIN_HALF_LENGTH`` where that is too cluttered; then back:
        the path is out-and-back, so it crosses again). Its start
        point is timed so that it reaches the line when a rover driving straight at
        ``CROSSING_ROVER_SPEED`` would. Paths keep clear of obstacles and start at least
        ``MIN_START_DISTANCE`` from the rover; a pedestrian with no free crossing after
        ``_CROSSING_TRIES`` candidates gets a normal path. Speeds and clothes are drawn as
        in :meth:`reset`. Returns how many pedestrians cross.
        """
        sx, sy = start
        gx, gy = goal
        span = math.hypot(gx - sx, gy - sy)
        line = math.atan2(gy - sy, gx - sx)
        t = np.linspace(0.0, 1.0, _PATH_SAMPLES)
        crossing = 0
        for i in range(self.n):
            speed = float(rng.uniform(*SPEED_RANGE))
            lo, hi = CROSSING_HALF_LENGTH_RANGE
            for attempt in range(_CROSSING_TRIES):
                if attempt == _CROSSING_TRIES // 2:  # cluttered: settle for shorter walks
                    lo, hi = CROSSING_MIN_HALF_LENGTH, CROSSING_HALF_LENGTH_RANGE[0]
                frac = float(rng.uniform(*CROSSING_FRACTION_RANGE))
                half = float(rng.uniform(lo, hi))
                side = 1.0 if rng.random() < 0.5 else -1.0
                walk = (
                    line
                    + side * 0.5 * math.pi
                    + float(rng.uniform(-1.0, 1.0)) * (CROSSING_ANGLE_JITTER)
                )
                ux, uy = math.cos(walk), math.sin(walk)
                cx, cy = sx + frac * span * math.cos(line), sy + frac * span * math.sin(line)
                ax, ay = cx - half * ux, cy - half * uy
                length = 2.0 * half
                arrive = frac * span / CROSSING_ROVER_SPEED  # s until the rover gets there
                phase = (half - speed * arrive) % (2.0 * length)
                px, py, _, _ = _position(_Path(ax, ay, ux, uy, length, speed), phase)
                if math.hypot(px - sx, py - sy) < MIN_START_DISTANCE:
                    continue
                xs, ys = ax + length * ux * t, ay + length * uy * t
                if np.all(self._world.clearance_many(xs[None], ys[None]) > PATH_CLEARANCE):
                    self._paths[i] = _Path(ax, ay, ux, uy, length, speed)
                    self._walked[i] = phase
                    crossing += 1
                    if self._crowd is not None:  # walked by the crowd model from there
                        px, py, wx, wy = _position(self._paths[i], phase)
                        a, b = (ax, ay), (ax + length * ux, ay + length * uy)
                        end, back = (b, a) if wx * ux + wy * uy > 0 else (a, b)
                        self._crowd.lay_crossing(i, (px, py), end, back, speed)
                    break
            else:
                if self._crowd is not None:  # keeps its own start and goal
                    self._recolour(i, rng)
                    continue
                (ax, ay), (ux, uy), length, phase = self._sample_path(rng, start)
                self._paths[i] = _Path(ax, ay, ux, uy, length, speed)
                self._walked[i] = phase
            self._recolour(i, rng)
        self._write_poses()
        return crossing

    def _recolour(self, i: int, rng: np.random.Generator) -> None:
        rgba = self._model.geom_rgba
        shirt = SHIRTS[rng.integers(len(SHIRTS))]
        trousers = TROUSERS[rng.integers(len(TROUSERS))]
        skin = SKIN[rng.integers(len(SKIN))]
        for part, colour in (
            ("torso", shirt),
            ("arm_l", shirt),
            ("arm_r", shirt),
            ("head", skin),
            ("leg_l", trousers),
            ("leg_r", trousers),
        ):
            rgba[self._geoms_by_part[part][i], :3] = colour

    def place(self, i: int, x: float, y: float, heading: float) -> None:
        """Pin pedestrian ``i`` standing at (x, y) facing ``heading`` (rad) until next reset."""
        if not 0 <= i < self.n:
            raise IndexError(f"pedestrian index {i} out of range: this world has {self.n}")
        if self._crowd is not None:
            self._crowd.place(i, float(x), float(y), float(heading))
            self._write_poses()
            return
        self._paths[i] = _Path(float(x), float(y), math.cos(heading), math.sin(heading), 0.0, 0.0)
        self._walked[i] = 0.0
        self._write_poses()

    def walked_state(self) -> list[float] | CrowdState:
        """Where every pedestrian is (for :meth:`restore_walked`)."""
        if self._crowd is not None:
            return self._crowd.state()
        return list(self._walked)

    def restore_walked(self, state: list[float] | CrowdState) -> None:
        """Put every pedestrian back where :meth:`walked_state` found it."""
        if isinstance(state, CrowdState):
            assert self._crowd is not None
            self._crowd.restore(state)
        else:
            self._walked = list(state)
        self._write_poses()

    # --- motion --------------------------------------------------------------------------------
    def advance(self, dt: float, rover_xy: tuple[float, float] | None = None) -> None:
        """Walk every pedestrian ``dt`` seconds on, then write the mocap poses.

        A pedestrian whose next position would come within YIELD_DISTANCE of the rover,
        with the rover ahead of it, waits instead (mocap bodies push with infinite mass:
        walking through the rover would throw it about).
        """
        if self._crowd is not None:
            if self._crowd.advance(dt, rover_xy):
                self._write_poses()
            return
        walked = self._walked
        for i, path in enumerate(self._paths):
            if path.length <= 0.0:
                continue
            nxt = walked[i] + path.speed * dt
            if rover_xy is not None:
                x, y, ux, uy = _position(path, nxt)
                rx, ry = rover_xy[0] - x, rover_xy[1] - y
                if rx * rx + ry * ry < YIELD_DISTANCE**2 and rx * ux + ry * uy > 0.0:
                    continue
            walked[i] = nxt
        self._write_poses()

    def _write_poses(self) -> None:
        """Mocap poses from the walked distances, or from the crowd (plain Python: a
        handful of figures)."""
        if self.n == 0:
            return
        pos_rows: list[list[float]] = []
        quat_rows: list[list[float]] = []
        crowd = self._crowd
        if crowd is None:
            for i, path in enumerate(self._paths):
                walked = self._walked[i]
                x, y, ux, uy = _position(path, walked)
                swing = (
                    LEG_SWING * math.sin(math.pi * walked / STEP_LENGTH + self._gait[i])
                    if path.length
                    else 0.0
                )
                self._pose(i, x, y, math.atan2(uy, ux), swing, pos_rows, quat_rows)
        else:
            self._write_crowd_poses(crowd)
            return
        self._data.mocap_pos[self._order] = pos_rows
        self._data.mocap_quat[self._order] = quat_rows

    def _write_crowd_poses(self, crowd: Crowd) -> None:
        """Mocap poses of the crowd's walkers (compiled: ten or twenty figures)."""
        self.positions[:] = crowd.pos
        self.headings[:] = crowd.heading
        crowd_kernel.pose_figures(
            crowd.pos, crowd.heading, crowd.vel, crowd.walked, crowd.here(), self._gait_arr,
            self._hip_arr, _LEGS, self._order, self._data.mocap_pos, self._data.mocap_quat,
        )  # fmt: skip

    def _pose(
        self,
        i: int,
        x: float,
        y: float,
        yaw: float,
        swing: float,
        pos_rows: list[list[float]],
        quat_rows: list[list[float]],
    ) -> None:
        """Append pedestrian ``i``'s three mocap poses (upper body, left, right leg)."""
        world = self._world
        hip = self._hip[i]
        positions = self.positions
        positions[i, 0], positions[i, 1] = x, y
        self.headings[i] = yaw
        z = 0.0 if world.heightfield is None else world.ground_height(x, y)
        cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        pos_rows.append([x, y, z])
        quat_rows.append([cy, 0.0, 0.0, sy])
        for side, angle in ((HIP_HALF_WIDTH, swing), (-HIP_HALF_WIDTH, -swing)):
            # hip = pos + R(yaw) (0, side, HIP_HEIGHT); leg quat = yaw * pitch(angle)
            cp, sp = math.cos(0.5 * angle), math.sin(0.5 * angle)
            pos_rows.append([x - sin_yaw * side, y + cos_yaw * side, z + hip])
            quat_rows.append([cy * cp, -sy * sp, cy * sp, sy * cp])


_LEGS = (LEG_SWING, STEP_LENGTH, HIP_HALF_WIDTH)  # crowd_kernel.pose_figures' gait


def _position(path: _Path, walked: float) -> tuple[float, float, float, float]:
    """(x, y, walking direction x, y) after ``walked`` metres on the out-and-back path."""
    if path.length <= 0.0:
        return path.ax, path.ay, path.ux, path.uy
    s = walked % (2.0 * path.length)
    if s <= path.length:
        return path.ax + s * path.ux, path.ay + s * path.uy, path.ux, path.uy
    along = 2.0 * path.length - s  # walking back towards the start
    return path.ax + along * path.ux, path.ay + along * path.uy, -path.ux, -path.uy
