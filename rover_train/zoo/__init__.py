"""The policy zoo: trained navigators shipped as small files, with the command that remakes each.

    from rover_train import zoo
    zoo.names()                                   # ['fused-inspect', 'fused-maze', ...]
    env = zoo.make_env("fused-maze", rl_obs_name="my_daemon", slot=0)  # kwargs override
    agent = zoo.load("fused-maze")
    obs, info = env.reset(seed=100_000)
    agent.reset()
    obs, reward, terminated, truncated, info = env.step(agent.act(obs))

The ``lidar-*`` and ``fused-*`` entries are students distilled from the privileged planner
expert (:mod:`rover_train.imitation.expert`) by DAgger (:mod:`rover_train.imitation.distill`);
the ``rl-*`` entries are Stable-Baselines3 models trained from the env's reward by
``rover-train`` (:class:`rover_train.algos.ModelAgent` drives them). ``command(name)`` is the
one command that reproduces an entry's file. Fused entries need the daemon for their env.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from rover_train.zoo.registry import (
    DAGGER,
    ENTRIES,
    EVAL_EPISODES,
    EVAL_MAX_STEPS,
    EVAL_SEED_BASE,
    FINETUNE,
    RETIRED,
    RL,
    EntrySpec,
    shown_path,
)

if TYPE_CHECKING:
    from rover_train.algos import ModelAgent
    from rover_train.shield import ShieldConfig, ShieldedAgent
    from rover_train.zoo.agent import (
        Agent,
        FeatureSpec,
        StudentAgent,
        StudentFileError,
        StudentNet,
    )

_FROM_AGENT = ("Agent", "FeatureSpec", "StudentAgent", "StudentFileError", "StudentNet")


def __getattr__(name: str) -> Any:
    # rover_train.zoo.agent (torch) is imported on first use: the names and specs of the
    # entries (rover-eval's argument parsing) need no torch
    if name in _FROM_AGENT:
        import rover_train.zoo.agent

        return getattr(rover_train.zoo.agent, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class UnknownEntryError(KeyError):
    """A zoo name that is not in the zoo."""

    def __str__(self) -> str:
        return str(self.args[0])


def _spec(name: str) -> EntrySpec:
    try:
        return ENTRIES[name]
    except KeyError:
        if name in RETIRED:
            raise UnknownEntryError(RETIRED[name].message(name)) from None
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
    if not spec.path.is_file() or spec.trainer != DAGGER:
        return spec.command
    from rover_train.zoo.agent import StudentAgent, StudentFileError

    try:
        recipe = StudentAgent.read_meta(spec.path).get("recipe")
    except StudentFileError:  # a damaged file: remade from the lab's table
        return spec.command
    if recipe is None:
        return spec.command
    return spec.distill_command(f"--recipe {shown_path(spec.path)}")


def make_env(name: str, **overrides: Any) -> gym.Env:
    """The env entry ``name`` was trained for (``gymnasium.make``); ``overrides`` replace or
    add constructor keywords (e.g. ``rl_obs_name``, ``slot``, ``render_mode``)."""
    import rover_env  # noqa: F401  (registers the roverav/ ids)
    from rover_train.envs import ENV_IDS

    spec = _spec(name)
    return gym.make(ENV_IDS[spec.kind], **{**spec.env_kwargs, **overrides})


def load(name: str, path: str | os.PathLike[str] | None = None,
         temperature: float | None = None, shield: bool | None = None,
         shield_config: ShieldConfig | None = None
         ) -> StudentAgent | ModelAgent | ShieldedAgent:  # fmt: skip
    """The agent of entry ``name``: ``agent.reset()`` per episode, ``agent.act(obs)`` (an
    :class:`Agent`). A student comes as a :class:`StudentAgent`, which also saves, fine-tunes
    and says what it is in ``meta`` (behind the shield, a
    :class:`rover_train.shield.ShieldedAgent` around it, its ``agent``); an RL entry as a
    :class:`rover_train.algos.ModelAgent`.

    :param path: another file made like the entry (a candidate) instead of the shipped one.
    :param temperature: a sampled RL entry's sampling temperature
        (``rover_train.algos.ModelAgent``; None: 1, the policy as trained).
    :param shield: drive behind the collision shield (``rover_train.shield``) or not: an RL
        entry over the relative table on its camera scan (on its LIDAR for an ``rl-lidar``
        entry), a fused or fused-gaze student on its camera scan (its env needs
        ``camera_scan=True``); None: as the entry says (``EntrySpec.shield``), or behind it
        where the entry was trained behind it (``rover-train --shield``).
    :param shield_config: the shield's settings at drive time (None: the entry's
        ``EntrySpec.shield_settings`` over ``ShieldConfig()``'s defaults, what the shielded
        recipes train behind); ValueError for an agent that drives without it.
    :raises FileNotFoundError: no file; :class:`StudentFileError`: a student file that does
        not read (cut short, say). Both name the file and the command that remakes it.
    """
    from rover_train.zoo.agent import StudentAgent, StudentFileError

    spec = _spec(name)
    file = spec.path if path is None else Path(path)
    if not file.is_file():
        raise FileNotFoundError(
            f"zoo entry {name!r} has no file at {file}; make it with: {spec.command}"
        )
    if spec.trainer != RL:
        try:
            student = StudentAgent.load(file)
        except StudentFileError as exc:
            raise StudentFileError(
                f"{exc}. Remake it with zoo entry {name}'s command: {spec.command}"
            ) from exc
        return _shielded_student(spec, student, shield, shield_config)
    from rover_train.algos import ModelAgent, algo_class
    from rover_train.recipe import read_recipe
    from rover_train.wrappers import agent_io

    recipe = read_recipe(file)
    model = algo_class(recipe["algo"], masked=bool(recipe.get("shield"))).load(file, device="cpu")
    observe, act = agent_io(recipe)
    if temperature is not None and not spec.sampled:
        raise ValueError(f"a sampling temperature is for the entries that sample their policy "
                         f"({', '.join(n for n, e in ENTRIES.items() if e.sampled)}), not "
                         f"{name}")  # fmt: skip
    guard = None
    if shield if shield is not None else (spec.shield or recipe.get("shield")):
        from rover_train.shield import shield_for

        guard = shield_for(recipe, f"zoo entry {name}", shield_config or drive_shield(name))
    elif shield_config is not None:
        raise ValueError(f"shield settings were given, but zoo entry {name} drives without the "
                         f"collision shield (shield=False, or not a shielded entry)")  # fmt: skip
    return ModelAgent(model, deterministic=not spec.sampled, observe=observe, act=act,
                      temperature=1.0 if temperature is None else temperature, shield=guard)


def _shielded_student(spec: EntrySpec, student: StudentAgent, shield: bool | None,
                      config: ShieldConfig | None) -> StudentAgent | ShieldedAgent:  # fmt: skip
    """``student`` behind the collision shield on its camera scan where asked (``shield``,
    None: as the entry ships), for the students that steer by Box commands."""
    from rover_train.shield import SHIELDED_STUDENT_KINDS, CollisionShield
    from rover_train.shield import ShieldedAgent as Guarded

    if not (shield if shield is not None else spec.shield):
        if config is not None:
            raise ValueError(f"shield settings were given, but zoo entry {spec.name} drives "
                             f"without the collision shield (shield=False, or not a shielded "
                             f"entry)")  # fmt: skip
        return student
    if spec.kind not in SHIELDED_STUDENT_KINDS:
        raise ValueError(f"the collision shield guards the RL entries and the students that "
                         f"steer by [speed, heading] on the camera scan (kinds "
                         f"{', '.join(SHIELDED_STUDENT_KINDS)}); zoo entry {spec.name} is a "
                         f"{spec.kind} student")  # fmt: skip
    return Guarded(student, CollisionShield(config or drive_shield(spec.name)))


def drive_shield(name: str, **overrides: Any) -> ShieldConfig:
    """The collision shield's settings entry ``name`` drives with: its
    ``EntrySpec.shield_settings`` over ``ShieldConfig()``'s defaults, then ``overrides``."""
    from rover_train.shield import ShieldConfig

    return ShieldConfig(**{**_spec(name).shield_settings, **overrides})


__all__ = [
    "DAGGER",
    "ENTRIES",
    "FINETUNE",
    "RETIRED",
    "RL",
    "EVAL_EPISODES",
    "EVAL_MAX_STEPS",
    "EVAL_SEED_BASE",
    "Agent",
    "EntrySpec",
    "FeatureSpec",
    "StudentAgent",
    "StudentFileError",
    "StudentNet",
    "UnknownEntryError",
    "command",
    "drive_shield",
    "load",
    "make_env",
    "names",
]
