"""RoverEnvDiscrete: the seed's Discrete(60) table on RoverEnv, headings relative to the yaw."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rover_env  # noqa: F401  (registers the ids)
from rover_env import RoverEnv, RoverEnvDiscrete
from rover_env.discrete_env import DIRECTION_ANGLES, SPEED_LEVELS, encode_action

STRAIGHT_ON = int(np.argmin(np.abs(DIRECTION_ANGLES)))  # direction 6: relative heading 0


def test_every_action_drives_as_the_continuous_env_with_its_table_entry() -> None:
    """A sequence over the whole table: the same seed and the decoded continuous actions
    give bit-identical observations and rewards."""
    disc = RoverEnvDiscrete(world_n="inspect", n_pedestrians=2)
    cont = RoverEnv(world_n="inspect", n_pedestrians=2)
    try:
        assert disc.action_space == gym.spaces.Discrete(60)
        od, _ = disc.reset(seed=5)
        oc, _ = cont.reset(seed=5)
        for a in np.random.default_rng(0).permutation(60):
            box = np.array([SPEED_LEVELS[a // 12], DIRECTION_ANGLES[a % 12]], np.float64)
            od, rd, td, _, _ = disc.step(int(a))
            oc, rc, tc, _, _ = cont.step(box)
            for key in oc:
                np.testing.assert_array_equal(od[key], oc[key], err_msg=key)
            assert (rd, td) == (rc, tc)
            if td:
                break
    finally:
        disc.close()
        cont.close()


def test_headings_are_relative_to_the_yaw() -> None:
    """Straight on at full speed keeps the heading whatever the yaw; a quarter-turn class
    held keeps turning the rover (a compass class, the fused discrete env's, would hold one
    heading)."""
    env = RoverEnvDiscrete(world_n="moon", n_pedestrians=0)
    try:
        for yaw in (-2.0, 0.5, 2.5):
            obs, _ = env.reset(seed=1, options={"rover_pose": (0.0, 0.0, yaw)})
            for _ in range(10):
                obs, *_ = env.step(encode_action(4, STRAIGHT_ON))
            assert abs(float(obs["imu"][2]) - yaw) < 0.15
            assert float(obs["velocities"][0]) > 0.3  # it drives, it does not spin
            turned, last = 0.0, float(obs["imu"][2])
            for _ in range(60):  # stand, heading -pi/2 relative: clockwise, on and on
                obs, *_ = env.step(encode_action(1, 3))
                turned += float(np.angle(np.exp(1j * (float(obs["imu"][2]) - last))))
                last = float(obs["imu"][2])
            assert turned < -2.0
    finally:
        env.close()


@pytest.mark.parametrize("bad", [60, -1, 1.5, "3", np.array([1, 2])])
def test_bad_actions_name_the_range(bad: object) -> None:
    env = RoverEnvDiscrete(world_n="maze", n_pedestrians=0)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="0..59|integer|one integer"):
            env.step(bad)
    finally:
        env.close()


def test_registered_id_passes_gymnasiums_checker() -> None:
    env = gym.make("roverav/RoverEnvDiscrete-v0", world_n="maze", n_pedestrians=1)
    try:
        assert isinstance(env.unwrapped, RoverEnvDiscrete)
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()
