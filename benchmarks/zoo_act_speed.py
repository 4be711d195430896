"""What an ensemble entry costs per step: ``agent.act`` of each zoo LIDAR entry against one
of its own students, alternated in one run.

    MUJOCO_GL=egl python benchmarks/zoo_act_speed.py --threads 1 --acts 2000
"""

from __future__ import annotations

import argparse
import time

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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--acts", type=int, default=2000)
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    print("| entry | students | ms per act (entry) | ms per act (one of its students) | ratio |")
    print("|---|---|---|---|---|")
    for name in (n for n in zoo.names() if zoo.ENTRIES[n].kind == "lidar"):
        entry = zoo.load(name)
        net = entry.net
        members = net.members if isinstance(net, EnsembleNet) else [net]
        one = StudentAgent(members[0], entry.meta)
        env = zoo.make_env(name)
        obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
        env.close()
        for _ in range(a.repeats):
            full, single = ms_per_act(entry, obs, a.acts), ms_per_act(one, obs, a.acts)
            print(f"| {name} | {len(members)} | {full:.3f} | {single:.3f} | {full / single:.1f} |")


if __name__ == "__main__":
    main()
