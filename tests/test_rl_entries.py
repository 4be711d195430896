"""RL models as zoo entries: the recipe rover-train stores in every model.zip, ``rover-train
--recipe FILE``, and ``zoo.load`` / ``rover-eval`` on an ``rl-*`` entry."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import pytest

from rover_train import evaluate, zoo
from rover_train.algos import ModelAgent
from rover_train.recipe import RECIPE_MEMBER, RecipeError, read_recipe
from rover_train.train import parse_args, train
from rover_train.zoo.registry import LOOKING_RL_PAIR

TINY = ["--env", "lidar-discrete", "--world", "inspect", "--task", "nav", "--n-steps", "64",
        "--batch-size", "32", "--n-epochs", "1", "--no-progress", "--checkpoint-every", "0",
        "--timesteps", "64", "--seed", "3"]  # fmt: skip


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 64-step PPO run on the RL entries' env."""
    out = tmp_path_factory.mktemp("rl_entry")
    metrics = train(parse_args([*TINY, "--logdir", str(out)]))
    assert metrics["status"] == "complete"
    return out


def test_a_finished_model_holds_the_arguments_that_made_it(run_dir: Path) -> None:
    recipe = read_recipe(run_dir / "model.zip")
    assert recipe["env"] == "lidar-discrete" and recipe["task"] == "nav"
    assert recipe["timesteps"] == 64 and recipe["seed"] == 3 and recipe["n_steps"] == 64
    for where_or_how in ("resume", "recipe", "logdir", "threads", "progress", "name"):
        assert where_or_how not in recipe  # not what the model is, but how a machine ran it
    assert recipe == {k: v for k, v in json.loads((run_dir / "run.json").read_text())["args"]
                      .items() if k in recipe}  # fmt: skip
    (checkpoint,) = (run_dir / "checkpoints").glob("*.zip")
    assert read_recipe(checkpoint) == recipe  # a checkpoint carries its run's recipe too


def test_recipe_flag_trains_the_stored_arguments_and_flags_override(
    run_dir: Path, tmp_path: Path
) -> None:
    model = run_dir / "model.zip"
    again = parse_args(["--recipe", str(model)])
    assert (again.env, again.world, again.task, again.seed) == ("lidar-discrete", "inspect",
                                                                 "nav", 3)  # fmt: skip
    assert again.timesteps == 64 and again.logdir == Path("runs/train") and again.resume is None
    assert again.progress  # an operational field: this invocation's, not the recipe's
    other = parse_args(["--recipe", str(model), "--seed", "4", "--logdir", str(tmp_path)])
    assert other.seed == 4 and other.logdir == tmp_path and other.n_steps == 64


def test_recipe_flag_refuses_a_file_without_a_recipe(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plain_zip = tmp_path / "other.zip"
    with zipfile.ZipFile(plain_zip, "w") as archive:
        archive.writestr("data", "{}")
    for bad in (plain_zip, tmp_path / "missing.zip", Path(__file__)):
        with pytest.raises(SystemExit) as exc:
            parse_args(["--recipe", str(bad)])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"--recipe: {bad}" in err
        assert "no such file" in err or "rl-*.zip" in err
    with pytest.raises(RecipeError, match=RECIPE_MEMBER):
        read_recipe(plain_zip)
    with pytest.raises(SystemExit):
        parse_args(["--recipe", str(plain_zip), "--resume", str(tmp_path)])
    assert "give one of them" in capsys.readouterr().err


def test_zoo_loads_an_rl_model_as_an_agent_that_drives_its_env(run_dir: Path) -> None:
    spec = zoo.ENTRIES["rl-lidar-inspect"]
    assert spec.trainer == zoo.RL and spec.path.suffix == ".zip"
    assert zoo.command("rl-lidar-inspect") == (
        "rover-train --recipe rover_train/zoo/entries/rl-lidar-inspect.zip "
        "--logdir runs/rl-lidar-inspect")
    agent = zoo.load("rl-lidar-inspect", run_dir / "model.zip")
    assert isinstance(agent, ModelAgent) and isinstance(agent, zoo.Agent)
    env = zoo.make_env("rl-lidar-inspect")
    try:
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        agent.reset()
        actions = []
        for _ in range(5):
            action = agent.act(obs)
            assert env.action_space.contains(int(action))
            actions.append(int(action))
            obs, *_ = env.step(action)
        agent.reset()
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        assert int(agent.act(obs)) == actions[0]  # deterministic
    finally:
        env.close()
    with pytest.raises(FileNotFoundError, match="rover-train --recipe"):
        zoo.load("rl-lidar-maze", run_dir / "nothing.zip")


def test_rover_eval_scores_an_rl_model_and_refuses_the_expert_for_it(
    run_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = evaluate.main(["rl-lidar-inspect", "--file", str(run_dir / "model.zip"),
                          "--episodes", "1", "--json"])  # fmt: skip
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["episodes"] == 1 and 0.0 <= summary["success_rate"] <= 1.0
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["rl-lidar-inspect", "--expert"])
    assert exc.value.code == 2
    assert "rover-eval lidar-inspect --expert" in capsys.readouterr().err
    not_a_model = run_dir / "run.json"
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["rl-lidar-inspect", "--file", str(not_a_model), "--episodes", "1"])
    assert exc.value.code == 2
    assert f"--file: {not_a_model} is not a model .zip" in capsys.readouterr().err



