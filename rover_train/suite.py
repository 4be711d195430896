"""The scenario suite's table: one agent over every scenario of :mod:`rover_env.scenarios`.

``rover-eval AGENT --suite`` (any agent: a zoo entry, a model, the planner expert, the
random policy) ends here: for each scenario an env is made with the scenario's keywords, the
same evaluation episodes are run (episode i: ``reset(seed=seed + i)``, ended at the first
goal, a termination, the env's length or ``max_steps``), and one row is printed per
scenario:

- success: share of episodes that reached the goal, with its 95 % Wilson interval;
- collisions: episodes in which the rover collided: a collision step in the seed's sense
  (the LIDAR closer than ``RewardConfig.collision_distance``) or any touch of a person or
  the scenery (``info["contact"]``); the headline the zoo's targets count;
- ped. contact / scenery contact: episodes in which the rover's body touched a pedestrian
  (either way round, ``info["pedestrian_collision"]``, with its 95 % interval) / touched
  the scenery;
- intimate: episodes with a pedestrian within 0.45 m at some step;
- timeouts, SPL, time to goal (s, successful episodes), personal-space intrusion (share of
  steps with a pedestrian within 1.2 m) and the smallest pedestrian distance (m).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rover_env.scenarios import Scenario

WILSON_Z = 1.96  # 95 % interval

SUITE_COLUMNS = (
    "scenario", "episodes", "success [95% CI]", "collisions", "ped. contact [95% CI]",
    "scenery contact", "intimate", "timeouts", "SPL", "time to goal (s)", "intrusion",
    "min dist. (m)",
)  # fmt: skip


def wilson_interval(successes: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a binomial share (0, 1 with n = 0)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


PAIRED_CONFIDENCE = 0.90
"""The two-sided level of the paired bootstrap intervals (looking against a fixed camera)."""
BOOTSTRAP = 2000
"""Resamples of the episodes for a bootstrap interval."""


def bootstrap(stat: Callable[[np.ndarray], np.ndarray], n: int, seed: int = 0) -> np.ndarray:
    """``stat`` of :data:`BOOTSTRAP` resamples of ``n`` episodes (its argument: (B, n) indices
    into the episodes)."""
    idx = np.random.default_rng(seed).integers(0, n, (BOOTSTRAP, n))
    return stat(idx)


def percentile_interval(samples: np.ndarray,
                        confidence: float = PAIRED_CONFIDENCE) -> tuple[float, float]:  # fmt: skip
    """The ``confidence`` percentile interval of bootstrap ``samples`` (their finite ones;
    NaNs without any)."""
    a = (1.0 - confidence) / 2 * 100
    finite = samples[np.isfinite(samples)]
    if len(finite) == 0:
        return math.nan, math.nan
    lo, hi = np.percentile(finite, [a, 100 - a])
    return float(lo), float(hi)


def run_suite(
    scenarios: Sequence[Scenario],
    evaluate: Callable[[Scenario], dict[str, Any]],
    progress: Callable[[Scenario, dict[str, Any]], None] | None = None,
) -> list[tuple[Scenario, dict[str, Any]]]:
    """``evaluate(scenario)`` for each scenario: the caller makes the env, runs the episodes
    and summarises them (``rover_train.evaluate.summarise_scenario``); ``progress`` hears
    each row as it is done."""
    rows = []
    for scenario in scenarios:
        summary = evaluate(scenario)
        rows.append((scenario, summary))
        if progress is not None:
            progress(scenario, summary)
    return rows


def _pct(v: float) -> str:
    """A share as a percentage to 0.1 (200 episodes resolve 0.5 %), without a trailing .0."""
    return f"{100 * v:.1f}".removesuffix(".0") + "%"


def format_suite_row(scenario: Scenario, s: dict[str, Any]) -> list[str]:
    """One Markdown row's cells (:data:`SUITE_COLUMNS`)."""
    lo, hi = s["success_ci95"]
    plo, phi = s["pedestrian_contact_ci95"]
    ttg = s["time_to_goal_s"]
    dmin = s["min_pedestrian_distance_m"]
    return [
        scenario.name,
        str(s["episodes"]),
        f"{_pct(s['success_rate'])} [{_pct(lo)}-{_pct(hi)}]",
        _pct(s["collision_rate"]),
        f"{_pct(s['pedestrian_contact_rate'])} [{_pct(plo)}-{_pct(phi)}]",
        _pct(s["scenery_contact_rate"]),
        _pct(s["intimate_intrusion_rate"]),
        str(s["timeouts"]),
        f"{s['spl']:.2f}",
        "n/a" if ttg is None else f"{ttg:.1f}",
        f"{100 * s['personal_space_intrusion_rate']:.1f}%",
        "n/a" if dmin is None else f"{dmin:.2f}",
    ]


def format_suite_table(rows: Sequence[tuple[Scenario, dict[str, Any]]], title: str) -> str:
    """The suite as one Markdown table under ``title``."""
    lines = [title, "", "| " + " | ".join(SUITE_COLUMNS) + " |"]
    lines.append("|" + "|".join(["---"] + ["---:"] * (len(SUITE_COLUMNS) - 1)) + "|")
    lines += ["| " + " | ".join(format_suite_row(sc, s)) + " |" for sc, s in rows]
    return "\n".join(lines)


def suite_json(rows: Sequence[tuple[Scenario, dict[str, Any]]]) -> dict[str, Any]:
    """The suite's summaries by scenario name (``--json``)."""
    return {sc.name: {**s, **sc.env_kwargs()} for sc, s in rows}
