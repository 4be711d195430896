"""maze: a walled maze for structured navigation.

The seed's spawn and goal square is x, y in [-4, 4]; leaving x, y in [-30, 30] ends the
episode (the outer wall at +-6 m keeps the rover well inside). Inner walls split the
enclosure into corridors 1.5-2.5 m wide; spawns, goals and pedestrian paths keep clear of
them.
"""

from __future__ import annotations

from rover_env.worlds import _mjcf
from rover_env.worlds.spec import Obstacle, Rect, WorldSpec, seed_areas

NAME = "maze"
WALL_HEIGHT = 1.0
WALL_THICKNESS = 0.2
_OUTER = 6.0
_WALL_RGBA = "0.80 0.76 0.68 1"
_INNER_RGBA = "0.70 0.66 0.58 1"
# Inner walls as centre lines (x0, y0) -> (x1, y1).
_INNER_WALLS = (
    ((-4.0, -6.0), (-4.0, -2.0)),
    ((-6.0, 2.0), (-2.0, 2.0)),
    ((0.0, -3.0), (0.0, 3.0)),
    ((-2.0, -2.0), (0.0, -2.0)),
    ((2.0, -2.0), (4.0, -2.0)),
    ((2.0, -6.0), (2.0, -4.0)),
    ((4.0, 0.0), (4.0, 6.0)),
    ((-2.0, 4.0), (2.0, 4.0)),
)


def build() -> WorldSpec:
    o = _OUTER
    parts = [_mjcf.floor((0.0, 0.0), 10.0)]
    obstacles: list[Obstacle] = []
    outer = (((-o, -o), (o, -o)), ((o, -o), (o, o)), ((o, o), (-o, o)), ((-o, o), (-o, -o)))
    for i, (a, b) in enumerate(outer):
        xml, fp = _mjcf.wall(f"outer_wall{i}", a, b, WALL_THICKNESS, WALL_HEIGHT, _WALL_RGBA)
        parts.append(xml)
        obstacles.append(fp)
    for i, (a, b) in enumerate(_INNER_WALLS):
        xml, fp = _mjcf.wall(f"wall{i}", a, b, WALL_THICKNESS, WALL_HEIGHT, _INNER_RGBA)
        parts.append(xml)
        obstacles.append(fp)
    return WorldSpec(
        name=NAME,
        **seed_areas(NAME),
        obstacles=tuple(obstacles),
        pedestrian_area=Rect((-5.8, 5.8), (-5.8, 5.8)),
        asset_xml=_mjcf.floor_assets("0.5 0.52 0.55", "0.45 0.47 0.5"),
        worldbody_xml="".join(parts),
        n_pedestrians=3,
    )
