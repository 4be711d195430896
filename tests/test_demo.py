"""The main job (`make demo` runs ``rover_train.imitation.demo`` under rover-pair): a short
run against a
real daemon writes its outputs, prints the same random row twice, and its table describes
the student file it leaves behind."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.daemon import Daemon

from rover_train import zoo
from rover_train.evaluate import summarise
from rover_train.imitation import demo
from rover_train.imitation.zoo_eval import evaluate_agent
from shm_protocol.names import NAME_ENV_VAR

EPISODES = 2
MAX_STEPS = 15


@pytest.fixture()
def daemon(monkeypatch: pytest.MonkeyPatch) -> Iterator[Daemon]:
    d = Daemon(f"test_demo_{uuid.uuid4().hex[:8]}").start()
    monkeypatch.setenv(NAME_ENV_VAR, d.name)  # what rover-pair sets for the demo
    try:
        yield d
    finally:
        d.stop()
        d.remove_leftovers()


def _run(out: Path) -> dict:
    args = ["--timesteps", "0", "--episodes", str(EPISODES), "--max-steps", str(MAX_STEPS),
            "--video-episodes", "1", "--out", str(out)]
    assert demo.main(args) == 0
    return json.loads((out / "metrics.json").read_text())


def test_demo_writes_its_outputs_and_a_reproducible_random_row(daemon: Daemon,
                                                                 tmp_path: Path) -> None:
    first = _run(tmp_path / "a")
    second = _run(tmp_path / "b")
    for name in ("student.pt", "metrics.json", "learning_curve.png", "eval.txt", "eval.mp4",
                 "eval_still.png"):
        assert (tmp_path / "a" / name).is_file(), name
    assert first["random"]["episodes"] == EPISODES
    # the random policy is seeded: two runs print the same row
    assert first["random"] == second["random"]
    table = (tmp_path / "a" / "eval.txt").read_text()
    assert "random policy (seed 0)" in table and "fused-maze" in table

    # the trained row is the saved student's own performance on the same seeds
    saved = zoo.StudentAgent.load(tmp_path / "a" / "student.pt")
    env = zoo.make_env("fused-maze", rl_obs_name=daemon.name)
    try:
        again = summarise(evaluate_agent(env, saved, EPISODES, zoo.EVAL_SEED_BASE, MAX_STEPS))
    finally:
        env.close()
    assert again == first["trained"]
