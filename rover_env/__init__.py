"""roverav's MuJoCo simulation and Gymnasium envs (RoverEnv, RoverEnvFused, discrete).

Importing this package sets ``MUJOCO_GL=egl`` (unless already set) before MuJoCo loads,
so rendering works headless, and registers the ``roverav/`` env ids:

- ``roverav/RoverEnv-v0``: :class:`RoverEnv` (LIDAR)
- ``roverav/RoverEnvDiscrete-v0``: :class:`RoverEnvDiscrete` (LIDAR, Discrete(60) relative)
- ``roverav/RoverEnvFused-v0``: :class:`RoverEnvFused` (needs the av-daemon)
- ``roverav/RoverEnvFusedDiscrete-v0``: :class:`DiscreteRoverEnvFused`
- ``roverav/RoverEnvFusedGaze-v0``: :class:`RoverEnvFusedGaze` (drive and pan the camera)
- ``roverav/RoverEnvFusedGazeDiscrete-v0``: :class:`DiscreteRoverEnvFusedGaze` (Discrete(180))

Episode length is the envs' own ``length`` argument (they truncate themselves), so no
``TimeLimit`` wrapper is registered. The fused ids are registered with ``slot="auto"`` (the
first daemon slot no open env holds), so ``gym.make_vec(id, num_envs=N, rl_obs_name=...)``
works in ``sync`` and ``async`` mode against ``av-daemon --slots N``; pass ``slot=i`` to
choose one.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from gymnasium.envs.registration import register, registry  # noqa: E402

from rover_env.core import RoverEnvBase  # noqa: E402
from rover_env.crowd import MAX_PEDESTRIANS, CrowdPlacementError  # noqa: E402
from rover_env.discrete_env import DiscreteRoverEnvFused  # noqa: E402
from rover_env.errors import EnvClosedError  # noqa: E402
from rover_env.fused_env import AUTO_SLOT, RoverEnvFused, served_slots  # noqa: E402
from rover_env.gaze_discrete_env import DiscreteRoverEnvFusedGaze  # noqa: E402
from rover_env.gaze_env import RoverEnvFusedGaze  # noqa: E402
from rover_env.lidar_discrete_env import RoverEnvDiscrete  # noqa: E402
from rover_env.lidar_env import RoverEnv  # noqa: E402
from rover_env.pedestrians import PEDESTRIAN_MODES, Appearance  # noqa: E402
from rover_env.readouts import (  # noqa: E402
    FORWARD_CAMERA,
    LIDAR_SCAN_LAG,
    CameraGeometry,
    ObstacleMap,
    lidar_ray_angles,
    obstacle_map,
)
from rover_env.rendering import CameraFrame  # noqa: E402
from rover_env.reward import RewardConfig  # noqa: E402
from rover_env.simulation import Contacts, Lighting, RoverSim  # noqa: E402
from rover_env.worlds import WORLD_NAMES, WorldSpec, make_world  # noqa: E402

_FUSED = {"slot": AUTO_SLOT}  # registered keywords of the fused ids
_ENVS = {
    "roverav/RoverEnv-v0": ("rover_env.lidar_env:RoverEnv", {}),
    "roverav/RoverEnvDiscrete-v0": ("rover_env.lidar_discrete_env:RoverEnvDiscrete", {}),
    "roverav/RoverEnvFused-v0": ("rover_env.fused_env:RoverEnvFused", _FUSED),
    "roverav/RoverEnvFusedDiscrete-v0": ("rover_env.discrete_env:DiscreteRoverEnvFused", _FUSED),
    "roverav/RoverEnvFusedGaze-v0": ("rover_env.gaze_env:RoverEnvFusedGaze", _FUSED),
    "roverav/RoverEnvFusedGazeDiscrete-v0": (
        "rover_env.gaze_discrete_env:DiscreteRoverEnvFusedGaze", _FUSED),
}
for _env_id, (_entry_point, _kwargs) in _ENVS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=_entry_point, kwargs=dict(_kwargs))

__all__ = [
    "AUTO_SLOT",
    "FORWARD_CAMERA",
    "LIDAR_SCAN_LAG",
    "MAX_PEDESTRIANS",
    "PEDESTRIAN_MODES",
    "WORLD_NAMES",
    "Appearance",
    "CameraFrame",
    "CameraGeometry",
    "Contacts",
    "CrowdPlacementError",
    "DiscreteRoverEnvFused",
    "DiscreteRoverEnvFusedGaze",
    "EnvClosedError",
    "Lighting",
    "ObstacleMap",
    "RewardConfig",
    "RoverEnv",
    "RoverEnvDiscrete",
    "RoverEnvBase",
    "RoverEnvFused",
    "RoverEnvFusedGaze",
    "RoverSim",
    "WorldSpec",
    "lidar_ray_angles",
    "make_world",
    "obstacle_map",
    "served_slots",
]
