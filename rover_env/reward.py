"""RewardConfig (every reward and termination constant a user can override) and the terms.

Defaults are RoverEnv's seed values; :meth:`RewardConfig.fused` gives the fused envs'.
Override any field with ``dataclasses.replace(RewardConfig(), stuck_window=50)`` or by
constructing ``RewardConfig(stuck_window=50)`` and passing it as ``reward_config=``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fused_image import FUSED_SIZE
from rover_env import constants as c
from rover_env import rover

# termination_reason values (info["termination_reason"]; "" while the episode runs)
FLIPPED = "flipped"
STUCK = "stuck"
STUCK_IN_COLLISION = "stuck_in_collision"
OUT_OF_BOUNDS = "out_of_bounds"
TIME_LIMIT = "time_limit"  # truncation, not termination
GOAL = "goal"  # success: ends the episode only with the env option goal_ends_episode=True

# RewardConfig.pedestrian_penalty_frame values
IMAGE_FRAME = "image"
HEADING_FRAME = "heading"
PENALTY_FRAMES = (IMAGE_FRAME, HEADING_FRAME)

# The pedestrians as heading_center_sum sees them: upright boards facing the camera
PEDESTRIAN_HALF_WIDTH = 0.25  # m: torso (0.17 m) and an arm
PEDESTRIAN_HEIGHT = 1.71  # m: the top of the head
PEDESTRIAN_FILL = 0.6
"""Share of its board's pixels a figure covers (legs and arms leave gaps): fitted so that
:func:`heading_center_sum` over 150 random placements 1-6 m ahead in the inspect world
equals the true pedestrian mask's centre-column sum (correlation 0.86)."""
CAMERA_HEIGHT = rover.REST_HEIGHT + rover.CAMERA_Z  # m above flat ground
_MIN_DEPTH = 0.05  # m: nearer than this (or behind) a pedestrian is not in front of the camera


