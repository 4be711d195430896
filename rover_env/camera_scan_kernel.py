"""The camera scan's update, compiled: one pass over the fused image and the memory.

:class:`rover_env.camera_scan.CameraScan` keeps the state and the constants; this function
does a step's arithmetic (every pixel of the image once, then the scenery grid's listed cells
and at most one person point per sector), which as
numpy array operations costs more than the render. Compiled by numba (``cache=True``: once
per machine, then loaded from ``__pycache__``), it costs a small fraction of a step
(benchmarks/RESULTS.md, "The camera scan"). The method is documented in
:mod:`rover_env.camera_scan`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi


@njit(cache=True, inline="always")
def _wrap(angle: float) -> float:
    return (angle + math.pi) % TWO_PI - math.pi


@njit(cache=True, inline="always")
def _sector(bearing: float, n: int) -> int:
    return int(math.floor((bearing + math.pi) / (TWO_PI / n))) % n


@njit(cache=True, inline="always")
def _fast_atan2(y: float, x: float) -> float:
    """``math.atan2`` to within 2e-6 rad (an odd minimax polynomial on [0, 1], reflected to
    the octant): a sector is 0.2 rad wide, and libm's atan2 was most of reading the grid."""
    ax, ay = abs(x), abs(y)
    big, small = max(ax, ay), min(ax, ay)
    if big == 0.0:
        return 0.0
    z = small / big
    z2 = z * z
    a = z * (0.99997726 + z2 * (-0.33262347 + z2 * (0.19354346 + z2 * (
        -0.11643287 + z2 * (0.05265332 + z2 * -0.01172120)))))  # fmt: skip
    if ay > ax:
        a = 0.5 * math.pi - a
    if x < 0.0:
        a = math.pi - a
    return -a if y < 0.0 else a


@njit(cache=True)
def _rebin(pts: np.ndarray, stamps: np.ndarray, rng: np.ndarray, x: float, y: float,
           yaw: float) -> None:  # fmt: skip
    """Re-index the stored points by their rover-frame sector from pose (x, y, yaw), keeping
    the nearest per sector; ``rng`` gets each sector's range (inf when empty)."""
    n = pts.shape[0]
    old_x, old_y, old_t = pts[:, 0].copy(), pts[:, 1].copy(), stamps.copy()
    for k in range(n):
        pts[k, 0] = np.nan
        pts[k, 1] = np.nan
        stamps[k] = -np.inf
        rng[k] = np.inf
    for i in range(n):
        if not math.isfinite(old_x[i]):
            continue
        dx, dy = old_x[i] - x, old_y[i] - y
        r = math.hypot(dx, dy)
        k = _sector(math.atan2(dy, dx) - yaw, n)
        if r < rng[k]:
            rng[k] = r
            pts[k, 0], pts[k, 1], stamps[k] = old_x[i], old_y[i], old_t[i]


@njit(cache=True)
def _forget_in_view(pts: np.ndarray, stamps: np.ndarray, rng: np.ndarray, cam_x: float,
                    cam_y: float, look: float, half_fov: float,
                    max_range: float) -> None:  # fmt: skip
    """Drop the stored points the camera sees now (in its view, within its range)."""
    for k in range(pts.shape[0]):
        if not math.isfinite(pts[k, 0]):
            continue
        dx, dy = pts[k, 0] - cam_x, pts[k, 1] - cam_y
        if abs(_wrap(math.atan2(dy, dx) - look)) <= half_fov and math.hypot(dx, dy) < max_range:
            pts[k, 0] = np.nan
            pts[k, 1] = np.nan
            stamps[k] = -np.inf
            rng[k] = np.inf


@njit(cache=True)
def _insert(pts: np.ndarray, stamps: np.ndarray, rng: np.ndarray, wx: float, wy: float,
            now: float, x: float, y: float, yaw: float) -> None:  # fmt: skip
    dx, dy = wx - x, wy - y
    r = math.hypot(dx, dy)
    k = _sector(math.atan2(dy, dx) - yaw, pts.shape[0])
    if r < rng[k]:
        rng[k] = r
        pts[k, 0], pts[k, 1], stamps[k] = wx, wy, now


QUANTILE_BIN_M = 0.02
QUANTILE_BINS = 64
"""The column quantile is read off a histogram of ``QUANTILE_BINS`` bins of
``QUANTILE_BIN_M`` from the column's nearest range (1.28 m; the rare quantile beyond it is
selected exactly): a sort per column cost more than the rest of the update."""


