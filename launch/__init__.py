"""Process supervision for the daemon + trainer pair (``rover-pair``)."""

from launch.run_pair import PairConfig, Supervisor, main

__all__ = ["PairConfig", "Supervisor", "main"]
