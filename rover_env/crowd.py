"""Crowd: pedestrians who walk to goals, as a social-force model (its loop compiled by numba).

The model is Helbing & Molnár's social force (1995): each person accelerates towards a
desired velocity (its speed, towards the next waypoint of its route) with relaxation time
``TAU``, and is pushed away from the people around it (exponential in the gap between their
bodies, weaker for people behind: anisotropy ``LAMBDA``) and from the scenery (exponential in
the clearance, along the gradient of a precomputed distance field). Groups (``groups`` mode)
add Moussaïd et al.'s (2010) coherence force towards the group's centre, as PySocialForce
does, share a goal, a speed and pauses. People who see the rover (every mode but
``oblivious``) treat it as a moving obstacle: they are pushed from the point of closest
approach over the next ``ROVER_LOOKAHEAD`` s and step aside (a sideways force, to the side
they already are on), so they slow, sidestep and pass; nobody freezes.

Routes: the pedestrian area is a grid of ``CELL`` m cells; a cell is free when its centre
is ``GRID_CLEARANCE`` m from every obstacle footprint. A goal is a free cell in the walker's
connected part of the grid, at least ``GOAL_MIN_DISTANCE`` away; the distance to it from
every cell is a row of the all-pairs route table (built once per world), and each
walker heads for the cell two moves down its route (its goal point in the last cell). On
arrival a walker pauses (probability ``PAUSE_PROBABILITY``, ``PAUSE_RANGE`` s) and draws a
new goal; one that makes no progress for ``STUCK_TIME`` s draws a new goal too.

Solid bodies: after each step of the forces, people are moved apart to ``MIN_SEPARATION`` m
(centre to centre), out of the scenery to ``BODY_RADIUS`` m of clearance, kept inside the
pedestrian area, and out of the rover's footprint (``ROVER_RADIUS`` + ``BODY_RADIUS``). Mocap
bodies push with infinite mass: a pedestrian moved into the rover would throw it about, so
nobody is; one held at the rover's body this step is reported by :attr:`Crowd.touching`.

Time: the model steps at a fixed ``CROWD_DT`` of simulated time whatever the env's
``control_dt``; :meth:`Crowd.advance` runs the whole steps that fit and keeps the rest.
Randomness (starts, goals, speeds, pauses) comes from a generator drawn at :meth:`Crowd.reset`
from the env's, so ``reset(seed=s)`` reproduces an episode.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rover_env import crowd_kernel
from rover_env.worlds.spec import Rect, WorldSpec

CROWD_DT = 0.1  # s: the model's fixed step (CrowdNav steps 0.25 s); poses move at 10 Hz
SPEED_RANGE = (1.0, 1.5)  # m/s: preferred walking speed (as the pacers')
MAX_SPEED_FACTOR = 1.3  # a pushed walker may go this much faster than it prefers
TAU = 0.5  # s: relaxation time towards the desired velocity
BODY_RADIUS = 0.3  # m: shoulders; clearance kept from the scenery
MIN_SEPARATION = 0.5  # m between two people's centres (bodies touch, never overlap)
ROVER_RADIUS = 0.33  # m: the rover's footprint as a disc (0.45 x 0.43 m chassis)
# Pedestrian-pedestrian repulsion (Helbing & Molnár; values as in PySocialForce's circular form)
A_PED, B_PED = 2.1, 0.3  # m/s^2, m
LAMBDA = 0.35  # weight of people behind (1 = isotropic)
GROUP_REPULSION_FACTOR = 0.3  # members of one group mind each other less
A_SIDE = 0.6  # sideways (evasive) share of a repulsion from someone ahead
# Scenery repulsion along the distance field's gradient
A_OBS, B_OBS = 4.0, 0.2
# The rover, for people who see it
A_ROVER, B_ROVER = 5.0, 0.45
ROVER_LAMBDA = 0.5
ROVER_LOOKAHEAD = 1.0  # s: they react to where the rover will be closest
A_ROVER_SIDE = 1.0
# Groups (Moussaïd et al. 2010, PySocialForce's group coherence)
A_COHERENCE = 2.0
GROUP_SIZES = (2, 3)
GROUP_SPACING = 0.7  # m between members at the start
# Routes and goals
CELL = 0.5  # m: routing grid
GRID_CLEARANCE = 0.45  # m: a free cell's centre is this far from every obstacle
FIELD_CELL = 0.1  # m: scenery distance field
FIELD_MARGIN = 1.0  # m around the pedestrian area
GOAL_MIN_DISTANCE = 3.0  # m from the walker
ARRIVAL_DISTANCE = 0.5  # m from the goal point
SLOW_DOWN_DISTANCE = 1.0  # m: walkers slow down this close to their goal
PAUSE_PROBABILITY = 0.5
PAUSE_RANGE = (1.0, 4.0)  # s
STUCK_TIME = 8.0  # s without 0.5 m of progress: a new goal
PLAN_EVERY = 3  # steps between route look-ups (0.3 s), and right after a new goal
MAX_STEP = MAX_SPEED_FACTOR * SPEED_RANGE[1] * CROWD_DT  # m a walker moves in one step
MIN_START_DISTANCE = 2.0  # m from the rover at the start
START_SPACING = 1.0  # m between people at the start (group members: GROUP_SPACING)
MAX_PEDESTRIANS = 20
_START_TRIES = 40  # batches of candidate starts (plus 10 per walker)
_START_BATCH = 64
_SQRT2 = math.sqrt(2.0)
_MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))


# The constants of one step, in the order rover_env.crowd_kernel.step unpacks them.
KERNEL_CONSTANTS = (
    TAU, SLOW_DOWN_DISTANCE, A_PED, B_PED, MIN_SEPARATION, LAMBDA, GROUP_REPULSION_FACTOR,
    A_SIDE, A_OBS, B_OBS, BODY_RADIUS, A_ROVER, B_ROVER, ROVER_RADIUS, ROVER_LAMBDA,
    ROVER_LOOKAHEAD, A_ROVER_SIDE, A_COHERENCE, MAX_STEP,
)  # fmt: skip


class CrowdPlacementError(ValueError):
    """The crowd asked for cannot stand in the world's pedestrian area."""


