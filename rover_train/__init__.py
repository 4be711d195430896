"""Training and evaluation of roverav policies with Stable-Baselines3 (rover-train, rover-eval)."""

from rover_train.envs import ENV_IDS, DaemonRecovery, env_factory, make_env

__all__ = ["ENV_IDS", "DaemonRecovery", "env_factory", "make_env"]
