"""rover_train.looking_pair: the rows of benchmarks/looking_rl.py and their paired figures (the
runs are the benchmark's; its smoke run is in its docstring)."""

from __future__ import annotations

import pytest

from rover_env.scenarios import LOOKING_SCENARIOS, SCENARIOS
from rover_train.evaluate import EpisodeResult
from rover_train.looking_pair import ROWS, Row, paired, parse_row, row_cells


def _episode(success: bool, touched: bool) -> EpisodeResult:
    return EpisodeResult(success=success, collided=touched, timeout=not success,
                         termination="goal" if success else "timeout", path_length=1.0,
                         start_distance=1.0, time_to_goal=None, steps=10, intrusion_steps=0,
                         min_ped_distance=2.0, ret=0.0, pedestrian_contact=touched)  # fmt: skip


def test_a_row_names_a_scenario_its_first_seed_and_its_episodes() -> None:
    row = parse_row("inspect-blind-crossing-3@200000:600")
    assert row == Row(LOOKING_SCENARIOS["inspect-blind-crossing-3"], 200_000, 600)
    assert row.seeds == "200000..200599" and row.label == "`inspect-blind-crossing-3`"
    assert parse_row("inspect-crowd-3@100000:200").label == "inspect, the default crowd (3)"
    assert [parse_row(r).scenario.world for r in ROWS] == ["inspect"] * 5
    assert SCENARIOS["inspect-crowd-3"] == parse_row(ROWS[0]).scenario
    for bad, words in (("inspect-crowd-3", "SCENARIO@SEED:EPISODES"),
                       ("inspect-crowd-3@1:x", "SCENARIO@SEED:EPISODES"),
                       ("mars-crowd-3@1:10", "no scenario 'mars-crowd-3'"),
                       ("inspect-crowd-3@1:0", "at least 1 episode")):  # fmt: skip
        with pytest.raises(ValueError, match=words):
            parse_row(bad)


def test_the_difference_is_paired_episode_by_episode() -> None:
    import numpy as np

    same = np.array([True, False] * 50)
    assert paired(same, same) == "+0.0 [+0.0, +0.0]"  # the same episodes: no spread at all
    a = np.array([True] * 60 + [False] * 40)
    b = np.array([True] * 50 + [False] * 50)  # b's goals are a subset of a's
    text = paired(a, b)
    assert text.startswith("+10.0 [")
    lo, hi = (float(x) for x in text[text.index("[") + 1 : -1].split(","))
    assert 4.0 <= lo < 10.0 < hi <= 16.0  # only the 10 differing episodes vary
    assert paired(b, a).startswith("-10.0")


def test_a_row_gives_both_agents_and_their_difference() -> None:
    row = parse_row("inspect-oblivious-10@100000:4")
    looking = [_episode(True, False), _episode(True, True), _episode(False, True),
               _episode(True, False)]  # fmt: skip
    fixed = [_episode(False, False), _episode(True, True), _episode(False, True),
             _episode(True, True)]  # fmt: skip
    cells = row_cells(row, looking, fixed)
    assert cells[:5] == ["`inspect-oblivious-10`", 4, "100000..100003", "75.0 / 50.0 %",
                         "50.0 / 75.0 %"]  # fmt: skip
    assert cells[5].startswith("+25.0") and cells[6].startswith("-25.0")
    with pytest.raises(ValueError, match="not paired"):
        row_cells(row, looking, fixed[:3])