def test_shipped_rl_entries_carry_the_recipe_their_command_trains() -> None:
    shipped = [n for n in zoo.names() if zoo.ENTRIES[n].trainer == zoo.RL]
    assert shipped == ["rl-fused-gaze-inspect", "rl-fused-inspect", "rl-fused-inspect-twin",
                       "rl-fused-maze", "rl-lidar-inspect", "rl-lidar-maze"]
    for name in shipped:
        spec = zoo.ENTRIES[name]
        recipe = read_recipe(spec.path)
        assert (recipe["env"], recipe["world"], recipe["task"]) == (spec.kind, spec.world, "nav")
        command = zoo.command(name).split()
        if spec.kind in ("fused", "fused-gaze"):  # under rover-pair, a slot for each env
            assert command[:2] == ["rover-pair", "--name"] and command[4] == str(recipe["slots"])
            command = command[command.index("--") + 1 :]
        again = parse_args(command[1:])  # rover-train --recipe <file> ...
        assert (again.env, again.world, again.timesteps) == (spec.kind, spec.world,
                                                              recipe["timesteps"])  # fmt: skip
        assert again.logdir == Path(f"runs/{name}")
        agent = zoo.load(name)
        assert isinstance(agent, ModelAgent)
        # the camera agents sample their policy (seeded), the LIDAR agents take its mode
        camera = spec.kind in ("fused", "fused-gaze")
        assert agent.deterministic is (not spec.sampled) and spec.sampled is camera
        if camera:  # the camera scan they were trained on, in the entry's env, and the shield
            assert recipe["camera_scan"] and spec.env_kwargs["camera_scan"]
            assert spec.shield and agent.shield is not None
        # the looking one drives its two heads (a drive, a pan window), its twin one
        assert bool(recipe.get("pan_head")) is (spec.kind == "fused-gaze")


def test_the_looking_pair_differs_in_the_camera_alone() -> None:
    looking, twin = (read_recipe(zoo.ENTRIES[n].path) for n in LOOKING_RL_PAIR)
    assert (looking["env"], twin["env"]) == ("fused-gaze", "fused")
    assert looking["pan_head"] and not twin.get("pan_head")
    same = {k: v for k, v in looking.items() if k not in ("env", "pan_head")}
    assert same == {k: v for k, v in twin.items() if k not in ("env", "pan_head")}
    assert same["timesteps"] == 401_408 and same["shield"] and same["relative_table"]
    assert [zoo.ENTRIES[n].env_kwargs for n in LOOKING_RL_PAIR] == [
        {"world_n": "inspect", "camera_scan": True}] * 2


def _actions(agent: ModelAgent, seed: int = zoo.EVAL_SEED_BASE, steps: int = 40) -> list[int]:
    env = zoo.make_env("rl-lidar-inspect")
    try:
        obs, _ = env.reset(seed=seed)
        agent.reset()
        out = []
        for _ in range(steps):
            action = agent.act(obs)
            out.append(int(action))
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        return out
    finally:
        env.close()


def test_a_sampling_agent_drives_an_episode_the_same_whatever_ran_before() -> None:
    import torch

    model = zoo.load("rl-lidar-inspect").model
    torch.manual_seed(123)
    before = torch.get_rng_state()
    first = _actions(ModelAgent(model, deterministic=False, seed=7))
    assert torch.equal(torch.get_rng_state(), before)  # the caller's draws are not moved
    agent = ModelAgent(model, deterministic=False, seed=7)
    _actions(agent, seed=zoo.EVAL_SEED_BASE + 1)  # another episode first
    assert _actions(agent) == first
    assert _actions(ModelAgent(model, deterministic=False, seed=8)) != first
    assert _actions(ModelAgent(model)) != first  # the most likely actions are another drive


def test_a_sampling_temperature_narrows_the_draws_toward_the_most_likely_action() -> None:
    import numpy as np

    model = zoo.load("rl-lidar-inspect").model
    env = zoo.make_env("rl-lidar-inspect")
    try:
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
    finally:
        env.close()
    best = int(ModelAgent(model).act(obs))

    def share_of_best(temperature: float) -> float:
        draws = [int(ModelAgent(model, deterministic=False, seed=s, temperature=temperature)
                     .act(obs)) for s in range(300)]  # fmt: skip
        return float(np.mean([d == best for d in draws]))

    cold, as_trained, hot = share_of_best(0.2), share_of_best(1.0), share_of_best(5.0)
    assert cold > as_trained > hot  # the spread follows the temperature
    assert cold > 0.9
    # the draw is still seeded by the observation: the same seed, the same action
    agent = ModelAgent(model, deterministic=False, seed=3, temperature=0.5)
    assert int(agent.act(obs)) == int(agent.act(obs))


def test_a_temperature_is_refused_where_it_means_nothing() -> None:
    model = zoo.load("rl-lidar-inspect").model
    with pytest.raises(ValueError, match="deterministic=False"):
        ModelAgent(model, temperature=0.5)  # the most likely action has no spread to scale
    with pytest.raises(ValueError, match="> 0"):
        ModelAgent(model, deterministic=False, temperature=0.0)
    with pytest.raises(ValueError, match="entries that sample"):
        zoo.load("rl-lidar-inspect", temperature=0.5)