@njit(cache=True)
def _quantile_index(values: np.ndarray, n: int, k: int, counts: np.ndarray) -> int:
    """An index ``i < n`` whose ``values[i]`` is the ``k``-th smallest of ``values[:n]`` to
    within ``QUANTILE_BIN_M`` (``values`` is left as it was)."""
    lo, at = np.inf, 0
    for i in range(n):
        if values[i] < lo:
            lo, at = values[i], i
    if k == 0:
        return at
    counts[:] = 0
    for i in range(n):
        b = int((values[i] - lo) / QUANTILE_BIN_M)
        counts[min(b, QUANTILE_BINS)] += 1
    seen, pick = 0, QUANTILE_BINS
    for b in range(QUANTILE_BINS + 1):
        seen += counts[b]
        if seen > k:
            pick = b
            break
    if pick < QUANTILE_BINS:
        for i in range(n):
            if int((values[i] - lo) / QUANTILE_BIN_M) == pick:
                return i
    # beyond the histogram: exactly, by elimination of smaller values (rare: a column whose
    # nearest pixels stand far in front of the rest)
    for i in range(n):
        below, upto = 0, 0
        for j in range(n):
            below += values[j] < values[i]
            upto += values[j] <= values[i]
        if below <= k < upto:
            return i
    return at


@njit(cache=True)
def _median(values: np.ndarray, n: int, scratch: np.ndarray) -> float:
    """The median of ``values[:n]`` (n >= 1) as numpy's (the mean of the two middle values
    for an even n), sorted in ``scratch`` by insertion: n is at most an image's height, and
    np.median allocates on every call."""
    for i in range(n):
        v, j = values[i], i
        while j > 0 and scratch[j - 1] > v:
            scratch[j] = scratch[j - 1]
            j -= 1
        scratch[j] = v
    half = n // 2
    return scratch[half] if n % 2 else 0.5 * (scratch[half - 1] + scratch[half])


@njit(cache=True, inline="always")
def _cell(coord: float, res: float) -> int:
    return int(math.floor(coord / res))


@njit(cache=True)
def _mark(grid_t: np.ndarray, grid_i: np.ndarray, occ: np.ndarray, occ_n: np.ndarray,
          g: int, ix: int, iy: int, now: float) -> None:  # fmt: skip
    """Scenery seen in world cell (ix, iy) now (the grid is toroidal: g x g slots)."""
    flat = (ix % g) * g + (iy % g)
    if grid_t[flat] == -np.inf:
        occ[occ_n[0]] = flat
        occ_n[0] += 1
    grid_i[flat, 0], grid_i[flat, 1], grid_t[flat] = ix, iy, now


@njit(cache=True)
def _clear_in_view(grid_t: np.ndarray, grid_i: np.ndarray, occ: np.ndarray, occ_n: np.ndarray,
                   res: float, cam_x: float, cam_y: float, look: float, half_fov: float,
                   left_col: np.ndarray, fwd_h: float, free_r: np.ndarray) -> None:  # fmt: skip
    """Free the listed cells the camera sees through now: those in its view nearer than
    their column's ``free_r`` (m from the camera on the ground). A cell's column follows
    from its bearing (``left_col`` over the horizon row's forward factor ``fwd_h``)."""
    width = left_col.shape[0]
    u_per_left = 1.0 / (left_col[0] - left_col[1])  # the focal length, in pixels
    cos_l, sin_l, tan_h = math.cos(look), math.sin(look), math.tan(half_fov)
    for i in range(occ_n[0]):
        flat = occ[i]
        if grid_t[flat] == -np.inf:
            continue
        dx = (grid_i[flat, 0] + 0.5) * res - cam_x
        dy = (grid_i[flat, 1] + 0.5) * res - cam_y
        fwd = dx * cos_l + dy * sin_l  # the cell in the camera's level frame
        left = dy * cos_l - dx * sin_l
        if fwd <= 0.0 or abs(left) > fwd * tan_h:
            continue
        u = int(round((left_col[0] - left / fwd * fwd_h) * u_per_left))
        u = min(max(u, 0), width - 1)
        if fwd * fwd + left * left < free_r[u] * free_r[u]:
            grid_t[flat] = -np.inf


