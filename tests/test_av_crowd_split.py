"""The perception's evaluation split among crowds: ``evaluate --pedestrian-mode
crowd --pedestrians N`` renders its driving frames with that many crowd pedestrians, caches
them under their own file name, and leaves the pacers' split and its name as they were."""

from __future__ import annotations

import argparse
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


def test_training_crowds_are_parsed_and_bad_ones_refused_with_the_fix() -> None:
    from active_vision.training.dataset import crowd_config, parse_crowds

    assert parse_crowds("pacing, crowd:3,crowd:10") == ("pacing", "crowd:3", "crowd:10")
    assert crowd_config("groups:8") == ("groups", 8)
    assert crowd_config("oblivious") == ("oblivious", None)
    for bad, named in (("walkers:3", "unknown pedestrian mode"), ("crowd:0", "1..20"),
                       ("crowd:21", "1..20"), ("crowd:x", "integer"), ("", "e.g.")):
        with pytest.raises(argparse.ArgumentTypeError, match=named):
            parse_crowds(bad)


def test_the_training_split_is_the_frames_shared_among_its_crowds(tmp_path: Path) -> None:
    from active_vision.training.train import AVNetRecipe, training_split

    recipe = AVNetRecipe(frames=25, worlds=("maze", "inspect"), crowds=("pacing", "crowd:7"))
    data = training_split(recipe, tmp_path)
    files = sorted(p.name for p in tmp_path.glob("*.npz"))
    # one cached file per scene, each from its own seed: 13 pacing frames, 12 among 7 people
    assert len(files) == 2 and "_s0_n13_" in files[0] and "_s1_n12_" in files[1]
    assert "_pcrowd7_" in files[1]
    assert len(data) == 25 and data.worlds == ("maze", "inspect")
    pacing, crowd = ds.Dataset.load(tmp_path / files[0]), ds.Dataset.load(tmp_path / files[1])
    assert np.array_equal(data.rgb[:13], pacing.rgb) and np.array_equal(data.rgb[13:], crowd.rgb)
    # driving episodes of the two scenes keep distinct numbers
    first, second = np.asarray(data.episode)[:13], np.asarray(data.episode)[13:]
    assert set(first[first >= 0]).isdisjoint(second[second >= 0])
    # a recipe of pacers alone reads the file it always read
    alone = training_split(AVNetRecipe(frames=13, worlds=("maze", "inspect")), tmp_path)
    assert np.array_equal(alone.rgb, pacing.rgb)
    assert len(list(tmp_path.glob("*.npz"))) == 2


def test_the_predictor_trains_among_its_crowds_and_evaluates_among_one(tmp_path: Path) -> None:
    from active_vision.training import predict_train as pt

    recipe = pt.PredictRecipe(episodes=5, crowds=("pacing", "crowd:6"))
    data = pt.training_sequences(recipe, tmp_path)
    names = sorted(p.name for p in tmp_path.glob("pred_*.npz"))
    # scene k from seed TRAIN_SEED + k: 3 episodes among the pacers, 2 among 6 crowd people
    assert len(names) == 2 and "_s0_e3_v" in names[0] and "_s1_e2_pcrowd6_v" in names[1]
    pacing = pt.SequenceData.load(tmp_path / names[0])
    crowd = pt.SequenceData.load(tmp_path / names[1])
    assert len(data.rgb) == len(pacing.rgb) + len(crowd.rgb)
    assert len(data.target_row) == len(pacing.target_row) + len(crowd.target_row)
    # the second scene's targets point at its own frames, after the first scene's
    shifted = data.target_row[len(pacing.target_row):]
    assert np.array_equal(data.rgb[shifted], crowd.rgb[crowd.target_row])
    assert np.all(data.episode_row[len(pacing.target_row):] >= len(pacing.rgb))
