"""WorldSpec: what an arena is (seed rectangles, obstacle footprints, MJCF scenery).

Geom groups used by every arena (the cameras show groups 0-2, the LIDAR casts against
groups 0 and 1 only):

- 0: scenery standing on the ground (walls, rocks, panels): collides, scanned, rendered
- 1: pedestrians: collide with the rover, scanned, rendered
- 2: rendered, not scanned: the ground (plane or height field: a level 2D scan never
  meets flat ground, and ray casting a height field is costly), the rover's
  visuals, and visual-only scenery (panel frames)
- 3: rover collision shapes: invisible
- 4: markers (goal): drawn in the chase view only
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TypedDict

import numpy as np

from rover_env.constants import WORLD_RECTANGLES

GROUP_PEDESTRIAN = 1
GROUP_VISUAL = 2  # rendered, not scanned, no collision
GROUP_GROUND = 2
GROUP_ROVER_VISUAL = 2
GROUP_ROVER_COLLISION = 3
GROUP_MARKER = 4

# Collision bits: scenery and pedestrians are contype 1 / conaffinity 2, the rover is
# contype 2 / conaffinity 1. So the rover collides with both, and nothing else collides
# (the rover's own parts, pedestrians with scenery or each other).
CONTYPE_WORLD, CONAFFINITY_WORLD = 1, 2
CONTYPE_ROVER, CONAFFINITY_ROVER = 2, 1
# Friction: wheels grip the ground (1.0, both priority 0, MuJoCo takes the max), but
# scenery and pedestrians have priority 1 and their own low friction, so a spinning
# wheel pressed against a wall slides instead of climbing it and flipping the rover.
GROUND_FRICTION = "1.0 0.01 0.001"
OBSTACLE_FRICTION = "0.3 0.005 0.0001"
OBSTACLE_PRIORITY = 1
_SAMPLE_BATCH = 16
_MAX_SAMPLE_BATCHES = 100


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle ``x in [x_lo, x_hi]``, ``y in [y_lo, y_hi]`` (metres)."""

    x: tuple[float, float]
    y: tuple[float, float]

    def contains(self, x: float, y: float) -> bool:
        return self.x[0] <= x <= self.x[1] and self.y[0] <= y <= self.y[1]

    def sample(self, rng: np.random.Generator) -> tuple[float, float]:
        """A point uniformly distributed in the rectangle."""
        return (float(rng.uniform(*self.x)), float(rng.uniform(*self.y)))

    def expanded(self, margin: float) -> Rect:
        x, y = self.x, self.y
        return Rect((x[0] - margin, x[1] + margin), (y[0] - margin, y[1] + margin))


@dataclass(frozen=True)
class Circle:
    """Circular obstacle footprint (rocks, poles, tanks)."""

    x: float
    y: float
    radius: float

    def distance(self, x: float, y: float) -> float:
        """Distance from (x, y) to the footprint (negative inside)."""
        return math.hypot(x - self.x, y - self.y) - self.radius