@dataclass(frozen=True, eq=False)
class CrowdMap:
    """What the crowd knows of a world: the routing grid and the scenery distance field."""

    area: Rect
    nx: int
    ny: int
    centres: np.ndarray  # (C, 2) cell centres, row-major (iy * nx + ix)
    free: np.ndarray  # (C,) bool
    component: np.ndarray  # (C,) int: connected part of the free grid (-1: not free)
    neighbours: np.ndarray  # (C + 1, 8) int: neighbour cells (C = none), row C all none
    weights: np.ndarray  # (C + 1, 8) float: move costs (inf = none)
    nearest_free: np.ndarray  # (C,) int: the free cell nearest each cell's centre
    field_origin: tuple[float, float]
    field: np.ndarray  # (fy, fx) clearance (m) at FIELD_CELL spacing
    table: np.ndarray  # (fy * fx, 4) clearance, unit gradient (x, y), ground z; flat
    corners: np.ndarray  # (fy * fx, 3) clearance and raw gradient, flat (crowd_kernel's bilinear)

    @property
    def capacity(self) -> int:
        """How many people can start in the area at once: one per START_SPACING² of free
        grid (a bound, not a promise: the rover's start keeps some of it)."""
        return int(self.free.sum() * CELL * CELL / (START_SPACING * START_SPACING))

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """(n,) the grid cell under each point (clipped to the grid)."""
        a = self.area
        ij = ((xy - (a.x[0], a.y[0])) * (1.0 / CELL)).astype(np.intp)
        np.minimum(np.maximum(ij, 0, out=ij), (self.nx - 1, self.ny - 1), out=ij)
        return ij[:, 1] * self.nx + ij[:, 0]

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """(n, 4) clearance, unit gradient (x, y) and ground height at the field point
        nearest each point (one lookup: the forces' view of the scenery, and where the
        figures' feet go)."""
        fy, fx = self.field.shape
        ij = ((xy - self.field_origin) * (1.0 / FIELD_CELL) + 0.5).astype(np.intp)
        np.minimum(np.maximum(ij, 0, out=ij), (fx - 1, fy - 1), out=ij)
        return self.table[ij[:, 1] * fx + ij[:, 0]]

    def route_distances(self, goal: int) -> np.ndarray:
        """(C + 1,) route length (m) from every cell to free cell ``goal`` (inf where none;
        entry C, the 'no neighbour' cell, is inf): a row of :meth:`all_routes`."""
        return self.all_routes()[goal]

    def all_routes(self) -> np.ndarray:
        """(C + 1, C + 1) route lengths between all cells over the free grid (Floyd-Warshall
        on the free cells, vectorised: tens of ms, once per world and process)."""
        hit = _ROUTES.get(self)
        if hit is not None:
            return hit
        n = len(self.free)
        free_idx = np.flatnonzero(self.free)
        k = len(free_idx)
        slot = np.full(n + 1, -1, dtype=np.intp)
        slot[free_idx] = np.arange(k)
        w = np.full((k, k), np.inf, dtype=np.float32)
        np.fill_diagonal(w, 0.0)
        rows = np.repeat(np.arange(k), 8)
        nbrs = self.neighbours[free_idx].reshape(-1)
        ok = nbrs < n
        w[rows[ok], slot[nbrs[ok]]] = self.weights[free_idx].reshape(-1)[ok]
        for m in range(k):
            np.minimum(w, w[:, m : m + 1] + w[m : m + 1, :], out=w)
        out = np.full((n + 1, n + 1), np.inf)
        out[np.ix_(free_idx, free_idx)] = w
        _ROUTES[self] = out
        return out


