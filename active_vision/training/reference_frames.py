"""The reference frames the daemon checks the int8 model against fp32 on.

``python -m active_vision.training.reference_frames [--out FILE]`` renders them
(:class:`~active_vision.precision.ReferenceRecipe`: ``frames_per_scene`` posed frames of each
pedestrian scene, over the worlds in turn, from ``np.random.default_rng([seed, j])``, as
:func:`~active_vision.training.dataset.render_dataset` poses them) and writes them with their
recipe to :data:`~active_vision.precision.REFERENCE_FRAMES` (compressed, about 90 kB), which
ships with the package. Posed frames rather than driving ones: each is another place, pose,
light and set of people (walking and standing in view, some at the frame's edge, and
empty views), so a few dozen cover what the network sees.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from active_vision.precision import REFERENCE_FRAMES, ReferenceRecipe
from active_vision.training.dataset import DatasetConfig, crowd_config, render_dataset

logger = logging.getLogger(__name__)


def render_reference_frames(recipe: ReferenceRecipe | None = None) -> np.ndarray:
    """The uint8 ``(N, 96, 96, 3)`` reference frames of ``recipe`` (needs MuJoCo)."""
    recipe = recipe or ReferenceRecipe()
    parts = []
    for scene in recipe.scenes:
        mode, count = crowd_config(scene)
        data = render_dataset(DatasetConfig(
            frames=recipe.frames_per_scene, seed=recipe.seed, drive_fraction=0.0,
            pedestrian_mode=mode, n_pedestrians=count), progress_every=0)
        parts.append(data.rgb)
    return np.concatenate(parts)


def write_reference_frames(path: Path | None = None,
                           recipe: ReferenceRecipe | None = None) -> Path:
    """Render the reference frames of ``recipe`` into ``path`` (default
    :data:`~active_vision.precision.REFERENCE_FRAMES`) with the recipe, atomically."""
    recipe = recipe or ReferenceRecipe()
    path = Path(path) if path is not None else REFERENCE_FRAMES
    rgb = render_reference_frames(recipe)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    try:
        np.savez_compressed(tmp, rgb=rgb, recipe=np.array(json.dumps(asdict(recipe))))
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    logger.info("wrote %d reference frames to %s (%.0f kB)", len(rgb), path,
                path.stat().st_size / 1e3)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m active_vision.training.reference_frames",
        description=f"Render the reference frames ({ReferenceRecipe()}) the daemon checks the "
                    "int8 model against fp32 on (needs MuJoCo: MUJOCO_GL=egl).")
    p.add_argument("--out", type=Path, default=REFERENCE_FRAMES,
                   help="file to write (default: %(default)s, shipped with the package)")
    p.add_argument("--log-level", default="INFO")
    a = p.parse_args(argv)
    logging.basicConfig(level=a.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    print(write_reference_frames(a.out))
    return 0


__all__ = ["render_reference_frames", "write_reference_frames"]


if __name__ == "__main__":
    raise SystemExit(main())
