"""A world's map for planning: an occupancy grid with a traversal cost per cell, and the
cost-to-go field of a goal on it (the geodesic distance, weighted away from the walls).

The planner expert (:mod:`rover_train.imitation.expert`) plans on it. The grid covers the
world's goal square plus a margin (``GRID_RES`` m cells). Each cell's cost grows as its
clearance from the nearest footprint falls below ``PREFERRED_CLEARANCE``, and is
prohibitive below ``HARD_CLEARANCE`` (the seed's collision test is a LIDAR return under
0.3 m from the rover's centre).
"""

from __future__ import annotations

import math

import numpy as np

from rover_env.worlds import WorldSpec

GRID_RES = 0.1  # m per grid cell
GRID_MARGIN = 2.5  # m of map around the goal square
HARD_CLEARANCE = 0.34  # m: below this a cell is (almost) impassable
PREFERRED_CLEARANCE = 0.75  # m: below this a cell costs more (keeps to corridor middles)
WALL_COST = 6.0  # extra cost per cell at HARD_CLEARANCE, falling linearly to 0
BLOCKED_COST = 200.0  # per cell closer than HARD_CLEARANCE (finite: a rover there gets out)
_SQRT2 = math.sqrt(2.0)


class CostToGo:
    """Cost-to-go field of one goal on a world's occupancy grid."""

    def __init__(
        self, grid: OccupancyGrid, goal: tuple[float, float], extra: np.ndarray | None = None
    ) -> None:
        self.grid = grid
        self.goal = (float(goal[0]), float(goal[1]))
        self.field = grid.cost_to_go(self.goal, extra)

    def value(self, x: float, y: float) -> float:
        i, j = self.grid.cell(x, y)
        return float(self.field[i, j])

    def descent(self, x: float, y: float, length: float) -> list[tuple[float, float]]:
        """Cell centres along steepest descent from (x, y), about ``length`` m long."""
        grid, field = self.grid, self.field
        i, j = grid.cell(x, y)
        points: list[tuple[float, float]] = []
        walked = 0.0
        n_i, n_j = field.shape
        while walked < length:
            best, bi, bj, step = field[i, j], i, j, 0.0
            for di, dj, d in _NEIGHBOURS:
                a, b = i + di, j + dj
                if 0 <= a < n_i and 0 <= b < n_j and field[a, b] < best:
                    best, bi, bj, step = field[a, b], a, b, d
            if step == 0.0:
                break
            i, j = bi, bj
            walked += step * grid.res
            points.append(grid.centre(i, j))
        return points

    def pursuit_point(
        self, x: float, y: float, lookahead: float, sight_clearance: float, samples: int
    ) -> tuple[float, float]:
        """The point to steer at from (x, y): the goal when it is nearer than ``lookahead``
        and in plain sight, else the farthest point of the descent within ``lookahead`` that
        a straight line reaches keeping ``sight_clearance`` (checked at ``samples`` points)."""
        goal, grid = self.goal, self.grid
        t = np.linspace(0.0, 1.0, samples)
        if math.hypot(goal[0] - x, goal[1] - y) < lookahead:
            xs, ys = x + (goal[0] - x) * t, y + (goal[1] - y) * t
            if grid.clearance_at(xs, ys).min() > sight_clearance:
                return goal
        path = self.descent(x, y, lookahead)
        if not path:
            return goal
        pts = np.asarray(path)
        xs = x + (pts[:, 0, None] - x) * t[None, :]
        ys = y + (pts[:, 1, None] - y) * t[None, :]
        visible = np.flatnonzero(grid.clearance_at(xs, ys).min(axis=1) > sight_clearance)
        k = int(visible[-1]) if len(visible) else 0
        return float(pts[k, 0]), float(pts[k, 1])


def goal_key(goal: tuple[float, float]) -> tuple[float, float]:
    """A goal rounded to the millimetre: the key fields are cached under."""
    return round(float(goal[0]), 3), round(float(goal[1]), 3)


class FieldCache:
    """Cost-to-go fields of one grid by goal (:func:`goal_key`), computed on first use; all
    are dropped when more than ``size`` are held."""

    def __init__(self, grid: OccupancyGrid, size: int = 64) -> None:
        self.grid = grid
        self.size = size
        self._fields: dict[tuple[float, float], CostToGo] = {}

    def peek(self, goal: tuple[float, float]) -> CostToGo | None:
        """The field of ``goal`` if it is held, else None (nothing is computed)."""
        return self._fields.get(goal_key(goal))

    def get(self, goal: tuple[float, float]) -> CostToGo:
        key = goal_key(goal)
        f = self._fields.get(key)
        if f is None:
            if len(self._fields) > self.size:
                self._fields.clear()
            f = self._fields[key] = CostToGo(self.grid, key)
        return f


