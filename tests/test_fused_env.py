"""RoverEnvFused and DiscreteRoverEnvFused against a real av-daemon subprocess."""

from __future__ import annotations

import math
import signal
import uuid
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from helpers.daemon import Daemon

import rover_env  # noqa: F401  (registers the ids)
from rover_env.discrete_env import DiscreteRoverEnvFused, decode_action
from rover_env.fused_env import RoverEnvFused
from shm_protocol import SPIN_S, SegmentNotFoundError, WriterGoneError, machine_spin

ROOT = Path(__file__).resolve().parents[1]
PI = np.float32(np.pi)


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    d = Daemon(f"test_fused_{uuid.uuid4().hex[:8]}", slots=2).start()
    yield d
    d.stop()
    d.remove_leftovers()


def _fused(daemon: Daemon, **kw: object) -> RoverEnvFused:
    kw.setdefault("world_n", "maze")
    return RoverEnvFused(rl_obs_name=daemon.name, connection_check_timeout=5, **kw)


def _discrete(daemon: Daemon, **kw: object) -> DiscreteRoverEnvFused:
    kw.setdefault("world_n", "maze")
    return DiscreteRoverEnvFused(rl_obs_name=daemon.name, connection_check_timeout=5, **kw)


# --- spaces and checkers ------------------------------------------------------------------------
def _seed_observation_space() -> spaces.Dict:
    f32 = np.float32
    return spaces.Dict(
        {
            "fused_image": spaces.Box(0.0, 1.0, shape=(96, 96, 3), dtype=f32),
            "pose": spaces.Box(
                np.array([-30, -30, -10], f32), np.array([30, 30, 10], f32), dtype=f32
            ),
            "imu": spaces.Box(np.array([-PI] * 3, f32), np.array([PI] * 3, f32), dtype=f32),
            "target": spaces.Box(np.array([0, -PI], f32), np.array([100, PI], f32), dtype=f32),
            "velocities": spaces.Box(np.array([-10, -10], f32), np.array([10, 10], f32), dtype=f32),
        }
    )


def test_spaces_equal_the_seeds(daemon: Daemon) -> None:
    with _fused(daemon) as env:
        assert env.observation_space == _seed_observation_space()
        assert env.action_space == spaces.Box(
            np.array([-0.6, -np.pi], np.float32),
            np.array([1.0, np.pi], np.float32),
            dtype=np.float32,
        )
        assert env.length == 6000 and env.reward_config.stuck_window == 5000
        assert env.reward_config.stuck_threshold == pytest.approx(0.0001)
    with _discrete(daemon) as env:
        assert env.observation_space == _seed_observation_space()
        assert env.action_space == spaces.Discrete(60)


@pytest.mark.parametrize("make", [_fused, _discrete], ids=["fused", "discrete"])
def test_gymnasium_and_sb3_checkers_pass(daemon: Daemon, make) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with make(daemon) as env:  # no report_latency: infos are deterministic
        check_env(env, skip_render_check=True)
    with make(daemon) as env:
        sb3_check_env(env, warn=False)


def test_registered_ids_make_the_envs(daemon: Daemon) -> None:
    env = gym.make("roverav/RoverEnvFusedDiscrete-v0", rl_obs_name=daemon.name, world_n="island",
                   report_latency=True)  # fmt: skip
    try:
        assert isinstance(env.unwrapped, DiscreteRoverEnvFused)
        assert env.unwrapped.world_name == "moon"
        obs, info = env.reset(seed=3)
        obs, *_, info = env.step(27)
        latency = info["frame_latency_ms"]  # asked for (wall clock, not asserted on)
        assert isinstance(latency, float) and latency > 0
        assert {"pedestrian_collision", "personal_space_intrusion", "heatmap_center"} <= info.keys()
    finally:
        env.close()


