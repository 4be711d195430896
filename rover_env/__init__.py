"""roverav's MuJoCo simulation and Gymnasium envs (RoverEnv, RoverEnvFused, discrete).

Importing this package sets ``MUJOCO_GL=egl`` (unless already set) before MuJoCo loads,
so rendering works headless, and registers the ``roverav/`` env ids.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from rover_env.simulation import CameraFrame, Contacts, RoverSim  # noqa: E402
from rover_env.worlds import WORLD_NAMES, WorldSpec, make_world  # noqa: E402

__all__ = ["WORLD_NAMES", "CameraFrame", "Contacts", "RoverSim", "WorldSpec", "make_world"]
