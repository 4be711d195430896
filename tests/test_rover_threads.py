"""PhaseThreads: PPO collects rollouts on --threads torch threads and runs its gradient
epochs on --update-threads (the envs and the daemon are idle then)."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch
from stable_baselines3 import PPO

from rover_train.threads import PhaseThreads, available_cores


class _RecordThreads(gym.Wrapper):
    def __init__(self, env: gym.Env, seen: list[int]) -> None:
        super().__init__(env)
        self.seen = seen

    def step(self, action):
        self.seen.append(torch.get_num_threads())
        return self.env.step(action)


def test_ppo_rollouts_and_updates_run_on_their_own_thread_counts() -> None:
    before = torch.get_num_threads()
    in_rollout: list[int] = []
    in_update: list[int] = []
    env = _RecordThreads(gym.make("Pendulum-v1"), in_rollout)
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=2, seed=0, device="cpu")
    step = model.policy.optimizer.step

    def recording_step(*args, **kwargs):
        in_update.append(torch.get_num_threads())
        return step(*args, **kwargs)

    model.policy.optimizer.step = recording_step
    try:
        model.learn(total_timesteps=96, callback=PhaseThreads(rollout=1, update=2))
    finally:
        torch.set_num_threads(before)
    assert len(in_rollout) >= 96 and set(in_rollout) == {1}
    assert len(in_update) >= 4 and set(in_update) == {2}


def test_update_threads_default_to_the_available_cores_and_bad_counts_are_refused() -> None:
    assert PhaseThreads(rollout=1).update == available_cores() >= 1
    with pytest.raises(ValueError, match="rollout threads must be >= 1"):
        PhaseThreads(rollout=0)
