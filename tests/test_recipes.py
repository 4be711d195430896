"""Every shipped artefact carries the recipe that made it, and its maker's command line,
generated from that recipe, starts from it with ``--recipe FILE``."""

from __future__ import annotations

import dataclasses
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from active_vision.models import DEFAULT_WEIGHTS  # noqa: E402
from active_vision.onnx_export import int8_file_name, onnx_file_name  # noqa: E402
from active_vision.training import predict_train, quantize, train  # noqa: E402
from rover_train.cli import recipe_dict, recipe_from_dict  # noqa: E402

WEIGHTS_DIR = DEFAULT_WEIGHTS.parent


SHIPPED_CROWDS = ("pacing", "crowd:3", "crowd:10", "groups:8", "crossing:6", "oblivious:6")
START_WEIGHTS = WEIGHTS_DIR / "start" / "avnet.pt"
START_AVNET = train.AVNetRecipe(crowds=SHIPPED_CROWDS, depth_world_weights={"moon": 4.0},
                                threads=2, calibrate=True, max_minutes=240.0)
"""The command that made the network the shipped one was fine-tuned from (everything else at
its default): ``--crowds ... --depth-world-weights moon=4 --threads 2 --calibrate
--max-minutes 240``, from scratch."""
SHIPPED_AVNET = dataclasses.replace(
    START_AVNET, epochs=2, lr=5e-4, threads=1, max_minutes=60.0, calibrate=False, clutter=0.5,
    clutter_worlds=("moon", "maze"), init=Path("active_vision/weights/start/avnet.pt"))
"""The shipped network's command: that network fine-tuned among distractors (``--init
active_vision/weights/start/avnet.pt --epochs 2 --lr 5e-4 --threads 1 --clutter 0.5
--clutter-worlds moon,maze --max-minutes 60``, no calibration)."""

SHIPPED_PREDICT = predict_train.PredictRecipe(crowds=("pacing", "crowd:3", "crowd:10"))
"""The shipped predictor's command: ``predict_train --crowds pacing,crowd:3,crowd:10``."""


def test_the_shipped_perception_files_carry_their_recipes() -> None:
    avnet = train.read_recipe(DEFAULT_WEIGHTS)
    assert avnet == SHIPPED_AVNET
    # the file it starts from ships too, with its own recipe, so each remakes from its file
    assert avnet.init is not None and avnet.init.resolve() == START_WEIGHTS.resolve()
    assert train.read_recipe(START_WEIGHTS) == START_AVNET
    assert predict_train.read_recipe(WEIGHTS_DIR / "predict.pt") == SHIPPED_PREDICT
    assert quantize.read_recipe(WEIGHTS_DIR / int8_file_name(DEFAULT_WEIGHTS, 96)) == (
        quantize.QuantizeRecipe())
    # the exports are named for these exact weights (the recipe is part of the file)
    assert (WEIGHTS_DIR / onnx_file_name(DEFAULT_WEIGHTS, 96)).is_file()


def test_recipe_option_starts_the_command_line_from_the_file(tmp_path: Path) -> None:
    recipe, run = train._parse(["--recipe", str(DEFAULT_WEIGHTS), "--epochs", "2",
                                   "--out", str(tmp_path / "x.pt")])  # fmt: skip
    assert recipe == dataclasses.replace(SHIPPED_AVNET, epochs=2)
    assert run.out == tmp_path / "x.pt"


def test_recipes_round_trip_through_plain_data() -> None:
    r = train.AVNetRecipe(widths=(4, 8, 8, 8), worlds=("moon",), init=Path("/x/w.pt"),
                          depth_world_weights={"moon": 2.0})  # fmt: skip
    data = recipe_dict(r)
    assert data["widths"] == [4, 8, 8, 8] and data["init"] == "/x/w.pt"
    assert recipe_from_dict(train.AVNetRecipe, data) == r
    with pytest.raises(ValueError, match="no field.*teachers"):
        recipe_from_dict(train.AVNetRecipe, {**data, "teachers": []})


def test_a_weights_file_without_a_recipe_is_a_clear_error(tmp_path: Path, capsys) -> None:
    import torch

    from active_vision.models import AVNet, AVNetConfig, save_weights

    torch.manual_seed(0)
    bare = save_weights(AVNet(AVNetConfig(widths=(4, 8, 8, 8))), tmp_path / "bare.pt")
    with pytest.raises(SystemExit):
        train._parse(["--recipe", str(bare)])
    assert "holds no recipe" in capsys.readouterr().err
