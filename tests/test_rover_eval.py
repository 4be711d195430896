"""rover-eval, the one evaluator: a zoo entry, a file made like it, its teacher (--expert) or
a random policy give per episode exactly what ``evaluate_agent`` gives on the same agent and
seeds; the defaults are the zoo's; a bare --suite is the agent's world's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from rover_env.scenarios import SCENARIOS
from rover_train import evaluate, zoo
from rover_train.agents import EXPERT_PLUGIN, PluginMissingError, RandomAgent, agent_plugin
from rover_train.evaluate import evaluate_agent
from rover_train.imitation.distill import RECIPES
from rover_train.imitation.expert import ExpertConfig
from rover_train.imitation.expert_agent import ExpertAgent

EPISODES = 2
MAX_STEPS = 40
SHORT = ["--episodes", str(EPISODES), "--max-steps", str(MAX_STEPS)]


def _rover_eval(argv: list[str], dump: Path) -> list[dict[str, Any]]:
    assert evaluate.main([*argv, *SHORT, "--dump", str(dump)]) == 0
    episodes: list[dict[str, Any]] = json.loads(dump.read_text())
    return episodes


def _library(entry: str, agent_for: Any) -> list[dict[str, Any]]:
    import dataclasses

    env = zoo.make_env(entry)
    try:
        results = evaluate_agent(env, agent_for(env), EPISODES, zoo.EVAL_SEED_BASE, MAX_STEPS)
    finally:
        env.close()
    return [json.loads(json.dumps(dataclasses.asdict(r))) for r in results]  # as --dump


@pytest.mark.parametrize("flags, agent_for", [
    ([], lambda env: zoo.load("lidar-maze")),
    (["--random"], lambda env: RandomAgent(env.action_space, zoo.EVAL_SEED_BASE)),
    (["--expert"], lambda env: ExpertAgent(env, "maze", ExpertConfig.with_manners(
        RECIPES["lidar-maze"].teacher_manners))),
], ids=["entry", "random", "expert"])  # fmt: skip
def test_rover_eval_of_an_entry_is_evaluate_agent_episode_for_episode(
    flags: list[str], agent_for: Any, tmp_path: Path
) -> None:
    got = _rover_eval(["lidar-maze", *flags], tmp_path / "dump.json")
    assert got == _library("lidar-maze", agent_for)
    assert [e["steps"] for e in got] and all(e["steps"] <= MAX_STEPS for e in got)


def test_a_student_file_is_evaluated_as_the_entry_it_was_made_like(tmp_path: Path) -> None:
    copy = tmp_path / "candidate.pt"
    copy.write_bytes(zoo.ENTRIES["lidar-maze"].path.read_bytes())
    by_file = _rover_eval([str(copy)], tmp_path / "a.json")
    assert by_file == _rover_eval(["lidar-maze", "--file", str(copy)], tmp_path / "b.json")
    assert by_file == _rover_eval(["lidar-maze"], tmp_path / "c.json")


def test_the_defaults_are_the_zoos() -> None:
    args = evaluate._parser().parse_args(["lidar-maze"])
    assert (args.episodes, args.seed, args.max_steps) == (
        zoo.EVAL_EPISODES, zoo.EVAL_SEED_BASE, zoo.EVAL_MAX_STEPS)
    assert (zoo.EVAL_EPISODES, zoo.EVAL_SEED_BASE, zoo.EVAL_MAX_STEPS) == (100, 100_000, 600)


def test_a_bare_suite_is_the_worlds_scenarios_for_a_model_or_random_too(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert evaluate.main(["--random", "--world", "moon", "--suite", "--episodes", "1",
                          "--max-steps", "3", "--json"]) == 0  # fmt: skip
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert list(data) == [s.name for s in SCENARIOS.values() if s.world == "moon"]


@pytest.mark.parametrize("argv, words", [
    ([], ["give an agent"]),
    (["lidar-maze", "--world", "moon"], ["--world", "made for", "lidar-maze"]),
    (["lidar-maze", "--manners", "firm"], ["--manners", "--expert"]),
    (["lidar-maze", "--expert", "--manners", "rude"], ["--expert", "rude", "polite"]),
    (["runs/x/model.zip", "--expert"], ["go with a zoo entry"]),
    (["lidar-mazz"], ["neither a zoo entry", "lidar-maze"]),
    (["lidar-maze", "--suite", "--dump", "x.json"], ["--dump", "--suite"]),
    (["runs/x/model.zip", "--temperature", "0.5"], ["--temperature", "add --sample"]),
    (["rl-fused-maze", "--temperature", "0"], ["--temperature", "> 0"]),
    (["rl-lidar-maze", "--temperature", "0.5"], ["entries that sample", "rl-fused-maze"]),
    (["--random", "--shield"], ["--shield", "not --random"]),
    (["lidar-maze", "--shield"], ["collision shield", "lidar-maze"]),
    (["fused-inspect-10"], ["fused-inspect-10", "was retired", "git show"]),
    (["rl-fused-inspect", "--person-margin", "-0.1"], ["--person-margin", "0 or more"]),
    (["rl-fused-inspect", "--no-shield", "--person-margin", "0.6"],
     ["--person-margin", "without --no-shield"]),
    (["lidar-maze", "--person-margin", "0.6"], ["collision shield", "lidar-maze"]),
], ids=["no_agent", "world", "manners", "bad_manners", "expert_model", "typo",
        "dump_suite", "temperature_unsampled", "temperature_zero",
        "temperature_greedy_entry", "shield_random", "shield_student", "retired",
        "margin_negative", "margin_unshielded", "margin_student"])  # fmt: skip
def test_rover_eval_usage_errors(argv: list[str], words: list[str],
                                 capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    with pytest.raises(SystemExit) as exc:
        evaluate.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    for word in words:
        assert word in err, err


def test_a_truncated_student_file_is_a_usage_error_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.pt"
    cut.write_bytes(zoo.ENTRIES["lidar-maze"].path.read_bytes()[:1000])
    for argv in ([str(cut)], ["lidar-maze", "--file", str(cut)]):
        with pytest.raises(SystemExit) as exc:
            evaluate.main(argv)
        assert exc.value.code == 2
        assert str(cut) in capsys.readouterr().err


def test_the_expert_comes_from_the_lab_as_a_plugin() -> None:
    source = agent_plugin(EXPERT_PLUGIN)("lidar-maze-rl", None)  # a fine-tuned entry: its start's
    assert source.label == f"planner expert ({RECIPES['lidar-maze'].teacher_manners})"
    with pytest.raises(PluginMissingError, match="pip install -e"):
        agent_plugin("no-such-agent")
