"""Process supervision for the daemon + trainer pair (``rover-pair``)."""

from launch.run_pair import PairConfig, Supervisor, main, segment_names

__all__ = ["PairConfig", "Supervisor", "main", "segment_names"]
