"""Save on stop and exact resume of rover-train, with real processes and real signals.

The exact-resume test trains PPO on the LIDAR env with ``--length`` equal to ``--n-steps``,
so every rollout boundary is also an episode boundary: the episode in flight at a stop is
restarted from its start on resume, and here that start is the boundary itself. Under that
condition the resumed run must be bit-for-bit the run that never stopped.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
import zipfile
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
PPO_SMALL = ["--env", "lidar", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "2",
             "--length", "64", "--no-progress", "--checkpoint-every", "128"]  # fmt: skip


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT), MUJOCO_GL="egl")


def _train(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rover_train.train", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT, env=_env())  # fmt: skip


def _start(argv: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=ROOT, env=_env(), start_new_session=True)  # fmt: skip


def _read_until(proc: subprocess.Popen[str], pattern: str, timeout: float = 180) -> str:
    assert proc.stdout is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        seen.append(line)
        if re.search(pattern, line):
            return "".join(seen)
    os.killpg(proc.pid, signal.SIGKILL)
    pytest.fail(f"never saw {pattern!r}:\n" + "".join(seen))


def _finish(proc: subprocess.Popen[str], timeout: float = 60) -> tuple[int, str]:
    out, _ = proc.communicate(timeout=timeout)
    return proc.returncode, out


def _policy(path: Path) -> tuple[dict[str, torch.Tensor], dict]:
    with zipfile.ZipFile(path) as z:
        params = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
        optim = torch.load(io.BytesIO(z.read("policy.optimizer.pth")), weights_only=True)
    return params, optim


def _state(run: Path) -> dict:
    record = json.loads((run / "run.json").read_text())
    stem = record["latest_checkpoint"]
    return pickle.loads((run / "checkpoints" / f"{stem}.state.pkl").read_bytes())


def _tb_scalars(run: Path, tag: str) -> dict[int, float]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    steps: dict[int, float] = {}
    for events in sorted(run.glob("tb/*/events.out.tfevents.*")):
        acc = EventAccumulator(str(events))
        acc.Reload()
        for ev in acc.Scalars(tag) if tag in acc.Tags()["scalars"] else []:
            assert ev.step not in steps, f"step {ev.step} of {tag} logged twice"
            steps[ev.step] = ev.value
    return steps


@pytest.fixture(scope="module")
def straight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A PPO run of 1024 steps that never stopped (nothing may write into it)."""
    run = tmp_path_factory.mktemp("straight")
    res = _train(*PPO_SMALL, "--timesteps", "1024", "--logdir", str(run))
    assert res.returncode == 0, res.stdout + res.stderr
    return run


@pytest.mark.slow
def test_sigint_then_resume_equals_the_run_that_never_stopped(
    straight: Path, tmp_path: Path
) -> None:
    stopped = tmp_path / "stopped"
    total = "1024"
    proc = _start([sys.executable, "-m", "rover_train.train", *PPO_SMALL, "--timesteps", total,
                   "--logdir", str(stopped)])  # fmt: skip
    _read_until(proc, r"checkpoint \(periodic\) at 128 steps")
    proc.send_signal(signal.SIGINT)
    code, out = _finish(proc)
    assert code == 130, out
    assert "SIGINT received" in out and f"rover-train --resume {stopped}" in out
    record = json.loads((stopped / "run.json").read_text())
    assert record["status"] == "interrupted"
    at_stop = record["num_timesteps"]
    assert 128 <= at_stop < 1024 and at_stop % 64 == 0  # a rollout boundary
    assert not (stopped / "model.zip").exists()

    res = _train("--resume", str(stopped), "--no-progress")
    assert res.returncode == 0, res.stdout + res.stderr
    record = json.loads((stopped / "run.json").read_text())
    assert record["status"] == "complete" and record["resumes"] == 1
    assert [h["steps_at_start"] for h in record["history"]] == [0, at_stop]

    # step counts and checkpoint contents line up
    a, b = _state(straight), _state(stopped)
    assert a["num_timesteps"] == b["num_timesteps"] == 1024
    assert a["episode_log"] == b["episode_log"] and len(a["episode_log"]) == 16
    assert a["env_rng"] == b["env_rng"]
    # the parameters and the optimiser state are identical, not just close
    (pa, oa), (pb, ob) = _policy(straight / "model.zip"), _policy(stopped / "model.zip")
    assert pa.keys() == pb.keys() and all(torch.equal(pa[k], pb[k]) for k in pa)
    for sa, sb in zip(oa["state"].values(), ob["state"].values(), strict=True):
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    # one TensorBoard run whose step axis (and values) match the straight run's
    assert [p.name for p in (stopped / "tb").iterdir()] == ["ppo_lidar_1"]
    ta = _tb_scalars(straight, "rollout/ep_rew_mean")
    tb = _tb_scalars(stopped, "rollout/ep_rew_mean")
    assert sorted(ta) == sorted(tb) == list(range(64, 1025, 64))
    assert ta == tb
    metrics = json.loads((stopped / "metrics.json").read_text())
    assert metrics["timesteps"] == metrics["timesteps_requested"] == 1024
    # the training time counts both parts, the resumed one's alone is wall_time_s
    parts = [h["ended_at"] - h["started_at"] for h in record["history"]]
    assert metrics["wall_time_total_s"] == pytest.approx(sum(parts), abs=0.02)
    assert len(parts) == 2 and min(parts) > 0


