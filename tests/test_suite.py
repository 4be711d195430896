"""The scenario suite: presets, selection, the contact split, and rover-eval --suite."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from rover_env import RoverEnv
from rover_env.scenarios import LOOKING_SCENARIOS, SCENARIOS, Scenario, select_scenarios
from rover_train import evaluate
from rover_train.evaluate import run_episode
from rover_train.suite import SUITE_COLUMNS, format_suite_row, wilson_interval

FORWARD = np.array([1.0, 0.0], dtype=np.float32)  # full speed, straight on


def test_scenarios_name_world_mode_density_and_make_their_env() -> None:
    sc = SCENARIOS["maze-crowd-6"]
    assert (sc.world, sc.mode, sc.n_pedestrians) == ("maze", "crowd", 6)
    env = gym.make("roverav/RoverEnv-v0", **sc.env_kwargs())
    try:
        env.reset(seed=0)
        sim = env.unwrapped.sim
        assert sim.world.name == "maze"
        assert len(sim.pedestrian_positions) == 6
    finally:
        env.close()
    for needed in ("inspect-crowd-3", "inspect-crowd-10", "maze-crowd-6", "moon-crossing-3",
                   "moon-oblivious-10", "inspect-groups-8"):  # fmt: skip
        assert needed in SCENARIOS


def test_scenario_refuses_what_no_env_takes() -> None:
    with pytest.raises(ValueError, match="unknown world"):
        Scenario("mars", "crowd", 3)
    with pytest.raises(ValueError, match="pedestrian mode"):
        Scenario("maze", "stampede", 3)
    with pytest.raises(ValueError, match="0-20"):
        Scenario("maze", "crowd", 21)


def test_select_scenarios() -> None:
    assert select_scenarios() == list(SCENARIOS.values())
    assert select_scenarios("all", world="moon") == [s for s in SCENARIOS.values()
                                                     if s.world == "moon"]  # fmt: skip
    assert {s.world for s in select_scenarios("maze")} == {"maze"}
    names = ["moon-crossing-3", "inspect-crowd-10"]
    assert [s.name for s in select_scenarios(",".join(names))] == names
    with pytest.raises(ValueError, match="unknown scenario.*inspect-crowd-99.*maze-crowd-6"):
        select_scenarios("inspect-crowd-99")
    # the looking presets are chosen by name, and stay out of the suite's table
    looking = select_scenarios("inspect-blind-crossing-3,moon-crossing-3")
    assert [(s.world, s.mode, s.n_pedestrians) for s in looking] == [
        ("inspect", "blind-crossing", 3), ("moon", "crossing", 3)]  # fmt: skip
    assert not set(LOOKING_SCENARIOS) & set(SCENARIOS)
    assert all(s.mode != "blind-crossing" for s in select_scenarios("all"))


def test_wilson_interval() -> None:
    lo, hi = wilson_interval(79, 100)
    assert lo == pytest.approx(0.700, abs=0.002) and hi == pytest.approx(0.858, abs=0.002)
    assert wilson_interval(0, 4)[0] == 0.0 and 0.45 < wilson_interval(0, 4)[1] < 0.55
    assert wilson_interval(4, 4)[1] == 1.0


def test_suite_row_keeps_the_half_percent_200_episodes_resolve() -> None:
    """199 of 200 is 99.5 %, not a rounded 100 % beside a table that says 99.5."""
    summary = {
        "episodes": 200, "success_rate": 0.995, "success_ci95": (0.9722, 0.9991),
        "collision_rate": 0.08, "pedestrian_contact_rate": 0.045,
        "pedestrian_contact_ci95": (0.024, 0.083), "scenery_contact_rate": 0.0,
        "intimate_intrusion_rate": 0.005, "timeouts": 1, "spl": 0.781, "time_to_goal_s": 9.31,
        "personal_space_intrusion_rate": 0.0612, "min_pedestrian_distance_m": 0.457,
    }  # fmt: skip
    row = dict(zip(SUITE_COLUMNS, format_suite_row(SCENARIOS["maze-crowd-3"], summary),
                   strict=True))  # fmt: skip
    assert row["success [95% CI]"] == "99.5% [97.2%-99.9%]"
    assert row["collisions"] == "8%" and row["ped. contact [95% CI]"] == "4.5% [2.4%-8.3%]"
    assert row["intimate"] == "0.5%" and row["SPL"] == "0.78" and row["intrusion"] == "6.1%"


def test_run_episode_splits_scenery_contact_from_pedestrian_contact() -> None:
    env = RoverEnv(world_n="maze", n_pedestrians=0)
    try:

        def into_the_wall(obs: object, _state: list[int] = [0]) -> np.ndarray:  # noqa: B006
            if _state[0] == 0:  # nose 5 cm from the east wall, facing it
                env.sim.set_rover_pose(5.62, -4.8, 0.0)
            _state[0] += 1
            return FORWARD

        hit = run_episode(env, into_the_wall, seed=0, max_steps=20, frames=None)
        assert hit.scenery_contact and not hit.pedestrian_contact
        parked = run_episode(env, lambda _obs: np.zeros(2, np.float32), 0, 20, None)
        assert not parked.scenery_contact and not parked.pedestrian_contact
    finally:
        env.close()


def test_rover_eval_suite_prints_one_row_per_scenario(capsys: pytest.CaptureFixture) -> None:
    names = "maze-crowd-3,moon-oblivious-10"
    code = evaluate.main(["--random", "--suite", names, "--episodes", "2",
                          "--max-steps", "30", "--json"])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out.strip().splitlines()
    header = next(line for line in out if line.startswith("| scenario"))
    assert header == "| " + " | ".join(SUITE_COLUMNS) + " |"
    rows = [line for line in out if line.startswith("| maze-") or line.startswith("| moon-")]
    assert [r.split(" | ")[0][2:] for r in rows] == names.split(",")
    data = json.loads(out[-1])
    assert list(data) == names.split(",")
    assert data["moon-oblivious-10"]["n_pedestrians"] == 10
    assert data["moon-oblivious-10"]["pedestrian_mode"] == "oblivious"
    assert data["maze-crowd-3"]["episodes"] == 2
    assert len(data["maze-crowd-3"]["success_ci95"]) == 2


def test_rover_eval_suite_refuses_unknown_names(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        evaluate.main(["--random", "--suite", "maze-riot-3"])
    assert "--suite: unknown scenario" in capsys.readouterr().err


def test_a_bare_suite_is_the_entrys_world(capsys: pytest.CaptureFixture) -> None:
    code = evaluate.main(["lidar-maze", "--random", "--suite", "--episodes", "1", "--json"])
    assert code == 0
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert list(data) == [s.name for s in SCENARIOS.values() if s.world == "maze"]
