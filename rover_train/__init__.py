"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval).

``RayVecEnv`` (``rover-train --ray``) is imported on first use, so the core install and
``import rover_train`` never need Ray.
"""

from typing import Any

from rover_train.daemon_keeper import DaemonKeeper
from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env
from rover_train.ray_worker import EnvWorker, WorkerConfig

_NEEDS_RAY = ("RayVecEnv", "WorkerLostError")


def __getattr__(name: str) -> Any:
    if name in _NEEDS_RAY:
        from rover_train import ray_vec_env

        return getattr(ray_vec_env, name)
    raise AttributeError(f"module 'rover_train' has no attribute {name!r}")


__all__ = [
    "ENV_IDS",
    "DaemonKeeper",
    "DaemonRecovery",
    "EnvWorker",
    "RayVecEnv",
    "WorkerConfig",
    "WorkerLostError",
    "env_factory",
    "make_env",
]
