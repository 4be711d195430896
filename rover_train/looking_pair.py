"""The zoo's looking RL entry against its fixed twin, paired on the same episodes: the rows of
``benchmarks/looking_rl.py`` and their figures.

A row is ``SCENARIO@SEED:EPISODES`` (a scenario of ``rover_env.scenarios``, the suite's or
``LOOKING_SCENARIOS``); its cells are each agent's success / episodes with a person touched
and looking minus fixed in points on the same episodes, with 90 % paired bootstrap intervals
over episodes (:func:`rover_train.suite.bootstrap`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rover_env.scenarios import LOOKING_SCENARIOS, SCENARIOS, Scenario
from rover_train.evaluate import EpisodeResult
from rover_train.suite import bootstrap, percentile_interval

ROWS = ("inspect-crowd-3@100000:200", "inspect-crowd-10@100000:200",
        "inspect-blind-crossing-3@100000:600", "inspect-blind-crossing-3@200000:600",
        "inspect-oblivious-10@100000:200")  # fmt: skip
"""RESULTS.md's rows: the crowds of 3 (the default) and 10, where looking must cost at most 3
points, the blind crossers on two seed ranges, ten people who do not see the rover."""
TITLE = ("A looking camera agent from the reward against its fixed-camera twin, paired on the "
         "same episodes (success / episodes with a person touched; looking \u2212 fixed in "
         "points, 90 % bootstrap intervals over episodes)")  # fmt: skip
COLUMNS = ["scenario", "episodes", "seeds", "looking (two heads)", "fixed camera",
           "looking \u2212 fixed: success", "looking \u2212 fixed: a person touched"]  # fmt: skip


@dataclass(frozen=True)
class Row:
    """One row: a scenario, its first seed and its episodes."""

    scenario: Scenario
    seed: int
    episodes: int

    @property
    def seeds(self) -> str:
        return f"{self.seed}..{self.seed + self.episodes - 1}"

    @property
    def label(self) -> str:
        if self.scenario == SCENARIOS["inspect-crowd-3"]:
            return "inspect, the default crowd (3)"
        return f"`{self.scenario.name}`"


def parse_row(text: str) -> Row:
    """``SCENARIO@SEED:EPISODES`` as a :class:`Row`; ValueError naming the fault."""
    try:
        name, rest = text.split("@")
        seed, episodes = (int(x) for x in rest.split(":"))
    except ValueError:
        raise ValueError(f"{text!r}: a row is SCENARIO@SEED:EPISODES, e.g. "
                         f"inspect-blind-crossing-3@100000:600") from None  # fmt: skip
    named = {**SCENARIOS, **LOOKING_SCENARIOS}
    if name not in named:
        raise ValueError(f"{text!r}: no scenario {name!r}; choose from {', '.join(named)}")
    if episodes < 1:
        raise ValueError(f"{text!r}: at least 1 episode")
    return Row(named[name], seed, episodes)


def paired(looking: np.ndarray, fixed: np.ndarray) -> str:
    """Looking minus fixed in points, with its 90 % paired bootstrap interval."""
    d = looking.astype(float) - fixed.astype(float)
    lo, hi = percentile_interval(bootstrap(lambda i: d[i].mean(1), len(d)))
    return f"{100 * d.mean():+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def row_cells(row: Row, looking: list[EpisodeResult], fixed: list[EpisodeResult]) -> list[Any]:
    """The record's row for one scenario: both agents' shares and the paired differences."""
    if len(looking) != len(fixed):
        raise ValueError(f"{len(looking)} and {len(fixed)} episodes: not paired")
    flags = {k: [np.array([getattr(r, k) for r in side], bool) for side in (looking, fixed)]
             for k in ("success", "pedestrian_contact")}  # fmt: skip

    def shares(i: int) -> str:
        return (f"{100 * flags['success'][i].mean():.1f} / "
                f"{100 * flags['pedestrian_contact'][i].mean():.1f} %")  # fmt: skip

    return [row.label, len(looking), row.seeds, shares(0), shares(1),
            paired(*flags["success"]), paired(*flags["pedestrian_contact"])]  # fmt: skip
