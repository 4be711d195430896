"""Process supervision for the daemon + trainer pair (``rover-pair``)."""

from launch.restart_policy import RestartDecision, RestartPolicy
from launch.run_pair import PairConfig, Supervisor, main

__all__ = ["PairConfig", "RestartDecision", "RestartPolicy", "Supervisor", "main"]
