"""Random lighting for rendered training frames, shared by the posed frames
(:mod:`active_vision.training.dataset`) and the driving ones
(:mod:`active_vision.training.driving`)."""

from __future__ import annotations

from typing import Any

import numpy as np


def random_lighting(sim: Any, rng: np.random.Generator) -> Any:
    """The world's default lights scaled by random factors (dim dusk to bright noon) with a
    random colour cast: a :class:`rover_env.simulation.Lighting` for ``sim.set_lighting``."""
    base = sim.default_lighting
    level = rng.uniform(0.35, 1.35)
    tint = 1.0 + rng.uniform(-0.15, 0.15, size=3)
    amb = rng.uniform(0.5, 1.6)
    return type(base)(
        diffuse=base.diffuse * level * tint,
        ambient=base.ambient * amb * tint,
        specular=base.specular * rng.uniform(0.3, 1.2),
        head_diffuse=base.head_diffuse * level * tint,
        head_ambient=base.head_ambient * amb * tint,
    )


__all__ = ["random_lighting"]
