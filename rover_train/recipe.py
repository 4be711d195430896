"""A trained model's recipe: the rover-train arguments that made it, stored inside its .zip.

``rover-train`` writes them into every finished run's ``model.zip`` (a member that
Stable-Baselines3 ignores), so a model copied anywhere (a zoo RL entry) still says how it
was made, and ``rover-train --recipe FILE`` trains it again.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

RECIPE_MEMBER = "rover_train_args.json"
"""The member of a model .zip that holds the arguments of the run that made it."""
OPERATIONAL_FIELDS = ("name", "log_level", "progress", "device", "threads", "update_threads",
                      "connect_timeout", "vec_env")  # fmt: skip
"""rover-train arguments that say how a machine runs the run, not what it trains."""


class RecipeError(ValueError):
    """A file that holds no rover-train recipe (the message names the file and the fix)."""


RENAMED_FIELDS = {"workers": "ray_workers"}
"""Old ``TrainArgs`` field -> its name now (rover-train's ``--workers`` became
``--ray-workers``: ``--workers`` is the daemon's serving threads)."""


def stored_args(args: dict[str, Any]) -> dict[str, Any]:
    """Run arguments as an artefact stored them (a model's recipe, a run's ``run.json``),
    in today's names: renamed fields (:data:`RENAMED_FIELDS`) and env kinds
    (``rover_train.zoo.registry.RENAMED_KINDS``: ``discrete`` is ``fused-discrete``)."""
    from rover_train.zoo.registry import stored_kind

    out = {RENAMED_FIELDS.get(k, k): v for k, v in args.items()}
    if isinstance(out.get("env"), str):
        out["env"] = stored_kind(out["env"])
    return out


NOT_RECIPE = ("resume", "recipe", "logdir", *OPERATIONAL_FIELDS)
"""Fields a recipe leaves out: where the run came from and where it writes, and how a machine
runs it."""


def recipe_of(args: dict[str, Any]) -> dict[str, Any]:
    """The recipe in a run's arguments (``TrainArgs`` as plain JSON): all but
    :data:`NOT_RECIPE`."""
    return {k: v for k, v in args.items() if k not in NOT_RECIPE}


def write_recipe(model_zip: Path, args: dict[str, Any]) -> None:
    """Store the recipe of ``args`` (a run's arguments as plain JSON) in ``model_zip``. A
    checkpoint's recipe is its run's: the model it holds is that run's at its step count."""
    with zipfile.ZipFile(model_zip, "a") as archive:
        archive.writestr(RECIPE_MEMBER, json.dumps(recipe_of(args), indent=2))


def read_recipe(model_zip: Path) -> dict[str, Any]:
    """The run arguments :func:`write_recipe` stored in ``model_zip``."""
    try:
        with zipfile.ZipFile(model_zip) as archive:
            data = json.loads(archive.read(RECIPE_MEMBER))
    except FileNotFoundError:
        raise RecipeError(f"{model_zip}: no such file") from None
    except (zipfile.BadZipFile, KeyError, ValueError) as exc:
        raise RecipeError(
            f"{model_zip} is not a model .zip with a rover-train recipe ({exc}); give a zoo RL "
            "entry (rover_train/zoo/entries/rl-*.zip) or the model.zip of a finished run"
        ) from None
    if not isinstance(data, dict):
        raise RecipeError(f"{model_zip}: its {RECIPE_MEMBER} is not a JSON object")
    return stored_args(data)
