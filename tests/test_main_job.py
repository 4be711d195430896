"""The main job (`make demo` runs ``rover_train.demo`` under rover-pair): PPO from scratch on
the fused env with the camera scan against a real daemon, then a learning curve on the
evaluation episodes. A short run writes its outputs, each curve point is the checkpoint's
own performance, and running the command again continues the run instead of losing it."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.daemon import Daemon

from rover_train import demo, zoo
from rover_train.envs import make_env
from rover_train.evaluate import evaluate_agent, load_policy, summarise
from rover_train.zoo import EVAL_SEED_BASE
from shm_protocol.names import NAME_ENV_VAR, SLOTS_ENV_VAR

EPISODES = 2
MAX_STEPS = 15
STEPS = 1024  # two checkpoints of 512 steps (one env)


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_main_job_{uuid.uuid4().hex[:8]}").start()
    try:
        yield d
    finally:
        d.stop()
        d.remove_leftovers()


@pytest.fixture()
def paired(daemon: Daemon, monkeypatch: pytest.MonkeyPatch) -> Daemon:
    monkeypatch.setenv(NAME_ENV_VAR, daemon.name)  # what rover-pair sets for the demo
    monkeypatch.setenv(SLOTS_ENV_VAR, "1")
    return daemon


def _args(out: Path, *extra: str) -> list[str]:
    return ["--timesteps", str(STEPS), "--points", "2", "--episodes", str(EPISODES),
            "--max-steps", str(MAX_STEPS), "--video-episodes", "1", "--out", str(out),
            *extra]  # fmt: skip


def test_the_main_job_trains_from_scratch_and_evaluates_each_checkpoint(
    paired: Daemon, tmp_path: Path
) -> None:
    out = tmp_path / "demo"
    assert demo.main(_args(out, "--n-steps", "256")) == 0
    for name in ("curve.json", "learning_curve.png", "eval.txt", "eval.mp4", "eval_still.png",
                 "run/model.zip", "run/metrics.json"):  # fmt: skip
        assert (out / name).is_file(), name
    record = json.loads((out / "curve.json").read_text())
    curve = record["curve"]
    assert [p["steps"] for p in curve] == [0, 512, 1024]
    assert curve[0]["policy"] == "random (seed 0)"
    assert all(p["episodes"] == EPISODES for p in curve)
    metrics = json.loads((out / "run/metrics.json").read_text())
    assert metrics["timesteps"] == STEPS and metrics["args"]["camera_scan"]
    assert metrics["args"]["n_steps"] == 256  # --n-steps: the rollout per env
    assert metrics["args"]["drop_image"] and metrics["args"]["relative_table"]
    assert metrics["args"]["shield"]  # trained behind the collision shield (MaskablePPO)

    # the last point is the saved model's own performance on the same episodes, its actions
    # sampled from the same seed
    env = make_env("fused", world="inspect", name=paired.name, task="nav", camera_scan=True)
    try:
        agent = load_policy(out / "run/model.zip", env, "ppo", deterministic=False, seed=0)
        assert agent.shield is not None  # driven behind the shield it was trained behind
        again = summarise(evaluate_agent(env, agent, EPISODES, EVAL_SEED_BASE, MAX_STEPS))
    finally:
        env.close()
    assert {k: again[k] for k in ("success_rate", "collision_rate", "mean_return")} == {
        k: curve[-1][k] for k in ("success_rate", "collision_rate", "mean_return")}

    # the zoo's camera agent from the reward drove the same episodes, as the zoo drives it
    reference = record["reference"]
    assert reference["policy"] == "zoo entry rl-fused-inspect"
    assert reference["episodes"] == EPISODES
    env = make_env("fused", world="inspect", name=paired.name, task="nav", camera_scan=True)
    try:
        entry = summarise(evaluate_agent(env, zoo.load("rl-fused-inspect"), EPISODES,
                                         EVAL_SEED_BASE, MAX_STEPS))  # fmt: skip
    finally:
        env.close()
    assert entry["mean_return"] == reference["mean_return"]

    table = (out / "eval.txt").read_text()
    assert "PPO, 1,024 steps" in table and "random policy (seed 0)" in table
    assert "zoo entry rl-fused-inspect" in table
    assert "| 512 |" in table and "| 1,024 |" in table

    # the same command again continues the finished run: nothing retrained, the same curve
    assert demo.main(_args(out, "--n-steps", "256")) == 0
    assert json.loads((out / "run/metrics.json").read_text())["timesteps"] == STEPS
    assert json.loads((out / "curve.json").read_text())["curve"] == curve


def test_another_world_over_an_earlier_run_is_refused_and_keeps_it(
    paired: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "demo" / "run"
    run.mkdir(parents=True)
    saved = json.dumps({"args": {"world": "inspect"}, "timesteps": STEPS, "status": "complete",
                        "latest_checkpoint": None, "num_timesteps": 0, "resumes": 0,
                        "history": [], "tb_log_name": "ppo_fused"})  # fmt: skip
    (run / "run.json").write_text(saved)
    with pytest.raises(SystemExit) as exc:
        demo.main(_args(tmp_path / "demo", "--world", "maze"))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "holds a run in the inspect world" in err and "--world inspect" in err
    assert (run / "run.json").read_text() == saved


def test_points_spread_over_the_slots_give_the_curve_one_slot_gives(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """With several daemon slots the curve's points are evaluated at once, one worker process
    a slot; each episode is driven as on one slot, so the curve is the same."""
    d = Daemon(f"test_main_job2_{uuid.uuid4().hex[:8]}", slots=2).start()
    try:
        monkeypatch.setenv(NAME_ENV_VAR, d.name)
        monkeypatch.setenv(SLOTS_ENV_VAR, "2")
        out = tmp_path / "demo"
        assert demo.main(_args(out, "--timesteps", "2048")) == 0  # checkpoints at 1,024 and 2,048
        curve = json.loads((out / "curve.json").read_text())["curve"]
        assert len(curve) >= 3  # random and the checkpoints: all but the last in workers
        jobs = [demo.PointJob("inspect", d.name, 0, None, 0, EPISODES, MAX_STEPS)]
        jobs += [demo.PointJob("inspect", d.name, 0, str(c.model_path), 0, EPISODES, MAX_STEPS)
                 for c in demo.checkpoints(out / "run")]  # fmt: skip
        one_slot = demo.evaluate_points(jobs, 1, [], 0)
        keys = ("success_rate", "collision_rate", "mean_return")
        assert [{k: p[k] for k in keys} for p in one_slot] == [
            {k: p[k] for k in keys} for p in curve]
    finally:
        d.stop()
        d.remove_leftovers()
