"""The algorithms rover-train trains and rover-eval loads, by name.

``recurrent-ppo`` is sb3-contrib's ``RecurrentPPO`` with its ``MultiInputLstmPolicy`` (an
LSTM over the ``RoverExtractor`` features, for the Dict observations); ``ppo`` trained behind
the collision shield (``rover-train --shield``) is sb3-contrib's ``MaskablePPO``, the shield's
mask applied to the policy in the rollouts and the updates; the others are
Stable-Baselines3's own. Both packages come with ``pip install 'roverav[train]'``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

ALGOS = ("ppo", "recurrent-ppo", "sac", "dqn")
ON_POLICY = ("ppo", "recurrent-ppo")
"""Rollout-and-update algorithms (``--n-steps``, ``--n-epochs``, ...)."""
RECURRENT = ("recurrent-ppo",)
"""Algorithms whose policy carries a state from step to step (reset at episode starts)."""
_POLICIES = {"recurrent-ppo": "MultiInputLstmPolicy"}
DEFAULT_POLICY = "MultiInputPolicy"
CONTRIB_PACKAGE = "sb3_contrib"
CONTRIB_INSTALL = "pip install -c constraints.txt 'roverav[train]' (it brings sb3-contrib)"


def policy_name(algo: str) -> str:
    """The SB3 policy ``algo`` is built with for the roverav Dict observations."""
    return _POLICIES.get(algo, DEFAULT_POLICY)


def contrib_missing(algo: str, masked: bool = False) -> str | None:
    """For an algorithm from sb3-contrib that is not installed: what to do; else None."""
    import importlib.util

    if (algo in RECURRENT or masked) and importlib.util.find_spec(CONTRIB_PACKAGE) is None:
        what = f"--algo {algo}" + (" --shield" if masked else "")
        return f"{what} needs sb3-contrib, which is not installed: {CONTRIB_INSTALL}"
    return None


def algo_class(name: str, masked: bool = False) -> Any:
    """The model class of algorithm ``name`` (a member of :data:`ALGOS`); ``masked``: trained
    with an action mask (``rover-train --shield``, PPO only): sb3-contrib's ``MaskablePPO``."""
    if name not in ALGOS:
        raise ValueError(f"unknown algorithm {name!r}; choose one of {ALGOS}")
    if masked and name != "ppo":
        raise ValueError(f"an action mask is trained with ppo (MaskablePPO), not {name}")
    if name == "recurrent-ppo" or masked:
        problem = contrib_missing(name, masked)
        if problem:
            raise ImportError(problem)
        from sb3_contrib import MaskablePPO, RecurrentPPO

        return MaskablePPO if masked else RecurrentPPO
    from stable_baselines3 import DQN, PPO, SAC

    return {"ppo": PPO, "sac": SAC, "dqn": DQN}[name]


def observation_seed(seed: int, obs: Any) -> int:
    """A 63-bit seed from ``seed`` and the bytes of ``obs`` (an array or a dict of them, keys
    in order): the same observation, the same draw."""
    import hashlib

    h = hashlib.blake2b(str(seed).encode(), digest_size=8)
    items = sorted(obs.items()) if isinstance(obs, dict) else [("", obs)]
    for key, value in items:
        h.update(key.encode())
        h.update(np.ascontiguousarray(value).tobytes())
    return int.from_bytes(h.digest(), "little") >> 1


def head_logits(wrapper: Any) -> list[Any] | None:
    """The logits of each categorical head of an SB3 (or sb3-contrib maskable) action
    distribution: one for ``Discrete``, one per dimension for ``MultiDiscrete``; None for a
    continuous one."""
    import torch

    dists = getattr(wrapper, "distributions", None)  # sb3-contrib's MultiDiscrete
    if dists is None:
        dist = wrapper.distribution
        dists = dist if isinstance(dist, list) else [dist]
    if not all(isinstance(d, torch.distributions.Categorical) for d in dists):
        return None
    return [d.logits for d in dists]


