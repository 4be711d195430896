"""PPO from a distilled student: fine-tune a zoo student on the env's reward, held near its
start by a KL term.

A zoo student is a softmax over (speed level, heading bin) classes
(:mod:`rover_train.zoo.agent`), so it is already a policy over a discrete action space:
:class:`StudentInterface` shows the env to it as its feature vector (with the episode's
:class:`~rover_train.zoo.agent.ObsHistory`) and takes a class as the action (the class's
speed and heading). A fused student's observation also carries its pooled fused image,
computed in the worker from the env's own camera by the daemon's network
(:class:`~rover_train.imitation.dagger.WithFusedView`, as in stage 1 of its distillation: no
daemon is needed); a gaze student's action is a pair, its driving class and its pan class
(:class:`~rover_train.wrappers.WithPanHead` turns the camera), and both heads learn.
PPO then trains the student's own network as the actor, beside a new critic on the state
features, with one more loss term: ``beta`` times KL(start || actor) on each minibatch's
states (summed over the heads), ``beta`` falling from ``kl_start`` to ``kl_end``, so the
first updates, made while the critic is still poor, cannot unlearn what DAgger taught. The
first ``value_warmup`` rollouts train the critic alone.

The result is a student file like any other (``zoo.load`` gives a ``StudentAgent``; it acts
on the most likely class, refined by its neighbours) whose ``meta["recipe"]`` is this
module's :class:`FineTuneRecipe`::

    python -m rover_train.imitation.finetune --start lidar-maze --out runs/ft/lidar-maze-rl.pt
    python -m rover_train.imitation.finetune --recipe rover_train/zoo/entries/lidar-maze-rl.pt

A run writes ``checkpoint.pt`` (every rollout, crash-safe) and ``progress.csv`` in its run
directory; ``--resume`` goes on from the checkpoint (the episodes in flight restart), to the
same or a longer ``--timesteps``.
"""

from __future__ import annotations

import copy
import csv
import functools
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from fused_image import FUSED_SIZE
from rover_env.crowd import MAX_PEDESTRIANS
from rover_train.checkpoint import durable_path
from rover_train.cli import parse_recipe_command, recipe_dict, recipe_from_dict
from rover_train.envs import TASKS
from rover_train.zoo.agent import (
    PAN_ANGLES,
    PAN_BINS,
    POOL,
    EnsembleNet,
    FeatureSpec,
    ObsHistory,
    StudentAgent,
    StudentNet,
    class_action,
    head_log_probs,
    image_features,
    state_features,
)
from rover_train.zoo.registry import (
    DAGGER,
    DIAGNOSTIC_SEED_BASE,
    ENTRIES,
    STUDENT_FUSED_KINDS,
    TABLE_KINDS,
    shown_path,
)
from roverav_cli import Episodes, shared_field

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.pt"
PROGRESS = "progress.csv"
PROGRESS_FIELDS = ("steps", "wall_s", "episodes", "success", "collisions", "mean_return",
                   "kl", "beta")  # fmt: skip
REWARD_SCALE = 0.05
"""The critic learns returns in this unit (the nav task's goal pays 100)."""
CRITIC_LR = 3e-4
MAX_GRAD_NORM = 0.5
STARTS = tuple(sorted(name for name, e in ENTRIES.items()
                     if e.trainer == DAGGER and e.kind not in TABLE_KINDS))  # fmt: skip
