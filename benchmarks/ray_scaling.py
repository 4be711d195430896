"""Ray overhead and scaling of fused env stepping: rover-pair's local pipeline against RayVecEnv.

    python -m benchmarks.ray_scaling              # the full table (about 4 minutes)
    python -m benchmarks.ray_scaling --quick      # fewer seconds per row

Rows, all RoverEnvFused (maze) with constant actions, each env served by an av-daemon
with one torch thread:

- ``local 2 envs``: what ``rover-pair --slots 2 -- rover-train --slots 2`` runs: one daemon
  with 2 slots and rover-train's own vector env (SB3 SubprocVecEnv).
- ``ray W x M``: ``rover-train --ray --ray-workers W --envs-per-worker M`` on a local Ray
  cluster: W actors with M envs each, each actor with its own daemon with M slots.
- ``train``: the same two set-ups under PPO (n_steps 256 per env, 1 epoch, batch 256), so
  the overhead ratio also shows what it is once a learner shares the machine.

Columns: steps/s over all envs; CPU seconds per step spent by the env workers and their
daemons (from /proc, so it counts work, not waiting) and by the driver. The projection
for a cluster uses the measured worker cost: a node with C free cores adds about
C / (worker CPU s per step) steps/s, until the driver (one process, its CPU per step)
becomes the limit at 1 / (driver CPU s per step).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

CLK = os.sysconf("SC_CLK_TCK")
WORLD = "maze"


def cpu_s(pids: list[int]) -> float:
    """User + system CPU seconds of the live processes ``pids``."""
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        total += (int(fields[11]) + int(fields[12])) / CLK
    return total


def measure(venv: Any, seconds: float, warmup: int, pids: list[int]) -> dict[str, float]:
    """Step ``venv`` with constant actions for ``seconds``; throughput and CPU per step."""
    n = venv.num_envs
    actions = np.tile(np.array([[0.3, 0.0]], dtype=np.float32), (n, 1))
    venv.reset()
    for _ in range(warmup):
        venv.step(actions)
    t0, c0, d0 = time.perf_counter(), cpu_s(pids), time.process_time()
    steps = 0
    while time.perf_counter() - t0 < seconds:
        venv.step(actions)
        steps += n
    wall = time.perf_counter() - t0
    return {"steps_per_s": steps / wall, "worker_cpu": (cpu_s(pids) - c0) / steps,
            "driver_cpu": (time.process_time() - d0) / steps}  # fmt: skip


def measure_train(venv: Any, steps: int, pids: list[int]) -> dict[str, float]:
    """PPO learning ``steps`` steps on ``venv``: throughput and CPU per step."""
    import torch
    from stable_baselines3 import PPO

    from rover_train.policies import RoverExtractor

    torch.set_num_threads(1)
    model = PPO("MultiInputPolicy", venv, n_steps=256, batch_size=256, n_epochs=1, seed=0,
                policy_kwargs={"features_extractor_class": RoverExtractor})  # fmt: skip
    model.learn(256 * venv.num_envs)  # warm-up: one rollout and one update
    t0, c0, d0 = time.perf_counter(), cpu_s(pids), time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    wall = time.perf_counter() - t0
    done = steps
    return {"steps_per_s": done / wall, "worker_cpu": (cpu_s(pids) - c0) / done,
            "driver_cpu": (time.process_time() - d0) / done}  # fmt: skip


def run_local(n: int, seconds: float, warmup: int, train_steps: int) -> list[tuple[str, dict]]:
    """rover-pair's pipeline: one daemon with n slots, rover-train's SubprocVecEnv."""
    from active_vision.launcher import spawn_daemon
    from rover_train.train import TrainArgs, build_vec_env

    name = f"bench_ray_local_{uuid.uuid4().hex[:6]}"
    rows = []
    with spawn_daemon(name, n, extra_args=["--threads", "1"]) as daemon, \
            tempfile.TemporaryDirectory() as monitor_dir:  # fmt: skip
        args = TrainArgs(env="fused", world=WORLD, slots=n, name=name, connect_timeout=30.0)
        venv = build_vec_env(args, Path(monitor_dir))
        try:
            pids = [daemon.pid] + [p.pid for p in getattr(venv, "processes", [])]
            rows.append((f"local {n} envs (rover-pair)", measure(venv, seconds, warmup, pids)))
            if train_steps:
                rows.append((f"local {n} envs, PPO", measure_train(venv, train_steps, pids)))
        finally:
            venv.close()
    return rows


def run_ray(w: int, m: int, seconds: float, warmup: int, train_steps: int
            ) -> list[tuple[str, dict]]:  # fmt: skip
    from rover_train.ray_vec_env import RayVecEnv
    from rover_train.ray_worker import WorkerConfig

    venv = RayVecEnv(WorkerConfig(kind="fused", world=WORLD, envs_per_worker=m), w)
    rows = []
    try:
        pids = [p for d in venv.describe_workers() for p in (d["pid"], d["daemon_pid"]) if p]
        rows.append((f"ray {w} x {m}", measure(venv, seconds, warmup, pids)))
        if train_steps:
            rows.append((f"ray {w} x {m}, PPO", measure_train(venv, train_steps, pids)))
    finally:
        venv.close()
    return rows


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="5 s per row, 512 PPO steps")
    p.add_argument("--seconds", type=float, default=15.0, help="measured seconds per row")
    p.add_argument("--train-steps", type=int, default=1536, help="PPO steps per train row")
    p.add_argument("--rows", default="local,ray2x1,ray1x2,ray1x1,ray4x1",
                   help="which set-ups, comma-separated (to split a run over quiet windows)")
    args = p.parse_args()
    seconds = 5.0 if args.quick else args.seconds
    train_steps = 512 if args.quick else args.train_steps
    warmup = 20
    load = os.getloadavg()
    signal.signal(signal.SIGTERM, _interrupt)  # a timeout's SIGTERM still closes the workers
    import ray

    from rover_train.ray_vec_env import connect

    connect(None, num_cpus=4)
    rows: list[tuple[str, dict]] = []
    plan: dict[str, Callable[[], list[tuple[str, dict]]]] = {
        "local": lambda: run_local(2, seconds, warmup, train_steps),
        "ray2x1": lambda: run_ray(2, 1, seconds, warmup, train_steps),
        "ray1x2": lambda: run_ray(1, 2, seconds, warmup, 0),
        "ray1x1": lambda: run_ray(1, 1, seconds, warmup, 0),
        "ray4x1": lambda: run_ray(4, 1, seconds, warmup, 0),
    }
    cores = os.cpu_count() or 1
    print(f"{time.strftime('%Y-%m-%d %H:%M %Z')}, {cores} cores, load average at start "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, {seconds:.0f} s per row\n")  # fmt: skip
    print("| set-up | steps/s | worker+daemon CPU ms/step | driver CPU ms/step |")
    print("|---|---:|---:|---:|", flush=True)
    try:
        for key in args.rows.split(","):
            for label, r in plan[key.strip()]():
                rows.append((label, r))
                print(f"| {label} | {r['steps_per_s']:.1f} | {1e3 * r['worker_cpu']:.2f} | "
                      f"{1e3 * r['driver_cpu']:.2f} |", flush=True)  # fmt: skip
    finally:
        ray.shutdown()
    res = dict(rows)
    print()
    summarise(res)
    subprocess.run(["uptime"], check=False)
    return 0


def summarise(res: dict[str, dict[str, float]]) -> None:
    """The overhead ratios, the scaling line and the projection, from the rows that ran."""
    if "local 2 envs (rover-pair)" not in res or "ray 2 x 1" not in res:
        return
    local, ray2 = res["local 2 envs (rover-pair)"], res["ray 2 x 1"]
    print(f"\nRay overhead ratio, 2 envs, stepping: local / Ray = "
          f"{local['steps_per_s'] / ray2['steps_per_s']:.2f}")  # fmt: skip
    if "local 2 envs, PPO" in res and "ray 2 x 1, PPO" in res:
        print(f"Ray overhead ratio, 2 envs, PPO training: local / Ray = "
              f"{res['local 2 envs, PPO']['steps_per_s'] / res['ray 2 x 1, PPO']['steps_per_s']:.2f}")  # noqa: E501
    if "ray 1 x 1" not in res:
        return
    one = res["ray 1 x 1"]
    for w in (1, 2, 4):
        if f"ray {w} x 1" not in res:
            continue
        r = res[f"ray {w} x 1"]
        print(f"ray {w} worker(s): {r['steps_per_s']:.1f} steps/s = "
              f"{r['steps_per_s'] / one['steps_per_s']:.2f}x one worker")  # fmt: skip
    per_worker = one["worker_cpu"]
    driver = ray2["driver_cpu"]
    print(f"\nProjection: each worker (1 env + its daemon) costs {1e3 * per_worker:.2f} CPU ms "
          f"per step, so a node with C free cores adds about C / {1e3 * per_worker:.2f} ms = "
          f"{1 / per_worker:.0f} x C steps/s (e.g. {8 / per_worker:.0f} steps/s for 8 cores);"
          f" the driver spends {1e3 * driver:.2f} CPU ms per step, which caps one driver at "
          f"about {1 / driver:.0f} steps/s before learning.")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