_MAPS: weakref.WeakKeyDictionary[WorldSpec, CrowdMap] = weakref.WeakKeyDictionary()
_ROUTES: weakref.WeakKeyDictionary[CrowdMap, np.ndarray] = weakref.WeakKeyDictionary()


def crowd_map(world: WorldSpec) -> CrowdMap:
    """The routing grid and distance field of ``world`` (built once per WorldSpec)."""
    hit = _MAPS.get(world)
    if hit is None:
        hit = _MAPS[world] = _build_map(world)
    return hit


def _build_map(world: WorldSpec) -> CrowdMap:
    area = world.pedestrian_area
    nx = max(1, int(round((area.x[1] - area.x[0]) / CELL)))
    ny = max(1, int(round((area.y[1] - area.y[0]) / CELL)))
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
    cx = area.x[0] + (ix.reshape(-1) + 0.5) * CELL
    cy = area.y[0] + (iy.reshape(-1) + 0.5) * CELL
    centres = np.stack([cx, cy], axis=1)
    free = world.clearance_many(cx, cy) > GRID_CLEARANCE
    n = nx * ny
    neighbours = np.full((n + 1, 8), n, dtype=np.intp)
    weights = np.full((n + 1, 8), np.inf)
    free2 = free.reshape(ny, nx)
    for k, (dx, dy) in enumerate(_MOVES):
        jx, jy = ix + dx, iy + dy
        inside = (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
        jxc, jyc = np.clip(jx, 0, nx - 1), np.clip(jy, 0, ny - 1)
        ok = inside & free2 & free2[jyc, jxc]
        if dx and dy:  # diagonal: no corner cutting
            ok &= free2[iy, jxc] & free2[jyc, ix]
        ok = ok.reshape(-1)
        neighbours[:n][ok, k] = (jyc * nx + jxc).reshape(-1)[ok]
        weights[:n][ok, k] = _SQRT2 if dx and dy else 1.0
    weights *= CELL
    component = np.full(n, -1, dtype=np.intp)
    label = 0
    for start in np.flatnonzero(free):
        if component[start] >= 0:
            continue
        component[start] = label
        stack = [int(start)]
        while stack:
            c = stack.pop()
            for nb in neighbours[c]:
                if nb < n and component[nb] < 0:
                    component[nb] = label
                    stack.append(int(nb))
        label += 1
    free_idx = np.flatnonzero(free)
    if len(free_idx):
        d2 = ((centres[:, None, :] - centres[None, free_idx, :]) ** 2).sum(axis=2)
        nearest_free = free_idx[np.argmin(d2, axis=1)]
    else:
        nearest_free = np.zeros(n, dtype=np.intp)
    x0, y0 = area.x[0] - FIELD_MARGIN, area.y[0] - FIELD_MARGIN
    fx = int(math.ceil((area.x[1] - area.x[0] + 2 * FIELD_MARGIN) / FIELD_CELL)) + 1
    fy = int(math.ceil((area.y[1] - area.y[0] + 2 * FIELD_MARGIN) / FIELD_CELL)) + 1
    gx, gy = np.meshgrid(x0 + FIELD_CELL * np.arange(fx), y0 + FIELD_CELL * np.arange(fy))
    field = np.minimum(world.clearance_many(gx, gy), 50.0)
    grad_y, grad_x = np.gradient(field, FIELD_CELL)
    norm = np.maximum(np.hypot(grad_x, grad_y), 1e-9)
    ground = world.ground_heights(gx, gy)
    table = np.stack([field, grad_x / norm, grad_y / norm, ground], axis=-1).reshape(-1, 4)
    corners = np.stack([field, grad_x, grad_y], axis=-1).reshape(-1, 3)
    return CrowdMap(
        area, nx, ny, centres, free, component, neighbours, weights, nearest_free,
        (x0, y0), field, table, corners,
    )  # fmt: skip


@dataclass
class CrowdState:
    """Everything that moves (for :meth:`Crowd.state` / :meth:`Crowd.restore`)."""

    pos: np.ndarray
    vel: np.ndarray
    heading: np.ndarray
    walked: np.ndarray
    goal: np.ndarray
    goal_cell: np.ndarray
    pause: np.ndarray
    best: np.ndarray
    stall: np.ndarray
    pinned: np.ndarray
    alternate: np.ndarray
    paused: np.ndarray
    group: np.ndarray
    clock: float
    rover_prev: tuple[float, float] | None
    rng: Mapping[str, Any]


class Crowd:
    """``n`` social-force walkers in ``world``'s pedestrian area.

    :param world: the arena (obstacles and pedestrian area).
    :param n: walkers (0 to ``MAX_PEDESTRIANS``).
    :param sees_rover: False for the ``oblivious`` mode: the rover is no force on anyone
        (their bodies still never enter its footprint).
    :param groups: walk in groups of 2-3 (``groups`` mode).
    """

    def __init__(
        self, world: WorldSpec, n: int, *, sees_rover: bool = True, groups: bool = False
    ) -> None:
        self.world = world
        self.map = crowd_map(world)
        self.n = n
        self.sees_rover = sees_rover
        self.grouped = groups
        if n > self.map.capacity:
            raise CrowdPlacementError(
                f"{n} pedestrians cannot be placed in world {world.name!r}: its pedestrian "
                f"area {world.pedestrian_area} has room for {self.map.capacity} (one per "
                f"{START_SPACING:g} m² of free ground); ask for at most {self.map.capacity}"
            )
        z = np.zeros(n)
        self.pos = np.zeros((n, 2))
        self.vel = np.zeros((n, 2))
        self.heading = z.copy()
        self.walked = z.copy()  # metres walked (the gait's phase)
        self.speed = np.full(n, SPEED_RANGE[0])
        self.goal = np.zeros((n, 2))
        self.goal_cell = np.zeros(n, dtype=np.intp)
        self.pause = z.copy()  # s left standing
        self.best = z.copy()  # closest route distance to the goal so far
        self.stall = z.copy()  # s since the last 0.5 m of progress
        self.pinned = np.zeros(n, dtype=bool)  # placed by hand: stands still
        self.alternate = np.full((n, 2), np.nan)  # crossing: the other end of the walk
        self.touching = np.zeros(n, dtype=bool)  # held at the rover's body this step
        self.group = np.arange(n)  # group id per walker (its leader's index)
        self._paused = np.zeros(n, dtype=bool)  # the leader has paused at this goal
        self._route = np.full((n, len(self.map.free) + 1), np.inf)
        self._clock = 0.0  # simulated time not yet stepped (< CROWD_DT)
        self._rover_prev: tuple[float, float] | None = None
        self._rng = np.random.default_rng(0)
        self._group_sizes = np.ones(n)
        self._planned = False  # _target and _target_cell hold a plan for the current goals
        self._target_cell = np.full(n, -1, dtype=np.intp)  # the cell headed for (-1: goal)
        self._target = np.zeros((n, 2))  # the point each walker heads for
        self._here: np.ndarray | None = None  # map.lookup(pos), while pos stays
        self._route_left = np.zeros(n)
        self._to_goal = np.zeros(n)
        self._due = np.zeros(n, dtype=bool)
        self._rover = np.zeros(4)  # the kernel's view of the rover: x, y, vx, vy
        self._plan_age = PLAN_EVERY
        m = self.map
        self._grid = (float(m.area.x[0]), float(m.area.y[0]), CELL, m.nx, m.ny)
        ox, oy = m.field_origin
        self._field = (float(ox), float(oy), FIELD_CELL, m.field.shape[1], m.field.shape[0])
        self._cap = MAX_SPEED_FACTOR * self.speed
        self._arrive = np.full(n, ARRIVAL_DISTANCE)
        area = world.pedestrian_area
        self._lo, self._hi = np.array([area.x[0], area.y[0]]), np.array([area.x[1], area.y[1]])

    # --- episode set-up ----------------------------------------------------------------------
    def reset(self, rng: np.random.Generator, avoid: tuple[float, float] | None) -> None:
        """New walkers: starts clear of the scenery, of each other and ``MIN_START_DISTANCE``
        from ``avoid`` (the rover), speeds, groups and first goals; the crowd's own
        generator is drawn from ``rng``."""
        self._rng = np.random.default_rng(int(rng.integers(2**63)))
        n = self.n
        self.group = np.arange(n)
        if self.grouped:
            i = 0
            while i < n:
                size = min(int(self._rng.choice(GROUP_SIZES)), n - i)
                self.group[i : i + size] = i
                i += size
        self._regroup()
        self.speed = self._rng.uniform(*SPEED_RANGE, n)
        self.speed = self.speed[self.group]  # a group walks at its first member's speed
        self._cap = MAX_SPEED_FACTOR * self.speed
        self.pos[:] = self._starts(avoid)
        self.vel[:] = 0.0
        self.heading[:] = self._rng.uniform(-math.pi, math.pi, n)
        self.walked[:] = 0.0
        self.pause[:] = 0.0
        self.pinned[:] = False
        self.alternate[:] = np.nan
        self.touching[:] = False
        self._paused[:] = False
        self._planned = False
        self._here = None
        self._clock = 0.0
        self._rover_prev = avoid
        for i in range(n):
            if self.group[i] == i:
                self._new_goal(i)

    def _regroup(self) -> None:
        """Derived group tables after ``group`` changed."""
        n = self.n
        self._group_sizes = np.bincount(self.group, minlength=n).astype(float)
        # a group has arrived when a member is this close to the goal
        self._arrive = ARRIVAL_DISTANCE + 0.3 * (self._group_sizes[self.group] - 1)

    def _starts(self, avoid: tuple[float, float] | None) -> np.ndarray:
        m, rng, n = self.map, self._rng, self.n
        out = np.zeros((n, 2))
        cells = np.flatnonzero(m.free)
        placed = 0
        for _ in range(_START_TRIES + 10 * n):
            if placed == n:
                break
            leader = placed if self.group[placed] == placed else int(self.group[placed])
            if placed == leader:
                pick = m.centres[rng.choice(cells, _START_BATCH)]
                cand = pick + rng.uniform(-0.5 * CELL, 0.5 * CELL, (_START_BATCH, 2))
                spacing = START_SPACING
            else:  # a group member: beside its leader
                a = rng.uniform(-math.pi, math.pi, _START_BATCH)
                cand = out[leader] + GROUP_SPACING * np.stack([np.cos(a), np.sin(a)], 1)
                spacing = GROUP_SPACING * 0.9
            ok = self.world.clearance_many(cand[:, 0], cand[:, 1]) > BODY_RADIUS + 0.1
            ok &= m.area.x[0] <= cand[:, 0]
            ok &= cand[:, 0] <= m.area.x[1]
            ok &= m.area.y[0] <= cand[:, 1]
            ok &= cand[:, 1] <= m.area.y[1]
            if avoid is not None:
                ok &= np.hypot(cand[:, 0] - avoid[0], cand[:, 1] - avoid[1]) >= MIN_START_DISTANCE
            if placed:
                gap = np.hypot(cand[:, None, 0] - out[None, :placed, 0],
                               cand[:, None, 1] - out[None, :placed, 1])
                ok &= np.all(gap >= spacing, axis=1)
            good = np.flatnonzero(ok)
            if len(good):
                out[placed] = cand[good[0]]
                placed += 1
            elif placed != leader:  # no room beside this leader: place the group anew
                placed = leader
        if placed < n:
            raise CrowdPlacementError(
                f"could place only {placed} of {self.n} pedestrians in world "
                f"{self.world.name!r} ({START_SPACING:g} m apart, {BODY_RADIUS + 0.1:g} m from "
                f"the scenery, {MIN_START_DISTANCE:g} m from the rover); ask for fewer"
            )
        return out

    def _new_goal(self, leader: int) -> None:
        """A new goal for walker ``leader`` and its group: a free cell of its part of the
        grid at least GOAL_MIN_DISTANCE away (the farthest of a few when none is)."""
        m, rng = self.map, self._rng
        here = m.nearest_free[m.cell_of(self.pos[leader : leader + 1])[0]]
        cells = np.flatnonzero(m.component == m.component[here])
        cand = cells[rng.integers(len(cells), size=8)]
        far = np.hypot(*(m.centres[cand] - self.pos[leader]).T)
        ok = np.flatnonzero(far >= GOAL_MIN_DISTANCE)
        cell = int(cand[ok[0]] if len(ok) else cand[np.argmax(far)])
        point = m.centres[cell] + rng.uniform(-0.2 * CELL, 0.2 * CELL, 2)
        self._set_goal(leader, cell, point)

    def _set_goal(self, leader: int, cell: int, point: np.ndarray) -> None:
        members = np.flatnonzero(self.group == leader)
        route = self.map.route_distances(cell)
        self.goal[members] = point
        self.goal_cell[members] = cell
        self._route[members] = route
        here = self.map.nearest_free[self.map.cell_of(self.pos[members])]
        self.best[members] = route[here]
        self.stall[members] = 0.0

    def lay_crossing(
        self,
        i: int,
        start: tuple[float, float],
        end: tuple[float, float],
        back: tuple[float, float],
        speed: float,
    ) -> None:
        """Walker ``i`` (alone, at ``speed``) walks from ``start`` to ``end``, then to
        ``back``, then to ``end`` again, and so on (crossing mode)."""
        self.group[self.group == i] = np.flatnonzero(self.group == i)
        self.group[i] = i
        self._regroup()
        self.pos[i] = start
        self.vel[i] = 0.0
        self.pause[i] = 0.0
        self.speed[i] = speed
        self._cap = MAX_SPEED_FACTOR * self.speed
        self._planned = False
        self._here = None
        self.alternate[i] = back
        self._goal_at(i, np.array(end))

    def _goal_at(self, i: int, point: np.ndarray) -> None:
        m = self.map
        cell = int(m.nearest_free[m.cell_of(point[None])[0]])
        self._set_goal(i, cell, point)

    def place(self, i: int, x: float, y: float, heading: float) -> None:
        """Pin walker ``i`` standing at (x, y), facing ``heading``, until the next reset."""
        self.pos[i] = (x, y)
        self.vel[i] = 0.0
        self.heading[i] = heading
        self.pinned[i] = True
        self._here = None

    # --- state ---------------------------------------------------------------------------------
    def state(self) -> CrowdState:
        return CrowdState(
            self.pos.copy(), self.vel.copy(), self.heading.copy(), self.walked.copy(),
            self.goal.copy(), self.goal_cell.copy(), self.pause.copy(), self.best.copy(),
            self.stall.copy(), self.pinned.copy(), self.alternate.copy(), self._paused.copy(),
            self.group.copy(), self._clock, self._rover_prev, self._rng.bit_generator.state,
        )  # fmt: skip

    def restore(self, s: CrowdState) -> None:
        self.pos[:], self.vel[:] = s.pos, s.vel
        self.heading[:], self.walked[:] = s.heading, s.walked
        self.goal[:], self.pause[:], self.best[:], self.stall[:] = s.goal, s.pause, s.best, s.stall
        self.pinned[:], self.alternate[:], self._paused[:] = s.pinned, s.alternate, s.paused
        self.group[:] = s.group
        self._regroup()
        self._planned = False
        self._here = None
        for i, cell in enumerate(s.goal_cell):
            if cell != self.goal_cell[i]:
                self._route[i] = self.map.route_distances(int(cell))
        self.goal_cell[:] = s.goal_cell
        self._clock, self._rover_prev = s.clock, s.rover_prev
        self._rng.bit_generator.state = s.rng

    # --- motion --------------------------------------------------------------------------------
    def here(self) -> np.ndarray:
        """(n, 4) :meth:`CrowdMap.lookup` at every walker's position (kept from the step
        that put them there)."""
        if self._here is None:
            self._here = self.map.lookup(self.pos)
        return self._here

    def advance(self, dt: float, rover_xy: tuple[float, float] | None) -> int:
        """Walk on ``dt`` s: the whole ``CROWD_DT`` steps that fit (the remainder carries
        to the next call), with the rover at ``rover_xy`` (its velocity from the last call).
        Returns how many steps ran."""
        self._clock += dt
        steps = int(self._clock / CROWD_DT + 1e-9)
        if steps == 0:
            return 0
        self._clock -= steps * CROWD_DT
        rover_v = np.zeros(2)
        if rover_xy is not None and self._rover_prev is not None:
            rover_v = (np.asarray(rover_xy) - self._rover_prev) / dt
        self._rover_prev = None if rover_xy is None else (float(rover_xy[0]), float(rover_xy[1]))
        for _ in range(steps):
            self._step(rover_xy, rover_v)
        return steps

    def _plan(self) -> None:
        """Each walker's next target: two moves down its route (its goal point in the last
        cells)."""
        m = self.map
        crowd_kernel.plan(
            self.pos, self._grid, m.nearest_free, m.neighbours, m.weights, self._route,
            self.goal_cell, self.goal, m.centres, self._target, self._target_cell,
            self._route_left,
        )  # fmt: skip
        self._plan_age = 0
        self._planned = True

    def _step(self, rover_xy: tuple[float, float] | None, rover_v: np.ndarray) -> None:
        n = self.n
        if n == 0:
            return
        dt = CROWD_DT
        if self._plan_age >= PLAN_EVERY or not self._planned:
            self._plan()
        self._plan_age += 1
        standing = (self.pause > 0.0) | self.pinned
        rover = self._rover
        if rover_xy is None:
            rover[0] = math.nan
        else:
            rover[:2], rover[2:] = rover_xy, rover_v
        here = self.here()
        to_goal = self._to_goal
        crowd_kernel.step(
            KERNEL_CONSTANTS, dt, self.pos, self.vel, self.heading, self.walked, self._target,
            self.goal, self.speed, self._cap, standing, self.pinned, self.group,
            self._group_sizes, self.grouped, rover, self.sees_rover, here, self._field,
            self.map.table, self.map.corners, self._lo, self._hi, self.touching, to_goal,
        )  # fmt: skip
        # goals: arrival, pauses, stalls (a Python loop only for the walkers concerned)
        due = self._due
        if not crowd_kernel.goal_clocks(
            dt, STUCK_TIME, standing, self.pinned, self.pause, self.best, self.stall,
            self._route_left, to_goal, self._arrive, due,
        ):  # fmt: skip
            return
        self._plan_age = PLAN_EVERY  # replan next step
        for i in sorted(set(self.group[due].tolist())):  # their leaders
            members = self.group == i
            if (self.pause[members] > 0.0).any():
                continue
            if to_goal[members].min() < self._arrive[i]:
                if not np.isnan(self.alternate[i, 0]):  # a crosser turns back
                    back = self.alternate[i].copy()
                    self.alternate[i] = self.goal[i]
                    self._goal_at(i, back)
                    continue
                if not self._paused[i] and self._rng.random() < PAUSE_PROBABILITY:
                    self.pause[members] = self._rng.uniform(*PAUSE_RANGE)
                    self._paused[i] = True
                    continue
                self._paused[i] = False
                self._new_goal(i)
            elif self.stall[members].max() > STUCK_TIME:
                if np.isnan(self.alternate[i, 0]):
                    self._new_goal(i)
                else:
                    self.stall[members] = 0.0