# --- the discrete action table ------------------------------------------------------------------
def test_discrete_decoding_covers_all_60_actions() -> None:
    speeds = [-0.2, 0.0, 0.3, 0.6, 1.0]
    headings = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    seen = set()
    for a in range(60):
        s, d = decode_action(a)
        assert (s, d) == (a // 12, a % 12)
        seen.add((speeds[s], round(float(headings[d]), 6)))
    assert len(seen) == 60
    s, d = decode_action(27)  # the seed's example
    assert speeds[s] == 0.3 and headings[d] == pytest.approx(-1.5708, abs=1e-4)
    assert decode_action(np.int64(59)) == (4, 11) and decode_action(np.array(0)) == (0, 0)
    for bad in (60, -1, 2.5, True, "3", np.array([1, 2])):
        with pytest.raises(ValueError):
            decode_action(bad)


def test_discrete_heading_is_absolute(daemon: Daemon) -> None:
    with _discrete(daemon) as env:
        env.reset(seed=0, options={"rover_pose": (0.0, 0.0, 1.0)})
        speed, heading = env._decode_action(27)
        assert speed == pytest.approx(0.3) and heading == pytest.approx(-np.pi / 2)
        with pytest.raises(ValueError, match="outside 0..59"):
            env.step(60)


# --- the heatmap penalty ------------------------------------------------------------------------
def _clear_view(env: RoverEnvFused, front: bool) -> None:
    """Rover at the origin facing +x; pedestrian 0 two metres ahead (or behind), the rest behind."""
    env.reset(seed=1, options={"rover_pose": (0.0, 0.0, 0.0), "goal": (-3.0, 3.0)})
    n = len(env.sim.pedestrian_positions)
    for i in range(n):
        env.sim.place_pedestrian(i, -3.0 - i, -3.0, 0.0)
    if front:
        env.sim.place_pedestrian(0, 2.0, 0.0, math.pi)


def test_heatmap_penalty_only_with_a_pedestrian_in_front(daemon: Daemon) -> None:
    with _fused(daemon) as env:
        _clear_view(env, front=True)
        _, reward, *_, info = env.step(np.zeros(2, np.float32))
        assert info["heatmap_center"] > 1.0
        assert info["reward_heatmap"] == pytest.approx(-0.1 * info["heatmap_center"])
        assert info["reward_heatmap"] < -0.1
        _clear_view(env, front=False)
        _, reward, *_, info = env.step(np.zeros(2, np.float32))
        assert info["reward_heatmap"] == pytest.approx(0.0, abs=0.05)


# --- determinism --------------------------------------------------------------------------------
def _rollout(env: RoverEnvFused, seed: int, actions: np.ndarray) -> list[dict[str, np.ndarray]]:
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, _, term, trunc, _ = env.step(a)
        out.append(obs)
        if term or trunc:
            break
    return out


def test_seeded_episodes_are_identical_fused_images_included(daemon: Daemon) -> None:
    rng = np.random.default_rng(5)
    actions = rng.uniform([-0.6, -np.pi], [1.0, np.pi], size=(40, 2)).astype(np.float32)
    with _fused(daemon) as env:
        a = _rollout(env, 11, actions)
        b = _rollout(env, 11, actions)
        c = _rollout(env, 12, actions)
    assert len(a) == len(b)
    for oa, ob in zip(a, b, strict=True):
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key], err_msg=key)
    assert not np.array_equal(a[0]["pose"], c[0]["pose"])


