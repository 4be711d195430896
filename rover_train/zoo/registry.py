"""The zoo's entries: which env each was trained for, where its file is, how to remake it."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rover_env.scenarios import Scenario
from roverav_cli import EVAL_EPISODES as EVAL_EPISODES
from roverav_cli import EVAL_MAX_STEPS as EVAL_MAX_STEPS
from roverav_cli import EVAL_SEED_BASE as EVAL_SEED_BASE

ENTRY_DIR = Path(__file__).resolve().parent / "entries"
# EVAL_SEED_BASE (100000), EVAL_MAX_STEPS (600) and EVAL_EPISODES (100), the evaluation
# defaults, are rover-eval's --seed, --max-steps and --episodes (roverav_cli.Episodes)
DIAGNOSTIC_SEED_BASE = 50_000
"""Diagnostic seeds (``benchmarks/zoo_diagnose.py``) start here: a change is chosen on them
and reported on the evaluation seeds; training episodes stay below them."""


def shown_path(path: Path) -> str:
    """``path`` as a command shows it: relative to the working directory when under it."""
    rel = os.path.relpath(path)
    return str(path) if rel.startswith("..") else rel


STUDENT_FUSED_KINDS = ("fused", "fused-gaze", "fused-discrete", "fused-gaze-discrete")
"""Kinds of student that see the fused image (their env needs the daemon)."""
GAZE_KINDS = ("fused-gaze", "fused-gaze-discrete")
"""Kinds of student that turn the camera."""
TABLE_KINDS = ("fused-discrete", "fused-gaze-discrete")
"""Kinds of student that drive the seed's discrete table (``Discrete(60)``, ``(180)``)."""
RENAMED_KINDS = {"discrete": "fused-discrete"}
"""Old env kind -> its name now. Artefacts store the kind they were made with (a model's
recipe, a run's arguments, a student's meta): :func:`stored_kind` reads them. Not a CLI
spelling: ``--env discrete`` is refused."""


def stored_kind(kind: str) -> str:
    """The env kind a stored artefact names, under its current name (``discrete`` was the
    fused discrete env, now ``fused-discrete``)."""
    return RENAMED_KINDS.get(kind, kind)


DAGGER = "dagger"
RL = "rl"
RL_FUSED_SLOTS = 4
"""Envs (daemon slots) the fused RL entries train on: their recipes' ``--slots``."""
FINETUNE = "finetune"


@dataclass(frozen=True)
class EntrySpec:
    """One zoo entry: what it drives and where its file is. How it is made (its recipe)
    is stored in the file: a student's ``rover_train.imitation.distill.DAggerRecipe``, an
    RL model's rover-train arguments (``rover_train.recipe``).

    :param name: the entry's name (``zoo.load(name)``).
    :param kind: the env (a ``rover-train --env`` name): ``lidar`` (RoverEnv), ``fused``
        (RoverEnvFused) or ``fused-gaze`` (RoverEnvFusedGaze) for the students;
        ``lidar-discrete``, ``fused`` or ``fused-gaze`` for the RL entries.
    :param world: the world it was trained in.
    :param env_kwargs: constructor keywords of the env it was trained for.
    :param trainer: ``dagger``: a student distilled from the planner expert (``<name>.pt``);
        ``rl``: a Stable-Baselines3 model trained on the env's reward by rover-train
        (``<name>.zip``); ``finetune``: a student fine-tuned on the env's reward by PPO from
        the entry ``start`` (``rover_train.imitation.finetune``; ``<name>.pt``).
    :param start: for ``finetune``: the student entry it starts from.
    :param sampled: an ``rl`` entry that acts by sampling its policy (seeded,
        ``rover_train.algos.ModelAgent``), not by its most likely action: the camera agents,
        which see part of the world and do better sampled (docs/decisions.md, "RL").
    :param shield: an ``rl`` entry over the relative table that drives behind the collision
        shield (``rover_train.shield``) on its camera scan, or on its LIDAR for RoverEnvDiscrete;
        ``zoo.load(name, shield=False)`` gives its policy alone.
    :param shield_settings: a shielded entry's shield at drive time, as
        ``rover_train.shield.ShieldConfig`` keywords (its berth from people, say); empty: the
        shield's defaults, what the shielded recipes train behind. The recipe in the file, and
        so ``zoo.command``, keeps the training settings: the drive-time ones are the entry's.
    """

    name: str
    kind: str
    world: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    trainer: str = DAGGER
    start: str | None = None
    sampled: bool = False
    shield: bool = False
    shield_settings: dict[str, Any] = field(default_factory=dict)

    @property
    def path(self) -> Path:
        return ENTRY_DIR / f"{self.name}{'.zip' if self.trainer == RL else '.pt'}"

    @property
    def command(self) -> str:
        """The command that makes the entry from its recipe in the lab's table (an RL entry:
        from the recipe in its file)."""
        if self.trainer == RL:
            cmd = f"rover-train --recipe {shown_path(self.path)} --logdir runs/{self.name}"
            if self.kind in STUDENT_FUSED_KINDS:  # a daemon slot for each of its envs
                name = f"rl_{self.name.replace('-', '_')}"
                return f"rover-pair --name {name} --slots {RL_FUSED_SLOTS} -- {cmd}"
            return cmd
        if self.trainer == FINETUNE:
            cmd = "python -m rover_train.imitation.finetune"
            if self.path.is_file():
                return f"{cmd} --recipe {shown_path(self.path)} --out {shown_path(self.path)}"
            mode = self.env_kwargs.get("pedestrian_mode")
            among = f" --pedestrian-mode {mode}" if mode else ""
            return f"{cmd} --start {self.start}{among} --out {shown_path(self.path)}"
        return self.distill_command(self.name)

    def distill_command(self, args: str) -> str:
        """``rover_train.imitation.distill`` with ``args``, under rover-pair for a fused
        entry (its stage 2 needs the daemon; one daemon name per entry, so that two entries
        can be made at once)."""
        cmd = f"python -m rover_train.imitation.distill {args}"
        if self.kind in STUDENT_FUSED_KINDS:
            return f"rover-pair --name distill_{self.name.replace('-', '_')} -- {cmd}"
        return cmd


