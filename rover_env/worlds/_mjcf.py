"""Small MJCF builders shared by the arenas: each returns (xml, footprint)."""

from __future__ import annotations

import math

from rover_env.worlds.spec import GROUND_FRICTION, GROUP_GROUND, Box, Circle

FLOOR_MATERIAL = "floor"
# Ground geoms override the scenery default: the wheels' own friction and priority.
GROUND_CONTACT = f'friction="{GROUND_FRICTION}" priority="0"'


def floor_assets(rgb1: str, rgb2: str) -> str:
    """A 1 m checker grid material for plane floors (texuniform: texrepeat is per metre)."""
    return (
        f'<texture name="{FLOOR_MATERIAL}" type="2d" builtin="checker" width="64" height="64" '
        f'rgb1="{rgb1}" rgb2="{rgb2}"/>'
        f'<material name="{FLOOR_MATERIAL}" texture="{FLOOR_MATERIAL}" texrepeat="0.5 0.5" '
        'texuniform="true" reflectance="0"/>'
    )


def heightfield_floor_assets(rgb1: str, rgb2: str, mark_rgb: str, extent: tuple[float, float],
                             square: float = 1.0, marks: float = 0.15) -> str:
    """The floor material for a height field: ``square``-metre checker squares with random
    darker texels (regolith grit, about 3 cm each at the default square).

    MuJoCo maps a height field's texture over the whole field (``texuniform`` does not apply
    to it): ``texrepeat`` counts tiles across the field, so it is set from the field's
    ``extent`` (full x and y size, m) for squares of ``square`` metres. With the plane
    floors' ``texrepeat`` instead, one checker square was stretched over 17 m and the
    ground read as untextured grey: nothing in the frame for monocular depth to measure.
    """
    tile = 2.0 * square  # a checker tile is two squares across
    return (
        f'<texture name="{FLOOR_MATERIAL}" type="2d" builtin="checker" width="64" height="64" '
        f'rgb1="{rgb1}" rgb2="{rgb2}" mark="random" random="{marks}" markrgb="{mark_rgb}"/>'
        f'<material name="{FLOOR_MATERIAL}" texture="{FLOOR_MATERIAL}" '
        f'texrepeat="{extent[0] / tile:.4g} {extent[1] / tile:.4g}" reflectance="0"/>'
    )


def floor(centre: tuple[float, float], half: float) -> str:
    """A square plane floor rendered in 1 m quads (third size value 1)."""
    return (
        f'<geom name="floor" type="plane" pos="{centre[0]} {centre[1]} 0" size="{half} {half} 1" '
        f'material="{FLOOR_MATERIAL}" group="{GROUP_GROUND}" {GROUND_CONTACT}/>'
    )


def box(
    name: str,
    x: float,
    y: float,
    half: tuple[float, float, float],
    rgba: str,
    yaw: float = 0.0,
    z: float | None = None,
) -> tuple[str, Box]:
    """A box standing on the ground (centre at z = half height unless ``z`` is given)."""
    hx, hy, hz = half
    zc = hz if z is None else z
    xml = (
        f'<geom name="{name}" type="box" pos="{x} {y} {zc}" size="{hx} {hy} {hz}" '
        f'euler="0 0 {math.degrees(yaw):.4f}" rgba="{rgba}"/>'
    )
    return xml, Box(x, y, hx, hy, yaw)


def cylinder(
    name: str, x: float, y: float, radius: float, height: float, rgba: str
) -> tuple[str, Circle]:
    """An upright cylinder standing on the ground."""
    xml = (
        f'<geom name="{name}" type="cylinder" pos="{x} {y} {height / 2}" '
        f'size="{radius} {height / 2}" rgba="{rgba}"/>'
    )
    return xml, Circle(x, y, radius)


def wall(
    name: str,
    a: tuple[float, float],
    b: tuple[float, float],
    thickness: float,
    height: float,
    rgba: str,
) -> tuple[str, Box]:
    """A straight wall from a to b (centre line), standing on the ground."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(dx, dy)
    return box(
        name,
        (a[0] + b[0]) / 2,
        (a[1] + b[1]) / 2,
        (length / 2 + thickness / 2, thickness / 2, height / 2),
        rgba,
        yaw=math.atan2(dy, dx),
    )
