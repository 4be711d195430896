"""The perception's evaluation split among crowds (issue 36): ``evaluate --pedestrian-mode
crowd --pedestrians N`` renders its driving frames with that many crowd pedestrians, caches
them under their own file name, and leaves the pacers' split and its name as they were."""

from __future__ import annotations

import json
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from active_vision.training import dataset as ds  # noqa: E402
from active_vision.training.evaluate import main as evaluate_main  # noqa: E402


def test_a_crowd_split_has_its_own_file_name() -> None:
    base = ds.DatasetConfig(frames=2700, seed=ds.HELDOUT_SEED, drive_fraction=1.0)
    crowd10 = ds.DatasetConfig(frames=2700, seed=ds.HELDOUT_SEED, drive_fraction=1.0,
                               pedestrian_mode="crowd", n_pedestrians=10)
    crowd3 = ds.DatasetConfig(frames=2700, seed=ds.HELDOUT_SEED, drive_fraction=1.0,
                              pedestrian_mode="crowd", n_pedestrians=3)
    names = {ds.dataset_path(Path("d"), c).name for c in (base, crowd10, crowd3)}
    assert len(names) == 3
    # the pacers' split keeps the name it was cached under before the option existed
    assert ds.dataset_path(Path("d"), base).name == (
        f"av_inspect-moon-maze_s{ds.HELDOUT_SEED}_n2700_96px_d100_v{ds.DATASET_VERSION}.npz")
    assert "_pcrowd10_" in ds.dataset_path(Path("d"), crowd10).name


def test_the_renderer_builds_the_crowd_it_is_given() -> None:
    r = ds.FrameRenderer("maze", ds.DatasetConfig(pedestrian_mode="crowd", n_pedestrians=7))
    try:
        assert r.n_peds == 7
    finally:
        r.close()


def test_evaluate_renders_and_reports_a_crowd_split(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert evaluate_main(["--pedestrian-mode", "crowd", "--pedestrians", "6", "--frames", "30",
                          "--data-dir", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["pedestrian_mode"] == "crowd" and out["n_pedestrians"] == 6
    files = sorted(p.name for p in tmp_path.glob("*.npz"))
    assert len(files) == 1 and "_pcrowd6_" in files[0]
    data = ds.Dataset.load(tmp_path / files[0])
    assert len(data) == 30 and np.all(data.kind == ds.KIND_DRIVING)
