"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval).

The names below are imported on first use (PEP 562), so ``import rover_train`` (and the
command lines' argument parsing) loads neither torch nor MuJoCo, and the core install never
needs Ray (``RayVecEnv``, ``rover-train --ray``).
"""

import os as _os
from importlib import import_module as _import_module
from typing import TYPE_CHECKING, Any

# A PPO update runs on every core (rover_train.threads.PhaseThreads) and rollouts on one:
# torch's OpenMP workers must sleep, not spin, between the phases and while the daemon and
# envs run (active_vision sets the same default for the daemon). Set before torch loads; an
# OMP_WAIT_POLICY set by the user wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

if TYPE_CHECKING:
    from rover_train.checkpoint import EpisodeRng, ResumeError, RunRecord, latest_checkpoint
    from rover_train.daemon_keeper import DaemonKeeper
    from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env
    from rover_train.ray_vec_env import RayVecEnv, WorkerLostError
    from rover_train.ray_worker import EnvWorker, WorkerConfig

_LAZY = {
    "EpisodeRng": "checkpoint",
    "ResumeError": "checkpoint",
    "RunRecord": "checkpoint",
    "latest_checkpoint": "checkpoint",
    "DaemonKeeper": "daemon_keeper",
    "ENV_IDS": "envs",
    "DaemonRecovery": "envs",
    "env_factory": "envs",
    "make_env": "envs",
    "EnvWorker": "ray_worker",
    "WorkerConfig": "ray_worker",
    "RayVecEnv": "ray_vec_env",  # needs Ray
    "WorkerLostError": "ray_vec_env",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:  # a submodule (``from rover_train import evaluate``) imports as usual
        raise AttributeError(f"module 'rover_train' has no attribute {name!r}")
    value = getattr(_import_module(f"rover_train.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


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
