"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval)."""

from rover_train.checkpoint import EpisodeRng, ResumeError, RunRecord, latest_checkpoint
from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env

__all__ = [
    "ENV_IDS",
    "DaemonRecovery",
    "EpisodeRng",
    "ResumeError",
    "RunRecord",
    "env_factory",
    "latest_checkpoint",
    "make_env",
]