DRIVE_PERSON_MARGIN_M = 0.6
"""The looking pair's and rl-fused-inspect's berth from people at drive time: twice the 0.3 m
they train behind. Among 10 people it cut the share of episodes with a person touched by 2.5-5
points at no cost in success; among 3 it changed nothing beyond the noise (docs/decisions.md,
"A wider berth from people in the shield, at drive time")."""

ENTRIES: dict[str, EntrySpec] = {
    f"{kind}-{world}": EntrySpec(f"{kind}-{world}", kind, world, {"world_n": world})
    for kind in ("lidar", "fused")
    for world in ("inspect", "maze")
}
LIDAR_SHIELD_MARGIN_M = 0.15
"""The LIDAR RL entries' drive-time shield margin from every LIDAR return (rl-lidar-maze) or
from the returns the world's map explains (rl-lidar-inspect's walls): chosen on the diagnostic
seeds among 10 people, where 0.1, 0.15 and 0.2 m kept both entries' success within a point of
each other and of their policies alone, and 0.3 m cost inspect 17 points in timeouts."""
LIDAR_PERSON_MARGIN_M = 0.45
"""rl-lidar-inspect's berth from the LIDAR returns the map does not explain (people): on the
diagnostic seeds among 10 people it touched a person in 3.0 % of the episodes against 6.0 with
one margin for every return, at the same success; the maze's did not gain (docs/decisions.md,
"A shield on the LIDAR")."""
ENTRIES.update(
    (f"rl-lidar-{world}",
     EntrySpec(f"rl-lidar-{world}", "lidar-discrete", world, {"world_n": world}, trainer=RL,
               shield=True, shield_settings=settings))
    for world, settings in (
        ("inspect", {"margin_m": LIDAR_SHIELD_MARGIN_M, "person_margin_m": LIDAR_PERSON_MARGIN_M,
                     "lidar_map": True}),
        ("maze", {"person_margin_m": LIDAR_SHIELD_MARGIN_M}))
)  # fmt: skip
ENTRIES.update(
    (f"rl-fused-{world}",
     EntrySpec(f"rl-fused-{world}", "fused", world, {"world_n": world, "camera_scan": True},
               trainer=RL, sampled=True, shield=True, shield_settings=settings))
    for world, settings in (("inspect", {"person_margin_m": DRIVE_PERSON_MARGIN_M}), ("maze", {}))
)  # fmt: skip  # the camera agents learnt from the reward: PPO over the camera scan, shielded
# (the maze's keeps its training berth: the wider one cost it 4 points of success among 3
# people, 1.5 among 10, for 1.5 points less contact, still short of the 7 % target)
LOOKING_RL_PAIR = {"rl-fused-gaze-inspect": "fused-gaze", "rl-fused-inspect-twin": "fused"}
"""Looking learnt from the reward, and its fixed-camera twin: one recipe (the main job's, behind
the shield, 401,408 steps), the gaze env's relative table as two heads (``rover-train
--pan-head``: a drive, a pan window) for the one, RoverEnvFused for the other."""
ENTRIES.update(
    (name, EntrySpec(name, kind, "inspect", {"world_n": "inspect", "camera_scan": True},
                     trainer=RL, sampled=True, shield=True,
                     shield_settings={"person_margin_m": DRIVE_PERSON_MARGIN_M}))
    for name, kind in LOOKING_RL_PAIR.items()
)  # fmt: skip
LOOKING_PAIRS = {
    "fused-moon": (Scenario("moon", "crossing", 3), "fused"),
    "fused-gaze-moon": (Scenario("moon", "crossing", 3), "fused-gaze"),
}
"""The looking pair of students: one recipe and scenario, the camera fixed or turned by the
student."""
ENTRIES["fused-gaze-inspect"] = EntrySpec(
    "fused-gaze-inspect", "fused-gaze", "inspect", ENTRIES["fused-inspect"].env_kwargs
)  # fused-inspect's looking twin: its recipe, the camera turned by the student
ENTRIES.update(
    (name, EntrySpec(name, kind, scenario.world, scenario.env_kwargs()))
    for name, (scenario, kind) in LOOKING_PAIRS.items()
)
ENTRIES.update(
    (name, EntrySpec(name, kind, "inspect", ENTRIES["fused-inspect"].env_kwargs))
    for name, kind in (("discrete-inspect", "fused-discrete"),
                       ("fused-gaze-discrete-inspect", "fused-gaze-discrete"))
)  # fmt: skip  # the pair on the seed's tables: fused-inspect's recipe, Discrete(60) / (180)
ENTRIES.update(
    (f"{start}-rl", EntrySpec(f"{start}-rl", ENTRIES[start].kind, ENTRIES[start].world,
                              ENTRIES[start].env_kwargs, trainer=FINETUNE, start=start))
    for start in LOOKING_PAIRS
)  # fmt: skip  # the looking pairs, fine-tuned by PPO on the nav task's reward
ENTRIES["lidar-maze-rl"] = EntrySpec(
    "lidar-maze-rl", "lidar", "maze", {"world_n": "maze", "pedestrian_mode": "pacing"},
    trainer=FINETUNE, start="lidar-maze",
)  # fine-tuned among the pacers, where the student collides more than its teacher