# --- slots --------------------------------------------------------------------------------------
def test_two_envs_on_two_slots_step_independently(daemon: Daemon) -> None:
    with _fused(daemon, slot=0) as e0, _fused(daemon, slot=1) as e1:
        o0, _ = e0.reset(seed=1)
        o1, _ = e1.reset(seed=2)
        for _ in range(5):
            o0, *_ = e0.step(np.array([1.0, 0.0], np.float32))
        for _ in range(3):
            o1, *_ = e1.step(np.array([0.0, 1.0], np.float32))
        # each env's fused image is its own camera's: compare with a solo rollout of slot 0
        assert e0.rl_obs_name == daemon.name and e1.rl_obs_name == f"{daemon.name}_1"
        assert not np.array_equal(o0["fused_image"], o1["fused_image"])
    with _fused(daemon, slot=0) as solo:
        solo.reset(seed=1)
        for _ in range(5):
            s0, *_ = solo.step(np.array([1.0, 0.0], np.float32))
    np.testing.assert_array_equal(s0["fused_image"], o0["fused_image"])


# --- failures -----------------------------------------------------------------------------------
def test_missing_daemon_is_a_descriptive_error_not_exit() -> None:
    name = f"test_nodaemon_{uuid.uuid4().hex[:8]}"
    try:
        RoverEnvFused(rl_obs_name=name, connection_check_timeout=0.2)
    except SystemExit:  # pragma: no cover - the seed's behaviour, which we replaced
        pytest.fail("RoverEnvFused called exit()")
    except SegmentNotFoundError as exc:
        text = str(exc)
        assert f"'{name}' not found" in text
        assert f"av-daemon --name {name}" in text and "rover-pair" in text
    else:
        pytest.fail("no error for a missing daemon")


def test_killed_daemon_raises_promptly_and_restart_recovers() -> None:
    d = Daemon(f"test_fusedkill_{uuid.uuid4().hex[:8]}").start()
    try:
        # With a 2 s frame timeout, a dead daemon noticed any later than that would surface
        # as FrameTimeoutError: WriterGoneError proves it is reported within 2 s.
        env = RoverEnvFused(rl_obs_name=d.name, world_n="maze", frame_timeout=2.0)
        env.reset(seed=0)
        env.step(np.zeros(2, np.float32))
        d.stop(signal.SIGKILL)
        with pytest.raises(WriterGoneError, match=d.name):
            env.step(np.zeros(2, np.float32))
        d.start()  # same name: takes over the segments left behind
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(np.zeros(2, np.float32))
        assert obs["fused_image"].shape == (96, 96, 3)
        # an orderly stop unlinks the segments; a new daemon makes new ones: re-attach
        d.stop(signal.SIGTERM)
        d.start()
        env.reset(seed=0)
        env.step(np.zeros(2, np.float32))
        env.close()
        env.close()  # twice is fine
    finally:
        d.stop()
        d.remove_leftovers()


def test_stalled_daemon_is_a_frame_timeout_and_the_env_recovers() -> None:
    from shm_protocol import FrameTimeoutError

    d = Daemon(f"test_fusedstall_{uuid.uuid4().hex[:8]}").start()
    try:
        with RoverEnvFused(rl_obs_name=d.name, world_n="maze", frame_timeout=0.5) as env:
            env.reset(seed=0)
            assert d.proc is not None
            d.proc.send_signal(signal.SIGSTOP)  # alive, but computes nothing
            try:
                with pytest.raises(FrameTimeoutError, match=d.name):
                    env.step(np.zeros(2, np.float32))
            finally:
                d.proc.send_signal(signal.SIGCONT)
            env.reset(seed=0)
            obs, *_ = env.step(np.zeros(2, np.float32))
            assert obs["fused_image"].shape == (96, 96, 3)
    finally:
        d.stop()
        d.remove_leftovers()


def test_spin_wait_decides_how_the_env_waits_for_its_frame(daemon: Daemon) -> None:
    for spin_wait, spin in ((None, machine_spin(2)), (True, SPIN_S), (False, 0.0)):
        env = _fused(daemon, spin_wait=spin_wait)
        try:
            assert env._fused is not None and env._fused.spin == spin
            env.reset(seed=0)
            env.step(env.action_space.sample())  # steps alike either way
        finally:
            env.close()
    with pytest.raises(ValueError, match="spin_wait must be True, False or None"):
        _fused(daemon, spin_wait="yes")