"""The zoo entries a fine-tune can start from: the distilled students of continuous actions
(its policy heads are the continuous students')."""
IMAGE_VALUES = 3 * (FUSED_SIZE[0] // POOL) * (FUSED_SIZE[1] // POOL)
"""Values of a fused student's pooled image in its flat observation (after the state)."""


@dataclass(frozen=True)
class FineTuneRecipe:
    """How a fine-tuned student is made (stored in its file: ``--recipe FILE``)."""

    start: str = field(default="lidar-maze", metadata={"choices": STARTS})
    """The zoo student to start from. Its episodes are RoverEnv's in the entry's world (a
    fused student's with the fused image computed in the worker, a gaze student's with the
    camera turned by its pan head)."""
    pedestrian_mode: str | None = shared_field(Episodes, "pedestrian_mode")
    """The pedestrians of the training episodes (default: the start entry's)."""
    n_pedestrians: int | None = shared_field(Episodes, "n_pedestrians")
    """How many (default: the start entry's)."""
    task: str = field(default="nav", metadata={"choices": tuple(TASKS)})
    """What an episode is (``rover-train --task``); ``nav`` ends it at the goal or the first
    collision, as the evaluators count."""
    timesteps: int = 400_000
    envs: int = 8
    """Envs stepped in parallel (worker processes)."""
    n_steps: int = 256
    """Steps per env per rollout."""
    epochs: int = 4
    minibatch: int = 512
    learning_rate: float = 2e-5
    """The actor's (the student's network); the new critic's is ``CRITIC_LR``."""
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.1
    kl_start: float = 1.0
    """Weight of KL(start || actor) at the first update."""
    kl_end: float = 0.05
    """... falling linearly to this at ``kl_decay`` of the timesteps, and staying there."""
    kl_decay: float = 0.5
    value_warmup: int = 3
    """Rollouts at the start that train the critic alone."""
    seed: int = 0
    """Seeds the networks, the sampling and the episodes (reset seeds ``seed * 1000 + i``,
    below the diagnostic and evaluation seeds)."""

    def problem(self) -> str | None:
        if self.timesteps < self.envs * self.n_steps:
            return (f"--timesteps {self.timesteps} is less than one rollout "
                    f"(--envs x --n-steps = {self.envs * self.n_steps})")  # fmt: skip
        if self.envs < 1 or self.n_steps < 1 or self.epochs < 1 or self.minibatch < 2:
            return "--envs, --n-steps and --epochs must be >= 1 and --minibatch >= 2"
        if not 0.0 <= self.kl_end <= self.kl_start or not 0.0 < self.kl_decay <= 1.0:
            return "need 0 <= --kl-end <= --kl-start and 0 < --kl-decay <= 1"
        if self.seed * 1000 + self.envs >= DIAGNOSTIC_SEED_BASE:
            return f"--seed {self.seed} reaches the diagnostic seeds ({DIAGNOSTIC_SEED_BASE})"
        if self.n_pedestrians is not None and not 0 <= self.n_pedestrians <= MAX_PEDESTRIANS:
            return f"--n-pedestrians must be 0 to {MAX_PEDESTRIANS}, got {self.n_pedestrians}"
        return None

    def env_kwargs(self) -> dict[str, Any]:
        """``rover_train.envs.make_env`` keywords of the training episodes: the start entry's
        env, its pedestrians replaced by the recipe's where given."""
        kw = dict(ENTRIES[self.start].env_kwargs)
        kw["world"] = kw.pop("world_n", ENTRIES[self.start].world)
        if self.pedestrian_mode is not None:
            kw["pedestrian_mode"] = self.pedestrian_mode
        if self.n_pedestrians is not None:
            kw["n_pedestrians"] = self.n_pedestrians
        return kw

    def beta(self, steps: int) -> float:
        """The KL weight after ``steps`` environment steps."""
        frac = min(steps / (self.kl_decay * self.timesteps), 1.0)
        return self.kl_start + frac * (self.kl_end - self.kl_start)


@dataclass(frozen=True)
class FineTuneRun:
    """Where a fine-tune runs (not part of the recipe)."""

    out: Path = Path("runs/finetune/student.pt")
    """The fine-tuned student file; the run directory is beside it (``<out stem>-run``)."""
    resume: bool = False
    """Go on from the run directory's checkpoint."""
    threads: int = 1
    """Torch threads for the updates."""

    @property
    def run_dir(self) -> Path:
        return self.out.with_name(f"{self.out.stem}-run")


class StudentInterface(gym.Wrapper):
    """RoverEnv as a student sees it and drives it.

    Observations: the student's state features (its ``ObsHistory`` kept per episode), and
    for a fused student its pooled fused image after them (``IMAGE_VALUES`` values 0-255,
    :func:`rover_train.zoo.agent.image_features`; the env must give ``fused_image``).
    Actions: a driving class (``Discrete``; :func:`rover_train.zoo.agent.class_action`), for
    a gaze student a (driving class, pan class) pair (``MultiDiscrete``; the env must take
    the gaze env's ``[speed, heading, pan target]``)."""

    def __init__(self, env: gym.Env, spec: FeatureSpec) -> None:
        super().__init__(env)
        keys = getattr(env.observation_space, "spaces", {})
        for needed, key in ((spec.image, "fused_image"), (spec.gaze, "gaze")):
            if needed and key not in keys:
                raise ValueError(
                    f"this student reads {key!r}, which the env does not give: "
                    "make the env with _make_env (WithFusedView, WithPanHead)"
                )
        self.features = spec
        self.history = ObsHistory(spec)
        size = spec.state_dim + (IMAGE_VALUES if spec.image else 0)
        self.observation_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self.action_space: spaces.Space[Any] = (
            spaces.MultiDiscrete([spec.n_drive, PAN_BINS]) if spec.gaze
            else spaces.Discrete(spec.n_drive)
        )  # fmt: skip

    def _observe(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = state_features(obs, self.features, self.history)
        if not self.features.image:
            return state
        return np.concatenate([state, image_features(obs).ravel().astype(np.float32)])

    def env_action(self, action: Any) -> np.ndarray:
        """The env's action for the student's class(es) ``action``."""
        a = np.atleast_1d(np.asarray(action)).astype(np.int64)
        drive = class_action(int(a[0]), self.features)
        if not self.features.gaze:
            return drive
        if not 0 <= a[1] < PAN_BINS:
            raise ValueError(f"pan class {a[1]} is outside the pan head's {PAN_BINS} classes")
        return np.append(drive, np.float32(PAN_ANGLES[a[1]])).astype(np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.history.reset()
        return self._observe(obs), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(self.env_action(action))
        return self._observe(obs), float(reward), terminated, truncated, info


def _make_env(recipe: FineTuneRecipe, spec: FeatureSpec) -> gym.Env:
    """The training env of ``recipe`` for a student of ``spec``: RoverEnv with the recipe's
    task (for a fused student rendering the fused size, with the fused image added; for a
    gaze student under the pan head), seen through :class:`StudentInterface`."""
    from rover_train.envs import make_env

    size = {"size": tuple(FUSED_SIZE)} if spec.image else {}
    env = make_env("lidar", env_checker=False, task=recipe.task, **size, **recipe.env_kwargs())
    if spec.gaze:
        from rover_train.wrappers import WithPanHead

        env = WithPanHead(env)
    if spec.image:
        from rover_train.imitation.dagger import WithFusedView

        env = WithFusedView(env)
    return StudentInterface(env, spec)


def save_durably(obj: Any, path: Path) -> None:
    """``torch.save`` through :func:`rover_train.checkpoint.durable_path` (all or nothing)."""
    with durable_path(path) as tmp:
        torch.save(obj, tmp)


def make_critic(n_inputs: int, hidden: int = 256) -> nn.Module:
    return nn.Sequential(
        nn.Linear(n_inputs, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
        nn.Linear(hidden, 1),
    )  # fmt: skip


def state_part(obs: torch.Tensor, spec: FeatureSpec) -> torch.Tensor:
    """The state features of flat :class:`StudentInterface` observations (the critic's
    input)."""
    return obs[:, : spec.state_dim]


def head_log_probs_of(net: StudentNet | EnsembleNet, obs: torch.Tensor) -> list[torch.Tensor]:
    """The student network's log-probabilities on flat :class:`StudentInterface`
    observations, one ``(N, classes)`` tensor per head (driving, then a gaze student's pan)."""
    spec = net.spec
    image = None
    if spec.image:
        h, w = FUSED_SIZE[0] // POOL, FUSED_SIZE[1] // POOL
        image = obs[:, spec.state_dim :].reshape(-1, 3, h, w)
    out = head_log_probs(net(state_part(obs, spec), image), spec)
    return [out[:, : spec.n_drive], out[:, spec.n_drive :]] if spec.gaze else [out]


def action_log_prob(heads: Sequence[torch.Tensor], actions: torch.Tensor) -> torch.Tensor:
    """The log-probability of each row's action (one class per head: ``(N,)`` or
    ``(N, heads)``) under ``heads``' log-probabilities: the sum over the heads."""
    cols = actions[:, None] if actions.dim() == 1 else actions
    return torch.stack([h.gather(1, cols[:, i : i + 1])[:, 0] for i, h in enumerate(heads)]).sum(0)


def ppo_losses(
    net: StudentNet | EnsembleNet, critic: nn.Module, start: StudentNet | EnsembleNet,
    batch: dict[str, torch.Tensor],
    clip_range: float, beta: float,
) -> dict[str, torch.Tensor]:  # fmt: skip
    """One minibatch's PPO losses: clipped surrogate, value (squared error, the critic on
    the state features), and KL(start || actor) over the batch's states, summed over the
    heads."""
    heads = head_log_probs_of(net, batch["obs"])
    logp = action_log_prob(heads, batch["actions"])
    ratio = torch.exp(logp - batch["logp"])
    adv = batch["advantages"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    policy = -torch.min(ratio * adv, ratio.clamp(1 - clip_range, 1 + clip_range) * adv).mean()
    value = (critic(state_part(batch["obs"], net.spec))[:, 0] - batch["returns"]).pow(2).mean()
    with torch.no_grad():
        refs = head_log_probs_of(start, batch["obs"])
    kl = torch.stack([(r.exp() * (r - h)).sum(dim=1).mean()
                      for r, h in zip(refs, heads, strict=True)]).sum()  # fmt: skip
    return {"policy": policy, "value": value, "kl": kl, "total": policy + beta * kl}


def advantages(
    rewards: np.ndarray, values: np.ndarray, dones: np.ndarray, last_values: np.ndarray,
    gamma: float, lam: float,
) -> np.ndarray:  # fmt: skip
    """GAE over a rollout of ``(n_steps, n_envs)``; ``dones[t]``: the episode ended at step
    t (terminal or truncated; a truncation's bootstrap is already in ``rewards``)."""
    n = len(rewards)
    adv = np.zeros_like(rewards)
    last = np.zeros(rewards.shape[1], np.float32)
    for t in reversed(range(n)):
        next_value = last_values if t == n - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * live - values[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv


class FineTuner:
    """The PPO loop (:func:`finetune` runs it)."""

    def __init__(self, recipe: FineTuneRecipe, run: FineTuneRun,
                 env_fns: Sequence[Callable[[], gym.Env]] | None = None) -> None:  # fmt: skip
        from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

        self.recipe, self.run = recipe, run
        torch.manual_seed(recipe.seed)
        self.rng = np.random.default_rng(recipe.seed)
        from rover_train import zoo

        base = zoo.load(recipe.start)
        assert isinstance(base, StudentAgent)
        self.spec = base.spec
        self.net = base.net.train()
        self.start = copy.deepcopy(base.net).eval().requires_grad_(False)
        self.critic = make_critic(self.spec.state_dim)
        self.opt_actor = torch.optim.Adam(self.net.parameters(), lr=recipe.learning_rate)
        self.opt_critic = torch.optim.Adam(self.critic.parameters(), lr=CRITIC_LR)
        self.steps = 0
        self.rollouts = 0
        self.wall = 0.0
        if env_fns is None:
            fn = functools.partial(_make_env, recipe, self.spec)
            env_fns = [fn] * recipe.envs
        self.venv = (SubprocVecEnv(list(env_fns)) if len(env_fns) > 1
                     else DummyVecEnv(list(env_fns)))  # fmt: skip
        self.venv.seed(recipe.seed * 1000)
        self._obs: np.ndarray = np.asarray(self.venv.reset())
        self._returns = np.zeros(self.venv.num_envs)

    # --- checkpoints --------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "recipe": recipe_dict(self.recipe), "net": self.net.state_dict(),
            "critic": self.critic.state_dict(), "opt_actor": self.opt_actor.state_dict(),
            "opt_critic": self.opt_critic.state_dict(), "steps": self.steps,
            "rollouts": self.rollouts, "wall": self.wall, "torch_rng": torch.get_rng_state(),
        }  # fmt: skip

    def save_checkpoint(self) -> None:
        save_durably(self.state(), self.run.run_dir / CHECKPOINT)

    def load_checkpoint(self) -> None:
        path = self.run.run_dir / CHECKPOINT
        if not path.is_file():
            raise FileNotFoundError(f"--resume: no {CHECKPOINT} in {self.run.run_dir}; start "
                                    "the run without --resume")  # fmt: skip
        blob = torch.load(path, map_location="cpu", weights_only=False)
        stored = recipe_from_dict(FineTuneRecipe, blob["recipe"])
        # a longer --timesteps goes on (the KL schedule stretches with it); the rest must match
        if replace(stored, timesteps=self.recipe.timesteps) != self.recipe:
            raise ValueError(
                f"--resume: {path} is of another recipe ({stored}); give the same options "
                "(a longer --timesteps goes on), or another --out"
            )
        if blob["steps"] > self.recipe.timesteps:
            raise ValueError(f"--resume: {path} is at {blob['steps']} steps, past --timesteps "
                             f"{self.recipe.timesteps}")  # fmt: skip
        self.net.load_state_dict(blob["net"])
        self.critic.load_state_dict(blob["critic"])
        self.opt_actor.load_state_dict(blob["opt_actor"])
        self.opt_critic.load_state_dict(blob["opt_critic"])
        self.steps, self.rollouts, self.wall = blob["steps"], blob["rollouts"], blob["wall"]
        torch.set_rng_state(blob["torch_rng"])
        self.venv.seed(self.recipe.seed * 1000 + self.rollouts)
        self._obs = np.asarray(self.venv.reset())
        self._returns[:] = 0.0
        log.info("resumed at %d steps (%d rollouts); the episodes in flight restarted",
                 self.steps, self.rollouts)  # fmt: skip

    # --- the loop -----------------------------------------------------------------------
    @torch.no_grad()
    def collect(self) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """One rollout of ``n_steps`` per env, with its advantages and returns."""
        r = self.recipe
        n, m = r.n_steps, self.venv.num_envs
        obs = np.zeros((n, m, *(self.venv.observation_space.shape or ())), np.float32)
        actions = np.zeros((n, m, *(self.venv.action_space.shape or ())), np.int64)
        logp = np.zeros((n, m), np.float32)
        values = np.zeros((n, m), np.float32)
        rewards = np.zeros((n, m), np.float32)
        dones = np.zeros((n, m), np.float32)
        ends: list[tuple[bool, bool, float]] = []
        for t in range(n):
            x = torch.as_tensor(self._obs, dtype=torch.float32)
            heads = head_log_probs_of(self.net, x)
            picks = [torch.distributions.Categorical(logits=h).sample() for h in heads]
            a = torch.stack(picks, dim=1) if self.spec.gaze else picks[0]
            obs[t], actions[t] = self._obs, a.numpy()
            logp[t] = action_log_prob(heads, a).numpy()
            values[t] = self.critic(state_part(x, self.spec))[:, 0].numpy()
            next_obs, rew, done, infos = self.venv.step(a.numpy())
            self._obs = np.asarray(next_obs)
            rewards[t] = rew * REWARD_SCALE
            self._returns += rew
            dones[t] = done
            for i in np.flatnonzero(done):
                info = infos[i]
                if info.get("TimeLimit.truncated", False):
                    last = torch.as_tensor(info["terminal_observation"], dtype=torch.float32)
                    value = self.critic(state_part(last[None], self.spec))[0, 0]
                    rewards[t, i] += r.gamma * float(value)
                ends.append((info.get("goals_reached", 0) > 0, bool(info.get("collision")),
                             float(self._returns[i])))  # fmt: skip
                self._returns[i] = 0.0
        last = state_part(torch.as_tensor(self._obs, dtype=torch.float32), self.spec)
        last_values = self.critic(last)[:, 0].numpy()
        adv = advantages(rewards, values, dones, last_values, r.gamma, r.gae_lambda)
        batch: dict[str, np.ndarray] = {"obs": obs, "actions": actions, "logp": logp,
                                        "advantages": adv, "returns": adv + values}  # fmt: skip
        stats = {"episodes": float(len(ends))}
        if ends:
            stats["success"] = float(np.mean([e[0] for e in ends]))
            stats["collisions"] = float(np.mean([e[1] for e in ends]))
            stats["mean_return"] = float(np.mean([e[2] for e in ends]))
        return batch, stats

    def update(self, batch: dict[str, np.ndarray], critic_only: bool) -> dict[str, float]:
        r = self.recipe
        flat = {k: torch.as_tensor(v.reshape(-1, *v.shape[2:])) for k, v in batch.items()}
        size = len(flat["actions"])
        beta = r.beta(self.steps)
        kls: list[float] = []
        for _ in range(r.epochs):
            order = torch.as_tensor(self.rng.permutation(size))
            for lo in range(0, size - r.minibatch + 1, r.minibatch):
                mb = {k: v[order[lo : lo + r.minibatch]] for k, v in flat.items()}
                losses = ppo_losses(self.net, self.critic, self.start, mb, r.clip_range, beta)
                self.opt_critic.zero_grad()
                losses["value"].backward()
                nn.utils.clip_grad_norm_(self.critic.parameters(), MAX_GRAD_NORM)
                self.opt_critic.step()
                if not critic_only:
                    self.opt_actor.zero_grad()
                    losses["total"].backward()
                    nn.utils.clip_grad_norm_(self.net.parameters(), MAX_GRAD_NORM)
                    self.opt_actor.step()
                kls.append(losses["kl"].item())
        return {"kl": float(np.mean(kls)), "beta": beta}

    def train(self) -> None:
        r = self.recipe
        self.run.run_dir.mkdir(parents=True, exist_ok=True)
        progress = self.run.run_dir / PROGRESS
        new_file = not progress.is_file() or self.steps == 0
        with progress.open("w" if new_file else "a", newline="") as fh:
            writer = csv.DictWriter(fh, PROGRESS_FIELDS)
            if new_file:
                writer.writeheader()
            while self.steps < r.timesteps:
                t0 = time.monotonic()
                batch, stats = self.collect()
                self.steps += r.n_steps * self.venv.num_envs
                upd = self.update(batch, critic_only=self.rollouts < r.value_warmup)
                self.rollouts += 1
                self.wall += time.monotonic() - t0
                row = {"steps": self.steps, "wall_s": round(self.wall, 1), **stats, **upd}
                writer.writerow({k: row.get(k, "") for k in PROGRESS_FIELDS})
                fh.flush()
                self.save_checkpoint()
                log.info("%d steps, %.0f s: %d episodes, success %s, collisions %s, kl %.3f",
                         self.steps, self.wall, stats["episodes"], stats.get("success", "-"),
                         stats.get("collisions", "-"), upd["kl"])  # fmt: skip

    def student(self) -> StudentAgent:
        start = ENTRIES[self.recipe.start]
        meta = {"name": f"{start.name}-rl", "kind": start.kind, "world": start.world,
                "recipe": recipe_dict(self.recipe),
                "finetune": {"steps": self.steps, "wall_s": round(self.wall, 1)}}  # fmt: skip
        return StudentAgent(copy.deepcopy(self.net).eval(), meta)

    def close(self) -> None:
        self.venv.close()


def finetune(recipe: FineTuneRecipe, run: FineTuneRun) -> Path:
    """Run the fine-tune to ``recipe.timesteps`` and write the student to ``run.out``."""
    tuner = FineTuner(recipe, run)
    try:
        if run.resume:
            tuner.load_checkpoint()
        tuner.train()
        run.out.parent.mkdir(parents=True, exist_ok=True)
        save_durably(tuner.student().state_dict(), run.out)
    finally:
        tuner.close()
    return run.out


def read_recipe(path: Path) -> FineTuneRecipe:
    """The recipe stored in a fine-tuned student file."""
    stored = StudentAgent.read_meta(path).get("recipe")
    if not isinstance(stored, dict) or "start" not in stored:
        raise ValueError(f"{path} holds no fine-tune recipe (was it made by "
                         "rover_train.imitation.finetune?)")  # fmt: skip
    return recipe_from_dict(FineTuneRecipe, stored)


def command(path: Path) -> str:
    """The command that remakes the fine-tuned student at ``path`` from its recipe."""
    p = shown_path(path)
    return f"python -m rover_train.imitation.finetune --recipe {p} --out {p}"


def main(argv: Sequence[str] | None = None) -> int:
    recipe, run, _ = parse_recipe_command(
        FineTuneRecipe, FineTuneRun, "rover_train.imitation.finetune",
        "PPO from a distilled zoo student, held near it by a KL term.", read_recipe, argv,
        what="a fine-tuned student file",
    )  # fmt: skip
    torch.set_num_threads(run.threads)
    out = finetune(recipe, run)
    start = ENTRIES[recipe.start]
    cmd = f"rover-eval {start.name} --file {shown_path(out)}"
    if recipe.pedestrian_mode is not None:
        cmd += f" --pedestrian-mode {recipe.pedestrian_mode}"
    if start.kind in STUDENT_FUSED_KINDS:
        cmd = f"rover-pair -- {cmd}"
    print(f"wrote {out}; evaluate it with: {cmd}")
    return 0


__all__ = ["FineTuneRecipe", "FineTuneRun", "FineTuner", "StudentInterface", "finetune"]

if __name__ == "__main__":
    sys.exit(main())
