"""The zoo's entries: which env each was trained for, where its file is, how to remake it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ENTRY_DIR = Path(__file__).resolve().parent / "entries"
EVAL_SEED_BASE = 100_000
"""Evaluation seeds start here; training (DAgger) episodes use seeds below it."""
EVAL_MAX_STEPS = 600
"""An evaluation episode ends at the first goal, a termination or 600 steps (30 s)."""


@dataclass(frozen=True)
class EntrySpec:
    """One zoo entry.

    :param kind: ``lidar`` (RoverEnv) or ``fused`` (RoverEnvFused).
    :param world: the world it was trained in.
    :param env_kwargs: constructor keywords of the env it was trained for.
    :param command: the one command that reproduces its file.
    """

    kind: str
    world: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    command: str = ""

    @property
    def path(self) -> Path:
        return ENTRY_DIR / f"{self.kind}-{self.world}.pt"


def _entry(kind: str, world: str) -> EntrySpec:
    name = f"{kind}-{world}"
    if kind == "lidar":
        command = f"python -m rover_train.distill {name}"
    else:
        command = f"rover-pair --name distill_{world} -- python -m rover_train.distill {name}"
    return EntrySpec(kind=kind, world=world, env_kwargs={"world_n": world}, command=command)


ENTRIES: dict[str, EntrySpec] = {
    f"{kind}-{world}": _entry(kind, world)
    for kind in ("lidar", "fused")
    for world in ("inspect", "maze")
}
