"""The fused envs' heatmap reward: one function (rover_env.reward), the one the env calls."""

from __future__ import annotations

import numpy as np
import pytest

from rover_env import reward as rw
from rover_env.reward import RewardConfig


def _heat(width: int, cols: slice, value: float = 1.0, height: int = 96) -> np.ndarray:
    heat = np.zeros((height, width), dtype=np.float32)
    heat[:, cols] = value
    return heat


def test_center_sum_takes_the_seeds_four_centre_columns_of_96() -> None:
    heat = _heat(96, slice(46, 50))
    heat[:, 0] = 5.0  # outside the centre: ignored
    heat[:, 45] = 7.0  # next to it: ignored
    heat[:, 50] = 7.0
    assert rw.heatmap_center_sum(heat) == pytest.approx(96 * 4)


def test_center_columns_scale_with_the_width() -> None:
    # 4 of 96 -> 2 of 48 (columns 23, 24) and 8 of 192
    assert rw.heatmap_center_sum(_heat(48, slice(23, 25), height=48)) == pytest.approx(48 * 2)
    assert rw.heatmap_center_sum(_heat(48, slice(22, 23), height=48)) == 0.0
    assert rw.heatmap_center_sum(_heat(192, slice(92, 100))) == pytest.approx(96 * 8)
    # never fewer than one column
    assert rw.heatmap_center_sum(_heat(8, slice(3, 4), height=8), columns=1) == pytest.approx(8)


def test_penalty_is_minus_scale_times_the_sum() -> None:
    cfg = RewardConfig.fused()
    assert cfg.heatmap_center_scale == 0.1  # seed 000
    assert rw.heatmap_center_penalty(384.0, cfg) == pytest.approx(-38.4)
    assert rw.heatmap_center_penalty(0.0, cfg) == 0.0
    custom = RewardConfig.fused(heatmap_center_scale=0.5)
    assert rw.heatmap_center_penalty(10.0, custom) == pytest.approx(-5.0)


def test_the_fused_env_reward_is_these_functions_of_its_observation(shm_name: str) -> None:
    from rover_env import RoverEnvFused
    from tests.helpers.daemon import Daemon

    daemon = Daemon(shm_name).start()
    try:
        env = RoverEnvFused(world_n="maze", rl_obs_name=shm_name, report_latency=False)
        cfg = env.reward_config
        env.reset(seed=3)
        checked = 0
        for _ in range(30):
            obs, _r, term, trunc, info = env.step(np.array([0.4, 0.3], dtype=np.float32))
            center = rw.heatmap_center_sum(obs["fused_image"][:, :, 1])
            assert info["heatmap_center"] == pytest.approx(center)
            if info["reward_goal"] == 0.0 and not term:
                expected = rw.heatmap_center_penalty(center, cfg)
                assert info["reward_heatmap"] == pytest.approx(expected)
                checked += 1
            if term or trunc:
                break
        env.close()
        assert checked > 0
    finally:
        daemon.stop()