def test_sigterm_to_the_process_group_saves_with_subprocess_workers(tmp_path: Path) -> None:
    # rover-pair stops a trainer with SIGTERM to its process group, and a terminal's Ctrl-C
    # reaches every process of the foreground group: the env workers get it too. They leave
    # it to the trainer, which saves and then closes them.
    proc = _start([sys.executable, "-m", "rover_train.train", *PPO_SMALL, "--timesteps",
                   "100000", "--slots", "2", "--vec-env", "subproc", "--logdir",
                   str(tmp_path)])  # fmt: skip
    _read_until(proc, r"checkpoint \(periodic\) at \d+ steps")
    workers = [int(p) for p in subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True,
                                              text=True).stdout.split()]  # fmt: skip
    os.killpg(proc.pid, signal.SIGTERM)
    code, out = _finish(proc)
    assert code == 143, out
    assert "Traceback" not in out and "EOFError" not in out and "BrokenPipe" not in out
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "interrupted" and record["num_timesteps"] > 0
    assert _state(tmp_path)["num_timesteps"] == record["num_timesteps"]
    time.sleep(0.5)
    alive = [p for p in workers if Path(f"/proc/{p}").exists()
             and Path(f"/proc/{p}/stat").read_text().split()[2] != "Z"]  # fmt: skip
    assert alive == [], f"processes of the trainer's session still alive: {alive}"


def test_resume_refuses_to_change_what_the_run_is(straight: Path, tmp_path: Path) -> None:
    before = json.loads((straight / "run.json").read_text())
    res = _train("--resume", str(straight), "--world", "maze")
    assert res.returncode == 2
    assert "--world was 'inspect'" in res.stderr and "another --logdir" in res.stderr
    assert json.loads((straight / "run.json").read_text()) == before  # refused, untouched
    res = _train("--resume", str(tmp_path / "nothing"))
    assert res.returncode == 2 and "expected a run directory" in res.stderr


def test_supervisor_giving_up_makes_the_trainer_save(tmp_path: Path) -> None:
    # a fused trainer under rover-pair that allows no restart: the daemon's crash stops the
    # run (70), and the trainer, its env waiting on the dead daemon, still writes a checkpoint
    name = f"test_resil_{uuid.uuid4().hex[:8]}"
    trainer = [sys.executable, "-m", "rover_train.train", "--env", "fused", "--timesteps",
               "100000", "--n-steps", "32", "--batch-size", "32", "--n-epochs", "1",
               "--checkpoint-every", "32", "--no-progress", "--logdir", str(tmp_path)]  # fmt: skip
    proc = _start([sys.executable, str(ROOT / "launch" / "run_pair.py"), "--name", name,
                   "--max-restarts", "0", "--daemon-arg=--threads", "--daemon-arg=1", "--",
                   *trainer])  # fmt: skip
    text = _read_until(proc, r"checkpoint \(periodic\) at \d+ steps", timeout=300)
    daemon_pid = int(re.search(r"daemon ready \(pid (\d+)\)", text).group(1))
    os.kill(daemon_pid, signal.SIGKILL)
    code, out = _finish(proc, timeout=120)
    assert code == 70, text + out
    assert "crash loop, 1 crashes" in out and "trainer stopped (status 143)" in out
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "interrupted" and record["num_timesteps"] >= 32
    assert not [p for p in os.listdir("/dev/shm") if p.startswith(name)]