@dataclass(frozen=True)
class RewardConfig:
    """Reward and termination constants (seed names in brackets where they differ)."""

    success_distance: float = c.SUCCESS_DISTANCE
    """Goal reached below this distance (m)."""
    goal_reward: float = c.GOAL_REWARD
    """Reward for reaching a goal; a new goal is sampled and the episode continues (or,
    with the env option ``goal_ends_episode=True``, the episode ends there)."""
    min_goal_distance: float = 1.0
    """New goals are resampled until at least this far from the rover (m). Not in the seed
    (which could place a goal under the rover for a free +100); 0 restores the seed."""
    collision_distance: float = c.COLLISION_DISTANCE
    """A step is a collision when the LIDAR minimum is below this (m)."""
    collision_penalty: float = c.COLLISION_PENALTY
    """Per collision step."""
    clearance_distance: float = 0.0
    """LIDAR envs: a step whose LIDAR minimum lies below this (m) pays ``clearance_penalty``
    per metre inside it. Not in the seed (0: no term); the nav task (rover_train) sets it,
    so that RL learns to keep off the panels before it touches one."""
    clearance_penalty: float = 0.0
    """Per metre of the LIDAR minimum inside ``clearance_distance``, per step (negative)."""
    clearance_footprints: bool = False
    """Measure the clearance term from the world's obstacle footprints too: the rover
    centre's distance to the nearest footprint where that is nearer than the LIDAR minimum.
    A footprint covers what the LIDAR's plane (0.30 m up) passes under: the inspect world's
    panels overhang their plinths from 0.45 m up, and the rover's body touches them while the
    LIDAR still reads their plinth 0.3 m or more away. The simulator's map, never an input."""
    personal_space_distance: float = 0.0
    """Every env: a step whose nearest pedestrian stands closer than this (m, rover centre to
    person centre on the ground) pays ``personal_space_penalty`` per metre inside it. Not in
    the seed (0: no term); the nav task (rover_train) sets it to the personal space, 1.2 m.
    It reads the simulator's pedestrian positions, not the agent's observation: a reward is
    the trainer's signal, so a camera agent cannot lower it by looking away."""
    personal_space_penalty: float = 0.0
    """Per metre of the nearest pedestrian inside ``personal_space_distance``, per step
    (negative): the charge grows as the person nears contact."""
    contact_is_collision: bool = False
    """True: a step in which the rover's body touches a pedestrian or the scenery
    (``info["contact"]``) counts as a collision step too (the penalty, and the
    stuck-in-collision count that ends the episode at ``collision_limit``). The seed's LIDAR
    envs count only the LIDAR minimum, which misses a person touching the rover's side; the
    fused envs count contacts already. The nav task sets it."""
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
    pedestrian_penalty_frame: str = IMAGE_FRAME
    """Fused envs: which way the heatmap term looks for pedestrians. ``image`` (the seed's):
    the centre columns of the fused image's heatmap, wherever the camera points, so a gaze
    agent lowers the penalty by looking away from a pedestrian; ``heading``: the same sum
    for a camera facing along the rover's heading, from the pedestrians' true positions
    (:func:`heading_center_sum`), so where the camera looks does not change it."""
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
        for name in ("clearance_penalty", "personal_space_penalty"):
            if getattr(self, name) > 0:
                raise ValueError(f"{name} is a penalty: it must be <= 0, got "
                                 f"{getattr(self, name)}")
        for name in ("success_distance", "stuck_threshold", "collision_distance",
                     "clearance_distance", "personal_space_distance"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.pedestrian_penalty_frame not in PENALTY_FRAMES:
            raise ValueError(
                f"pedestrian_penalty_frame must be one of {PENALTY_FRAMES}, got "
                f"{self.pedestrian_penalty_frame!r}"
            )

    @classmethod
    def fused(cls, **overrides: float | str) -> RewardConfig:
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


def clearance_penalty(nearest: float, cfg: RewardConfig) -> float:
    """``clearance_penalty`` times the metres by which the LIDAR minimum ``nearest`` lies
    inside ``clearance_distance`` (0 outside it, and with the term off)."""
    return cfg.clearance_penalty * max(0.0, cfg.clearance_distance - nearest)


def personal_space_penalty(nearest_pedestrian: float, cfg: RewardConfig) -> float:
    """``personal_space_penalty`` times the metres by which the nearest pedestrian
    (``nearest_pedestrian`` m away, ``inf`` with none) stands inside
    ``personal_space_distance`` (0 outside it, and with the term off)."""
    if not cfg.personal_space_penalty:
        return 0.0
    return cfg.personal_space_penalty * max(0.0, cfg.personal_space_distance - nearest_pedestrian)


def heatmap_center_sum(heatmap: np.ndarray, columns: int = c.HEATMAP_CENTER_COLUMNS) -> float:
    """Sum of the centre columns of an (H, W) heatmap: ``columns`` of the seed's 96, scaled
    to the width W (``max(1, round(columns * W / 96))`` columns, centred)."""
    width = heatmap.shape[1]
    n = max(1, round(columns * width / FUSED_SIZE[1]))
    lo = (width - n) // 2
    return float(heatmap[:, lo : lo + n].sum())


def heading_center_sum(
    x: float,
    y: float,
    heading: float,
    pedestrians: np.ndarray,
    size: tuple[int, int] = FUSED_SIZE,
    columns: int = c.HEATMAP_CENTER_COLUMNS,
) -> float:
    """:func:`heatmap_center_sum` of a perfect heatmap (1 on every pedestrian pixel) seen by
    the rover's forward camera (``rover.CAMERA_X`` ahead of the rover at (x, y), its height,
    vertical field of view and pitch, frames of ``size`` (H, W)) were it facing along
    ``heading`` (rad, world frame) whatever its pan. ``pedestrians`` (P, 2) are their true
    ground positions; each is an upright ``PEDESTRIAN_HALF_WIDTH`` x ``PEDESTRIAN_HEIGHT``
    board facing the camera on flat ground, ``PEDESTRIAN_FILL`` of it covered, none hides
    another. What the seed's heatmap term charges for a pedestrian ahead when the camera
    looks ahead, in the rover's frame.
    """
    peds = np.asarray(pedestrians, dtype=np.float64).reshape(-1, 2)
    if len(peds) == 0:
        return 0.0
    height, width = size
    cos_h, sin_h = math.cos(heading), math.sin(heading)
    dx = peds[:, 0] - (x + rover.CAMERA_X * cos_h)
    dy = peds[:, 1] - (y + rover.CAMERA_X * sin_h)
    ahead = dx * cos_h + dy * sin_h  # m along the heading
    left = -dx * sin_h + dy * cos_h  # m to the left of it
    front = ahead > _MIN_DEPTH
    if not front.any():
        return 0.0
    ahead, left = ahead[front], left[front]
    focal = 0.5 * height / math.tan(math.radians(rover.CAMERA_FOVY) / 2)  # px
    # columns, from the image centre (right positive): the centre strip and each board
    n = max(1, round(columns * width / FUSED_SIZE[1]))
    lo = (width - n) // 2 - 0.5 * width
    x0 = -focal * (left + PEDESTRIAN_HALF_WIDTH) / ahead
    x1 = -focal * (left - PEDESTRIAN_HALF_WIDTH) / ahead
    cols = np.clip(np.minimum(x1, lo + n) - np.maximum(x0, lo), 0.0, None)
    # rows of the board's centre line (up positive), the camera pitched down
    pitch = math.radians(rover.CAMERA_PITCH)
    cos_p, sin_p = math.cos(pitch), math.sin(pitch)

    def row(z: float) -> np.ndarray:
        depth = ahead * cos_p - z * sin_p
        up = ahead * sin_p + z * cos_p
        return np.clip(focal * up / np.maximum(depth, 1e-9), -0.5 * height, 0.5 * height)

    rows = row(PEDESTRIAN_HEIGHT - CAMERA_HEIGHT) - row(-CAMERA_HEIGHT)
    return float(min(PEDESTRIAN_FILL * (cols * rows).sum(), n * height))


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