class ModelAgent:
    """A Stable-Baselines3 model driving one env, deterministic by default: ``act(obs)`` (or
    calling it) -> action, keeping a recurrent policy's LSTM state from step to step;
    :meth:`reset` starts an episode (call it after each ``env.reset()``;
    ``rover_train.evaluate.run_episode`` does). It is a zoo ``Agent``
    (``rover_train.zoo.load`` returns one for an RL entry).

    :param deterministic: True: the policy's most likely action; False: an action sampled from
        the policy, as in training, its draw seeded by ``seed`` and the observation, so that
        an episode (a reset seed) is driven the same whatever ran before it, on any slot
        (the global torch RNG is left as it was). A memoryless policy that sees part of the
        world can do better sampled: a deterministic one repeats its choice wherever its
        observations look alike (the camera agents, docs/decisions.md).
    :param observe: applied to each observation before the model sees it (a model trained
        with ``rover-train --waypoint`` gets its ``waypoint`` key this way).
    :param act: applied to the model's action before the env gets it (a model trained with
        ``rover-train --relative-table`` drives the continuous env this way).
    :param seed: seeds the sampled actions (``deterministic=False``).
    :param temperature: sampled actions only: the policy's spread is scaled by it before the
        draw (a categorical's logits divided by it, a Gaussian's standard deviation
        multiplied by it). 1 draws from the policy as trained; below 1 the draws keep nearer
        its most likely action while still breaking the ties a deterministic policy loops
        on. Feed-forward actor-critic policies (PPO) only.
    :param shield: for a policy over discrete actions: the observation -> a bool mask of the
        actions allowed now (``rover_train.shield.CollisionShield``). The action is chosen
        as without it (drawn or most likely) among the allowed ones only; where the policy's
        own choice is allowed, it is the same choice. Feed-forward actor-critic policies only.
    """

    def __init__(self, model: Any, deterministic: bool = True,
                 observe: Callable[[Any], Any] | None = None,
                 act: Callable[[Any], Any] | None = None, seed: int = 0,
                 temperature: float = 1.0,
                 shield: Callable[[Any], np.ndarray] | None = None) -> None:  # fmt: skip
        if not temperature > 0:
            raise ValueError(f"temperature must be > 0 (1: the policy as trained), got "
                             f"{temperature}")  # fmt: skip
        tempered = temperature != 1.0
        policy = model.policy
        feed_forward = (not hasattr(policy, "lstm_actor")
                        and hasattr(policy, "get_distribution"))  # fmt: skip
        if tempered and (deterministic or not feed_forward):
            raise ValueError("a sampling temperature applies to the sampled actions of a "
                             "feed-forward actor-critic (PPO): give deterministic=False, and a "
                             f"PPO model (got a {type(policy).__name__})")  # fmt: skip
        tabled = hasattr(policy.action_space, "n") or hasattr(policy.action_space, "nvec")
        if shield is not None and not (feed_forward and tabled):
            raise ValueError("a shield restricts a discrete feed-forward actor-critic's actions "
                             f"(PPO over a table); got a {type(policy).__name__} over "
                             f"{policy.action_space}")  # fmt: skip
        self.model = model
        self.shield = shield
        self.deterministic = deterministic
        self.observe = observe
        self.act_map = act
        self.seed = seed
        self.temperature = temperature
        self.reset()

    def reset(self) -> None:
        self._state: Any = None
        self._episode_start = np.ones((1,), dtype=bool)

    def __call__(self, obs: Any) -> Any:
        if self.observe is not None:
            obs = self.observe(obs)
        if self.deterministic:
            action = self._predict(obs)
        else:
            import torch

            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(observation_seed(self.seed, obs))
                action = self._predict(obs)
        self._episode_start = np.zeros((1,), dtype=bool)
        return action if self.act_map is None else self.act_map(action)

    def _predict(self, obs: Any) -> Any:
        if self.temperature != 1.0 or self.shield is not None:
            return self._drawn(obs)
        action, self._state = self.model.predict(
            obs, state=self._state, episode_start=self._episode_start,
            deterministic=self.deterministic,
        )  # fmt: skip
        return action

    def _drawn(self, obs: Any) -> Any:
        """One action from the policy's own distribution, its spread scaled by the temperature
        and, with a shield, among the allowed actions; shaped as ``model.predict`` shapes it
        for one observation."""
        import torch

        policy = self.model.policy
        with torch.no_grad():
            obs_tensor, vectorized = policy.obs_to_tensor(obs)
            wrapper = policy.get_distribution(obs_tensor)
            heads = head_logits(wrapper)
            if heads is not None and (self.shield is not None or len(heads) > 1):
                return self._shielded(obs, [h / self.temperature for h in heads], vectorized)
            dist = wrapper.distribution
            if isinstance(dist, torch.distributions.Categorical):
                draw = torch.distributions.Categorical(logits=dist.logits / self.temperature)
            elif isinstance(dist, torch.distributions.Normal):
                draw = torch.distributions.Normal(dist.mean, dist.stddev * self.temperature)
            else:
                raise TypeError(f"no sampling temperature for a {type(dist).__name__} policy")
            action = draw.sample().cpu().numpy()
        space = policy.action_space
        action = action.reshape((-1, *space.shape))
        if hasattr(space, "low"):  # a Box: squash or clip as predict does
            action = (policy.unscale_action(action) if policy.squash_output
                      else np.clip(action, space.low, space.high))  # fmt: skip
        return action if vectorized else action.squeeze(axis=0)

    def _shielded(self, obs: Any, heads: list[Any], vectorized: bool) -> Any:
        """The policy's choice, head by head (one for a table, one per dimension of a
        ``MultiDiscrete``), among the actions the shield allows (all without one): its draw
        (or most likely action) when allowed, else a draw from (or the most likely of) the
        allowed ones. The shield's mask is the heads' masks end to end, as sb3-contrib's."""
        import torch

        sizes = [int(h.shape[-1]) for h in heads]
        mask = (np.ones(sum(sizes), dtype=bool) if self.shield is None
                else np.asarray(self.shield(obs), dtype=bool))  # fmt: skip
        chosen = []
        for logits, allowed in zip(heads, torch.split(torch.as_tensor(mask).reshape(1, -1),
                                                      sizes, dim=1), strict=True):  # fmt: skip
            if self.deterministic:
                action = torch.where(allowed, logits, -torch.inf).argmax(dim=-1)
            else:
                action = torch.distributions.Categorical(logits=logits).sample()
                if not bool(allowed[0, action[0]]):
                    masked = torch.where(allowed, logits, -torch.inf)
                    action = torch.distributions.Categorical(logits=masked).sample()
            chosen.append(action)
        action = (chosen[0] if len(chosen) == 1 else torch.stack(chosen, dim=1)).cpu().numpy()
        return action if vectorized else action.squeeze(axis=0)

    act = __call__


__all__ = [
    "ALGOS",
    "DEFAULT_POLICY",
    "ON_POLICY",
    "RECURRENT",
    "ModelAgent",
    "algo_class",
    "contrib_missing",
    "head_logits",
    "observation_seed",
    "policy_name",
]
