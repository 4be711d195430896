"""rover-train and rover-eval: tiny real runs (lidar and fused) and their outputs."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from helpers.daemon import Daemon

from rover_train.train import TrainArgs, validate

ROOT = Path(__file__).resolve().parents[1]


def _cli(module: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env,
    )  # fmt: skip


def _check_outputs(logdir: Path, env: str) -> None:
    assert (logdir / "model.zip").stat().st_size > 1000
    assert (logdir / "learning_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = json.loads((logdir / "metrics.json").read_text())
    assert metrics["env"] == env and metrics["timesteps"] >= 256
    assert list((logdir / "tb").rglob("events.out.tfevents.*"))


@pytest.fixture(scope="module")
def lidar_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """rover-train PPO on the LIDAR env, 256 steps (nothing may write into it: tests that
    continue it work on a copy)."""
    logdir = tmp_path_factory.mktemp("lidar")
    res = _cli("rover_train.train", "--env", "lidar", "--timesteps", "256", "--n-steps", "128",
               "--logdir", str(logdir), "--no-progress", "--checkpoint-every", "128")  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    return logdir


def test_lidar_train_then_eval(lidar_run: Path) -> None:
    _check_outputs(lidar_run, "lidar")
    assert sorted(p.name for p in (lidar_run / "checkpoints").iterdir()) == [
        "ppo_128_steps.state.pkl", "ppo_128_steps.zip", "ppo_256_steps.state.pkl",
        "ppo_256_steps.zip",
    ]  # fmt: skip
    res = _cli("rover_train.evaluate", str(lidar_run / "model.zip"), "--env", "lidar",
               "--episodes", "2", "--max-steps", "30", "--json")  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    for row in (
        "success rate",
        "collision rate",
        "timeouts",
        "path length",
        "SPL",
        "mean time to goal",
        "personal-space intrusion rate",
        "min pedestrian distance",
    ):
        assert row in res.stdout  # fmt: skip
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert summary["episodes"] == 2 and summary["timeouts"] == 2


def test_resume_with_more_timesteps_extends_the_run(lidar_run: Path, tmp_path: Path) -> None:
    run = shutil.copytree(lidar_run, tmp_path / "run")  # a finished run of 256 steps
    again = _cli("rover_train.train", "--timesteps", "384", "--no-progress",
                 "--resume", str(run))  # fmt: skip
    assert again.returncode == 0, again.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["timesteps"] == 384 and metrics["args"]["n_steps"] == 128  # the run's own


def test_fused_train_then_eval_with_video(tmp_path: Path) -> None:
    d = Daemon(f"test_train_{uuid.uuid4().hex[:8]}").start()
    try:
        res = _cli("rover_train.train", "--env", "fused", "--timesteps", "256", "--n-steps", "128",
                   "--logdir", str(tmp_path), "--no-progress", "--name", d.name)  # fmt: skip
        assert res.returncode == 0, res.stdout + res.stderr
        _check_outputs(tmp_path, "fused")
        video = tmp_path / "eval.mp4"
        res = _cli("rover_train.evaluate", str(tmp_path / "model.zip"), "--env", "fused",
                   "--episodes", "1", "--max-steps", "10", "--name", d.name,
                   "--video", str(video))  # fmt: skip
        assert res.returncode == 0, res.stdout + res.stderr
        assert "success rate" in res.stdout
        import cv2

        cap = cv2.VideoCapture(str(video))
        ok, frame = cap.read()
        cap.release()
        assert ok and frame.shape[1] == 4 * frame.shape[0]  # chase view + 3 fused channels
    finally:
        d.stop()
        d.remove_leftovers()


def test_fused_without_daemon_says_how_to_start_one(tmp_path: Path) -> None:
    name = f"test_nodaemon_{uuid.uuid4().hex[:8]}"
    res = _cli("rover_train.train", "--env", "fused", "--timesteps", "64", "--logdir",
               str(tmp_path), "--name", name, "--connect-timeout", "0.2")  # fmt: skip
    assert res.returncode == 1
    assert f"av-daemon --name {name}" in res.stderr and "rover-pair" in res.stderr
    assert not (tmp_path / "model.zip").exists()


@pytest.mark.parametrize(
    ("env", "algo", "fragment"),
    [("lidar", "dqn", "--env lidar-discrete|fused-discrete"),
     ("fused-discrete", "sac", "continuous")],
)
def test_invalid_algorithm_env_pairs_are_explained(env: str, algo: str, fragment: str) -> None:
    problem = validate(TrainArgs(env=env, algo=algo))
    assert problem is not None and fragment in problem


def test_extractor_tells_a_graze_from_open_ground_and_bearings_across_pi() -> None:
    """The MLP's inputs (RoverExtractor.vector_inputs) separate a LIDAR range of 0.3 m (a
    collision) from 0.5 m by far more than the bounds scaling (0.03 over 12 m) does, and a
    target just left of straight behind from one just right of it by almost nothing."""
    import gymnasium as gym
    import numpy as np
    import torch

    import rover_env  # noqa: F401  (registers the ids)
    from rover_train.policies import PROXIMITY_M, RoverExtractor

    env = gym.make("roverav/RoverEnv-v0", world_n="maze")
    try:
        space = env.observation_space
    finally:
        env.close()
    extractor = RoverExtractor(space)
    obs = {k: np.stack([space[k].sample()] * 2) for k in space.spaces}
    obs["lidar"][0], obs["lidar"][1] = 0.3, 0.5
    obs["target"][0], obs["target"][1] = (5.0, np.pi - 1e-3), (5.0, -np.pi + 1e-3)
    x = extractor.vector_inputs({k: torch.as_tensor(v) for k, v in obs.items()}).numpy()
    n_scaled = sum(int(np.prod(s.shape)) for s in space.spaces.values())
    assert x.shape[1] == n_scaled + 32 + 3
    proximity = np.abs(x[0, n_scaled:n_scaled + 32] - x[1, n_scaled:n_scaled + 32])
    expected = np.exp(-0.3 / PROXIMITY_M) - np.exp(-0.5 / PROXIMITY_M)
    assert proximity == pytest.approx(np.full(32, expected), rel=1e-5)
    assert expected > 5 * 0.2 / 6.0  # five times the bounds scaling's gap (0.2 m of 12 m)
    assert np.allclose(x[0, -3:], x[1, -3:], atol=3e-3)  # (near distance, cos, sin) of bearing
