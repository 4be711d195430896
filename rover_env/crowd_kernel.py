"""The crowd's inner loop, compiled: one social-force step and the route look-up.

:class:`rover_env.crowd.Crowd` keeps the state and the decisions (goals, pauses, groups);
these functions do the arithmetic of every walker and every pair, which in numpy cost ~100
small array operations a step, more than all of MuJoCo's work for the rover. Compiled by
numba (``cache=True``: once per machine, then loaded from ``__pycache__``), a step of 10
walkers costs microseconds. The model and its constants are documented in
:mod:`rover_env.crowd`; each block below names the force it computes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def plan(
    pos: np.ndarray,
    grid: tuple[float, float, float, int, int],
    nearest_free: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    route: np.ndarray,
    goal_cell: np.ndarray,
    goal: np.ndarray,
    centres: np.ndarray,
    target: np.ndarray,
    target_cell: np.ndarray,
    route_left: np.ndarray,
) -> None:
    """Each walker's next target: two moves down its route to its goal, the goal point
    itself in the last cells. Writes ``target`` (n, 2), ``target_cell`` (-1: the goal
    point) and ``route_left`` (route length from the walker's cell)."""
    x0, y0, cell, nx, ny = grid
    n_free = centres.shape[0]
    for i in range(pos.shape[0]):
        ix = min(max(int((pos[i, 0] - x0) * (1.0 / cell)), 0), nx - 1)
        iy = min(max(int((pos[i, 1] - y0) * (1.0 / cell)), 0), ny - 1)
        here = nearest_free[iy * nx + ix]
        nxt = _downhill(here, i, neighbours, weights, route)
        nxt2 = _downhill(nxt, i, neighbours, weights, route)
        route_left[i] = route[i, here]
        if here == goal_cell[i] or nxt == goal_cell[i] or nxt2 >= n_free:
            target_cell[i] = -1
            target[i, 0], target[i, 1] = goal[i, 0], goal[i, 1]
        else:
            target_cell[i] = nxt2
            target[i, 0], target[i, 1] = centres[nxt2, 0], centres[nxt2, 1]


@njit(cache=True, error_model="numpy")
def _downhill(
    cell: int, i: int, neighbours: np.ndarray, weights: np.ndarray, route: np.ndarray
) -> int:
    """The neighbour of ``cell`` that minimises move cost + route left (the first on ties)."""
    best, pick = np.inf, neighbours[cell, 0]
    for k in range(neighbours.shape[1]):
        nb = neighbours[cell, k]
        cost = weights[cell, k] + route[i, nb]
        if cost < best:
            best, pick = cost, nb
    return pick


@njit(cache=True, error_model="numpy")
def step(
    k: tuple,  # KERNEL_CONSTANTS
    dt: float,
    pos: np.ndarray,
    vel: np.ndarray,
    heading: np.ndarray,
    walked: np.ndarray,
    target: np.ndarray,
    goal: np.ndarray,
    speed: np.ndarray,
    cap: np.ndarray,
    standing: np.ndarray,
    pinned: np.ndarray,
    group: np.ndarray,
    group_sizes: np.ndarray,
    grouped: bool,
    rover: np.ndarray,
    sees_rover: bool,
    here: np.ndarray,
    field: tuple[float, float, float, int, int],
    table: np.ndarray,
    corners: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    touching: np.ndarray,
    to_goal: np.ndarray,
) -> None:
    """One ``dt`` step of every walker, in place: forces, semi-implicit Euler with the speed
    capped, then solid bodies; ``pos``, ``vel``, ``heading``, ``walked``, ``here`` (the
    scenery table at the new positions), ``touching`` and ``to_goal`` (distance to the goal
    before the step) are written. ``rover``: (x, y, vx, vy), NaN x when there is none."""
    (tau, slow_down, a_ped, b_ped, min_sep, lam, group_rep, a_side, a_obs, b_obs, body_r,
     a_rover, b_rover, rover_r, rover_lam, lookahead, a_rover_side, a_coh,
     max_step) = k  # fmt: skip
    n = pos.shape[0]
    fx = np.empty(n)
    fy = np.empty(n)
    ex = np.empty(n)
    ey = np.empty(n)
    # desired velocity: towards the target, slowing near the goal; standing: none
    for i in range(n):
        tx, ty = target[i, 0] - pos[i, 0], target[i, 1] - pos[i, 1]
        length = max(math.hypot(tx, ty), 1e-9)
        ex[i], ey[i] = tx / length, ty / length
        to_goal[i] = math.hypot(goal[i, 0] - pos[i, 0], goal[i, 1] - pos[i, 1])
        desired = 0.0 if standing[i] else speed[i] * min(1.0, to_goal[i] * (1.0 / slow_down))
        fx[i] = (desired * ex[i] - vel[i, 0]) * (1.0 / tau)
        fy[i] = (desired * ey[i] - vel[i, 1]) * (1.0 / tau)
    # other people: repulsion (weaker from behind), and a step aside from those ahead
    closest = np.inf
    for i in range(n):
        push_x = push_y = aside = 0.0
        for j in range(n):
            if j == i:
                continue
            dx, dy = pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1]
            d = math.hypot(dx, dy)
            closest = min(closest, d)
            nx_, ny_ = dx / max(d, 1e-9), dy / max(d, 1e-9)
            cos_phi = -(nx_ * ex[i] + ny_ * ey[i])
            rel_imag = ny_ * ex[i] - nx_ * ey[i]  # j to i's right (>= 0): i steps left
            mag = a_ped * math.exp((min_sep + 0.1 - d) * (1.0 / b_ped))
            if grouped and group[i] == group[j]:
                mag *= group_rep
            mag *= lam + (1.0 - lam) * 0.5 * (1.0 + cos_phi)
            push_x += mag * nx_
            push_y += mag * ny_
            aside += max(cos_phi, 0.0) * mag * math.copysign(a_side, rel_imag)
        fx[i] += push_x - ey[i] * aside
        fy[i] += push_y + ex[i] * aside
    # groups: coherence towards the group's centre
    if grouped:
        cx = np.zeros(n)
        cy = np.zeros(n)
        for i in range(n):
            cx[group[i]] += pos[i, 0]
            cy[group[i]] += pos[i, 1]
        for i in range(n):
            size = group_sizes[group[i]]
            ox, oy = cx[group[i]] / size - pos[i, 0], cy[group[i]] / size - pos[i, 1]
            far = math.hypot(ox, oy)
            if far > 0.5 * (size - 1):
                fx[i] += a_coh * ox / max(far, 1e-9)
                fy[i] += a_coh * oy / max(far, 1e-9)
    # scenery: along the distance field's gradient
    for i in range(n):
        push = a_obs * math.exp((body_r - here[i, 0]) * (1.0 / b_obs))
        fx[i] += push * here[i, 1]
        fy[i] += push * here[i, 2]
    # the rover, for those who see it: from the point of closest approach
    has_rover = not math.isnan(rover[0])
    if has_rover and sees_rover:
        for i in range(n):
            rx, ry = pos[i, 0] - rover[0], pos[i, 1] - rover[1]
            vx, vy = vel[i, 0] - rover[2], vel[i, 1] - rover[3]
            vv = max(vx * vx + vy * vy, 1e-9)
            t_star = min(max(-(rx * vx + ry * vy) / vv, 0.0), lookahead)
            nx_, ny_ = rx + vx * t_star, ry + vy * t_star
            dn = max(math.hypot(nx_, ny_), 1e-9)
            nx_, ny_ = nx_ / dn, ny_ / dn
            cos_r = -(nx_ * ex[i] + ny_ * ey[i])
            rr_imag = ny_ * ex[i] - nx_ * ey[i]
            mag = (
                a_rover
                * math.exp((rover_r + body_r - dn) * (1.0 / b_rover))
                * (rover_lam + (1.0 - rover_lam) * 0.5 * (1.0 + cos_r))
            )
            aside = max(cos_r, 0.0) * mag * math.copysign(a_rover_side, rr_imag)
            fx[i] += mag * nx_ - ey[i] * aside
            fy[i] += mag * ny_ + ex[i] * aside
    # integrate (semi-implicit Euler), speed capped
    new = np.empty((n, 2))
    for i in range(n):
        vx, vy = vel[i, 0] + fx[i] * dt, vel[i, 1] + fy[i] * dt
        scale = min(1.0, cap[i] / max(math.hypot(vx, vy), 1e-9))
        vx, vy = vx * scale, vy * scale
        if pinned[i]:
            vx = vy = 0.0
        new[i, 0], new[i, 1] = pos[i, 0] + vx * dt, pos[i, 1] + vy * dt
    # solid bodies: apart from each other (two Jacobi sweeps), out of the rover's
    # footprint, out of the scenery, inside the area
    if closest < min_sep + 2.0 * max_step:
        shift = np.empty((n, 2))
        for _ in range(2):
            moved = False
            for i in range(n):
                sx = sy = 0.0
                for j in range(n):
                    if j == i:
                        continue
                    dx, dy = new[i, 0] - new[j, 0], new[i, 1] - new[j, 1]
                    d = math.hypot(dx, dy)
                    short = min_sep - d
                    if short > 0.0:
                        moved = True
                        sx += 0.5 * short / max(d, 1e-9) * dx
                        sy += 0.5 * short / max(d, 1e-9) * dy
                shift[i, 0], shift[i, 1] = sx, sy
            if not moved:
                break
            new += shift
    for i in range(n):
        touching[i] = False
        if has_rover:
            rx, ry = new[i, 0] - rover[0], new[i, 1] - rover[1]
            d = math.hypot(rx, ry)
            if d < rover_r + body_r:
                touching[i] = True
                s = (rover_r + body_r - d) / max(d, 1e-9)
                new[i, 0] += rx * s
                new[i, 1] += ry * s
        if here[i, 0] < body_r + max_step + 0.1:  # near the scenery: the exact clearance
            c, gx, gy = _bilinear(new[i, 0], new[i, 1], field, corners)
            if c < body_r:
                new[i, 0] += gx * (body_r - c)
                new[i, 1] += gy * (body_r - c)
        new[i, 0] = min(max(new[i, 0], lo[0]), hi[0])
        new[i, 1] = min(max(new[i, 1], lo[1]), hi[1])
    # the step taken: velocity, distance walked, facing; the scenery table at the new place
    x0, y0, cell, fxn, fyn = field
    for i in range(n):
        sx, sy = new[i, 0] - pos[i, 0], new[i, 1] - pos[i, 1]
        vel[i, 0], vel[i, 1] = sx * (1.0 / dt), sy * (1.0 / dt)
        moved_by = math.hypot(sx, sy)
        walked[i] += moved_by
        if moved_by > 0.2 * dt:
            heading[i] = math.atan2(sy, sx)
        pos[i, 0], pos[i, 1] = new[i, 0], new[i, 1]
        u = min(max(int((new[i, 0] - x0) * (1.0 / cell) + 0.5), 0), fxn - 1)
        v = min(max(int((new[i, 1] - y0) * (1.0 / cell) + 0.5), 0), fyn - 1)
        row = v * fxn + u
        for c in range(table.shape[1]):
            here[i, c] = table[row, c]


