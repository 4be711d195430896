"""A zoo entry's recipe distilled in a few seconds, stage 2 with a real daemon."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from helpers.daemon import Daemon

from rover_train import zoo
from rover_train.imitation.distill import RECIPES, DistillRun, distill_entry, read_recipe
from rover_train.zoo import StudentAgent


@contextmanager
def tiny_entry(entry: str, tmp_path: Path) -> Iterator[tuple[StudentAgent, str]]:
    """Distil a tiny run of ``entry``'s recipe (its stored recipe checked) and yield the
    student and the name of the daemon that served stage 2, still running."""
    # one member: an ensemble's members are whole runs like this one
    recipe = replace(RECIPES[entry], iterations=1, steps=60, epochs=1, synthetic_goals=1,
                     synthetic_per_goal=5, fused_iterations=1, fused_steps=30,
                     members=1)  # fmt: skip
    d = Daemon(f"test_tiny_{uuid.uuid4().hex[:8]}").start()
    try:
        out = tmp_path / f"{entry}.pt"
        distill_entry(recipe, DistillRun(out=out, member_dir=tmp_path, name=d.name))
        assert read_recipe(out) == recipe
        agent = zoo.load(entry, out)
        assert isinstance(agent, StudentAgent)
        yield agent, d.name
    finally:
        d.stop()
        d.remove_leftovers()