_NEIGHBOURS = (
    (1, 0, 1.0),
    (-1, 0, 1.0),
    (0, 1, 1.0),
    (0, -1, 1.0),
    (1, 1, _SQRT2),
    (1, -1, _SQRT2),
    (-1, 1, _SQRT2),
    (-1, -1, _SQRT2),
)


class OccupancyGrid:
    """Per-cell traversal cost of a world's goal square plus a margin.

    Rows index x, columns index y: cell (i, j) has its centre at
    ``(x0 + (i + 0.5) res, y0 + (j + 0.5) res)``.
    """

    def __init__(self, world: WorldSpec, res: float = GRID_RES, margin: float = GRID_MARGIN):
        self.world = world
        self.res = float(res)
        rect = world.goal.expanded(margin)
        b = world.bounds
        x_lo, x_hi = max(rect.x[0], b.x[0]), min(rect.x[1], b.x[1])
        y_lo, y_hi = max(rect.y[0], b.y[0]), min(rect.y[1], b.y[1])
        self.x0, self.y0 = x_lo, y_lo
        self.shape = (int(math.ceil((x_hi - x_lo) / res)), int(math.ceil((y_hi - y_lo) / res)))
        xs = x_lo + (np.arange(self.shape[0]) + 0.5) * res
        ys = y_lo + (np.arange(self.shape[1]) + 0.5) * res
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        self.clearance = world.clearance_many(gx, gy)
        extra = WALL_COST * np.clip(
            (PREFERRED_CLEARANCE - self.clearance) / (PREFERRED_CLEARANCE - HARD_CLEARANCE), 0, 1
        )
        self.cost = 1.0 + extra
        self.cost[self.clearance < HARD_CLEARANCE] = BLOCKED_COST
        self.cost[self.clearance <= 0.0] = np.inf  # inside an obstacle

    def cell(self, x: float, y: float) -> tuple[int, int]:
        i = int((x - self.x0) / self.res)
        j = int((y - self.y0) / self.res)
        return min(max(i, 0), self.shape[0] - 1), min(max(j, 0), self.shape[1] - 1)

    def clearance_at(self, xs: np.ndarray | float, ys: np.ndarray | float) -> np.ndarray:
        """Clearance of the cells under points (nearest cell; outside the grid: its edge)."""
        i = np.clip(((np.asarray(xs) - self.x0) / self.res).astype(int), 0, self.shape[0] - 1)
        j = np.clip(((np.asarray(ys) - self.y0) / self.res).astype(int), 0, self.shape[1] - 1)
        return self.clearance[i, j]

    def discs_cost(self, centres: np.ndarray, radius: float, cost: float) -> np.ndarray:
        """A per-cell extra cost of ``cost`` inside discs of ``radius`` around ``centres``."""
        xs = self.x0 + (np.arange(self.shape[0]) + 0.5) * self.res
        ys = self.y0 + (np.arange(self.shape[1]) + 0.5) * self.res
        extra = np.zeros(self.shape)
        for cx, cy in np.asarray(centres).reshape(-1, 2):
            inside = (xs[:, None] - cx) ** 2 + (ys[None, :] - cy) ** 2 < radius**2
            extra[inside] = cost
        return extra

    def centre(self, i: int, j: int) -> tuple[float, float]:
        return self.x0 + (i + 0.5) * self.res, self.y0 + (j + 0.5) * self.res

    def cost_to_go(
        self, goal: tuple[float, float], extra: np.ndarray | None = None
    ) -> np.ndarray:
        """Dijkstra-equivalent field: relaxation sweeps over the 8 neighbours until stable.

        Edge cost between neighbours is the mean of their cell costs times the step length.
        Every cell within the success radius' inner part (0.25 m) of the goal is a source,
        so a goal placed close to a wall still has a reachable free source.
        """
        cost = self.cost if extra is None else self.cost + extra
        gi, gj = self.cell(*goal)
        field = np.full(self.shape, np.inf)
        r = max(1, int(0.25 / self.res))
        src = (slice(max(gi - r, 0), gi + r + 1), slice(max(gj - r, 0), gj + r + 1))
        field[src] = np.where(np.isfinite(cost[src]), 0.0, np.inf)
        if not np.isfinite(field).any():
            field[gi, gj] = 0.0
        n_i, n_j = self.shape
        before = field.copy()
        for sweep in range(4 * (n_i + n_j)):
            for di, dj, d in _NEIGHBOURS:
                # dst cells [a0:a1, b0:b1] take from src cells shifted by (di, dj)
                a0, a1 = max(0, -di), n_i - max(0, di)
                b0, b1 = max(0, -dj), n_j - max(0, dj)
                dst = field[a0:a1, b0:b1]
                src_f = field[a0 + di : a1 + di, b0 + dj : b1 + dj]
                edge = 0.5 * (cost[a0:a1, b0:b1] + cost[a0 + di : a1 + di, b0 + dj : b1 + dj])
                np.minimum(dst, src_f + d * edge, out=dst)
            if sweep % 8 == 7:
                if np.array_equal(before, field):
                    break
                before = field.copy()
        return field