def test_env_whose_first_reset_meets_a_stalled_daemon_recovers() -> None:
    # the daemon stalls between the env's construction and its first reset (a resumed run's
    # first reset during a fault): DaemonRecovery retries the reset until frames come back,
    # and the first step works (Gymnasium's passive checker used to fail it, unpacking reset
    # data it never got)
    import threading

    from active_vision.launcher import spawn_daemon
    from rover_train.envs import env_factory

    name = f"test_resil_{uuid.uuid4().hex[:8]}"
    with spawn_daemon(name, 1, extra_args=["--threads", "1"]) as daemon:
        env = env_factory("fused", world="inspect", name=name, slot=0, connect_timeout=30.0)()
        try:
            os.kill(daemon.pid, signal.SIGSTOP)
            resume = threading.Timer(4.0, os.kill, (daemon.pid, signal.SIGCONT))
            resume.start()
            obs, info = env.reset(seed=3)  # the first try times out (2 s), a retry succeeds
            resume.join()
            assert "episode_rng_state" in info
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert obs["fused_image"].shape == (96, 96, 3) and "daemon_error" not in info
        finally:
            os.kill(daemon.pid, signal.SIGCONT)
            env.close()


@pytest.fixture(scope="module")
def sac_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SAC run of 64 steps (its replay buffer in its one checkpoint); tests resume copies."""
    run = tmp_path_factory.mktemp("sac")
    sac = ["--env", "lidar", "--algo", "sac", "--learning-starts", "32", "--batch-size", "16",
           "--length", "64", "--checkpoint-every", "0", "--no-progress"]  # fmt: skip
    res = _train(*sac, "--timesteps", "64", "--logdir", str(run))
    assert res.returncode == 0, res.stdout + res.stderr
    assert [p.name for p in (run / "checkpoints").glob("*.replay.pkl")] == [
        "sac_64_steps.replay.pkl"
    ]
    return run


def test_off_policy_resume_keeps_the_replay_buffer(sac_run: Path, tmp_path: Path) -> None:
    from stable_baselines3.common.save_util import load_from_pkl

    run = shutil.copytree(sac_run, tmp_path / "run")
    res = _train("--resume", str(run), "--timesteps", "96", "--no-progress")
    assert res.returncode == 0, res.stdout + res.stderr
    state = _state(run)
    assert state["num_timesteps"] == 96 and state["replay_buffer"] == "sac_96_steps.replay.pkl"
    assert [p.name for p in (run / "checkpoints").glob("*.replay.pkl")] == [
        "sac_96_steps.replay.pkl"
    ]
    buffer = load_from_pkl(run / "checkpoints" / state["replay_buffer"])
    assert buffer.pos == 96 and not buffer.full  # 64 from the first run + 32 after the resume


def test_off_policy_resume_past_a_cut_short_replay_buffer(sac_run: Path, tmp_path: Path) -> None:
    run = shutil.copytree(sac_run, tmp_path / "run")
    replay = run / "checkpoints" / "sac_64_steps.replay.pkl"
    os.truncate(replay, replay.stat().st_size // 2)
    res = _train("--resume", str(run), "--timesteps", "96", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert re.search(r"resume: replay buffer not loaded \(sac_64_steps\.replay\.pkl is \d+ bytes, "
                     r"\d+ were written: cut short .*\): resuming with an empty one", res.stderr)
    assert [p.name for p in (run / "checkpoints").glob("*.replay.pkl")] == [
        "sac_96_steps.replay.pkl"
    ]
