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
    """One zoo entry: what it drives and where its file is. How it is made (its recipe)
    is stored in the file (``rover_train.imitation.distill.DAggerRecipe``).

    :param kind: ``lidar`` (RoverEnv) or ``fused`` (RoverEnvFused).
    :param world: the world it was trained in.
    :param env_kwargs: constructor keywords of the env it was trained for.
    """

    kind: str
    world: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.world}"

    @property
    def path(self) -> Path:
        return ENTRY_DIR / f"{self.name}.pt"

    @property
    def command(self) -> str:
        """The command that makes the entry from its recipe in the lab's table."""
        return self.distill_command(self.name)

    def distill_command(self, args: str) -> str:
        """``rover_train.imitation.distill`` with ``args``, under rover-pair for a fused
        entry (its stage 2 needs the daemon)."""
        cmd = f"python -m rover_train.imitation.distill {args}"
        if self.kind == "fused":
            return f"rover-pair --name distill_{self.world} -- {cmd}"
        return cmd


ENTRIES: dict[str, EntrySpec] = {
    f"{kind}-{world}": EntrySpec(kind=kind, world=world, env_kwargs={"world_n": world})
    for kind in ("lidar", "fused")
    for world in ("inspect", "maze")
}
