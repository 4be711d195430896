"""Gymnasium's own tools on every roverav/ id: check_env, and make_vec (sync and async) over
the daemon's slots with slot="auto" (real av-daemon, real shared memory)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers.daemon import Daemon

import rover_env
from rover_env import AUTO_SLOT, RoverEnvFused, served_slots
from shm_protocol import SegmentBusyError

ROVERAV_IDS = sorted(i for i in gym.registry if i.startswith("roverav/"))
LIDAR_IDS = ("roverav/RoverEnv-v0", "roverav/RoverEnvDiscrete-v0")
FUSED_IDS = [i for i in ROVERAV_IDS if i not in LIDAR_IDS]
SLOTS = 2


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_gymapi_{uuid.uuid4().hex[:8]}", slots=SLOTS).start()
    yield d
    d.stop()
    d.remove_leftovers()


def _kwargs(env_id: str, daemon: Daemon) -> dict[str, object]:
    kw: dict[str, object] = {"world_n": "maze"}
    if env_id in FUSED_IDS:
        kw.update(rl_obs_name=daemon.name, connection_check_timeout=5)
    return kw


def test_every_roverav_id_is_tested() -> None:
    assert len(ROVERAV_IDS) == 6 and set(LIDAR_IDS) <= set(ROVERAV_IDS)
    for env_id in LIDAR_IDS:
        assert gym.spec(env_id).kwargs == {}  # no daemon, no slot
    for env_id in FUSED_IDS:
        assert gym.spec(env_id).kwargs == {"slot": AUTO_SLOT}


@pytest.mark.parametrize("env_id", ROVERAV_IDS)
def test_check_env_passes(daemon: Daemon, env_id: str) -> None:
    env = gym.make(env_id, **_kwargs(env_id, daemon))
    try:
        check_env(env.unwrapped, skip_render_check=True)
        check_env(env, skip_render_check=True)  # through gym.make's wrappers too
        _, info = env.reset(seed=0)
        _, *_, info = env.step(env.action_space.sample())
        assert "frame_latency_ms" not in info  # wall clock: only when asked for
    finally:
        env.close()


def test_served_slots_counts_the_daemons_slots(daemon: Daemon) -> None:
    assert served_slots(daemon.name) == SLOTS
    assert served_slots(f"test_gymapi_none_{uuid.uuid4().hex[:8]}") == 0


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_takes_one_slot_per_env(daemon: Daemon, mode: str) -> None:
    # This process has rendered already (the tests above), and the async workers start with
    # the default context: rendering made it forkserver, as a forked child could not render.
    envs = gym.make_vec("roverav/RoverEnvFused-v0", num_envs=SLOTS, vectorization_mode=mode,
                        **_kwargs("roverav/RoverEnvFused-v0", daemon))  # fmt: skip
    try:
        assert sorted(envs.get_attr("slot")) == list(range(SLOTS))
        obs, _ = envs.reset(seed=1)  # env i is seeded 1 + i
        first = obs["fused_image"].copy()
        assert first.shape == (SLOTS, 96, 96, 3)
        assert not np.array_equal(first[0], first[1])
        for _ in range(3):
            obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert obs["fused_image"].shape == (SLOTS, 96, 96, 3) and reward.shape == (SLOTS,)
        assert not np.array_equal(obs["fused_image"][0], obs["fused_image"][1])
        assert not np.array_equal(obs["pose"][0], obs["pose"][1])
    finally:
        envs.close()
    # each env saw its own camera: a lone env with env 1's seed sees env 1's first image
    with RoverEnvFused(slot=AUTO_SLOT, **_kwargs("roverav/RoverEnvFused-v0", daemon)) as solo:
        solo_obs, _ = solo.reset(seed=2)
    np.testing.assert_array_equal(solo_obs["fused_image"], first[1])


def test_auto_slot_with_every_slot_taken_says_what_to_do(daemon: Daemon) -> None:
    kw = _kwargs("roverav/RoverEnvFused-v0", daemon)
    with RoverEnvFused(slot=AUTO_SLOT, **kw) as e0, RoverEnvFused(slot=AUTO_SLOT, **kw) as e1:
        assert (e0.slot, e1.slot) == (0, 1)
        assert e1.rl_obs_name == f"{daemon.name}_1"
        with pytest.raises(SegmentBusyError) as err:
            RoverEnvFused(slot=AUTO_SLOT, **kw)
    msg = str(err.value)
    assert "no free slot" in msg and f"{SLOTS} slot(s)" in msg and daemon.name in msg
    assert f"--slots {SLOTS + 1}" in msg and "close an env" in msg
    # a closed env's slot is free again
    with RoverEnvFused(slot=AUTO_SLOT, **kw) as again:
        assert again.slot == 0


def test_rover_env_exports_the_slot_api() -> None:
    assert rover_env.AUTO_SLOT == "auto" and callable(rover_env.served_slots)
