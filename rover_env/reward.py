"""RewardConfig (every reward and termination constant a user can override) and the terms.

Defaults are RoverEnv's seed values; :meth:`RewardConfig.fused` gives the fused envs'.
Override any field with ``dataclasses.replace(RewardConfig(), stuck_window=50)`` or by
constructing ``RewardConfig(stuck_window=50)`` and passing it as ``reward_config=``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fused_image import FUSED_SIZE
from rover_env import constants as c

# termination_reason values (info["termination_reason"]; "" while the episode runs)
FLIPPED = "flipped"
STUCK = "stuck"
STUCK_IN_COLLISION = "stuck_in_collision"
OUT_OF_BOUNDS = "out_of_bounds"
TIME_LIMIT = "time_limit"  # truncation, not termination


@dataclass(frozen=True)
class RewardConfig:
    """Reward and termination constants (seed names in brackets where they differ)."""

    success_distance: float = c.SUCCESS_DISTANCE
    """Goal reached below this distance (m)."""
    goal_reward: float = c.GOAL_REWARD
    """Reward for reaching a goal; a new goal is sampled and the episode continues."""
    min_goal_distance: float = 1.0
    """New goals are resampled until at least this far from the rover (m). Not in the seed
    (which could place a goal under the rover for a free +100); 0 restores the seed."""
    collision_distance: float = c.COLLISION_DISTANCE
    """A step is a collision when the LIDAR minimum is below this (m)."""
    collision_penalty: float = c.COLLISION_PENALTY
    """Per collision step."""
    distance_delta_scale: float = c.DISTANCE_DELTA_SCALE
    """Progress reward per metre closer to the goal (seed: 0.3 * 1.5; fused: 0.9)."""
    linear_velocity_scale: float = c.LINEAR_VELOCITY_SCALE
    """Reward per m/s of wheel-odometry forward speed."""
    turn_penalty_scale: float = c.TURN_PENALTY_SCALE
    """Penalty per rad/s of wheel-odometry yaw rate (applied as -scale * |rate|)."""
    heatmap_center_scale: float = c.HEATMAP_CENTER_SCALE
    """Fused envs: penalty per unit of pedestrian heatmap in the centre columns."""
    heatmap_center_columns: int = c.HEATMAP_CENTER_COLUMNS
    """Fused envs: how many centre columns of the heatmap count."""
    pan_penalty: float = c.PAN_PENALTY
    """Gaze envs: cost of one discrete camera pan move (subtracted from the reward)."""
    flip_threshold: float = c.FLIP_THRESHOLD
    """|roll| or |pitch| above this (rad) ends the episode with ``general_penalty``."""
    stuck_window: int = c.STUCK_WINDOW
    """Steps over which the rover must move at least ``stuck_threshold``."""
    stuck_threshold: float = c.STUCK_THRESHOLD
    """Metres; less displacement over ``stuck_window`` steps ends the episode."""
    stuck_penalty: float = c.STUCK_PENALTY
    """[stuck_penilty]."""
    collision_limit: int = c.STUCK_WINDOW
    """More collision steps than this in an episode ends it (the seed compares its
    collision_count with stuck_window)."""
    general_penalty: float = c.GENERAL_PENALTY
    """[general_penility] flip and stuck-in-collision."""
    too_far_away_penalty: float = c.TOO_FAR_AWAY_PENALTY
    """[too_far_away_penilty] leaving the world's out-of-bounds rectangle."""

    def __post_init__(self) -> None:
        if self.stuck_window < 1:
            raise ValueError(f"stuck_window must be >= 1 step, got {self.stuck_window}")
        if self.collision_limit < 0:
            raise ValueError(f"collision_limit must be >= 0, got {self.collision_limit}")
        for name in ("success_distance", "stuck_threshold", "collision_distance"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")

    @classmethod
    def fused(cls, **overrides: float) -> RewardConfig:
        """The fused envs' values (seeds 000/002): stuck window 5000 steps / 0.0001 m,
        progress scale 0.9; ``overrides`` replace any field."""
        values: dict = {
            "stuck_window": c.FUSED_STUCK_WINDOW,
            "stuck_threshold": c.FUSED_STUCK_THRESHOLD,
            "collision_limit": c.FUSED_STUCK_WINDOW,
            "distance_delta_scale": c.FUSED_DISTANCE_DELTA_SCALE,
        }
        values.update(overrides)
        return cls(**values)


# --- reward terms ------------------------------------------------------------------------------
def goal_reward(reached: bool, cfg: RewardConfig) -> float:
    return cfg.goal_reward if reached else 0.0


def progress_reward(distance_delta: float, cfg: RewardConfig) -> float:
    """``distance_delta`` (m closer to the goal this step) times the progress scale."""
    return distance_delta * cfg.distance_delta_scale


def velocity_bonus(linear_velocity: float, cfg: RewardConfig) -> float:
    return linear_velocity * cfg.linear_velocity_scale


def turn_penalty(angular_velocity: float, cfg: RewardConfig) -> float:
    return -cfg.turn_penalty_scale * abs(angular_velocity)


def collision_penalty(collided: bool, cfg: RewardConfig) -> float:
    return cfg.collision_penalty if collided else 0.0


def heatmap_center_sum(heatmap: np.ndarray, columns: int = c.HEATMAP_CENTER_COLUMNS) -> float:
    """Sum of the centre columns of an (H, W) heatmap: ``columns`` of the seed's 96, scaled
    to the width W (``max(1, round(columns * W / 96))`` columns, centred)."""
    width = heatmap.shape[1]
    n = max(1, round(columns * width / FUSED_SIZE[1]))
    lo = (width - n) // 2
    return float(heatmap[:, lo : lo + n].sum())


def heatmap_center_penalty(center_sum: float, cfg: RewardConfig) -> float:
    """Fused envs' heatmap term: ``-heatmap_center_scale * center_sum`` (seed 000), where
    ``center_sum`` is :func:`heatmap_center_sum` of the fused image's channel 1."""
    return -cfg.heatmap_center_scale * center_sum


def termination_penalty(reason: str, cfg: RewardConfig) -> float:
    """The seed's terminal reward for ``reason`` (0 for anything else)."""
    if reason in (FLIPPED, STUCK_IN_COLLISION):
        return cfg.general_penalty
    if reason == STUCK:
        return cfg.stuck_penalty
    if reason == OUT_OF_BOUNDS:
        return cfg.too_far_away_penalty
    return 0.0