@dataclass(frozen=True)
class Box:
    """Rectangular obstacle footprint: centre, half sizes, yaw (rad)."""

    x: float
    y: float
    half_x: float
    half_y: float
    yaw: float = 0.0

    def distance(self, x: float, y: float) -> float:
        """Distance from (x, y) to the footprint (negative inside)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        qx, qy = abs(lx) - self.half_x, abs(ly) - self.half_y
        outside = math.hypot(max(qx, 0.0), max(qy, 0.0))
        return outside + min(max(qx, qy), 0.0)


Obstacle = Circle | Box


@dataclass(frozen=True, eq=False)
class HeightField:
    """A MuJoCo height field: ``elevation`` (nrow, ncol) in [0, 1], row index along +y.

    The geom sits at ``(centre, 0)``, spans ``centre +- (radius_x, radius_y)``; the ground
    height is ``elevation * z_top`` and the solid extends ``base`` metres below z = 0
    (MuJoCo hfield ``size="radius_x radius_y z_top base"``).
    """

    centre: tuple[float, float]
    radius_x: float
    radius_y: float
    z_top: float
    base: float
    elevation: np.ndarray = field(repr=False)

    def height(self, x: float, y: float) -> float:
        """Ground height at (x, y) by bilinear interpolation (0 outside the field)."""
        nrow, ncol = self.elevation.shape
        u = (x - self.centre[0] + self.radius_x) / (2 * self.radius_x) * (ncol - 1)
        v = (y - self.centre[1] + self.radius_y) / (2 * self.radius_y) * (nrow - 1)
        if not (0.0 <= u <= ncol - 1 and 0.0 <= v <= nrow - 1):
            return 0.0
        c0, r0 = min(int(u), ncol - 2), min(int(v), nrow - 2)
        fu, fv = u - c0, v - r0
        e = self.elevation
        h = (
            e[r0, c0] * (1 - fu) * (1 - fv)
            + e[r0, c0 + 1] * fu * (1 - fv)
            + e[r0 + 1, c0] * (1 - fu) * fv
            + e[r0 + 1, c0 + 1] * fu * fv
        )
        return float(h * self.z_top)

    def heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """:meth:`height` at many points at once (the same bilinear values)."""
        nrow, ncol = self.elevation.shape
        u = (np.asarray(x) - self.centre[0] + self.radius_x) / (2 * self.radius_x) * (ncol - 1)
        v = (np.asarray(y) - self.centre[1] + self.radius_y) / (2 * self.radius_y) * (nrow - 1)
        inside = (u >= 0.0) & (u <= ncol - 1) & (v >= 0.0) & (v <= nrow - 1)
        c0 = np.minimum(np.maximum(u, 0.0), ncol - 2).astype(np.intp)  # (np.clip: slower)
        r0 = np.minimum(np.maximum(v, 0.0), nrow - 2).astype(np.intp)
        fu, fv = u - c0, v - r0
        e = self.elevation
        h = (
            e[r0, c0] * (1 - fu) * (1 - fv)
            + e[r0, c0 + 1] * fu * (1 - fv)
            + e[r0 + 1, c0] * (1 - fu) * fv
            + e[r0 + 1, c0 + 1] * fu * fv
        )
        return np.where(inside, h * self.z_top, 0.0)


@dataclass(frozen=True, eq=False)
class WorldSpec:
    """One arena: the seed's rectangles, obstacle footprints, and its MJCF scenery.

    :param name: canonical world name (``inspect``, ``moon``, ``maze``).
    :param spawn: rover spawn rectangle (seed ``rand_x_range`` x ``rand_y_range``).
    :param goal: goal rectangle (seed ``rand_goal_x_range`` x ``rand_goal_y_range``).
    :param bounds: out-of-bounds rectangle (seed ``too_far_away_*``): leaving it ends the
        episode.
    :param obstacles: footprints of everything the rover cannot stand on; spawn, goals
        and pedestrian paths keep clear of them.
    :param pedestrian_area: where pedestrian paths are laid out.
    :param asset_xml: MJCF ``<asset>`` children (textures, materials, hfields).
    :param worldbody_xml: MJCF ``<worldbody>`` children (ground and scenery geoms).
    :param heightfield: the terrain, when the ground is not flat.
    :param n_pedestrians: walking figures in this world.
    """

    name: str
    spawn: Rect
    goal: Rect
    bounds: Rect
    obstacles: tuple[Obstacle, ...]
    pedestrian_area: Rect
    asset_xml: str
    worldbody_xml: str
    heightfield: HeightField | None = None
    n_pedestrians: int = 3

    @cached_property
    def _footprints(self) -> tuple[np.ndarray, np.ndarray]:
        """Obstacles as arrays: circles (k, 3) x y r; boxes (m, 6) x y hx hy cos sin."""
        circles = np.array(
            [(o.x, o.y, o.radius) for o in self.obstacles if isinstance(o, Circle)]
        ).reshape(-1, 3)
        boxes = np.array(
            [
                (o.x, o.y, o.half_x, o.half_y, math.cos(o.yaw), math.sin(o.yaw))
                for o in self.obstacles
                if isinstance(o, Box)
            ]
        ).reshape(-1, 6)
        return circles, boxes

    def clearance_many(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest obstacle footprint (negative inside)."""
        x, y = np.asarray(x, dtype=float)[..., None], np.asarray(y, dtype=float)[..., None]
        circles, boxes = self._footprints
        best = np.full(x.shape[:-1], np.inf)
        if len(circles):
            d = np.hypot(x - circles[:, 0], y - circles[:, 1]) - circles[:, 2]
            best = np.minimum(best, d.min(axis=-1))
        if len(boxes):
            dx, dy = x - boxes[:, 0], y - boxes[:, 1]
            c, s = boxes[:, 4], boxes[:, 5]
            qx = np.abs(c * dx + s * dy) - boxes[:, 2]
            qy = np.abs(-s * dx + c * dy) - boxes[:, 3]
            d = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0)) + np.minimum(
                np.maximum(qx, qy), 0.0
            )
            best = np.minimum(best, d.min(axis=-1))
        return best

    def ray_distances(self, x: float, y: float, angles: np.ndarray, max_range: float) -> np.ndarray:
        """Distance along each ray from (x, y) at ``angles`` (rad, world frame) to the first
        obstacle footprint it meets, ``max_range`` where it meets none within that (0 from
        inside one). A level 2D cast against the footprints: what a planar LIDAR sees of
        the scenery, without the pedestrians."""
        angles = np.asarray(angles, dtype=float)
        dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
        best = np.full(angles.shape, float(max_range))
        circles, boxes = self._footprints
        if len(circles):
            ox, oy = x - circles[:, 0], y - circles[:, 1]
            b = ox * dx + oy * dy
            c = ox**2 + oy**2 - circles[:, 2] ** 2
            disc = b**2 - c
            with np.errstate(invalid="ignore"):
                t = np.where(c <= 0.0, 0.0, -b - np.sqrt(disc))
            t = np.where((disc >= 0.0) & (t >= 0.0), t, np.inf)
            best = np.minimum(best, t.min(axis=1))
        if len(boxes):
            co, si = boxes[:, 4], boxes[:, 5]
            ox, oy = x - boxes[:, 0], y - boxes[:, 1]
            lx, ly = co * ox + si * oy, -si * ox + co * oy  # origin in each box's frame
            ldx, ldy = co * dx + si * dy, -si * dx + co * dy  # directions likewise
            ldx = np.where(np.abs(ldx) < 1e-12, 1e-12, ldx)
            ldy = np.where(np.abs(ldy) < 1e-12, 1e-12, ldy)
            tx1, tx2 = (-boxes[:, 2] - lx) / ldx, (boxes[:, 2] - lx) / ldx
            ty1, ty2 = (-boxes[:, 3] - ly) / ldy, (boxes[:, 3] - ly) / ldy
            near = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
            far = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
            t = np.where((near <= far) & (far >= 0.0), np.maximum(near, 0.0), np.inf)
            best = np.minimum(best, t.min(axis=1))
        return best

    def clearance(self, x: float, y: float) -> float:
        """Distance from (x, y) to the nearest obstacle footprint (inf with none)."""
        return float(self.clearance_many(np.array(x), np.array(y)))

    def is_free(self, x: float, y: float, clearance: float = 0.0) -> bool:
        """True when a disc of radius ``clearance`` at (x, y) touches no obstacle."""
        return self.clearance(x, y) > clearance

    def in_bounds(self, x: float, y: float) -> bool:
        """False once the seed's out-of-bounds rectangle is left."""
        return self.bounds.contains(x, y)

    def ground_height(self, x: float, y: float) -> float:
        """Terrain height at (x, y) (0 on flat worlds)."""
        return 0.0 if self.heightfield is None else self.heightfield.height(x, y)

    def ground_heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """:meth:`ground_height` at many points at once."""
        if self.heightfield is None:
            return np.zeros(np.shape(x))
        return self.heightfield.heights(x, y)

    def sample_free(
        self, rng: np.random.Generator, rect: Rect, clearance: float
    ) -> tuple[float, float]:
        """Uniform point of ``rect`` whose ``clearance`` disc is obstacle-free.

        Rejection sampling (candidates drawn in batches, the first free one wins), so the
        result is uniform over the free part of the rectangle.
        """
        for _ in range(_MAX_SAMPLE_BATCHES):
            xs = rng.uniform(rect.x[0], rect.x[1], _SAMPLE_BATCH)
            ys = rng.uniform(rect.y[0], rect.y[1], _SAMPLE_BATCH)
            free = np.flatnonzero(self.clearance_many(xs, ys) > clearance)
            if len(free):
                return float(xs[free[0]]), float(ys[free[0]])
        raise RuntimeError(
            f"world {self.name!r}: no free point with clearance {clearance} m found in "
            f"{rect} after {_MAX_SAMPLE_BATCHES * _SAMPLE_BATCH} tries; the obstacles cover "
            "the rectangle"
        )


class SeedAreas(TypedDict):
    """:func:`seed_areas`' keywords (typed, so that ``WorldSpec(**seed_areas(n))`` checks)."""

    spawn: Rect
    goal: Rect
    bounds: Rect


def seed_areas(name: str) -> SeedAreas:
    """The seed's ``spawn``, ``goal`` and ``bounds`` rectangles of world ``name``, as
    keyword arguments for :class:`WorldSpec`."""
    r = WORLD_RECTANGLES[name]
    return {
        "spawn": Rect(r["rand_x_range"], r["rand_y_range"]),
        "goal": Rect(r["rand_goal_x_range"], r["rand_goal_y_range"]),
        "bounds": Rect(r["too_far_away_x"], r["too_far_away_y"]),
    }
