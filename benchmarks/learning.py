"""Does PPO learn? PPO against the random policy on RoverEnv (maze) and RoverEnvFused.

    python benchmarks/learning.py                      # lidar: 3 seeds x 100k steps; fused: 2 x 20k
    python benchmarks/learning.py --lidar-steps 30000 --seeds 1 --fused-steps 0   # quick look

For each seed it trains with rover-train's own code, then evaluates the trained policy and
the random policy on the same fixed evaluation seeds (rover-eval's code) and prints one
table. The fused part starts its own av-daemon on a private segment name.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from active_vision.launcher import spawn_daemon  # noqa: E402
from rover_train import evaluate  # noqa: E402
from rover_train.envs import make_env  # noqa: E402
from rover_train.train import TrainArgs, train  # noqa: E402


def evaluate_policy(
    kind: str, world: str, model: Path | None, episodes: int, max_steps: int, shm: str
) -> dict:
    env = make_env(kind, world=world, shm_name=shm)
    try:
        act = evaluate.load_policy(
            model, None if model else "random", env, "ppo" if model else None
        )
        results = [
            evaluate.run_episode(env, act, 5000 + i, max_steps, None) for i in range(episodes)
        ]
    finally:
        env.close()
    return evaluate.summarise(results)


def evaluate_greedy(world: str, episodes: int, max_steps: int) -> dict:
    """A hand-written reference: full speed towards the goal's bearing, no obstacle sense."""
    env = make_env("lidar", world=world)
    try:

        def act(obs: dict) -> np.ndarray:
            return np.array([1.0, obs["target"][1]], np.float32)

        results = [
            evaluate.run_episode(env, act, 5000 + i, max_steps, None) for i in range(episodes)
        ]
    finally:
        env.close()
    return evaluate.summarise(results)


def run(
    kind: str, world: str, steps: int, seeds: int, episodes: int, max_steps: int, shm: str
) -> list[str]:
    rows = []
    random = evaluate_policy(kind, world, None, episodes, max_steps, shm)
    for seed in range(seeds):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            args = TrainArgs(
                env=kind, world=world, timesteps=steps, seed=seed, logdir=Path(tmp),
                checkpoint_every=0, progress=False, shm_name=shm, length=1000,
                n_envs=4 if kind == "lidar" else 1,
            )  # fmt: skip
            train(args)
            wall = time.perf_counter() - t0
            trained = evaluate_policy(
                kind, world, Path(tmp) / "model.zip", episodes, max_steps, shm
            )
        rows.append(
            f"| {kind} | {world} | {steps} | {seed} | {wall:.0f} | "
            f"{trained['success_rate']:.0%} | {trained['mean_return']:.1f} | "
            f"{trained['spl']:.2f} | "
            f"{random['success_rate']:.0%} | {random['mean_return']:.1f} |"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--world", default="maze")
    p.add_argument("--lidar-steps", type=int, default=400_000)
    p.add_argument("--fused-steps", type=int, default=20_000)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--fused-seeds", type=int, default=2)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--max-steps", type=int, default=600)
    a = p.parse_args()
    header = (
        "| env | world | train steps | seed | train s | PPO success | PPO return | PPO SPL "
        "| random success | random return |\n|---|---|---|---|---|---|---|---|---|---|"
    )
    print(header, flush=True)
    rows = []
    if a.lidar_steps > 0:
        g = evaluate_greedy(a.world, a.episodes, a.max_steps)
        greedy = (
            f"greedy reference (1 m/s towards the goal bearing, lidar, {a.world}): "
            f"success {g['success_rate']:.0%}, return {g['mean_return']:.1f}, "
            f"SPL {g['spl']:.2f}, collision rate {g['collision_rate']:.0%}"
        )
        print(greedy, flush=True)
        rows += run("lidar", a.world, a.lidar_steps, a.seeds, a.episodes, a.max_steps, "")
    if a.fused_steps > 0:
        name = f"bench_learning_{os.getpid()}"
        with spawn_daemon(name, 1, extra_args=["--threads", "1"]):
            rows += run(
                "fused", a.world, a.fused_steps, a.fused_seeds, a.episodes, a.max_steps, name
            )
    print("\n" + header + "\n" + "\n".join(rows))
    if a.lidar_steps > 0:
        print("\n" + greedy)
    return 0


if __name__ == "__main__":
    sys.exit(main())
