"""One flag vocabulary across av-daemon, rover-pair, rover-train and rover-eval, and the one
daemon launcher (active_vision.launcher) that the supervisor, tests and benchmarks share."""

from __future__ import annotations

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
    for old in ("--shm-name", "--n-envs"):  # hidden aliases are not advertised
        assert old not in text


def test_rover_train_old_spellings_still_parse_and_slots_follow_rover_pair(monkeypatch) -> None:
    from rover_train.train import TrainArgs, hyperparameters, parse_args

    a = parse_args(["--n-envs", "3", "--shm-name", "x1", "--log-level", "debug"])
    assert (a.slots, a.name, a.log_level) == (3, "x1", "DEBUG")
    monkeypatch.setenv("ROVERAV_SLOTS", "4")
    monkeypatch.setenv("ROVERAV_SHM_NAME", "from_pair")
    monkeypatch.setenv("ROVERAV_LOG_LEVEL", "WARNING")
    b = parse_args([])
    assert (b.slots, b.name, b.log_level) == (4, "from_pair", "WARNING")
    assert parse_args(["--slots", "2"]).slots == 2  # an explicit flag wins
    hp = hyperparameters(TrainArgs(algo="ppo", n_steps=64, gamma=0.95))
    assert hp["n_steps"] == 64 and hp["gamma"] == 0.95 and hp["batch_size"] == 256
    assert hyperparameters(TrainArgs(algo="dqn", env="discrete"))["learning_rate"] == 1e-4


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