@njit(cache=True, error_model="numpy")
def goal_clocks(
    dt: float,
    stuck_time: float,
    standing: np.ndarray,
    pinned: np.ndarray,
    pause: np.ndarray,
    best: np.ndarray,
    stall: np.ndarray,
    route_left: np.ndarray,
    to_goal: np.ndarray,
    arrive: np.ndarray,
    due: np.ndarray,
) -> bool:
    """After a step: pauses run down, progress along the route (0.5 m better than the best
    so far) resets the stall clock, and ``due`` marks who has arrived (and is not pausing)
    or has stalled for ``stuck_time``. Returns whether anyone is due."""
    anyone = False
    for i in range(pause.shape[0]):
        pause[i] = max(pause[i] - dt, 0.0)
        if route_left[i] < best[i] - 0.5:
            best[i] = route_left[i]
            stall[i] = 0.0
        elif standing[i]:
            stall[i] = 0.0
        else:
            stall[i] += dt
        due[i] = not pinned[i] and (
            (to_goal[i] < arrive[i] and pause[i] <= 0.0) or stall[i] > stuck_time
        )
        anyone = anyone or due[i]
    return anyone


@njit(cache=True, error_model="numpy")
def _bilinear(
    x: float, y: float, field: tuple[float, float, float, int, int], corners: np.ndarray
) -> tuple[float, float, float]:
    """Clearance and unit gradient at (x, y), bilinear between the field's four corners."""
    x0, y0, cell, fx, fy = field
    u = min(max((x - x0) * (1.0 / cell), 0.0), fx - 1.000001)
    v = min(max((y - y0) * (1.0 / cell), 0.0), fy - 1.000001)
    iu, iv = int(u), int(v)
    a, b = u - iu, v - iv
    k = iv * fx + iu
    out = np.empty(3)
    for c in range(3):
        top = corners[k, c] + a * (corners[k + 1, c] - corners[k, c])
        bottom = corners[k + fx, c] + a * (corners[k + fx + 1, c] - corners[k + fx, c])
        out[c] = top + b * (bottom - top)
    norm = max(math.hypot(out[1], out[2]), 1e-9)
    return out[0], out[1] / norm, out[2] / norm


