"""The zoo's entries: which env each was trained for, where its file is, how to remake it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ENTRY_DIR = Path(__file__).resolve().parent / "entries"
EVAL_SEED_BASE = 100_000
"""Evaluation seeds start here; training (DAgger) episodes use seeds below it."""
DIAGNOSTIC_SEED_BASE = 50_000
"""Diagnostic seeds (``benchmarks/zoo_diagnose.py``) start here: a change is chosen on them
and reported on the evaluation seeds; training episodes stay below them."""
EVAL_MAX_STEPS = 600
"""An evaluation episode ends at the first goal, a termination or 600 steps (30 s)."""


@dataclass(frozen=True)
class EntrySpec:
    """One zoo entry.

    :param kind: ``lidar`` (RoverEnv) or ``fused`` (RoverEnvFused).
    :param world: the world it was trained in.
    :param env_kwargs: constructor keywords of the env it was trained for.
    :param command: the one command that reproduces its file.
    :param members: students in the file: more than 1 is an ensemble of that many DAgger
        runs (``rover_train.imitation.distill --members``, whose default this is).
    :param unmapped_scan: its LIDAR students see which returns the world's map does not
        explain (``rover_train.zoo.agent.unmapped_scan``; ``distill --unmapped-scan``, whose
        default this is).
    """

    kind: str
    world: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    command: str = ""
    members: int = 1
    unmapped_scan: bool = False

    @property
    def path(self) -> Path:
        return ENTRY_DIR / f"{self.kind}-{self.world}.pt"


def _entry(kind: str, world: str) -> EntrySpec:
    name = f"{kind}-{world}"
    if kind == "lidar":
        command = f"python -m rover_train.imitation.distill {name}"
    else:
        command = (f"rover-pair --name distill_{world} -- "
                   f"python -m rover_train.imitation.distill {name}")
    return EntrySpec(kind=kind, world=world, env_kwargs={"world_n": world}, command=command,
                     members=MEMBERS.get(name, 1),
                     unmapped_scan=name in UNMAPPED_SCAN)  # fmt: skip


MEMBERS = {"lidar-inspect": 5, "lidar-maze": 2, "fused-maze": 3}
"""Entries that are ensembles, and of how many students (chosen on the diagnostic seeds;
benchmarks/RESULTS.md, "Ensembles")."""

UNMAPPED_SCAN: frozenset[str] = frozenset({"lidar-maze"})
"""LIDAR entries whose students see the returns the world's map does not explain
(``rover_train.zoo.agent.unmapped_scan``): lidar-maze's students, made with it, collided in
34 of 200 diagnostic episodes on average against 40 without (5 students each; benchmarks/
RESULTS.md, "The unmapped scan"). lidar-inspect's entry was made before it and meets its
targets without it."""

ENTRIES: dict[str, EntrySpec] = {
    f"{kind}-{world}": _entry(kind, world)
    for kind in ("lidar", "fused")
    for world in ("inspect", "maze")
}
