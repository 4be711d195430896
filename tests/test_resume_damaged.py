"""A run survives one bad file: checkpoints and run.json written so a crash cannot tear them,
resume falling back past damaged checkpoints, and a damaged run.json a usage error.

Each test damages a copy of one real run (rover-train PPO on the LIDAR env, checkpoints at
128, 256, 384 and 512 steps) the way a crash, a power loss or a full disk would, then runs
``rover-train --resume`` on it.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest

from rover_train.checkpoint import atomic_write, durable_path

ROOT = Path(__file__).resolve().parents[1]
PPO_SMALL = ["--env", "lidar", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
             "--length", "64", "--no-progress", "--checkpoint-every", "128"]  # fmt: skip


def _train(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), MUJOCO_GL="egl")
    return subprocess.run([sys.executable, "-m", "rover_train.train", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT, env=env)  # fmt: skip


def _skips(stderr: str) -> dict[str, str]:
    """stem -> why, from the resume's warning lines."""
    return dict(re.findall(r"resume: skipping checkpoint (\S+): (.*)", stderr))


def _whole(zip_path: Path) -> bool:
    with zipfile.ZipFile(zip_path) as archive:
        return archive.testzip() is None


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("run")
    res = _train(*PPO_SMALL, "--timesteps", "512", "--logdir", str(run))
    assert res.returncode == 0, res.stdout + res.stderr
    ckdir = run / "checkpoints"
    assert sorted(p.name for p in ckdir.glob("*.zip")) == [
        f"ppo_{n}_steps.zip" for n in (128, 256, 384, 512)
    ]
    # no temporary file left behind, and each state file records its .zip's size
    assert not [p for p in run.rglob(".*.tmp")]
    for state in ckdir.glob("*.state.pkl"):
        files = pickle.loads(state.read_bytes())["files"]
        zip_name = state.name.replace(".state.pkl", ".zip")
        assert files == {zip_name: (ckdir / zip_name).stat().st_size}
    return run


