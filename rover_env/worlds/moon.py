"""moon (alias island): rough lunar terrain, a height field with hills, crater rims and rocks.

The seed's spawn and goal square is x, y in [-4, 4]; leaving x in [-20, 10] or
y in [-20, 20] ends the episode. The terrain is gentle around the spawn square (small
undulation and scattered rocks) and steepens away from it: hills and crater rims with
slopes past 40 degrees, where the rover can roll or pitch over. The layout is fixed
(a constant seed); only spawn, goal and pedestrians change per episode.
"""

from __future__ import annotations

import numpy as np

from rover_env.worlds import _mjcf
from rover_env.worlds.spec import (
    GROUP_GROUND,
    Circle,
    HeightField,
    Obstacle,
    Rect,
    WorldSpec,
    seed_areas,
)

NAME = "moon"
_LAYOUT_SEED = 2024
_CENTRE = (-5.0, 0.0)
_RADIUS = (17.0, 22.0)  # hfield covers x in [-22, 12], y in [-22, 22]
_CELL = 1.0  # m between height samples: coarse, cheap to collide and ray-cast
_BASE = 0.5
_FLAT_HALF = 5.0  # |x|, |y| below this stay gentle
_ROUGHNESS = 0.05
"""Standard deviation (m) of each 1 m cell's random height beyond the spawn square. Lunar
regolith slopes a few degrees at a 1 m baseline; with 0.05 m neighbouring cells differ by 5
degrees in the median over the height field (13 at 0.25 m: facets each tilted its own way,
which no camera at 96 pixels can read depth from; benchmarks/RESULTS.md, "Moon depth
harness"). The hills and crater rims keep
their steep faces, up to 46 degrees between cells."""
_ROCK_RGBA = "0.42 0.41 0.39 1"
# Hills (x, y, height m, sigma m) and craters (x, y, rim radius m, rim height m).
_HILLS = (
    (-12.0, 9.0, 2.6, 2.2),
    (6.0, -9.0, 2.2, 1.8),
    (-15.0, -12.0, 3.0, 2.5),
    (8.0, 12.0, 2.0, 2.0),
    (-3.0, 14.0, 1.8, 1.6),
    (-9.0, -15.0, 1.6, 1.5),
)
_CRATERS = ((-11.0, -4.0, 3.0, 0.9), (4.5, 7.5, 2.2, 0.7), (-2.0, -11.0, 2.5, 0.8))


def _terrain(x: np.ndarray, y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Ground height (m) on the grid, before normalisation."""
    h = 0.12 * np.sin(0.7 * x + 0.3) * np.cos(0.55 * y - 0.2) + 0.08 * np.sin(1.3 * y + x)
    rough = np.zeros_like(x)
    for hx, hy, height, sigma in _HILLS:
        rough += height * np.exp(-((x - hx) ** 2 + (y - hy) ** 2) / (2 * sigma**2))
    for cx, cy, radius, rim in _CRATERS:
        r = np.hypot(x - cx, y - cy)
        rough += rim * np.exp(-((r - radius) ** 2) / (2 * 0.6**2))
        rough -= 1.2 * rim * np.exp(-(r**2) / (2 * (0.5 * radius) ** 2))
    rough += _ROUGHNESS * rng.standard_normal(x.shape)  # metre-scale regolith roughness
    # Keep the spawn square gentle: roughness fades in beyond _FLAT_HALF.
    d = np.maximum(np.abs(x), np.abs(y)) - _FLAT_HALF
    fade = np.clip(d / 3.0, 0.0, 1.0)
    return h + fade * rough


def _rocks(rng: np.random.Generator, hf: HeightField) -> tuple[str, list[Obstacle]]:
    parts: list[str] = []
    obstacles: list[Obstacle] = []
    rect = Rect((-19.0, 9.0), (-19.0, 19.0))
    placed: list[tuple[float, float, float]] = []
    n_near, n_far = 7, 28
    while len(placed) < n_near + n_far:
        near = len(placed) < n_near
        if near:
            x, y = rng.uniform(-4.5, 4.5, 2)
            r = rng.uniform(0.2, 0.45)
        else:
            x, y = rect.sample(rng)
            r = rng.uniform(0.3, 0.8)
        if any(np.hypot(x - px, y - py) < r + pr + 0.8 for px, py, pr in placed):
            continue
        placed.append((float(x), float(y), float(r)))
    for i, (x, y, r) in enumerate(placed):
        z = hf.height(x, y) - 0.35 * r  # partly buried
        parts.append(
            f'<geom name="rock{i}" type="sphere" pos="{x:.3f} {y:.3f} {z:.3f}" size="{r:.3f}" '
            f'rgba="{_ROCK_RGBA}"/>'
        )
        obstacles.append(Circle(x, y, r))
    return "".join(parts), obstacles


def build() -> WorldSpec:
    rng = np.random.default_rng(_LAYOUT_SEED)
    ncol = int(round(2 * _RADIUS[0] / _CELL)) + 1
    nrow = int(round(2 * _RADIUS[1] / _CELL)) + 1
    xs = np.linspace(_CENTRE[0] - _RADIUS[0], _CENTRE[0] + _RADIUS[0], ncol)
    ys = np.linspace(_CENTRE[1] - _RADIUS[1], _CENTRE[1] + _RADIUS[1], nrow)
    gx, gy = np.meshgrid(xs, ys)  # (nrow, ncol): row index along y
    h = _terrain(gx, gy, rng)
    h -= h.min()
    z_top = float(h.max())
    elevation = h / z_top
    hf = HeightField(_CENTRE, _RADIUS[0], _RADIUS[1], z_top, _BASE, elevation)
    rocks_xml, obstacles = _rocks(rng, hf)
    # MuJoCo reads the elevation rows from +y down (like an image); HeightField (and so
    # spawn heights, rock placement, the dataset's poses) counts rows along +y: flip them.
    data = " ".join(f"{v:.5f}" for v in elevation[::-1].reshape(-1))
    asset = _mjcf.heightfield_floor_assets(
        "0.58 0.58 0.56", "0.48 0.48 0.46", "0.40 0.40 0.38", (2 * _RADIUS[0], 2 * _RADIUS[1])
    ) + (
        f'<hfield name="terrain" nrow="{nrow}" ncol="{ncol}" '
        f'size="{_RADIUS[0]} {_RADIUS[1]} {z_top:.5f} {_BASE}" elevation="{data}"/>'
    )
    ground = (
        f'<geom name="terrain" type="hfield" hfield="terrain" pos="{_CENTRE[0]} {_CENTRE[1]} 0" '
        f'material="{_mjcf.FLOOR_MATERIAL}" group="{GROUP_GROUND}" {_mjcf.GROUND_CONTACT}/>'
    )
    return WorldSpec(
        name=NAME,
        **seed_areas(NAME),
        obstacles=tuple(obstacles),
        pedestrian_area=Rect((-6.0, 6.0), (-6.0, 6.0)),
        asset_xml=asset,
        worldbody_xml=ground + rocks_xml,
        heightfield=hf,
        n_pedestrians=3,
    )
