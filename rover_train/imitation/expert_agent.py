"""The planner expert as an evaluation agent: ``rover-eval ENTRY --expert`` runs it.

:func:`teacher` is registered in ``pyproject.toml`` as the ``expert`` plugin of
``rover_train.agents.AGENT_PLUGINS``: rover-eval loads it by that name, so the product never
imports the lab.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rover_train import zoo
from rover_train.agents import AgentSource
from rover_train.imitation.distill import RECIPES
from rover_train.imitation.expert import ExpertConfig, PlannerExpert


class ExpertAgent:
    """The planner expert behind the agent interface (it reads the env's privileged state)."""

    def __init__(self, env: Any, world: str, config: ExpertConfig | None = None) -> None:
        self.env = env
        self.expert = PlannerExpert(world, config)

    def reset(self) -> None:
        self.expert.reset()

    def act(self, obs: Any) -> np.ndarray:
        del obs
        return self.expert.act_env(self.env)


def teacher(entry: str, manners: str | None = None) -> AgentSource:
    """The planner expert that teaches zoo entry ``entry`` (a fine-tuned entry's: that of the
    entry it starts from), with its pedestrian terms ``manners`` (a key of
    :data:`~rover_train.imitation.expert.MANNERS`; default: the teacher's of the entry's
    recipe). Raises ValueError for other manners, naming the choices."""
    spec = zoo.ENTRIES[entry]
    if manners is None:
        manners = RECIPES[spec.start if spec.start is not None else entry].teacher_manners
    ExpertConfig.with_manners(manners)  # unknown manners: ValueError now, naming the choices
    return AgentSource(
        f"planner expert ({manners})",
        lambda env: ExpertAgent(env, spec.world, ExpertConfig.with_manners(manners)),
    )
