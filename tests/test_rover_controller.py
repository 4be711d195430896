"""HeadingPID (seed gains, simulated dt) and the reward terms."""

from __future__ import annotations

import math

import pytest

from rover_env.controller import HeadingPID, wrap_angle
from rover_env.reward import (
    RewardConfig,
    collision_penalty,
    progress_reward,
    turn_penalty,
    velocity_bonus,
)


def test_pid_has_the_seed_gains() -> None:
    pid = HeadingPID()
    assert (pid.kp, pid.ki, pid.kd, pid.max_output) == (2.0, 0.0, 0.1, 7.0)


def test_pid_output_for_known_errors() -> None:
    pid = HeadingPID(dt=0.05)
    # First update: P = 2 * 0.5, D = 0.1 * (0.5 - 0) / 0.05 = 1.0
    assert pid.update(0.5, 0.0) == pytest.approx(2.0)
    # Same error again: no derivative term
    assert pid.update(0.5, 0.0) == pytest.approx(1.0)
    # Error shrinks to 0.25: P 0.5, D 0.1 * -0.25 / 0.05 = -0.5
    assert pid.update(0.75, 0.5) == pytest.approx(0.0)


def test_pid_wraps_the_error_the_short_way() -> None:
    pid = HeadingPID(dt=0.05)
    # From 3.0 rad to -3.0 rad is +0.283 rad (through pi), not -6 rad.
    out = pid.update(-3.0, 3.0)
    error = 2 * math.pi - 6.0
    assert out == pytest.approx(2.0 * error + 0.1 * error / 0.05)
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)


def test_pid_clamps_and_resets() -> None:
    pid = HeadingPID(dt=0.05)
    assert pid.update(3.0, 0.0) == 7.0
    assert pid.update(-3.0, 0.0) == -7.0
    pid.reset()
    assert (pid.integral_error, pid.last_error) == (0.0, 0.0)


def test_pid_uses_simulated_dt() -> None:
    # The derivative term depends on dt, not on the wall clock: two controllers with the
    # same dt agree exactly however long the host takes.
    a, b = HeadingPID(dt=0.1), HeadingPID(dt=0.1)
    errors = (0.1, 0.2, 0.1)
    assert [a.update(e, 0.0) for e in errors] == [b.update(e, 0.0) for e in errors]
    assert HeadingPID(dt=0.1).update(0.1, 0.0) == pytest.approx(0.2 + 0.1)


def test_pid_rejects_bad_dt() -> None:
    with pytest.raises(ValueError, match="dt"):
        HeadingPID(dt=0.0)


def test_reward_terms_follow_the_seed_table() -> None:
    cfg = RewardConfig()
    assert progress_reward(1.0, cfg) == pytest.approx(0.3 * 1.5)
    assert velocity_bonus(1.0, cfg) == pytest.approx(0.0025)
    assert turn_penalty(-2.0, cfg) == pytest.approx(-0.003)
    assert collision_penalty(True, cfg) == -0.5 and collision_penalty(False, cfg) == 0.0
    assert (cfg.goal_reward, cfg.success_distance) == (100.0, 0.5)
    assert (cfg.stuck_penalty, cfg.general_penalty, cfg.too_far_away_penalty) == (-25, -20, -10)
    assert (cfg.stuck_window, cfg.stuck_threshold, cfg.flip_threshold) == (600, 0.001, 1.48)


def test_fused_reward_config() -> None:
    cfg = RewardConfig.fused()
    assert (cfg.stuck_window, cfg.stuck_threshold) == (5000, 0.0001)
    assert cfg.distance_delta_scale == 0.9
    assert RewardConfig.fused(stuck_window=7).stuck_window == 7


def test_reward_config_validates() -> None:
    with pytest.raises(ValueError, match="stuck_window"):
        RewardConfig(stuck_window=0)
