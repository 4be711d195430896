"""Evaluate zoo entries (or the planner expert) the way the zoo's targets are defined.

    python -m rover_train.imitation.zoo_eval lidar-maze --episodes 100
    python -m rover_train.imitation.zoo_eval lidar-maze --expert  # the teacher on the same episodes
    rover-pair --name zoo_eval -- python -m rover_train.imitation.zoo_eval fused-maze --episodes 100

Episode i is ``reset(seed=EVAL_SEED_BASE + i)`` (no training episode uses these seeds), then
steps until the first goal (``info["is_success"]``), a termination, a truncation or 600
steps. The metrics are rover-eval's (success, episodes with a collision, SPL, time to goal,
personal-space intrusion rate, ...).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rover_env.pedestrians import PEDESTRIAN_MODES
from rover_train import zoo
from rover_train.cli import add_deprecated_alias
from rover_train.evaluate import (
    EpisodeResult,
    format_table,
    run_episode,
    summarise,
    summarise_scenario,
)
from rover_train.imitation.distill import RECIPES
from rover_train.imitation.expert import MANNERS, ExpertConfig, PlannerExpert
from rover_train.progress import StatusLine
from rover_train.recipe import RecipeError
from rover_train.zoo.registry import STUDENT_FUSED_KINDS


def evaluate_agent(
    env: Any,
    agent: zoo.Agent,
    episodes: int,
    seed: int = zoo.EVAL_SEED_BASE,
    max_steps: int = zoo.EVAL_MAX_STEPS,
    frames: list[np.ndarray] | None = None,
    video_episodes: int = 0,
    status: StatusLine | None = None,
) -> list[EpisodeResult]:
    """Run ``episodes`` evaluation episodes of ``agent`` (``reset()``/``act(obs)``) on
    seeds ``seed``, ``seed + 1``, ..."""
    results = []
    for i in range(episodes):
        agent.reset()
        act: Callable[[Any], Any] = agent.act
        if status is not None:

            def act(obs: Any, _act: Callable[[Any], Any] = agent.act) -> Any:
                status.step()
                return _act(obs)

        record = frames if (frames is not None and i < video_episodes) else None
        result = run_episode(env, act, seed + i, max_steps, record)
        if status is not None:
            status.episode(result.success)
        results.append(result)
    return results


def entry_env(entry: str, name: str | None = None, **overrides: Any) -> Any:
    """Zoo entry ``entry``'s env (``overrides``: env keywords, e.g. a scenario's); a fused
    one attaches to daemon ``name`` (default: ``$ROVERAV_SHM_NAME``, which rover-pair
    sets)."""
    if zoo.ENTRIES[entry].kind not in STUDENT_FUSED_KINDS:
        return zoo.make_env(entry, **overrides)
    from shm_protocol import default_name

    return zoo.make_env(entry, rl_obs_name=name or default_name(), **overrides)


class ExpertAgent:
    """The planner expert behind the agent interface (it reads the env's privileged state)."""

    def __init__(self, env: Any, world: str, config: ExpertConfig | None = None) -> None:
        self.env = env
        self.expert = PlannerExpert(world, config)

    def reset(self) -> None:
        self.expert.reset()

    def act(self, obs: Any) -> np.ndarray:
        del obs
        return self.expert.act_env(self.env)


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


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    p = argparse.ArgumentParser(
        prog="rover_train.imitation.zoo_eval", description=__doc__.split("\n")[0]
    )
    p.add_argument("entry", choices=sorted(zoo.ENTRIES))
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=zoo.EVAL_SEED_BASE)
    p.add_argument(
        "--expert", action="store_true",
        help="evaluate the planner expert that teaches the entry instead (all-round view)",
    )  # fmt: skip
    p.add_argument(
        "--manners", choices=sorted(MANNERS), default=None,
        help="with --expert: its pedestrian terms (default: those of the entry's teacher)",
    )  # fmt: skip
    p.add_argument("--random", action="store_true", help="evaluate a seeded random policy")
    p.add_argument("--pedestrian-mode", choices=PEDESTRIAN_MODES, default=None,
                   help="the pedestrians (default: the env's, the crowd; pacing: those the "
                        "fused entries were made among)")  # fmt: skip
    p.add_argument("--file", help="a file made like the entry instead of the shipped one (a "
                   "student .pt; for an rl-* entry a rover-train model .zip)")
    name = p.add_argument(
        "--name", help="daemon name for fused entries (default: $ROVERAV_SHM_NAME, set by "
        "rover-pair)"
    )
    add_deprecated_alias(p, "--rl-obs-name", name)
    p.add_argument("--json", action="store_true", help="print the summary as JSON last")
    p.add_argument(
        "--dump", help="write every episode's result to this JSON file (to merge split runs)"
    )
    p.add_argument(
        "--suite", nargs="?", const="world", default=None, metavar="SCENARIOS",
        help="evaluate over the scenario suite (rover_env.scenarios) and print one table: "
             "by default the scenarios of the entry's world; 'all', a world, or names "
             "separated by commas",
    )  # fmt: skip
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    spec = zoo.ENTRIES[args.entry]
    if args.expert and spec.trainer == zoo.RL:
        p.error(f"--expert: the planner expert drives RoverEnv, and {args.entry} its discrete "
                f"twin; evaluate the expert on the same episodes with: zoo_eval "
                f"lidar-{spec.world} --expert")
    scenarios = None
    if args.suite is not None:
        from rover_env.scenarios import select_scenarios

        try:
            scenarios = select_scenarios(None if args.suite == "world" else args.suite,
                                         world=spec.world)  # fmt: skip
        except ValueError as exc:
            p.error(f"--suite: {exc}")
    if args.expert:
        taught_by = spec.start if spec.start is not None else args.entry
        manners = args.manners or RECIPES[taught_by].teacher_manners
        who = f"planner expert ({manners})"
    elif args.random:
        who = "random policy"
    else:
        who = args.file or f"zoo {args.entry}"
    student = None
    if not (args.expert or args.random):
        try:
            student = zoo.load(args.entry, args.file)
        except (FileNotFoundError, RecipeError) as exc:
            p.error(f"--file: {exc}" if args.file else str(exc))

    def agent_for(env: Any) -> zoo.Agent:
        if args.expert:
            return ExpertAgent(env, spec.world, ExpertConfig.with_manners(manners))
        if args.random:
            return RandomAgent(env.action_space, args.seed)
        assert student is not None
        return student

    def evaluate_on(overrides: dict[str, Any], label: str) -> list[EpisodeResult]:
        env = entry_env(args.entry, args.name, **overrides)
        try:
            status = StatusLine(f"eval {who}{label}", args.episodes * zoo.EVAL_MAX_STEPS,
                                every=10.0)  # fmt: skip
            return evaluate_agent(env, agent_for(env), args.episodes, args.seed, status=status)
        finally:
            env.close()

    last = args.seed + args.episodes - 1
    if scenarios is not None:
        from rover_train.suite import format_suite_row, format_suite_table, run_suite, suite_json

        rows = run_suite(
            scenarios,
            lambda sc: summarise_scenario(evaluate_on(sc.env_kwargs(), f" {sc.name}")),
            progress=lambda sc, s: print("| " + " | ".join(format_suite_row(sc, s)) + " |",
                                         flush=True),  # each row as it is done
        )
        print(format_suite_table(rows, f"{who} on {args.entry}'s suite, seeds {args.seed}..{last}"))
        if args.json:
            print(json.dumps(suite_json(rows)))
        return 0
    t0 = time.monotonic()
    results = evaluate_on(
        {} if args.pedestrian_mode is None else {"pedestrian_mode": args.pedestrian_mode}, ""
    )
    wall = time.monotonic() - t0
    summary = summarise(results)
    summary["wall_s"] = wall
    if args.dump:
        with open(args.dump, "w") as f:
            json.dump([dataclasses.asdict(r) for r in results], f)
    print(format_table(summary, f"{who} on {args.entry}, seeds {args.seed}..{last}"))
    if args.json:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
