"""The DAgger fine-tune that was the main job (`make demo-finetune` runs
``rover_train.imitation.demo`` under rover-pair): a short run against a real daemon writes
its outputs, prints the same random row twice, and its table puts the zoo entry before
fine-tuning beside the student file it leaves behind and random."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path

import cv2
import pytest
from helpers.daemon import Daemon

from rover_train import zoo
from rover_train.evaluate import evaluate_agent, summarise
from rover_train.imitation import demo
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
    # one table, three policies side by side, each on the same episodes
    table = (tmp_path / "a" / "eval.txt").read_text()
    header = next(line for line in table.splitlines() if line.startswith("| "))
    for column in ("zoo fused-maze (before)", "fine-tuned (0 steps)", "random policy (seed 0)"):
        assert column in header, table
    episodes = next(line for line in table.splitlines() if line.startswith("| episodes"))
    assert [c.strip() for c in episodes.strip("|").split("|")] == ["episodes"] + [
        str(EPISODES)] * 3  # fmt: skip
    assert first["before"]["episodes"] == first["trained"]["episodes"] == EPISODES

    # the video keeps its 1024x256 frames (four labelled panels)
    cap = cv2.VideoCapture(str(tmp_path / "a" / "eval.mp4"))
    ok, frame = cap.read()
    cap.release()
    assert ok and frame.shape == (256, 1024, 3)

    # the rows are the shipped entry's and the saved student's own performance on the seeds
    saved = zoo.StudentAgent.load(tmp_path / "a" / "student.pt")
    env = zoo.make_env("fused-maze", rl_obs_name=daemon.name)
    try:
        again = summarise(evaluate_agent(env, saved, EPISODES, zoo.EVAL_SEED_BASE, MAX_STEPS))
        shipped = summarise(evaluate_agent(env, zoo.load("fused-maze"), EPISODES,
                                           zoo.EVAL_SEED_BASE, MAX_STEPS))  # fmt: skip
    finally:
        env.close()
    assert again == first["trained"]
    assert shipped == first["before"]
