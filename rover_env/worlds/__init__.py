"""The arenas: ``make_world(name)`` returns a :class:`WorldSpec`.

Names are the seed's: ``inspect``, ``moon`` (``island`` is an alias, as in the seed) and
``maze``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

from rover_env.constants import WORLD_ALIASES
from rover_env.worlds import inspect, maze, moon
from rover_env.worlds.spec import Box, Circle, HeightField, Obstacle, Rect, WorldSpec

_BUILDERS: dict[str, Callable[[], WorldSpec]] = {
    inspect.NAME: inspect.build,
    moon.NAME: moon.build,
    maze.NAME: maze.build,
}
WORLD_NAMES: tuple[str, ...] = tuple(_BUILDERS)
WORLD_CHOICES: tuple[str, ...] = (*WORLD_NAMES, *WORLD_ALIASES)
"""Every accepted ``world_n``: the names and the seed's aliases (for CLI choices)."""


def canonical_world_name(name: str) -> str:
    """``name`` with the seed's alias applied ('island' -> 'moon'); ValueError if unknown."""
    canonical = WORLD_ALIASES.get(name, name)
    if canonical not in _BUILDERS:
        choices = sorted(WORLD_CHOICES)
        raise ValueError(f"unknown world {name!r}; choose one of {choices}")
    return canonical


@cache
def _build(name: str) -> WorldSpec:
    return _BUILDERS[name]()


def make_world(name: str) -> WorldSpec:
    """The :class:`WorldSpec` of world ``name`` (built once per process, then shared)."""
    return _build(canonical_world_name(name))


__all__ = [
    "WORLD_CHOICES",
    "WORLD_NAMES",
    "Box",
    "Circle",
    "HeightField",
    "Obstacle",
    "Rect",
    "WorldSpec",
    "canonical_world_name",
    "make_world",
]
