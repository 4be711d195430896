"""Torch threads per phase of on-policy training.

An on-policy run alternates two phases with opposite needs on a small machine:

- **rollout**: one batch-1 policy forward per env step, while the env renders and the
  av-daemon runs its network on the other cores. More torch threads here only fight those
  processes for the cores (and a batch-1 forward of this policy does not split well).
- **update**: the gradient epochs over the whole rollout (PPO: 10 epochs of 256-sample
  minibatches). The envs and the daemon are idle meanwhile, so every core is free.

:class:`PhaseThreads` switches ``torch.set_num_threads`` at the two boundaries SB3 reports
(``on_rollout_start`` / ``on_rollout_end``). Off-policy algorithms (SAC, DQN) interleave
gradient steps with env steps and never get a free core: use one count for both.
"""

from __future__ import annotations

import logging

import torch
from stable_baselines3.common.callbacks import BaseCallback

from shm_protocol import available_cores

log = logging.getLogger(__name__)


class PhaseThreads(BaseCallback):
    """``rollout`` torch threads while collecting, ``update`` threads for the gradient epochs.

    :param rollout: threads while the envs step (the trainer's ``--threads``).
    :param update: threads for the update; 0 means :func:`available_cores`.
    """

    def __init__(self, rollout: int = 1, update: int = 0) -> None:
        super().__init__()
        if rollout < 1 or update < 0:
            raise ValueError(f"rollout threads must be >= 1 and update threads >= 0 (0: all "
                             f"cores), got rollout={rollout}, update={update}")
        self.rollout = rollout
        self.update = update or available_cores()

    def _on_training_start(self) -> None:
        log.info("torch threads: %d while collecting rollouts, %d for the updates",
                 self.rollout, self.update)

    def _on_rollout_start(self) -> None:
        torch.set_num_threads(self.rollout)

    def _on_rollout_end(self) -> None:
        torch.set_num_threads(self.update)

    def _on_step(self) -> bool:
        return True


__all__ = ["PhaseThreads", "available_cores"]
