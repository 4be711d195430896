"""The planner expert among 3 and 10 people: what its students can learn at best.

    nice -n 19 .venv/bin/python -m benchmarks.expert_table                  # every row
    nice -n 19 .venv/bin/python -m benchmarks.expert_table --episodes 4 \\
        --record runs/expert/smoke.json                                     # a smoke run

Run from the repository root. Each row drives the expert (``ExpertAgent``: true positions
all round) on RoverEnv, the zoo's evaluation episodes (episode i reset with seed 100000 + i,
ended at the first goal, a termination or 600 steps) among the crowd, for each world,
crowd size, manners (``rover_train.imitation.expert.MANNERS``) and way of estimating the
pedestrians' velocities (``ExpertConfig.velocity_from``: ``steps``, what taught the shipped
students, against ``updates``). Columns as in the pedestrian-contact table: success, the
headline collision share (contact counted), pedestrian contact with its 95 % Wilson
interval, timeouts, SPL. Rows are saved as each finishes; a stopped run resumes (rows in the
record are skipped unless ``--redo``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym

import rover_env  # noqa: F401  (registers the ids)
from benchmarks.machine import cpu_description
from benchmarks.record_file import add_record_arguments, read_record, save_record
from rover_train.evaluate import evaluate_agent, summarise
from rover_train.imitation.expert import MANNERS, VELOCITY_FROM, ExpertConfig
from rover_train.imitation.expert_agent import ExpertAgent
from rover_train.suite import wilson_interval
from rover_train.zoo.registry import EVAL_SEED_BASE

RECORD = Path("benchmarks/records/expert.json")
TITLE = "The planner expert among the crowd, 200 episodes a row; 95 % Wilson intervals"
SECTION = "the-planner-expert"
WORLDS = ("inspect", "maze")
PEOPLE = (3, 10)
COLUMNS = [
    "world", "people", "manners", "velocities from", "success %",
    "collision % (contact counted)", "pedestrian contact % [95 % interval]", "timeouts", "SPL",
]  # fmt: skip
NOTES = (
    "The expert drives RoverEnv with every pedestrian's true position (rover-eval "
    "lidar-WORLD --expert is the polite row with velocities from updates). Velocities from "
    "steps: differences of consecutive control steps (20 Hz) of positions the crowd moves at "
    "10 Hz, so the estimate reads 0 and twice the speed on alternate steps; it taught the "
    "fused students. From updates: over the last change of the positions, held between "
    "changes (the default; it taught the LIDAR students). Targets for the zoo's navigators: "
    "pedestrian contact at most 3 % among 3 people, 7 % among 10; a student seldom keeps "
    "clearer than its teacher."
)


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="The planner expert among 3 and 10 people, by manners and velocity "
                    "estimate; one resumable record.")  # fmt: skip
    add_record_arguments(p, RECORD, 200)
    p.add_argument("--worlds", default=",".join(WORLDS), help="worlds, separated by commas")
    p.add_argument("--manners", default=",".join(sorted(MANNERS)),
                   help="manners, separated by commas")  # fmt: skip
    p.add_argument("--velocity-from", default=",".join(VELOCITY_FROM),
                   help="velocity estimates, separated by commas")  # fmt: skip
    args = p.parse_args(argv)
    args.worlds, args.manners = args.worlds.split(","), args.manners.split(",")
    args.velocity_from = args.velocity_from.split(",")
    for flag, given, known in (("--worlds", args.worlds, WORLDS),
                               ("--manners", args.manners, tuple(MANNERS)),
                               ("--velocity-from", args.velocity_from, VELOCITY_FROM)):  # fmt: skip
        bad = [g for g in given if g not in known]
        if bad:
            p.error(f"{flag}: {', '.join(bad)} not among {', '.join(known)}")
    if args.episodes < 1:
        p.error("--episodes must be at least 1")
    return args


def measure(world: str, people: int, manners: str, velocity_from: str,
            episodes: int) -> list[Any]:  # fmt: skip
    """One row: the expert so configured on ``episodes`` evaluation episodes."""
    env = gym.make("roverav/RoverEnv-v0", world_n=world, n_pedestrians=people,
                   pedestrian_mode="crowd")  # fmt: skip
    try:
        agent = ExpertAgent(env, world,
                            ExpertConfig.with_manners(manners, velocity_from=velocity_from))
        results = evaluate_agent(env, agent, episodes, EVAL_SEED_BASE)  # fmt: skip
    finally:
        env.close()
    s = summarise(results)
    contacts = sum(r.pedestrian_contact for r in results)
    lo, hi = wilson_interval(contacts, len(results))
    return [world, people, manners, velocity_from, round(100 * s["success_rate"], 1),
            round(100 * s["collision_rate"], 1),
            f"{100 * s['pedestrian_contact_rate']:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]",
            s["timeouts"], round(s["spl"], 2)]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    command = " ".join([".venv/bin/python", "-m", "benchmarks.expert_table",
                        *(sys.argv[1:] if argv is None else argv)])  # fmt: skip
    empty = {"title": TITLE, "section": SECTION, "command": command, "cpu": "", "date": "",
             "columns": COLUMNS, "align": "lrllrrlrr", "rows": [], "notes": NOTES}  # fmt: skip
    for world, people, manners, velocity in itertools.product(
            args.worlds, PEOPLE, args.manners, args.velocity_from):  # fmt: skip
        key = [world, people, manners, velocity]
        record = read_record(args.record, empty)
        if any(row[:4] == key for row in record["rows"]) and not args.redo:
            print(f"{key}: in the record, skipped", flush=True)
            continue
        t0 = time.monotonic()
        row = measure(world, people, manners, velocity, args.episodes)
        record = read_record(args.record, empty) if args.record.is_file() else record
        record["rows"] = sorted([r for r in record["rows"] if r[:4] != key] + [row],
                                key=lambda r: (r[0], r[1], r[2], r[3]))  # fmt: skip
        record.update(command=command, cpu=cpu_description(), notes=NOTES,
                      date=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d"),
                      load="beside other runs (seeded, deterministic episodes)")  # fmt: skip
        save_record(args.record, record)
        print(f"{row} ({time.monotonic() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