@njit(cache=True)
def _read_grid(grid_t: np.ndarray, grid_i: np.ndarray, occ: np.ndarray, occ_n: np.ndarray,
               res: float, x: float, y: float, yaw: float, now: float, memory_s: float,
               keep_m: float, max_range: float, rng: np.ndarray) -> None:  # fmt: skip
    """Each sector's nearest remembered scenery within ``max_range`` (``rng``, inf where
    none); cells freed, older than ``memory_s`` or farther than ``keep_m`` leave the list."""
    n = rng.shape[0]
    for k in range(n):
        rng[k] = np.inf  # squared ranges until the end
    keep2, seen2 = keep_m * keep_m, max_range * max_range
    i = 0
    while i < occ_n[0]:
        flat = occ[i]
        t = grid_t[flat]
        dx = (grid_i[flat, 0] + 0.5) * res - x
        dy = (grid_i[flat, 1] + 0.5) * res - y
        r2 = dx * dx + dy * dy
        if t == -np.inf or now - t > memory_s or r2 > keep2:
            grid_t[flat] = -np.inf
            occ_n[0] -= 1
            occ[i] = occ[occ_n[0]]
            continue
        i += 1
        if r2 >= seen2:  # kept for later, but reads as the range like an empty sector
            continue
        k = _sector(_fast_atan2(dy, dx) - yaw, n)
        if r2 < rng[k]:
            rng[k] = r2
    for k in range(n):
        rng[k] = math.sqrt(rng[k])


