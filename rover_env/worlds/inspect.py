"""inspect: an industrial inspection zone with rows of solar panels and service structures.

The seed's spawn and goal square is x, y in [-27, -19]; leaving x in [-29, -13] or
y in [-29, -17] ends the episode. Two panel rows cross the spawn square and three more
stand east of it; an inverter house, a water tank, a utility pole and junction boxes stand
around and inside it. Panel rows sit on a 0.45 m concrete plinth, so the 0.30 m LIDAR sees
them and the rover cannot drive under them.
"""

from __future__ import annotations

import math

from rover_env.worlds import _mjcf
from rover_env.worlds.spec import GROUP_VISUAL, Box, Obstacle, Rect, WorldSpec, seed_areas

NAME = "inspect"
_CONCRETE = "0.62 0.62 0.6 1"
_PANEL = "0.1 0.14 0.32 1"
_FRAME = "0.75 0.76 0.78 1"
_HOUSE = "0.78 0.74 0.66 1"
_TANK = "0.45 0.5 0.45 1"
_POLE = "0.4 0.3 0.22 1"
_BOX = "0.55 0.58 0.52 1"

PLINTH_HEIGHT = 0.45
PANEL_TILT = math.radians(25.0)
# Panel rows: centre x, centre y, half length along x.
_ROWS = (
    (-23.5, -25.0, 2.5),
    (-23.5, -21.5, 2.5),
    (-16.0, -26.5, 1.8),
    (-16.0, -23.5, 1.8),
    (-16.0, -20.5, 1.8),
)
_ROW_HALF_DEPTH = 0.6


def _panel_row(i: int, x: float, y: float, half_len: float) -> tuple[str, Obstacle]:
    plinth_xml, _ = _mjcf.box(f"plinth{i}", x, y, (half_len, 0.25, PLINTH_HEIGHT / 2), _CONCRETE)
    # The tilted panel rests on the plinth, facing south (-y), 1.2 m deep.
    hz = 0.02
    zc = PLINTH_HEIGHT + _ROW_HALF_DEPTH * math.sin(PANEL_TILT) + hz
    panel_xml = (
        f'<geom name="panel{i}" type="box" pos="{x} {y} {zc:.4f}" '
        f'size="{half_len} {_ROW_HALF_DEPTH} {hz}" euler="{math.degrees(PANEL_TILT):.3f} 0 0" '
        f'rgba="{_PANEL}"/>'
        f'<geom name="panel_frame{i}" type="box" pos="{x} {y + 0.005} {zc - 0.01:.4f}" '
        f'size="{half_len + 0.03} {_ROW_HALF_DEPTH + 0.03} {hz / 2}" '
        f'euler="{math.degrees(PANEL_TILT):.3f} 0 0" rgba="{_FRAME}" contype="0" '
        f'conaffinity="0" group="{GROUP_VISUAL}"/>'
    )
    # The footprint covers the whole panel's shadow, not only the plinth.
    footprint = Box(x, y, half_len, _ROW_HALF_DEPTH * math.cos(PANEL_TILT))
    return plinth_xml + panel_xml, footprint


def build() -> WorldSpec:
    parts: list[str] = [_mjcf.floor((-21.0, -23.0), 12.0)]
    obstacles: list[Obstacle] = []
    for i, row in enumerate(_ROWS):
        xml, fp = _panel_row(i, *row)
        parts.append(xml)
        obstacles.append(fp)
    for xml, fp in (
        _mjcf.box("inverter_house", -20.5, -18.2, (1.2, 0.8, 1.25), _HOUSE),
        _mjcf.cylinder("water_tank", -27.6, -18.6, 0.8, 2.2, _TANK),
        _mjcf.cylinder("utility_pole", -19.8, -23.2, 0.12, 4.0, _POLE),
        _mjcf.box("junction_box0", -26.0, -20.0, (0.25, 0.2, 0.35), _BOX),
        _mjcf.box("junction_box1", -20.5, -26.8, (0.25, 0.2, 0.35), _BOX, yaw=0.4),
    ):
        parts.append(xml)
        obstacles.append(fp)
    return WorldSpec(
        name=NAME,
        **seed_areas(NAME),
        obstacles=tuple(obstacles),
        pedestrian_area=Rect((-28.0, -14.0), (-28.0, -18.0)),
        asset_xml=_mjcf.floor_assets("0.66 0.63 0.56", "0.6 0.57 0.5"),
        worldbody_xml="".join(parts),
        n_pedestrians=3,
    )
