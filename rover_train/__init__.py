"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval).

``RayVecEnv`` (``rover-train --ray``) is imported on first use, so the core install and
``import rover_train`` never need Ray.
"""

import os as _os
from typing import Any

# A PPO update runs on every core (rover_train.threads.PhaseThreads) and rollouts on one:
# torch's OpenMP workers must sleep, not spin, between the phases and while the daemon and
# envs run (active_vision sets the same default for the daemon). Set before torch loads; an
# OMP_WAIT_POLICY set by the user wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from rover_train.checkpoint import (  # noqa: E402
    EpisodeRng,
    ResumeError,
    RunRecord,
    latest_checkpoint,
)
from rover_train.daemon_keeper import DaemonKeeper  # noqa: E402
from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env  # noqa: E402
from rover_train.ray_worker import EnvWorker, WorkerConfig  # noqa: E402

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
    "EpisodeRng",
    "RayVecEnv",
    "ResumeError",
    "RunRecord",
    "WorkerConfig",
    "WorkerLostError",
    "env_factory",
    "latest_checkpoint",
    "make_env",
]
