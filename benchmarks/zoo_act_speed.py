"""What an ensemble entry costs per step: ``agent.act`` of each zoo LIDAR entry against one
of its own students, alternated in one run; with ``--against FILE``, the entry against
another file of it (say the version before, to see what a new feature costs).

    MUJOCO_GL=egl python -m benchmarks.zoo_act_speed --threads 1 --acts 2000
    git show REV:rover_train/zoo/entries/lidar-maze.pt > /tmp/old.pt
    MUJOCO_GL=egl python -m benchmarks.zoo_act_speed --against /tmp/old.pt
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from rover_train import zoo
from rover_train.zoo.agent import EnsembleNet, StudentAgent


def ms_per_act(agent: StudentAgent, obs: dict, acts: int) -> float:
    agent.reset()
    for _ in range(50):  # warm-up
        agent.act(obs)
    t = time.perf_counter()
    for _ in range(acts):
        agent.act(obs)
    return (time.perf_counter() - t) / acts * 1e3


def first_obs(name: str) -> dict:
    """The first observation of entry ``name``'s first evaluation episode."""
    env = zoo.make_env(name)
    obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
    env.close()
    return obs


def alternated(a: StudentAgent, b: StudentAgent, obs: dict, acts: int,
               repeats: int) -> list[tuple[float, float]]:
    """ms per act of ``a`` and of ``b`` on ``obs``, alternated ``repeats`` times."""
    return [(ms_per_act(a, obs, acts), ms_per_act(b, obs, acts)) for _ in range(repeats)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--acts", type=int, default=2000)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument(
        "--against", type=Path, action="append", default=[],
        help="another file of a LIDAR entry, timed against the entry (repeatable)",
    )  # fmt: skip
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    print("| entry | students | ms per act (entry) | ms per act (one of its students) | ratio |")
    print("|---|---|---|---|---|")
    for name in (n for n in zoo.names() if zoo.ENTRIES[n].kind == "lidar"):
        entry = zoo.load(name)
        net = entry.net
        members = net.members if isinstance(net, EnsembleNet) else [net]
        one = StudentAgent(members[0], entry.meta)
        for full, single in alternated(entry, one, first_obs(name), a.acts, a.repeats):
            print(f"| {name} | {len(members)} | {full:.3f} | {single:.3f} | {full / single:.1f} |")
    if a.against:
        print("\n| entry | ms per act (entry) | file | ms per act (file) | ratio |")
        print("|---|---|---|---|---|")
    for path in a.against:
        other = StudentAgent.load(path)
        name = other.meta.get("name", "")
        if name not in zoo.ENTRIES or zoo.ENTRIES[name].kind != "lidar":
            raise SystemExit(f"{path} is not a file of a LIDAR zoo entry (its name: {name!r})")
        pairs = alternated(zoo.load(name), other, first_obs(name), a.acts, a.repeats)
        for new, old in pairs:
            print(f"| {name} | {new:.3f} | {path.name} | {old:.3f} | {new / old:.2f} |")


if __name__ == "__main__":
    main()
