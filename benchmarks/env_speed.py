"""RoverEnv speed per world on one CPU core, against the seed's wall-clock ROS/Gazebo env.

Measured per world (``inspect``, ``moon``, ``maze``), in this process pinned to one core:

- steps/s: ``env.step`` with uniformly random actions (drawn up front), episodes reset
  when they end (resets not counted in the step time); the raw ``RoverEnv``, and through
  ``gym.make`` (which adds Gymnasium's checker and order-enforcing wrappers);
- reset: ``env.reset()`` wall time, median and 95th percentile;
- x real time: simulated seconds per wall second (steps/s x control_dt);
- vs seed: the seed steps at real time (one 0.05 s control period per 0.05 s, so
  ``x real time`` is also the speed-up) and its reset alone sleeps at least 11 s
  (100 x 0.1 s ROS spins + 1 s), so reset speed-up = 11 s / our reset.

A second table times the forward camera (96x96) the fused envs render every step: RGB,
RGB + metric depth, RGB + depth + pedestrian mask.

A fourth table times that camera frame while driving (a random action between frames) among
the crowd of 3 and of 10, each frame rendered twice in alternating order: with every geom
drawn (the way before the camera left out what it cannot see) and as the env renders it,
leaving out the pedestrian geoms wholly outside the view frustum and, looking straight
ahead, the rover's own body. The two renders of a frame are checked to be pixel-identical.

A third table times RoverEnv's steps/s with the 3 pacing pedestrians (the default
when the crowd came) against 3, 10 and 20 walkers of the social-force crowd (the default
now), in interleaved rounds (medians), and the ratios crowd 10 / pacing 3 (the target is
>= 80 %) and crowd 10 / crowd 3, taken within each round (median, quartiles in brackets):
this VM's speed drifts 2x within minutes, the ratio of rows run a second apart far less.

    python -m benchmarks.env_speed            # about 30 s
    python -m benchmarks.env_speed --quick    # about 8 s
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from benchmarks.machine import cpu_name
from fused_image import FUSED_SIZE
from rover_env import WORLD_NAMES, RoverEnv  # sets MUJOCO_GL=egl first

SEED_RESET_S = 100 * 0.1 + 1.0  # the seed's reset: 100 spins of 0.1 s, then sleep(1)
SEED_REAL_TIME = 1.0  # the seed's steps run at wall-clock speed
CROWD_ROWS = ((3, "pacing"), (3, "crowd"), (10, "crowd"), (20, "crowd"))  # (n, mode) columns
CROWD_ROUNDS = 40  # interleaved rounds of the crowd table: the VM's speed drifts 2x


@dataclass
class Args:
    """What one run measures."""

    steps: int = 20000
    """Env steps timed per world."""
    resets: int = 300
    """Resets timed per world."""
    frames: int = 300
    """Camera frames timed per world and mode."""
    cpu: int = 0
    """Core to pin this process to (-1: do not pin)."""
    seed: int = 0


def pin(cpu: int) -> str:
    if cpu < 0 or not hasattr(os, "sched_setaffinity"):
        return "not pinned"
    os.sched_setaffinity(0, {cpu})
    return f"pinned to CPU {cpu}"


def time_steps(env: gym.Env, n: int, seed: int) -> float:
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    actions = rng.uniform(low, high, size=(n, 2)).astype(np.float32)
    env.reset(seed=seed)
    stepping = 0.0
    for action in actions:
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        stepping += time.perf_counter() - t0
        if terminated or truncated:
            env.reset()
    return n / stepping


def _ratio(r: np.ndarray) -> str:
    """Median of per-round ratios, with their quartiles."""
    q1, med, q3 = np.percentile(r, (25, 50, 75))
    return f"{med:.0%} ({q1:.0%}-{q3:.0%})"


def time_resets(env: RoverEnv, n: int, seed: int) -> np.ndarray:
    env.reset(seed=seed)
    times = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        env.reset()
        times[i] = time.perf_counter() - t0
    return times


def time_camera(env: RoverEnv, n: int) -> tuple[float, float, float]:
    sim = env.sim
    sim.render_camera()  # creates the renderer
    out = []
    for kwargs in ({}, {"depth": True}, {"depth": True, "segmentation": True}):
        t0 = time.perf_counter()
        for _ in range(n):
            sim.render_camera(**kwargs)
        out.append((time.perf_counter() - t0) / n * 1e3)
    return out[0], out[1], out[2]


def time_camera_culling(
    world: str, n_pedestrians: int, frames: int, seed: int
) -> tuple[float, float]:
    """Median ms of a driving camera frame with every geom drawn, and as the env renders it
    (unseen geoms left out); raises if the two frames ever differ."""
    env = RoverEnv(world_n=world, n_pedestrians=n_pedestrians)
    sim = env.sim
    every = np.zeros(0, dtype=np.intp)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    sim.render_camera()  # creates the renderer
    full, culled = np.empty(frames), np.empty(frames)
    for i in range(frames):
        _, _, terminated, truncated, _ = env.step(rng.uniform([-0.6, -np.pi], [1.0, np.pi]))
        if terminated or truncated:
            env.reset()
        out = {}
        for mode in ("full", "culled") if i % 2 else ("culled", "full"):
            if mode == "full":
                sim._unseen_geoms = lambda: every  # every geom drawn
            t0 = time.perf_counter()
            out[mode] = sim.render_camera(depth=True)
            (full if mode == "full" else culled)[i] = time.perf_counter() - t0
            if mode == "full":
                del sim._unseen_geoms
        a, b = out["full"], out["culled"]
        if not (np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)):
            raise AssertionError(f"{world}, {n_pedestrians} people: frame {i} differs")
    env.close()
    return float(np.median(full)) * 1e3, float(np.median(culled)) * 1e3


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and resets")
    parser.add_argument("--cpu", type=int, default=Args.cpu)
    args_ns = parser.parse_args(argv)
    args = Args(cpu=args_ns.cpu)
    if args_ns.quick:
        args = Args(steps=4000, resets=100, frames=100, cpu=args_ns.cpu)
    where = pin(args.cpu)
    print(f"# RoverEnv speed: {cpu_name()}, {where}; python {platform.python_version()}")

    rows, cams = [], []
    for world in WORLD_NAMES:
        env = RoverEnv(world_n=world, size=FUSED_SIZE)
        sps = time_steps(env, args.steps, args.seed)
        resets = time_resets(env, args.resets, args.seed)
        cams.append((world, *time_camera(env, args.frames)))
        env.close()
        # The same through gym.make (PassiveEnvChecker and OrderEnforcing wrappers).
        wrapped = gym.make("roverav/RoverEnv-v0", world_n=world)
        sps_made = time_steps(wrapped, args.steps // 2, args.seed)
        wrapped.close()
        rows.append((world, sps, sps_made, resets, env.control_dt))

    print()
    print("| world | steps/s | x real time (= vs seed) | via gym.make | reset median | "
          "reset p95 | reset vs seed (>= 11 s) |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    for world, sps, sps_made, resets, dt in rows:
        med, p95 = np.median(resets) * 1e3, np.percentile(resets, 95) * 1e3
        print(
            f"| {world} | {sps:,.0f} | {sps * dt / SEED_REAL_TIME:,.0f}x | {sps_made:,.0f} | "
            f"{med:.2f} ms | {p95:.2f} ms | {SEED_RESET_S / (med / 1e3):,.0f}x |"
        )
    print()
    print("| world | camera 96x96 RGB | + depth | + depth + pedestrian mask |")
    print("|---|---:|---:|---:|")
    for world, rgb, depth, seg in cams:
        print(f"| {world} | {rgb:.2f} ms | {depth:.2f} ms | {seg:.2f} ms |")
    print()
    print("| world | people | camera + depth, every geom drawn | as rendered (unseen left out) "
          "| ratio |")  # fmt: skip
    print("|---|---:|---:|---:|---:|")
    for world in WORLD_NAMES:
        for n in (3, 10):
            full, culled = time_camera_culling(world, n, args.frames * 2, args.seed)
            print(f"| {world} | {n} | {full:.3f} ms | {culled:.3f} ms | {full / culled:.2f}x |")
    print()
    print("| world | pacing 3 steps/s | crowd 3 | crowd 10 | crowd 20 | crowd 10 / pacing 3 | "
          "crowd 10 / crowd 3 |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    for world in WORLD_NAMES:
        envs = [RoverEnv(world_n=world, n_pedestrians=n, pedestrian_mode=mode)
                for n, mode in CROWD_ROWS]  # fmt: skip
        for env in envs:
            time_steps(env, 200, args.seed)  # warm the crowd's route cache a little
        # interleaved blocks, so a change of load on a shared machine hits every row alike
        block = max(100, args.steps // (2 * CROWD_ROUNDS))
        speeds = np.array([[time_steps(env, block, args.seed + r) for env in envs]
                           for r in range(CROWD_ROUNDS)])  # fmt: skip
        for env in envs:
            env.close()
        p3, c3, c10, c20 = np.median(speeds, axis=0)
        # ratios within each round (the rows ran seconds apart), then their median and quartiles
        vs_p3, vs_c3 = _ratio(speeds[:, 2] / speeds[:, 0]), _ratio(speeds[:, 2] / speeds[:, 1])
        print(f"| {world} | {p3:,.0f} | {c3:,.0f} | {c10:,.0f} | {c20:,.0f} | {vs_p3} | "
              f"{vs_c3} |")  # fmt: skip
    print()
    print(f"{args.steps} steps (random actions, control_dt {rows[0][4]} s) and "
          f"{args.resets} resets per world; camera: {args.frames} frames per mode, "
          f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}.")  # fmt: skip


if __name__ == "__main__":
    main()
