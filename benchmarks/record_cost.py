"""What recording an episode as ROS 2 MCAP costs: steps/s with and without it.

One run, interleaved rounds (this VM's speed drifts within minutes; rows a second apart
far less), medians over the rounds, the same seeded random actions in every row:

- RoverEnv (inspect, the default crowd of 3): no recording; recording the state topics only
  (``RecordConfig(camera=False)``: scan, IMU, odometry, tf, cmd_vel, goal, pedestrians,
  path); with the forward camera too (the default: the LIDAR env renders it only for the
  recording); the chase view drawn each step without recording (what ``--video`` pays); and
  recording all of it, chunks compressed with zstd (the default) and with lz4.
- RoverEnvFused beside a real av-daemon (``--no-fused`` skips it; one slot per row, a worker
  per slot): no recording, and recording (camera rendered once more, the three fused
  channels).

Each row also gives the file's size per 1,000 steps. Each recording is one
:class:`rover_train.record.EpisodeRecorder` over the round's steps, written to a temporary
folder.

    python -m benchmarks.record_cost            # about 2 minutes on 2 vCPUs
    python -m benchmarks.record_cost --quick    # about 30 s
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np

import rover_env  # noqa: F401  (registers the ids)
from benchmarks.machine import cpu_name
from rover_train.record import EpisodeRecorder, RecordConfig

WORLD = "inspect"
SEED = 0
CHASE_SIZE = (480, 360)  # the envs' default render_size


@dataclass(frozen=True)
class Row:
    name: str
    env: str  # "lidar" or "fused"
    chase: bool  # render_mode="rgb_array" (and env.render() each step when not recording)
    config: RecordConfig | None  # None: no recording


ROWS = (
    Row("RoverEnv, no recording", "lidar", False, None),
    Row("RoverEnv, record state topics (no camera)", "lidar", False, RecordConfig(camera=False)),
    Row("RoverEnv, record + camera (default)", "lidar", False, RecordConfig()),
    Row("RoverEnv, chase view drawn, no recording", "lidar", True, None),
    Row("RoverEnv, record + camera + chase, zstd", "lidar", True, RecordConfig()),
    Row("RoverEnv, record + camera + chase, lz4", "lidar", True,
        RecordConfig(compression="lz4")),
)
FUSED_ROWS = (
    Row("RoverEnvFused, no recording", "fused", False, None),
    Row("RoverEnvFused, record + camera + fused", "fused", False, RecordConfig()),
)


def run_row(env: gym.Env, row: Row, actions: np.ndarray, folder: Path) -> tuple[float, float]:
    """(steps/s, MB per 1,000 steps) of one round of ``row`` on ``env``."""
    obs, info = env.reset(seed=SEED)
    rec = None
    path = folder / f"{uuid.uuid4().hex}.mcap"
    if row.config is not None:
        rec = EpisodeRecorder(env, path, row.config)
        rec.reset(obs, info)
    draw: Callable[[], object] | None = env.render if row.chase and rec is None else None
    n = 0
    t0 = time.perf_counter()
    for a in actions:
        obs, _, terminated, truncated, info = env.step(a)
        n += 1
        if rec is not None:
            rec.step(obs, info)
        elif draw is not None:
            draw()
        if terminated or truncated:
            break
    if rec is not None:
        rec.close()
    elapsed = time.perf_counter() - t0  # closing the file (index, fsync) counted
    size = path.stat().st_size / 1e6 * 1000 / n if path.exists() else 0.0
    path.unlink(missing_ok=True)
    return n / elapsed, size


def make(row: Row, daemon_name: str | None, slot: int) -> gym.Env:
    kwargs: dict = {"world_n": WORLD, "render_size": CHASE_SIZE,
                    "render_mode": "rgb_array" if row.chase else None}
    if row.env == "fused":
        return gym.make("roverav/RoverEnvFused-v0", rl_obs_name=daemon_name, slot=slot,
                        length=100_000, **kwargs)
    return gym.make("roverav/RoverEnv-v0", length=100_000, **kwargs)


def measure(rows: tuple[Row, ...], steps: int, rounds: int,
            daemon_name: str | None = None) -> dict[str, tuple[float, float]]:
    envs = {r.name: make(r, daemon_name, slot) for slot, r in enumerate(rows)}
    space = next(iter(envs.values())).action_space
    space.seed(SEED)
    actions = np.stack([space.sample() for _ in range(steps)])
    results: dict[str, list[tuple[float, float]]] = {r.name: [] for r in rows}
    try:
        with tempfile.TemporaryDirectory(prefix="record_cost_") as tmp:
            for row in rows:  # warm-up: renderers, the type store, the daemon's first frames
                run_row(envs[row.name], row, actions[: max(10, steps // 10)], Path(tmp))
            for _ in range(rounds):
                for row in rows:
                    results[row.name].append(run_row(envs[row.name], row, actions, Path(tmp)))
    finally:
        for env in envs.values():
            env.close()
    return {name: (float(np.median([r[0] for r in rs])), float(np.median([r[1] for r in rs])))
            for name, rs in results.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=300, help="steps per row and round")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--quick", action="store_true", help="100 steps, 3 rounds")
    p.add_argument("--no-fused", dest="fused", action="store_false",
                   help="skip the fused env (needs no daemon then)")
    a = p.parse_args(argv)
    steps, rounds = (100, 3) if a.quick else (a.steps, a.rounds)
    print(f"{cpu_name()}; {steps} steps x {rounds} interleaved rounds per row, world {WORLD}, "
          f"chase view {CHASE_SIZE[0]}x{CHASE_SIZE[1]}", flush=True)
    table = measure(ROWS, steps, rounds)
    if a.fused:
        from active_vision import spawn_daemon

        name = f"record_cost_{uuid.uuid4().hex[:8]}"
        with spawn_daemon(name, len(FUSED_ROWS), extra_args=["--log-level", "WARNING"]):
            table.update(measure(FUSED_ROWS, steps, rounds, daemon_name=name))
    base = {"lidar": table[ROWS[0].name][0]}
    if a.fused:
        base["fused"] = table[FUSED_ROWS[0].name][0]
    width = max(len(name) for name in table)
    print(f"| {'row'.ljust(width)} | steps/s | vs no recording | MB / 1,000 steps |")
    print(f"|{'-' * (width + 2)}|---------|-----------------|------------------|")
    for row in ROWS + (FUSED_ROWS if a.fused else ()):
        rate, size = table[row.name]
        print(f"| {row.name.ljust(width)} | {rate:7,.0f} | {rate / base[row.env]:15.2f} | "
              f"{size:16.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