@njit(cache=True)
def scan_update(
    fused: np.ndarray,
    fwd_row: np.ndarray,
    up_row: np.ndarray,
    left_col: np.ndarray,
    params: np.ndarray,
    pose: np.ndarray,
    grid_t: np.ndarray,
    grid_i: np.ndarray,
    occ: np.ndarray,
    occ_n: np.ndarray,
    person: np.ndarray,
    person_t: np.ndarray,
    seen_t: np.ndarray,
    out: np.ndarray,
    columns: np.ndarray,
) -> bool:
    """One update of the scan's memory and its observation; False, with nothing changed,
    when a heatmap or depth pixel of ``fused`` is not finite.

    ``fused`` (H, W, 3) float32; ``fwd_row``/``up_row`` (H,) and ``left_col`` (W,): a pixel at
    optical depth d lies d * (fwd_row[r], left_col[u], up_row[r]) from the camera in its
    level frame. ``params``: depth_max, max_range, person_threshold, obstacle_height
    above the camera (negative), half_fov, memory_s, person_memory_s, camera_x, now,
    cell size (m), cells per side of the grid, the obstacle quantile, the clearing margin
    (m). ``pose``: x, y, yaw, pan. Scenery lives in a toroidal world-frame grid:
    ``grid_t`` (g*g,) when each cell was last seen occupied (-inf: free), ``grid_i`` (g*g, 2)
    the world cell each slot holds, ``occ`` the listed slots and ``occ_n`` (1,) their
    count. The person store (n, 2) world points with their stamps (n,)
    is indexed by rover-frame sector; ``seen_t`` (n,) by world-bearing sector; ``out`` (3, n)
    gets the observation; ``columns`` (3, W) gets each column's obstacle pixel's depth and
    its row (inf / -1 where none), then the median depth of its person pixels (inf where
    none), for checks.
    """
    depth_max, max_range, threshold, high_from = params[0], params[1], params[2], params[3]
    half_fov, memory_s, person_memory_s = params[4], params[5], params[6]
    camera_x, now = params[7], params[8]
    res, g = params[9], int(params[10])
    x, y, yaw, pan = pose[0], pose[1], pose[2], pose[3]
    n = seen_t.shape[0]
    height, width = fused.shape[0], fused.shape[1]
    width_s = TWO_PI / n
    look = yaw + pan
    cam_x, cam_y = x + camera_x * math.cos(yaw), y + camera_x * math.sin(yaw)
    cos_l, sin_l = math.cos(look), math.sin(look)
    quantile, margin = params[11], params[12]
    counts = np.empty(QUANTILE_BINS + 1, dtype=np.int64)
    far = depth_max * 0.999
    hot = np.empty(height)
    scratch = np.empty(max(height, width))
    ahead = np.empty(height)
    row_at = np.empty(height, dtype=np.int64)
    hit_x, hit_y, free_r = np.empty(width), np.empty(width), np.empty(width)
    cols = np.empty((3, width))
    # the image first, into locals: a non-finite heatmap or depth pixel returns False
    # before anything the scan keeps has changed
    for u in range(width):
        best_s, row_s, m, ms = np.inf, -1, 0, 0
        for r in range(height):
            if not math.isfinite(fused[r, u, 1] + fused[r, u, 2]):
                return False
            d = (1.0 - fused[r, u, 2]) * depth_max
            if d >= far or d * up_row[r] <= high_from:  # beyond the range, or the ground
                continue
            if fused[r, u, 1] > threshold:
                hot[m] = d
                m += 1
            else:
                ahead[ms], row_at[ms] = d * fwd_row[r], r
                ms += 1
        if ms:
            # the column's obstacle: the quantile of its scenery pixels' ground ranges (the
            # nearest of 30-60 noisy pixels reads 0.1-0.2 m short of a wall 1-2 m away)
            row_s = row_at[_quantile_index(ahead, ms, int(quantile * (ms - 1)), counts)]
            best_s = (1.0 - fused[row_s, u, 2]) * depth_max
        cols[0, u], cols[1, u] = best_s, row_s
        # a person's depth is the median of its hot pixels' (the network's depth is noisy at
        # a figure's edges, and the nearest of them reads a metre short)
        cols[2, u] = _median(hot, m, scratch) if m else np.inf
        # the column sees through to its obstacle (a margin short of it: the network's
        # depth is noisy), or to the range when it shows none
        if row_s >= 0:
            fwd, left = best_s * fwd_row[row_s], best_s * left_col[u]
            hit_x[u] = cam_x + fwd * cos_l - left * sin_l
            hit_y[u] = cam_y + fwd * sin_l + left * cos_l
            free_r[u] = max(math.hypot(fwd, left) - margin, 0.0)
        else:
            hit_x[u] = np.nan
            free_r[u] = max_range
    columns[:] = cols
    for k in range(n):  # the world-bearing sectors in view are seen now
        if abs(_wrap(-math.pi + (k + 0.5) * width_s - look)) <= half_fov:
            seen_t[k] = now
    obstacle_r = np.empty(n)
    person_r = np.empty(n)
    _rebin(person, person_t, person_r, x, y, yaw)
    _forget_in_view(person, person_t, person_r, cam_x, cam_y, look, half_fov, max_range)
    _clear_in_view(grid_t, grid_i, occ, occ_n, res, cam_x, cam_y, look, half_fov, left_col,
                   fwd_row[height // 2], free_r)  # fmt: skip
    for u in range(width):
        if math.isfinite(hit_x[u]):
            _mark(grid_t, grid_i, occ, occ_n, g, _cell(hit_x[u], res), _cell(hit_y[u], res), now)
    # each run of adjacent person columns is one person: its middle column at the run's
    # median depth, on the horizon row's forward factor (a figure stands up from the ground)
    horizon_fwd = fwd_row[height // 2]
    u = 0
    while u < width:
        if not math.isfinite(columns[2, u]):
            u += 1
            continue
        start = u
        while u < width and math.isfinite(columns[2, u]):
            u += 1
        d = _median(columns[2, start:u], u - start, scratch)
        mid = 0.5 * (start + u - 1)
        lo = int(math.floor(mid))
        left_factor = left_col[lo] + (mid - lo) * (left_col[min(lo + 1, width - 1)] - left_col[lo])
        fwd, left = d * horizon_fwd, d * left_factor
        _insert(person, person_t, person_r, cam_x + fwd * cos_l - left * sin_l,
                cam_y + fwd * sin_l + left * cos_l, now, x, y, yaw)
    _read_grid(grid_t, grid_i, occ, occ_n, res, x, y, yaw, now, memory_s, max_range + 1.0,
               max_range, obstacle_r)  # fmt: skip
    for k in range(n):  # readings older than their memory are dropped
        if now - person_t[k] > person_memory_s:
            person[k, 0] = np.nan
            person[k, 1] = np.nan
            person_r[k] = np.inf
        out[0, k] = min(obstacle_r[k], max_range)
        out[1, k] = min(person_r[k], max_range)
        world = _sector(-math.pi + (k + 0.5) * width_s + yaw, n)
        out[2, k] = min(now - seen_t[world], memory_s)
    return True


@njit(cache=True)
def scan_ages(seen_t: np.ndarray, yaw: float, now: float, memory_s: float,
              out: np.ndarray) -> None:  # fmt: skip
    """Only the ages row of ``out`` (a step whose image or pose could not be used)."""
    n = seen_t.shape[0]
    width_s = TWO_PI / n
    for k in range(n):
        world = _sector(-math.pi + (k + 0.5) * width_s + yaw, n)
        out[2, k] = min(now - seen_t[world], memory_s)
