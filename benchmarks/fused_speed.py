"""End-to-end speed of RoverEnvFused with a live av-daemon, and where the time goes.

    python benchmarks/fused_speed.py                # 1 env, then 2 envs on 2 slots
    python benchmarks/fused_speed.py --steps 500    # shorter

Per step the env advances physics (0.05 s of simulated time), renders its camera,
publishes the frame and waits for the daemon's fused frame. The table splits a step into
physics, render, and "daemon round trip" (publish -> fused frame received: the daemon's
perception plus two shared-memory hand-offs), and reports the pipeline efficiency

    efficiency = (physics + render + perception + 2 x IPC hand-off, each measured alone)
                 / (end-to-end step time)

where perception is the daemon's own network run alone in this process (same thread
count) and the hand-off is one FrameWriter -> FrameReader latency (p50). Everything that is
not one of those stages (observation building, reward, Python overhead, scheduling) makes
the efficiency drop below 1. The seed's way: its Gazebo loop runs in real time, 20 steps/s
at a 0.05 s control period, and its reset sleeps at least 11 s.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from active_vision.launcher import spawn_daemon  # noqa: E402

SEED_STEPS_PER_S = 20.0  # the seed steps in real time at 0.05 s control


def _timed(fn, acc: list[float]):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        acc.append(time.perf_counter() - t0)
        return out

    return wrapper


def run_env(name: str, slot: int, steps: int, world: str, out: mp.Queue) -> None:
    """Step one env ``steps`` times; put its timings on ``out``."""
    from rover_env.fused_env import RoverEnvFused

    env = RoverEnvFused(rl_obs_name=name, slot=slot, world_n=world)
    physics: list[float] = []
    render: list[float] = []
    env.sim.advance = _timed(env.sim.advance, physics)
    env.sim.render_camera = _timed(env.sim.render_camera, render)
    rng = np.random.default_rng(slot)
    actions = rng.uniform([-0.6, -np.pi], [1.0, np.pi], size=(steps, 2)).astype(np.float32)
    env.reset(seed=slot)
    for a in actions[:20]:  # warm-up
        env.step(a)
    physics.clear()
    render.clear()
    latency = []
    resets = 0
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, info = env.step(a)
        latency.append(info["frame_latency_ms"] / 1e3)
        if term or trunc:
            env.reset()
            resets += 1
    wall = time.perf_counter() - t0
    n = len(actions) + resets  # resets also render and round-trip one frame
    t_reset = time.perf_counter()
    env.reset(seed=slot + 100)
    reset_s = time.perf_counter() - t_reset
    env.close()
    out.put(
        {
            "wall": wall,
            "steps": len(actions),
            "physics": float(np.sum(physics)) / len(actions),
            "render": float(np.sum(render)) / n,
            "roundtrip": float(np.mean(latency)),
            "reset_s": reset_s,
        }
    )


def perception_alone(threads: int, n: int = 300) -> float:
    """Seconds per frame of the daemon's perception, batch 1, in this process."""
    import torch

    from active_vision import Perception, PerceptionConfig

    torch.set_num_threads(threads)
    perc = Perception(PerceptionConfig(threads=threads))
    frame = np.random.default_rng(0).integers(0, 255, (1, 96, 96, 3), dtype=np.uint8)
    for _ in range(20):
        perc(frame)
    t0 = time.perf_counter()
    for _ in range(n):
        perc(frame)
    return (time.perf_counter() - t0) / n


def ipc_handoff(n: int = 2000) -> float:
    """p50 seconds of one publish -> wait_next hand-off between two processes."""
    from shm_protocol import FrameWriter

    name = f"bench_fused_ipc_{os.getpid()}"
    w = FrameWriter(name, shape=(96, 96, 3), dtype=np.float32)
    ctx = mp.get_context("spawn")
    q: mp.Queue = ctx.Queue()
    child = ctx.Process(target=_ipc_child, args=(name, n, q))
    child.start()
    time.sleep(1.0)
    frame = np.zeros((96, 96, 3), np.float32)
    for i in range(n):
        frame[0, 0, 0] = i
        w.publish(frame, source_seq=i)
        time.sleep(0.0005)
    lat = q.get(timeout=60)
    child.join()
    w.close(unlink=True)
    return float(np.median(lat))


def _ipc_child(name: str, n: int, q: mp.Queue) -> None:
    sys.path.insert(0, str(ROOT))
    from shm_protocol import FrameReader, FrameTimeoutError

    r = FrameReader(name)
    lat = []
    out = np.empty((96, 96, 3), np.float32)
    while len(lat) < n:
        try:
            f = r.wait_next(timeout=1.0, out=out)
        except FrameTimeoutError:
            break
        lat.append(time.time() - f.timestamp)
    r.close()
    q.put(lat[10:])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=2000, help="steps per env")
    p.add_argument("--world", default="maze")
    p.add_argument("--threads", type=int, default=1, help="daemon torch threads")
    a = p.parse_args()

    alone_perc = perception_alone(a.threads)
    alone_ipc = ipc_handoff()
    rows = []
    for n_envs in (1, 2):
        name = f"bench_fused_{os.getpid()}_{n_envs}"
        with spawn_daemon(name, n_envs,
                          extra_args=["--threads", str(a.threads), "--log-level", "WARNING"]):
            ctx = mp.get_context("spawn")
            q: mp.Queue = ctx.Queue()
            procs = [
                ctx.Process(target=run_env, args=(name, i, a.steps, a.world, q))
                for i in range(n_envs)
            ]
            t0 = time.perf_counter()
            for pr in procs:
                pr.start()
            results = [q.get(timeout=600) for _ in procs]
            for pr in procs:
                pr.join()
            total = time.perf_counter() - t0
        agg = sum(r["steps"] / r["wall"] for r in results)
        r0 = results[0]
        step_s = r0["wall"] / r0["steps"]
        stages = r0["physics"] + r0["render"] + alone_perc + 2 * alone_ipc
        rows.append(
            (n_envs, agg, agg / SEED_STEPS_PER_S, step_s * 1e3, r0["physics"] * 1e3,
             r0["render"] * 1e3, r0["roundtrip"] * 1e3, alone_perc * 1e3, stages / step_s,
             r0["reset_s"] * 1e3, total)
        )  # fmt: skip

    print(
        f"\nRoverEnvFused end to end ({a.world}, {a.steps} steps per env, "
        f"daemon --threads {a.threads})"
    )
    print(
        f"perception alone: {alone_perc * 1e3:.2f} ms/frame; "
        f"IPC hand-off alone (p50): {alone_ipc * 1e6:.0f} us\n"
    )
    print(
        "| envs | steps/s (all envs) | x seed (20/s) | ms/step | physics ms | render ms "
        "| daemon round trip ms | perception alone ms | efficiency | reset ms |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]:.0f} | {r[2]:.1f}x | {r[3]:.2f} | {r[4]:.2f} | {r[5]:.2f} | "
              f"{r[6]:.2f} | {r[7]:.2f} | {r[8]:.2f} | {r[9]:.1f} |")  # fmt: skip
    print("\nms/step, physics, render, round trip and efficiency are those of env 0.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
