"""Keeping clear of people: ``info["contact"]`` counts a touched person, the
evaluators' headline counts it as a collision episode, and the nav task's personal-space
term works the same on the LIDAR, fused and gaze envs."""

from __future__ import annotations

import dataclasses
import math
import uuid
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from helpers.daemon import Daemon

from rover_env import RoverEnv, RoverEnvFused
from rover_env.gaze_env import RoverEnvFusedGaze
from rover_env.reward import STUCK_IN_COLLISION, RewardConfig, personal_space_penalty
from rover_train.envs import (
    NAV_CLEARANCE,
    NAV_CLEARANCE_PENALTY,
    NAV_PERSONAL_SPACE,
    NAV_PERSONAL_SPACE_PENALTY,
    env_kwargs,
    get_task,
)
from rover_train.evaluate import run_episode, summarise, summarise_scenario

PARK = np.array([0.0, 0.0], dtype=np.float32)
ROVER_AT = (-2.0, 0.5, math.pi / 2)  # moon's open ground, facing +y


class WalkerIntoRover(gym.Wrapper):
    """RoverEnv on the moon with one oblivious walker laid on an 8 m line straight through
    the parked rover: every reset (whatever the seed) sets the same scene up."""

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        kwargs["options"] = {"rover_pose": ROVER_AT, "goal": (3.0, 3.0)}
        obs, info = self.env.reset(**kwargs)
        rx, ry, _ = ROVER_AT
        crowd = self.env.unwrapped.sim.pedestrians.crowd
        crowd.lay_crossing(0, (rx - 4.0, ry), (rx + 4.0, ry), (rx - 4.0, ry), 1.2)
        return obs, info


def _walker_env(**kwargs: Any) -> WalkerIntoRover:
    return WalkerIntoRover(RoverEnv(world_n="moon", n_pedestrians=1,
                                    pedestrian_mode="oblivious", **kwargs))  # fmt: skip


def test_a_person_walking_into_the_rover_is_a_contact_but_not_a_lidar_collision() -> None:
    env = _walker_env()
    try:
        env.reset(seed=1)
        contacts, lidar_collisions = 0, 0
        for _ in range(140):
            _, _, terminated, _, info = env.step(PARK)
            assert info["contact"] == (info["pedestrian_collision"] or info["scenery_contact"])
            contacts += info["contact"]
            lidar_collisions += info["collision"]
            assert not terminated
        assert contacts > 0 and lidar_collisions == 0  # the seed's collision misses it
    finally:
        env.close()


def test_the_evaluators_headline_counts_a_touched_person_as_a_collision_episode() -> None:
    env = _walker_env()
    try:
        result = run_episode(env, lambda obs: PARK, seed=1, max_steps=140, frames=None)
    finally:
        env.close()
    assert result.pedestrian_contact and not result.seed_collision
    assert result.collided  # the headline: contact counted
    assert result.walked_into  # parked: the person walked into it
    assert summarise([result])["walked_into_rate"] == 1.0
    summary = summarise_scenario([result])
    assert summary["collision_rate"] == 1.0 and summary["seed_collision_rate"] == 0.0
    assert summary["pedestrian_contact_rate"] == 1.0
    assert summary["intimate_intrusion_rate"] == float(result.intimate_intrusion)
    lo, hi = summary["pedestrian_contact_ci95"]
    assert 0.0 < lo < 1.0 and hi == 1.0
    assert summarise([result])["collision_rate"] == 1.0


def test_the_nav_task_ends_the_episode_at_a_touched_person_and_charges_the_approach() -> None:
    env = _walker_env(**{k: v for k, v in env_kwargs("lidar", "moon", task="nav").items()
                         if k != "world_n"})  # fmt: skip
    try:
        env.reset(seed=1)
        charged = 0
        for _ in range(140):
            _, reward, terminated, _, info = env.step(PARK)
            if terminated:
                break
            d = info["min_pedestrian_distance"]
            expected = NAV_PERSONAL_SPACE_PENALTY * max(0.0, NAV_PERSONAL_SPACE - d)
            assert info["reward_personal_space"] == pytest.approx(expected)
            charged += expected < 0
            parts = sum(v for k, v in info.items() if k.startswith("reward_"))
            assert parts == pytest.approx(reward)
        assert terminated, "the walker never reached the rover"
        assert info["contact"] and info["collision"]  # the contact made it a collision step
        assert info["termination_reason"] == STUCK_IN_COLLISION
        assert charged >= 5  # paid on the approach, before the touch
    finally:
        env.close()


def test_the_term_is_off_by_default_and_checked() -> None:
    assert personal_space_penalty(0.3, RewardConfig()) == 0.0  # not in the seed
    assert not RewardConfig().contact_is_collision
    assert not RewardConfig.fused().contact_is_collision
    cfg = RewardConfig(personal_space_distance=1.2, personal_space_penalty=-1.0)
    assert personal_space_penalty(0.7, cfg) == pytest.approx(-0.5)
    assert personal_space_penalty(2.0, cfg) == 0.0
    assert personal_space_penalty(math.inf, cfg) == 0.0  # nobody in the world
    with pytest.raises(ValueError, match="personal_space_penalty is a penalty"):
        RewardConfig(personal_space_penalty=1.0)
    with pytest.raises(ValueError, match="personal_space_distance must be >= 0"):
        RewardConfig(personal_space_distance=-1.0)
    seed = env_kwargs("lidar", "moon")  # the seed's task leaves the reward alone
    assert "reward_config" not in seed
    for kind in ("lidar", "lidar-discrete", "fused", "fused-gaze", "fused-discrete",
                 "fused-gaze-discrete"):  # fmt: skip
        cfg = get_task("nav").reward_config(kind)
        assert cfg is not None and cfg.contact_is_collision
        assert cfg.personal_space_distance == NAV_PERSONAL_SPACE
        assert cfg.personal_space_penalty == NAV_PERSONAL_SPACE_PENALTY
        assert cfg.heatmap_center_scale == 0.0  # the term in its place on the fused envs