@njit(cache=True, error_model="numpy")
def pose_figures(
    pos: np.ndarray,
    heading: np.ndarray,
    vel: np.ndarray,
    walked: np.ndarray,
    here: np.ndarray,
    gait: np.ndarray,
    hip: np.ndarray,
    legs: tuple[float, float, float],
    order: np.ndarray,
    mocap_pos: np.ndarray,
    mocap_quat: np.ndarray,
) -> None:
    """Each walker's three mocap poses (upper body; left and right leg at the hips, swung
    in opposite phase while walking) written into MuJoCo's ``mocap_pos``/``mocap_quat``
    rows ``order[3 i]``, ``order[3 i + 1]``, ``order[3 i + 2]``; the feet on the ground
    height of ``here``. ``legs``: (swing amplitude rad, step length m, hip half width m)."""
    swing_amp, step_length, half_width = legs
    for i in range(pos.shape[0]):
        x, y, z, yaw = pos[i, 0], pos[i, 1], here[i, 3], heading[i]
        swing = 0.0
        if abs(vel[i, 0]) + abs(vel[i, 1]) > 0.05:
            swing = swing_amp * math.sin(math.pi * walked[i] / step_length + gait[i])
        cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        cp, sp = math.cos(0.5 * swing), math.sin(0.5 * swing)
        r = order[3 * i]
        mocap_pos[r, 0], mocap_pos[r, 1], mocap_pos[r, 2] = x, y, z
        mocap_quat[r, 0], mocap_quat[r, 1], mocap_quat[r, 2], mocap_quat[r, 3] = cy, 0.0, 0.0, sy
        for leg in range(2):
            side, sign = (half_width, 1.0) if leg == 0 else (-half_width, -1.0)
            r = order[3 * i + 1 + leg]
            mocap_pos[r, 0] = x - sin_yaw * side
            mocap_pos[r, 1] = y + cos_yaw * side
            mocap_pos[r, 2] = z + hip[i]
            mocap_quat[r, 0] = cy * cp
            mocap_quat[r, 1] = -sy * sp * sign
            mocap_quat[r, 2] = cy * sp * sign
            mocap_quat[r, 3] = sy * cp