@dataclass(frozen=True)
class RetiredEntry:
    """An entry taken out of the zoo: its figures stay in benchmarks/RESULTS.md, its file in
    the history (``git show COMMIT:rover_train/zoo/entries/FILE``).

    :param why: the figure that retired it.
    :param file: its file's name under ``rover_train/zoo/entries``.
    :param commit: a commit that still has the file.
    :param env: how to make the env it drove (``gymnasium.make`` of its id and keywords).
    """

    why: str
    file: str
    commit: str
    env: str

    def message(self, name: str) -> str:
        return (f"zoo entry {name!r} was retired: {self.why}. Its file is in the history: "
                f"git show {self.commit}:rover_train/zoo/entries/{self.file} > {self.file}; "
                f"load it with rover_train.zoo.StudentAgent.load('{self.file}') and drive "
                f"{self.env}")  # fmt: skip


_AMONG_10 = "world_n='inspect', pedestrian_mode='crowd', n_pedestrians=10"
RETIRED: dict[str, RetiredEntry] = {
    "fused-inspect-10": RetiredEntry(
        "made among 10 people, it touched a person in 13.0 % of the zoo's 200 episodes among 10 "
        "(target 7 %) and 5.0 % among 3 (target 3 %)", "fused-inspect-10.pt", "817492d",
        f"gym.make('roverav/RoverEnvFused-v0', {_AMONG_10})"),
    "fused-gaze-inspect-10": RetiredEntry(
        "the looking student made among 10 people: 6.0 points less success than its fixed "
        "twin, paired, and a person touched in 11.0 % of the episodes among 10 (target 7 %); "
        "looking learnt from the reward replaced it (rl-fused-gaze-inspect)",
        "fused-gaze-inspect-10.pt", "817492d",
        f"gym.make('roverav/RoverEnvFusedGaze-v0', {_AMONG_10})"),
    "fused-inspect-10-rl": RetiredEntry(
        "fused-inspect-10 fine-tuned by PPO: a person touched in 12.0 % of the episodes among "
        "10 (target 7 %)", "fused-inspect-10-rl.pt", "817492d",
        f"gym.make('roverav/RoverEnvFused-v0', {_AMONG_10})"),
    "fused-gaze-inspect-10-rl": RetiredEntry(
        "fused-gaze-inspect-10 fine-tuned by PPO: 9.5 points less success than its fixed twin, "
        "paired, and a person touched in 8.0 % of the episodes among 10 (target 7 %)",
        "fused-gaze-inspect-10-rl.pt", "817492d",
        f"gym.make('roverav/RoverEnvFusedGaze-v0', {_AMONG_10})"),
}
"""Entries taken out of the zoo (2026-12-03: the pair made among 10 people and its fine-tunes,
which missed the contact targets and whose looking cost success); ``zoo.load`` of one names
where its file is."""
