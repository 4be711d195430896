"""The scenario suite: named presets of world x pedestrian mode x density.

A scenario is what a paper's table row names: ``inspect-crowd-10`` is the inspect world
with ten social-force walkers who see the rover. Its :meth:`Scenario.env_kwargs` are env
keywords, so any roverav env takes one::

    gym.make("roverav/RoverEnv-v0", **SCENARIOS["maze-crowd-6"].env_kwargs())

``rover-eval AGENT --suite`` evaluates an agent over them (:mod:`rover_train.suite` prints
the table). The suite covers each world at the default density (3) and at 10, and each crowd
mode once:

- ``crowd``: walkers who see the rover and make room for it;
- ``oblivious``: the same walkers, blind to the rover (they walk into a stopped one);
- ``crossing``: walkers crossing the rover's start-goal line;
- ``groups``: walkers in twos and threes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rover_env.crowd import MAX_PEDESTRIANS
from rover_env.pedestrians import PEDESTRIAN_MODES
from rover_env.worlds import WORLD_NAMES


@dataclass(frozen=True)
class Scenario:
    """One world, one pedestrian mode, one density."""

    world: str
    mode: str
    n_pedestrians: int

    def __post_init__(self) -> None:
        if self.world not in WORLD_NAMES:
            raise ValueError(f"unknown world {self.world!r}; choose from {WORLD_NAMES}")
        if self.mode not in PEDESTRIAN_MODES:
            raise ValueError(
                f"unknown pedestrian mode {self.mode!r}; choose from {PEDESTRIAN_MODES}"
            )
        if not 0 <= self.n_pedestrians <= MAX_PEDESTRIANS:
            raise ValueError(f"n_pedestrians must be 0-{MAX_PEDESTRIANS}, got {self.n_pedestrians}")

    @property
    def name(self) -> str:
        """``world-mode-density``, e.g. ``inspect-crowd-10``."""
        return f"{self.world}-{self.mode}-{self.n_pedestrians}"

    def env_kwargs(self) -> dict[str, Any]:
        """The env keywords that make this scenario (``world_n``, ``pedestrian_mode``,
        ``n_pedestrians``)."""
        return {
            "world_n": self.world,
            "pedestrian_mode": self.mode,
            "n_pedestrians": self.n_pedestrians,
        }


_SUITE = (
    Scenario("inspect", "crowd", 3),
    Scenario("inspect", "crowd", 10),
    Scenario("inspect", "groups", 8),
    Scenario("maze", "crowd", 3),
    Scenario("maze", "crowd", 6),
    Scenario("maze", "crowd", 10),
    Scenario("moon", "crowd", 3),
    Scenario("moon", "crossing", 3),
    Scenario("moon", "oblivious", 10),
)
SCENARIOS: dict[str, Scenario] = {s.name: s for s in _SUITE}
"""The suite, by name, in table order."""

_LOOKING = (
    Scenario("inspect", "oblivious", 10),
    Scenario("inspect", "blind-crossing", 3),
    Scenario("maze", "blind-crossing", 3),
    Scenario("moon", "blind-crossing", 3),
)
LOOKING_SCENARIOS: dict[str, Scenario] = {s.name: s for s in _LOOKING}
"""Presets where looking can matter, beside the suite's ``moon-crossing-3`` and
``moon-oblivious-10``: people who do not see the rover, in the worlds without them in the
suite, and ``blind-crossing`` walkers who cross the rover's way from outside a forward
camera's view. Not in the suite's table; :func:`select_scenarios` takes their names."""


def select_scenarios(spec: str | None = None, world: str | None = None) -> list[Scenario]:
    """The scenarios ``spec`` names: None or ``"all"`` for the whole suite (only ``world``'s
    when a world is given), a world name for that world's, or names separated by commas.
    Raises ValueError naming the unknown ones and the choices."""
    if spec in (None, "", "all"):
        chosen = list(SCENARIOS.values())
        return [s for s in chosen if world is None or s.world == world]
    if spec in WORLD_NAMES:
        return [s for s in SCENARIOS.values() if s.world == spec]
    named = {**SCENARIOS, **LOOKING_SCENARIOS}
    names = [n.strip() for n in str(spec).split(",") if n.strip()]
    unknown = [n for n in names if n not in named]
    if unknown or not names:
        raise ValueError(
            f"unknown scenario(s) {', '.join(unknown) or repr(spec)}: give 'all', a world "
            f"({', '.join(WORLD_NAMES)}) or names from: {', '.join(named)}"
        )
    return [named[n] for n in names]
