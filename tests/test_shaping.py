"""rover-train --shaping geodesic: a potential-based term on the path distance to the goal."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor

from rover_env import RoverEnv
from rover_train.envs import env_factory
from rover_train.imitation.expert import PlannerExpert
from rover_train.shaping import GeodesicShaping


def _env(gamma: float = 1.0) -> GeodesicShaping:
    return GeodesicShaping(RoverEnv(world_n="maze", pedestrian_mode="pacing", n_pedestrians=0),
                           gamma)  # fmt: skip


def test_the_terms_telescope_to_the_change_in_potential() -> None:
    """With gamma 1 the terms of a stretch without a terminal step sum to phi(end) -
    phi(start): shaping cannot be farmed by going round in circles."""
    env = _env()
    env.reset(seed=3)
    start = env.potential()
    rng = np.random.default_rng(0)
    total, plain, shaped = 0.0, 0.0, 0.0
    for _ in range(60):
        action = np.array([rng.uniform(-0.3, 0.5), rng.uniform(-1.0, 1.0)], dtype=np.float32)
        _, reward, terminated, truncated, info = env.step(action)
        assert not (terminated or truncated)
        total += info["shaping"]
        shaped += reward
        plain += reward - info["shaping"]
    assert total == pytest.approx(env.potential() - start, abs=1e-9)
    assert shaped - plain == pytest.approx(total, abs=1e-9)
    env.close()


def test_driving_along_the_path_is_paid_and_the_potential_is_the_path_length() -> None:
    env = _env(gamma=0.99)
    env.reset(seed=5)
    base = env.unwrapped
    straight = float(np.hypot(*(np.asarray(base.goal[:2]) - base.position[:2])))
    assert env.potential() <= -straight + 0.2  # a path is never shorter than the straight line
    expert = PlannerExpert("maze")
    terms = []
    for _ in range(40):
        _, _, terminated, truncated, info = env.step(expert.act_env(env))
        terms.append(info["shaping"])
        if terminated or truncated:
            break
    assert sum(terms) > 1.0  # the expert walks down the cost-to-go: the potential rises
    env.close()


def test_the_learner_sees_the_shaped_reward_and_the_monitor_the_envs() -> None:
    env = env_factory("lidar", world="maze", task="nav", shaping="geodesic", gamma=0.9)()
    assert isinstance(env, GeodesicShaping) and isinstance(env.env, Monitor)
    assert env.gamma == 0.9
    env.close()
    with pytest.raises(ValueError, match="geodesic"):
        env_factory("lidar", world="maze", shaping="euclid")()
    with pytest.raises(ValueError, match="gamma"):
        _env(gamma=0.0)
