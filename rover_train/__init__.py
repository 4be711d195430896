"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval)."""

import os as _os

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
from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env  # noqa: E402

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
