"""What a fused entry's stage 1 pays for its fused image: RoverEnv steps alone against
RoverEnv steps plus :class:`rover_train.imitation.dagger.FusedView` (render the forward
camera, run the
daemon's perception in-process) and the depth scan read off it, in one run.

    MUJOCO_GL=egl python benchmarks/stage1_view_cost.py --steps 300 --repeats 3
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from fused_image import CHANNEL_DEPTH, FUSED_SIZE
from rover_train.imitation.dagger import SCAN_BANDS, FusedView, make_training_env
from rover_train.zoo.agent import depth_scan


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--world", default="maze")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args(argv)
    torch.set_num_threads(1)  # stage 1 drives on one thread (distill --threads 1)
    env = make_training_env("lidar", args.world, size=FUSED_SIZE)
    rover_env = env.unwrapped
    view = FusedView()
    action = np.array([0.3, 0.0], np.float32)

    def ms_per_step(extra: Callable[[], object]) -> float:
        env.reset(seed=1)
        t = time.perf_counter()
        for _ in range(args.steps):
            env.step(action)
            extra()
        return (time.perf_counter() - t) / args.steps * 1e3

    env.reset(seed=1)
    view(rover_env)  # the perception is made on first use
    print("| repeat | RoverEnv step (ms) | + FusedView and scan (ms) | added (ms) |")
    print("|---|---|---|---|")
    try:
        for r in range(args.repeats):
            base = ms_per_step(lambda: None)
            with_view = ms_per_step(
                lambda: depth_scan(view(rover_env)[:, :, CHANNEL_DEPTH], SCAN_BANDS)
            )
            print(f"| {r + 1} | {base:.2f} | {with_view:.2f} | {with_view - base:.2f} |")
    finally:
        env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
