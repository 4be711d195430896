"""One flag vocabulary across av-daemon, rover-pair, rover-train and rover-eval, and the one
daemon launcher (active_vision.launcher) that the supervisor, tests and benchmarks share."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from active_vision.launcher import READY_MARKER, DaemonStartError, spawn_daemon
from shm_protocol import existing_segments

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "av-daemon": ["-m", "active_vision"],
    "rover-pair": ["-m", "launch.run_pair"],  # imports the package, as the console script does
    "rover-train": ["-m", "rover_train.train"],
    "rover-eval": ["-m", "rover_train.evaluate"],
}
RECIPE_COMMANDS = {"perception-train": ["-m", "active_vision.training.train"]}


def _help(cmd: str) -> str:
    argv = {**COMMANDS, **RECIPE_COMMANDS}[cmd]
    res = subprocess.run([sys.executable, *argv, "--help"], capture_output=True,
                         text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                         timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr
    return res.stdout


@pytest.mark.parametrize("cmd", sorted(COMMANDS))
def test_every_command_speaks_name_slots_log_level(cmd: str) -> None:
    text = _help(cmd)
    for flag in ("--name", "--slots", "--log-level"):
        assert flag in text, f"{cmd} --help lacks {flag}"
    for old in ("--shm-name", "--n-envs", "--rl-obs-name"):
        assert old not in text


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """Every user-facing command line that takes shared flags, built in this process."""
    from active_vision.daemon import build_parser as daemon_parser
    from launch.run_pair import build_parser as pair_parser
    from rover_train import evaluate, train
    from rover_train.cli import build_parser
    from rover_train.imitation import demo, distill
    from rover_train.imitation.finetune import FineTuneRecipe, FineTuneRun

    return {
        "av-daemon": daemon_parser(),
        "rover-pair": pair_parser(),
        "rover-train": train._parser(),
        "rover-eval": evaluate._parser(),
        "distill": distill._parser(None),
        "finetune": build_parser((FineTuneRecipe, FineTuneRun), "finetune", ""),
        "demo": demo._parser(),
    }


# the groups' flags each command takes
TRAINING_SEED = ("rover-train", "distill", "finetune", "demo")
"""Commands whose --seed is a training seed (default 0 or the recipe's), not the groups' --seed
(the evaluation seeds, from 100000, which training episodes stay clear of)."""
USES = {
    "av-daemon": {"Connection": "*"},
    "rover-pair": {"Connection": "*"},
    "rover-train": {"Connection": "*",
                    "Episodes": ("world", "pedestrian_mode", "n_pedestrians")},
    "rover-eval": {"Connection": "*", "Episodes": "*"},
    "distill": {"Connection": ("name", "log_level"),
                "Episodes": ("pedestrian_mode", "n_pedestrians")},
    "finetune": {"Connection": ("log_level",), "Episodes": ("pedestrian_mode", "n_pedestrians")},
    "demo": {"Episodes": ("world", "episodes", "max_steps")},
}


def test_shared_flags_are_the_groups_in_every_command(monkeypatch) -> None:
    """Same flag, same type, default, choices and help, wherever it appears: each is built
    from roverav_cli's groups."""
    import dataclasses

    import roverav_cli

    for var in ("ROVERAV_SHM_NAME", "ROVERAV_SLOTS", "ROVERAV_LOG_LEVEL"):
        monkeypatch.delenv(var, raising=False)
    groups = {g.__name__: g for g in roverav_cli.GROUPS}
    for cmd, parser in _parsers().items():
        actions = {s: a for a in parser._actions for s in a.option_strings}
        for gname, names in USES[cmd].items():
            group = groups[gname]
            names = [f.name for f in dataclasses.fields(group)] if names == "*" else names
            for name in names:
                flag = roverav_cli.option(name)
                assert flag in actions, f"{cmd} lacks {flag}"
                got, want = actions[flag], roverav_cli.argument_kwargs(group, name)
                assert got.dest == name, (cmd, flag)
                assert got.type is want["type"], (cmd, flag, got.type)
                assert got.default == want["default"], (cmd, flag, got.default)
                assert tuple(got.choices or ()) == tuple(want.get("choices", ())), (cmd, flag)
                assert got.help == want["help"], (cmd, flag)
        for flag in actions:  # no command defines a shared flag its own way
            for group in roverav_cli.GROUPS:
                for f in dataclasses.fields(group):
                    if flag == roverav_cli.option(f.name) and not (
                            cmd in TRAINING_SEED and f.name == "seed"):  # fmt: skip
                        uses = USES[cmd].get(group.__name__, ())
                        assert uses == "*" or f.name in uses, f"{cmd} {flag} not the group's"


def test_shared_flags_follow_rover_pair_and_the_evaluation_defaults(monkeypatch) -> None:
    from rover_train.evaluate import _parser
    from rover_train.zoo import EVAL_EPISODES, EVAL_MAX_STEPS, EVAL_SEED_BASE

    monkeypatch.setenv("ROVERAV_SLOTS", "4")
    monkeypatch.setenv("ROVERAV_SHM_NAME", "from_pair")
    monkeypatch.setenv("ROVERAV_LOG_LEVEL", "WARNING")
    a = _parser().parse_args(["--random"])
    assert (a.slots, a.name, a.log_level) == (4, "from_pair", "WARNING")
    assert (a.episodes, a.seed, a.max_steps) == (100, 100_000, 600)
    assert (EVAL_EPISODES, EVAL_SEED_BASE, EVAL_MAX_STEPS) == (100, 100_000, 600)
    assert (a.world, a.pedestrian_mode, a.n_pedestrians) == (None, None, None)


def test_the_groups_copies_of_rover_env_are_equal() -> None:
    import roverav_cli
    from rover_env.constants import DEFAULT_WORLD
    from rover_env.crowd import MAX_PEDESTRIANS
    from rover_env.pedestrians import DEFAULT_MODE, PEDESTRIAN_MODES
    from rover_env.worlds import WORLD_CHOICES

    assert roverav_cli.WORLD_CHOICES == tuple(WORLD_CHOICES)
    assert roverav_cli.DEFAULT_WORLD == DEFAULT_WORLD
    assert roverav_cli.PEDESTRIAN_MODES == tuple(PEDESTRIAN_MODES)
    assert roverav_cli.DEFAULT_PEDESTRIAN_MODE == DEFAULT_MODE
    assert roverav_cli.MAX_PEDESTRIANS == MAX_PEDESTRIANS


@pytest.mark.parametrize("cmd, argv", [
    ("rover-train", ["--shm-name", "x1"]),
    ("rover-train", ["--n-envs", "3"]),
    ("rover-train", ["--workers", "3"]),  # Ray actors are --ray-workers
    ("rover-train", ["--env", "discrete"]),  # the fused discrete env is fused-discrete
    ("rover-train", ["--rl-obs-name", "x1"]),
    ("rover-eval", ["--random", "--shm-name", "x1"]),
    ("rover-eval", ["--random", "--slot", "1"]),
    ("av-daemon", ["--shm-name", "x1"]),
    ("rover-pair", ["--shm-name", "x1"]),
])  # fmt: skip
def test_removed_spellings_are_refused(cmd: str, argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        _parsers()[cmd].parse_args(argv)
    assert exc.value.code == 2


def test_rover_train_slots_follow_rover_pair(monkeypatch) -> None:
    from rover_train.train import TrainArgs, hyperparameters, parse_args

    a = parse_args(["--slots", "3", "--name", "x1", "--log-level", "debug"])
    assert (a.slots, a.name, a.log_level) == (3, "x1", "DEBUG")
    monkeypatch.setenv("ROVERAV_SLOTS", "4")
    monkeypatch.setenv("ROVERAV_SHM_NAME", "from_pair")
    monkeypatch.setenv("ROVERAV_LOG_LEVEL", "WARNING")
    b = parse_args([])
    assert (b.slots, b.name, b.log_level) == (4, "from_pair", "WARNING")
    assert (b.world, b.pedestrian_mode, b.seed) == ("inspect", "crowd", 0)
    assert parse_args(["--slots", "2"]).slots == 2  # an explicit flag wins
    hp = hyperparameters(TrainArgs(algo="ppo", n_steps=64, gamma=0.95))
    assert hp["n_steps"] == 64 and hp["gamma"] == 0.95 and hp["batch_size"] == 256
    assert hyperparameters(TrainArgs(algo="dqn", env="fused-discrete"))["learning_rate"] == 1e-4


def test_stored_artefacts_with_old_names_read_under_the_new() -> None:
    from rover_train.recipe import stored_args
    from rover_train.zoo.registry import stored_kind

    assert stored_kind("discrete") == "fused-discrete" and stored_kind("fused") == "fused"
    old = {"env": "discrete", "workers": 3, "world": "maze"}
    assert stored_args(old) == {"env": "fused-discrete", "ray_workers": 3, "world": "maze"}


def test_rover_train_help_is_generated_from_the_dataclass() -> None:
    from rover_train.cli import field_docs
    from rover_train.train import TrainArgs

    docs = field_docs(TrainArgs)
    text = " ".join(_help("rover-train").split())
    for name in ("timesteps", "gae_lambda", "exploration_fraction"):
        assert "--" + name.replace("_", "-") in text
        assert docs[name].split(".")[0] in text


def test_recipe_help_prints_percent_signs() -> None:
    """argparse expands %-formats in help texts: a docstring's "70 %" crashed --help once."""
    assert "70 % driving" in " ".join(_help("perception-train").split())


def test_spawn_daemon_is_ready_drains_and_cleans_up(shm_name: str) -> None:
    with spawn_daemon(shm_name, slots=2, extra_args=["--threads", "1", "--log-every", "1"]) as d:
        assert d.poll() is None and d.ready.is_set()
        assert any(READY_MARKER in line for line in d.tail)
        assert existing_segments(shm_name) == sorted(
            [shm_name, f"{shm_name}_camera", f"{shm_name}_1", f"{shm_name}_1_camera"])
    assert d.poll() == 0
    assert existing_segments(shm_name) == []


def test_spawn_daemon_failure_names_the_reason_with_the_log_tail(shm_name: str) -> None:
    with pytest.raises(DaemonStartError) as err, spawn_daemon(
        shm_name, extra_args=["--weights", "/nonexistent/avnet.pt"]
    ):
        pass
    text = str(err.value)
    assert "before it was ready" in text and "avnet.pt" in text and "log tail" in text
    assert existing_segments(shm_name) == []


def test_off_policy_update_schedule_is_the_library_default_unless_given() -> None:
    from rover_train.train import TrainArgs, hyperparameters, parse_args, validate

    plain = hyperparameters(TrainArgs(algo="sac", env="fused"))
    assert "train_freq" not in plain and "gradient_steps" not in plain  # SB3's own: 1 / 1
    args = parse_args(["--algo", "sac", "--env", "fused", "--train-freq", "4",
                       "--gradient-steps", "2"])  # fmt: skip
    hp = hyperparameters(args)
    assert (hp["train_freq"], hp["gradient_steps"]) == (4, 2)
    assert "train_freq" not in hyperparameters(TrainArgs(algo="ppo"))  # on-policy: no such knob
    sac = {"algo": "sac", "env": "fused"}
    for bad, flag in ((TrainArgs(**sac, gradient_steps=0), "--gradient-steps"),
                      (TrainArgs(**sac, gradient_steps=-2), "--gradient-steps"),
                      (TrainArgs(**sac, train_freq=0), "--train-freq")):  # fmt: skip
        problem = validate(bad)
        assert problem is not None and flag in problem


def test_crowd_sizes_give_each_training_env_its_own_crowd(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from rover_train.train import build_vec_env, crowd_size, parse_args

    args = parse_args(["--env", "lidar", "--crowd-sizes", "3,10", "--slots", "4"])
    assert args.crowd_sizes == "3,10"
    assert [crowd_size(args, i) for i in range(4)] == [3, 10, 3, 10]
    venv = build_vec_env(args, tmp_path)
    try:
        assert [e.unwrapped.options.n_pedestrians for e in venv.envs] == [3, 10, 3, 10]
    finally:
        venv.close()
    plain = parse_args(["--env", "lidar", "--n-pedestrians", "5"])
    assert crowd_size(plain, 2) == 5
    with pytest.raises(SystemExit):
        parse_args(["--env", "lidar", "--crowd-sizes", "3,10", "--n-pedestrians", "5"])
    assert "leave out --n-pedestrians" in capsys.readouterr().err
    for bad in ("3,x", "3,21", ""):
        with pytest.raises(SystemExit):
            parse_args(["--env", "lidar", "--crowd-sizes", bad])
        assert "--crowd-sizes" in capsys.readouterr().err
