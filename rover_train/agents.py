"""What drives an evaluation episode besides a trained file: a seeded random policy, and the
agents the lab plugs in (the planner expert).

Every agent is a :class:`rover_train.zoo.Agent`: ``reset()`` at each episode start, then
``act(obs)`` -> the env's action. ``zoo.load`` gives the students and the RL entries,
``rover_train.evaluate.load_policy`` a rover-train model, :class:`RandomAgent` random
actions. An :class:`AgentSource` says who is evaluated (its label in the tables) and makes
its agent for each env (``rover-eval --slots`` makes one env per daemon slot).

The planner expert (``rover-eval ENTRY --expert``) belongs to the lab
(``rover_train.imitation``), which the product never imports. The lab registers it as the
``expert`` plugin of the entry-point group :data:`AGENT_PLUGINS` (``pyproject.toml``), and
:func:`agent_plugin` loads it by that name: the product names no lab module, and without the
lab ``--expert`` says what is missing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import distributions
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from rover_train.zoo.agent import Agent


def __getattr__(name: str) -> Any:
    # re-exported on first use: rover_train.zoo.agent imports torch, which rover-eval's
    # argument parsing does without
    if name == "Agent":
        from rover_train.zoo.agent import Agent

        return Agent
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


AGENT_PLUGINS = "roverav.agents"
"""The entry-point group of the agents other packages add to rover-eval."""
EXPERT_PLUGIN = "expert"
"""The planner expert's plugin (``rover_train.imitation.expert_agent.teacher``): called with
``(entry, manners)``, it returns an :class:`AgentSource`."""


class RandomAgent:
    """Uniform random actions from a generator seeded once (the same seed, the same row)."""

    def __init__(self, action_space: Any, seed: int) -> None:
        self.space = action_space
        self.seed = seed
        self.space.seed(seed)

    def reset(self) -> None:
        return None

    def act(self, obs: Any) -> np.ndarray:
        del obs
        return self.space.sample()


@dataclass(frozen=True)
class AgentSource:
    """Who is evaluated: ``label`` (a table's title names it) and ``agent(env)``, its agent
    for one env (called once per env)."""

    label: str
    agent: Callable[[Any], Agent]


class PluginMissingError(LookupError):
    """No package registered the agent plugin asked for (the message says how to get it)."""


def agent_plugin(name: str) -> Callable[..., AgentSource]:
    """The agent maker registered as ``name`` in the :data:`AGENT_PLUGINS` entry-point
    group (loaded now, so its package is imported only when it is asked for)."""
    # Every distribution on the path, not importlib.metadata.entry_points(), which keeps
    # only the first of each name: a roverav.egg-info left in the source tree by an older
    # build shadows the installed metadata whenever the tree is on sys.path (pytest, and
    # python -m from the tree's root).
    for dist in distributions():
        for point in dist.entry_points.select(group=AGENT_PLUGINS, name=name):
            maker: Callable[..., AgentSource] = point.load()
            return maker
    raise PluginMissingError(
        f"no {name!r} agent is registered in the {AGENT_PLUGINS!r} entry points: the lab "
        "(rover_train.imitation) registers it in pyproject.toml; reinstall roverav from "
        "its source tree (pip install -e .) to get it"
    )


__all__ = [
    "AGENT_PLUGINS",
    "EXPERT_PLUGIN",
    "Agent",
    "AgentSource",
    "PluginMissingError",
    "RandomAgent",
    "agent_plugin",
]