# --- the fused and gaze envs, on a real daemon ----------------------------------------------------
@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_safety_{uuid.uuid4().hex[:8]}", slots=1).start()
    yield d
    assert d.proc is not None and d.proc.poll() is None, "daemon died:\n" + "".join(d.log)
    d.stop()
    d.remove_leftovers()


@pytest.mark.parametrize("cls", [RoverEnvFused, RoverEnvFusedGaze])
def test_the_fused_envs_charge_the_nav_tasks_personal_space_wherever_the_camera_looks(
    daemon: Daemon, cls: type[RoverEnvFused]
) -> None:
    kwargs = env_kwargs("fused", "moon", task="nav")
    assert kwargs["reward_config"].clearance_penalty == 0.0  # off on the fused envs' nav task
    reward = dataclasses.replace(kwargs["reward_config"], clearance_distance=NAV_CLEARANCE,
                                 clearance_penalty=NAV_CLEARANCE_PENALTY)  # the env can pay it
    env = cls(rl_obs_name=daemon.name, connection_check_timeout=5, slot=0, world_n="moon",
              reward_config=reward, n_pedestrians=1,
              pedestrian_mode="pacing")  # fmt: skip
    try:
        rx, ry, _ = ROVER_AT
        env.reset(seed=1, options={"rover_pose": (rx, ry, 0.0), "goal": (3.0, 3.0)})
        charges = []
        clearances: list[float] = []
        for ahead, pan in ((0.9, 0.0), (0.9, 1.0), (0.6, 0.0), (3.0, 0.0)):
            env.sim.place_pedestrian(0, rx + ahead, ry, math.pi)
            action = [0.0, 0.0, pan] if cls is RoverEnvFusedGaze else [0.0, 0.0]
            if cls is not RoverEnvFusedGaze and pan:
                continue
            _, reward, terminated, _, info = env.step(np.array(action, dtype=np.float32))
            assert not terminated
            d = info["min_pedestrian_distance"]
            expected = NAV_PERSONAL_SPACE_PENALTY * max(0.0, NAV_PERSONAL_SPACE - d)
            assert info["reward_personal_space"] == pytest.approx(expected)
            assert info["reward_heatmap"] == 0.0  # the seed's heatmap term is off in the task
            lidar_min = float(env.sim.lidar(32, 12.0).min())  # the reward's, not the agent's
            assert info["reward_clearance"] == pytest.approx(
                NAV_CLEARANCE_PENALTY * max(0.0, NAV_CLEARANCE - lidar_min))
            assert "lidar" not in env.observation_space.spaces
            parts = sum(v for k, v in info.items() if k.startswith("reward_"))
            assert parts == pytest.approx(reward)
            charges.append((pan, info["reward_personal_space"]))
            clearances.append(info["reward_clearance"])
        assert charges[0][1] < 0 and charges[-1][1] == 0.0  # inside 1.2 m, then out of it
        assert min(clearances) < 0 and clearances[-1] == 0.0  # the person 0.6 m ahead
        if cls is RoverEnvFusedGaze:  # looking away does not lower it
            assert charges[1][1] == pytest.approx(charges[0][1], abs=0.02)
    finally:
        env.close()


@pytest.mark.parametrize("wrapper", ["WithPanHead", "ContactOrigins"])
@pytest.mark.parametrize(("start", "seen"), [((-4.0, 0.0), False), ((-1.0, 4.0), True)])
def test_first_contact_says_whether_the_person_was_in_view_before(
    start: tuple[float, float], seen: bool, wrapper: str
) -> None:
    """An oblivious walker walks through the parked rover from its left side (never in the
    forward camera's 90° view) or from ahead, a little left (in view from the start, 4 m off):
    the first contact (WithPanHead's, or ContactOrigins' over any env) records which, and
    where the walker was first seen."""
    from rover_train import wrappers

    rx, ry, _ = ROVER_AT
    env = getattr(wrappers, wrapper)(
        RoverEnv(world_n="moon", n_pedestrians=1, pedestrian_mode="oblivious"))
    try:
        env.reset(seed=1, options={"rover_pose": ROVER_AT, "goal": (3.0, 3.0)})
        a = (rx + start[0], ry + start[1])
        b = (rx - start[0], ry - start[1])
        env.unwrapped.sim.pedestrians.crowd.lay_crossing(0, a, b, a, 1.2)
        env.views.reset(env.unwrapped)  # the walker was elsewhere at the reset
        hold = np.zeros(env.action_space.shape, dtype=np.float32)
        for _ in range(140):
            env.step(hold)
            if env.first_contact is not None:
                break
    finally:
        env.close()
    contact = env.first_contact
    assert contact is not None and contact.seen_before is seen
    if seen:
        assert contact.first_seen is not None
        distance, bearing = contact.first_seen
        assert 3.5 < distance < 4.5 and 5.0 < bearing < 20.0  # ahead and left, where it started
    else:
        assert contact.first_seen is None