@pytest.fixture
def run(finished_run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(finished_run, copy)
    return copy


def test_truncated_newest_zip_resumes_from_the_one_before(run: Path) -> None:
    newest = run / "checkpoints" / "ppo_512_steps.zip"
    size = newest.stat().st_size
    os.truncate(newest, size // 3)  # what a power loss leaves of an unsynced file
    res = _train("--resume", str(run), "--timesteps", "640", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert _skips(res.stderr) == {
        "ppo_512_steps": f"ppo_512_steps.zip is {size // 3} bytes, {size} were written: cut "
        "short (a crash, a power loss or a full disk)"
    }
    assert "ppo_384_steps.zip (384 steps): the newest checkpoint that loads (1 skipped)" in (
        res.stderr
    )
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "complete" and record["num_timesteps"] == 640
    assert [h["steps_at_start"] for h in record["history"]] == [0, 384]
    assert _whole(newest)  # the resumed run wrote its own 512-step checkpoint over it


def test_each_kind_of_damage_is_skipped_and_named(run: Path) -> None:
    ckdir = run / "checkpoints"
    # 640: a .zip whose state file was never written (the run stopped while saving)
    shutil.copy(ckdir / "ppo_512_steps.zip", ckdir / "ppo_640_steps.zip")
    # 512: a whole zip of the recorded size that SB3 cannot load
    state = pickle.loads((ckdir / "ppo_512_steps.state.pkl").read_bytes())
    with zipfile.ZipFile(ckdir / "ppo_512_steps.zip", "w") as archive:
        archive.writestr("data", "not json")
        archive.writestr("policy.pth", b"not a torch file")
    state["files"] = {"ppo_512_steps.zip": (ckdir / "ppo_512_steps.zip").stat().st_size}
    (ckdir / "ppo_512_steps.state.pkl").write_bytes(pickle.dumps(state))
    # 384: its state file cut short
    state_384 = ckdir / "ppo_384_steps.state.pkl"
    os.truncate(state_384, state_384.stat().st_size // 2)
    # 256: a checkpoint from before sizes were recorded, its .zip cut short
    state = pickle.loads((ckdir / "ppo_256_steps.state.pkl").read_bytes())
    del state["files"]
    (ckdir / "ppo_256_steps.state.pkl").write_bytes(pickle.dumps(state))
    os.truncate(ckdir / "ppo_256_steps.zip", 5000)

    res = _train("--resume", str(run), "--no-progress")
    assert res.returncode == 0, res.stderr
    skips = _skips(res.stderr)
    assert list(skips) == ["ppo_640_steps", "ppo_512_steps", "ppo_384_steps", "ppo_256_steps"]
    assert skips["ppo_640_steps"].startswith("no ppo_640_steps.state.pkl: the run stopped while")
    assert skips["ppo_512_steps"].startswith("Stable-Baselines3 cannot load ppo_512_steps.zip (")
    assert skips["ppo_384_steps"].startswith("ppo_384_steps.state.pkl cannot be read (")
    assert skips["ppo_256_steps"].startswith("ppo_256_steps.zip is not a readable zip file (")
    assert "ppo_128_steps.zip (128 steps): the newest checkpoint that loads (4 skipped)" in (
        res.stderr
    )
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "complete" and record["num_timesteps"] == 512
    assert [h["steps_at_start"] for h in record["history"]] == [0, 128]


def test_no_checkpoint_that_loads_is_a_usage_error(run: Path) -> None:
    for zip_path in (run / "checkpoints").glob("*.zip"):
        os.truncate(zip_path, 0)
    res = _train("--resume", str(run), "--no-progress")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    error = res.stderr.split("rover-train: error: ", 1)[1]
    assert error.startswith(f"--resume {run}: no checkpoint in {run / 'checkpoints'} can be "
                            "resumed from: ppo_512_steps: ppo_512_steps.zip is 0 bytes")
    assert all(f"ppo_{n}_steps: " in error for n in (128, 256, 384))
    assert "Start the run again" in error


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "timesteps"}),
         'lacks "timesteps" (the total steps requested, an integer)'),
        (lambda text: text[: len(text) // 2], "is not valid JSON ("),
        (lambda text: "", "is empty"),
        (lambda text: text.replace('"resumes": 0', '"resumes": "none"'),
         'has "resumes": "none", expected an integer'),
    ],
    ids=["missing-field", "cut-short", "empty", "wrong-type"],
)  # fmt: skip
def test_damaged_run_json_is_a_usage_error(
    run: Path, damage: Callable[[str], str], problem: str
) -> None:
    path = run / "run.json"
    path.write_text(damage(path.read_text()))
    res = _train("--resume", str(run), "--no-progress")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    error = res.stderr.split("rover-train: error: ", 1)[1]
    assert error.startswith(f"{path} {problem}")
    assert f'"args" and "timesteps_requested" in {run / "metrics.json"}' in error
    assert f"then run rover-train --resume {run} again" in error and "another --logdir" in error


# --- durable writes -------------------------------------------------------------------------
def test_durable_path_syncs_the_file_before_its_rename_and_the_directory_after(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    events: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(src: str | Path, dst: str | Path) -> None:
        events.append(("replace", f"{src} -> {dst}"))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    target = tmp_path / "run.json"
    atomic_write(target, b"{}")
    tmp = tmp_path / ".run.json.tmp"
    assert events == [("fsync", str(tmp)), ("replace", f"{tmp} -> {target}"),
                      ("fsync", str(tmp_path))]  # fmt: skip
    assert target.read_bytes() == b"{}"


def test_durable_path_keeps_the_old_file_when_writing_fails(tmp_path: Path) -> None:
    target = tmp_path / "ppo_64_steps.zip"
    target.write_bytes(b"old")
    with pytest.raises(OSError, match="disk full"), durable_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise OSError("disk full")
    assert target.read_bytes() == b"old"
    assert list(tmp_path.iterdir()) == [target]
