"""Why a zoo student fails: each episode's ending, how often it reverses where its teacher
would not, and whether it ended stuck.

    python -m benchmarks.zoo_diagnose lidar-inspect --episodes 40
    rover-pair --name diag -- python -m benchmarks.zoo_diagnose fused-inspect --file S.pt

Episodes run as rover-eval runs a zoo entry but on diagnostic seeds (50000+ by default:
neither training seeds, which stay below 50000 (``run_dagger`` checks), nor the evaluation seeds at
100000+), so that a change can be chosen here and reported there. At every step the
planner expert labels the state beside the student (it only reads the simulator); a
*phantom reverse* is a step where the student commands reverse and the expert does not.
An episode is *stuck* when the rover stayed within ``STUCK_RADIUS`` m of where it was
``STUCK_WINDOW`` steps before its end.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rover_train import zoo
from rover_train.evaluate import entry_env
from rover_train.imitation.expert import PlannerExpert
from rover_train.imitation.expert_agent import ExpertAgent
from rover_train.zoo.registry import DIAGNOSTIC_SEED_BASE

STUCK_WINDOW = 200  # steps (10 s)
STUCK_RADIUS = 0.35  # m


@dataclass
class Diagnosis:
    ending: str
    """goal, collision (a contact ended it), timeout, or the env's termination reason."""
    contact: bool
    steps: int
    reverse: int
    """Steps the student commanded a negative speed."""
    phantom: int
    """Of those, steps where the expert's speed was not negative."""
    stuck: bool


def diagnose_episode(env, agent, expert: PlannerExpert, seed: int, max_steps: int) -> Diagnosis:
    obs, info = env.reset(seed=seed)
    agent.reset()
    expert.reset()
    track = [np.array(obs["pose"][:2], dtype=np.float64)]
    contact = False
    reverse = phantom = 0
    ending = "timeout"
    for _ in range(max_steps):
        action = np.asarray(agent.act(obs))
        label = np.asarray(expert.act_env(env))
        if action[0] < 0:
            reverse += 1
            phantom += int(label[0] >= 0)
        obs, _, terminated, truncated, info = env.step(action)
        track.append(np.array(obs["pose"][:2], dtype=np.float64))
        contact |= bool(info.get("collision", False))
        if info.get("goals_reached", 0) > 0:
            ending = "goal"
            break
        if terminated:
            ending = str(info.get("termination_reason") or "terminated")
            break
        if truncated:
            break
    steps = len(track) - 1
    stuck = False
    if ending != "goal" and steps >= STUCK_WINDOW:
        window = np.stack(track[-STUCK_WINDOW - 1 :])
        stuck = float(np.linalg.norm(window - window[0], axis=1).max()) < STUCK_RADIUS
    return Diagnosis(ending, contact, steps, reverse, phantom, stuck)


def summary_rows(diags: list[Diagnosis]) -> list[tuple[str, int, float, float, int, int]]:
    """(ending, episodes, mean reverse steps, mean phantom steps, with contact, stuck)."""
    rows = []
    for ending in sorted({d.ending for d in diags}, key=lambda e: (e != "goal", e)):
        ds = [d for d in diags if d.ending == ending]
        rows.append((
            ending,
            len(ds),
            float(np.mean([d.reverse for d in ds])),
            float(np.mean([d.phantom for d in ds])),
            sum(d.contact for d in ds),
            sum(d.stuck for d in ds),
        ))  # fmt: skip
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("entry", choices=sorted(zoo.ENTRIES))
    p.add_argument("--file", help="a student file instead of the shipped entry")
    p.add_argument("--expert", action="store_true",
                   help="diagnose the planner expert itself (its phantom count is 0)")
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--seed", type=int, default=DIAGNOSTIC_SEED_BASE)
    p.add_argument("--name",
                   help="daemon name for fused entries (default: $ROVERAV_SHM_NAME)")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error("--episodes must be at least 1")
    import torch

    torch.set_num_threads(1)
    spec = zoo.ENTRIES[args.entry]
    env = entry_env(args.entry, args.name)
    expert = PlannerExpert(spec.world)
    if args.expert:
        agent = ExpertAgent(env, spec.world)
    else:
        agent = zoo.StudentAgent.load(args.file) if args.file else zoo.load(args.entry)
    diags = []
    try:
        for i in range(args.episodes):
            d = diagnose_episode(env, agent, expert, args.seed + i, zoo.EVAL_MAX_STEPS)
            diags.append(d)
            print(f"seed {args.seed + i}: {d.ending:10s} steps {d.steps:3d} reverse "
                  f"{d.reverse:3d} phantom {d.phantom:3d}{' contact' if d.contact else ''}"
                  f"{' stuck' if d.stuck else ''}", flush=True)  # fmt: skip
    finally:
        env.close()
    who = "planner expert" if args.expert else args.file or f"zoo {args.entry}"
    print(f"\n{who} on {args.entry}, seeds {args.seed}..{args.seed + args.episodes - 1}")
    print("| ending | episodes | reverse steps | phantom reverse | with contact | stuck |")
    print("|---|---|---|---|---|---|")
    for ending, n, rev, ph, contact, stuck in summary_rows(diags):
        print(f"| {ending} | {n} | {rev:.0f} | {ph:.0f} | {contact} | {stuck} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
