"""The policy zoo: trained navigators shipped as small files, with the command that remakes each.

    from rover_train import zoo
    zoo.names()                                   # ['fused-inspect', 'fused-maze', ...]
    env = zoo.make_env("fused-maze", rl_obs_name="my_daemon", slot=0)  # kwargs override
    agent = zoo.load("fused-maze")
    obs, info = env.reset(seed=100_000)
    agent.reset()
    obs, reward, terminated, truncated, info = env.step(agent.act(obs))

Each entry is a student distilled from the privileged planner expert
(:mod:`rover_train.imitation.expert`) by DAgger
(:mod:`rover_train.imitation.distill`); ``command(name)`` is
the one command that reproduces its file. Fused entries need the daemon for their env.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym

from rover_train.zoo.agent import Agent, FeatureSpec, StudentAgent, StudentNet
from rover_train.zoo.registry import ENTRIES, EVAL_MAX_STEPS, EVAL_SEED_BASE, EntrySpec


class UnknownEntryError(KeyError):
    """A zoo name that is not in the zoo."""

    def __str__(self) -> str:
        return str(self.args[0])


def _spec(name: str) -> EntrySpec:
    try:
        return ENTRIES[name]
    except KeyError:
        raise UnknownEntryError(
            f"no zoo entry {name!r}; the zoo knows {sorted(ENTRIES)} "
            "(those shipped: rover_train.zoo.names())"
        ) from None


def names() -> list[str]:
    """The names of the shipped entries (those whose file is present), sorted."""
    return sorted(n for n, e in ENTRIES.items() if e.path.is_file())


def command(name: str) -> str:
    """The one command that remakes entry ``name``'s file from the recipe the file stores
    (``--recipe FILE``); for an entry whose file is missing, the command that makes it from
    its recipe in the lab's table."""
    spec = _spec(name)
    if not spec.path.is_file():
        return spec.command
    recipe = StudentAgent.read_meta(spec.path).get("recipe")
    if recipe is None:
        return spec.command
    path = os.path.relpath(spec.path)
    return spec.distill_command(f"--recipe {spec.path if path.startswith('..') else path}")


def make_env(name: str, **overrides: Any) -> gym.Env:
    """The env entry ``name`` was trained for (``gymnasium.make``); ``overrides`` replace or
    add constructor keywords (e.g. ``rl_obs_name``, ``slot``, ``render_mode``)."""
    import rover_env  # noqa: F401  (registers the roverav/ ids)
    from rover_train.envs import ENV_IDS

    spec = _spec(name)
    return gym.make(ENV_IDS[spec.kind], **{**spec.env_kwargs, **overrides})


def load(name: str) -> StudentAgent:
    """The agent of entry ``name``: ``agent.reset()`` per episode, ``agent.act(obs)`` (an
    :class:`Agent`; the concrete :class:`StudentAgent` also saves, fine-tunes and says
    what it is in ``meta``)."""
    spec = _spec(name)
    if not spec.path.is_file():
        raise FileNotFoundError(
            f"zoo entry {name!r} has no file at {spec.path}; make it with: {spec.command}"
        )
    return StudentAgent.load(spec.path)


__all__ = [
    "ENTRIES",
    "EVAL_MAX_STEPS",
    "EVAL_SEED_BASE",
    "Agent",
    "EntrySpec",
    "FeatureSpec",
    "StudentAgent",
    "StudentNet",
    "UnknownEntryError",
    "command",
    "load",
    "make_env",
    "names",
]
