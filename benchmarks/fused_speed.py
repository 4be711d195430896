"""End-to-end speed of RoverEnvFused with a live av-daemon, and where the time goes,
for each perception backend (torch and onnx) side by side in one run.

    python -m benchmarks.fused_speed                     # both backends, 1 and 2 envs, training
    python -m benchmarks.fused_speed --steps 500 --train-steps 0   # shorter, no training rows
    python -m benchmarks.fused_speed --backends onnx     # one backend
    python -m benchmarks.fused_speed --backends onnx --precision fp32,int8 --repeats 3 \
        --train-steps 0                           # both precisions, interleaved
    python -m benchmarks.fused_speed --backends onnx --spin-wait auto,off --envs 1 \
        --repeats 3 --train-steps 0               # env and daemon spinning, and not

Every env row is one (backend, precision) combination: the daemon runs with ``--backend B
--precision P``. With ``--repeats N`` all rows are run N times in interleaved rounds and
each cell is the median over the rounds; the last column gives each row's steps/s at the
first env count over the first row's (measured in the same run).

For each backend the daemon (``av-daemon --backend B``) serves 1 env, then 2 envs on 2
slots (``--envs``: other counts, each env its own process; the rows of 2+ envs once per
``--workers`` value: 0, the default, is the daemon's own choice, a worker thread per core,
and ``--workers 1,0`` adds the one-loop daemon in the same run; every row once per
``--spin-wait`` value: ``auto``, the default, lets env and daemon watch for each other's
frames before sleeping where there are two cores per slot, ``off`` never); then ``rover-train --env
fused`` (PPO, rover-train's defaults, 1 env) trains for ``--train-steps`` steps against a
daemon of that backend and its steps/s is read from its ``metrics.json`` (plus one run of
the last backend with the PPO update on every core, ``--update-threads 0``).

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
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from active_vision.launcher import spawn_daemon
from fused_image import FUSED_SHAPE, FUSED_SIZE

ROOT = Path(__file__).resolve().parents[1]

SEED_STEPS_PER_S = 20.0  # the seed steps in real time at 0.05 s control


def _timed(fn, acc: list[float]):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        acc.append(time.perf_counter() - t0)
        return out

    return wrapper


def run_env(name: str, slot: int, steps: int, world: str, out: mp.Queue,
            spin_wait: bool | None = None) -> None:
    """Step one env ``steps`` times; put its timings on ``out``."""
    from rover_env.fused_env import RoverEnvFused

    env = RoverEnvFused(rl_obs_name=name, slot=slot, world_n=world, report_latency=True,
                        spin_wait=spin_wait)
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


def perception_alone(threads: int, backend: str, n: int = 300,
                     weights: Path | None = None, precision: str = "int8") -> float:
    """Seconds per frame of the daemon's perception, batch 1, in this process."""
    import torch

    from active_vision import Perception, PerceptionConfig

    torch.set_num_threads(threads)
    perc = Perception(PerceptionConfig(threads=threads, backend=backend, weights=weights,
                                       precision=precision))  # type: ignore[arg-type]
    frame = np.random.default_rng(0).integers(0, 255, (1, *FUSED_SIZE, 3), dtype=np.uint8)
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
    w = FrameWriter(name, shape=FUSED_SHAPE, dtype=np.float32)
    ctx = mp.get_context("spawn")
    q: mp.Queue = ctx.Queue()
    child = ctx.Process(target=_ipc_child, args=(name, n, q))
    child.start()
    time.sleep(1.0)
    frame = np.zeros(FUSED_SHAPE, np.float32)
    for i in range(n):
        frame[0, 0, 0] = i
        w.publish(frame, source_seq=i)
        time.sleep(0.0005)
    lat = q.get(timeout=60)
    child.join()
    w.close(unlink=True)
    return float(np.median(lat))


def _ipc_child(name: str, n: int, q: mp.Queue) -> None:
    from shm_protocol import FrameReader, FrameTimeoutError

    r = FrameReader(name)
    lat = []
    out = np.empty(FUSED_SHAPE, np.float32)
    while len(lat) < n:
        try:
            f = r.wait_next(timeout=1.0, out=out)
        except FrameTimeoutError:
            break
        lat.append(time.time() - f.timestamp)
    r.close()
    q.put(lat[10:])


def daemon_args(threads: int, backend: str, weights: Path | None = None,
                precision: str | None = None, workers: int | None = None,
                spin_wait: str = "auto") -> list[str]:
    extra = ["--weights", str(weights)] if weights is not None else []
    if precision is not None:
        extra += ["--precision", precision]
    if workers is not None:
        extra += ["--workers", str(workers)]
    extra += ["--spin-wait", spin_wait]
    return ["--threads", str(threads), "--backend", backend, "--log-level", "WARNING", *extra]


def run_envs(name: str, n_envs: int, steps: int, world: str,
             spin_wait: str = "auto") -> tuple[list[dict], float]:
    ctx = mp.get_context("spawn")
    q: mp.Queue = ctx.Queue()
    spin = {"auto": None, "on": True, "off": False}[spin_wait]
    procs = [ctx.Process(target=run_env, args=(name, i, steps, world, q, spin))
             for i in range(n_envs)]
    t0 = time.perf_counter()
    for pr in procs:
        pr.start()
    results = [q.get(timeout=600) for _ in procs]
    for pr in procs:
        pr.join()
    return results, time.perf_counter() - t0


def train_speed(backend: str, steps: int, threads: int, world: str,
                extra: tuple[str, ...] = ()) -> float:
    """rover-train --env fused steps/s (its own metrics.json) against a ``backend`` daemon."""
    import json
    import tempfile

    name = f"bench_fused_train_{os.getpid()}_{backend}"
    with spawn_daemon(name, 1, extra_args=daemon_args(threads, backend)):
        with tempfile.TemporaryDirectory(prefix="roverav_bench_train_") as tmp:
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            subprocess.run(
                [sys.executable, "-m", "rover_train.train", "--env", "fused", "--world", world,
                 "--timesteps", str(steps), "--name", name, "--logdir", tmp,
                 "--no-progress", "--checkpoint-every", "0", *extra],
                check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            metrics = json.loads((Path(tmp) / "metrics.json").read_text())
    return float(metrics["steps_per_s"])


def env_rows(a: argparse.Namespace, backends: list[str]) -> None:
    """The env-stepping table: per (backend, precision) row, 1 env then 2 envs on 2
    slots, ``--repeats`` interleaved rounds, medians."""
    alone_ipc = ipc_handoff()
    precisions = [p.strip() for p in a.precision.split(",") if p.strip()]
    # (backend, precision, weights file or None for the shipped one): rows in run order
    runs = [(b, p, None) for b in backends for p in precisions]
    runs += [(b, p, w) for w in a.weights for b in backends for p in precisions]
    # perception alone is timed again right before each row of each round (the machine's
    # load drifts; a figure taken minutes apart makes "round trip - perception" meaningless)
    alone_perc: dict[int, list[float]] = {}
    print(
        f"\nRoverEnvFused end to end ({a.world}, {a.steps} steps per env, "
        f"daemon --threads {a.threads}, {a.repeats} interleaved round(s), medians); "
        f"IPC hand-off alone (p50): {alone_ipc * 1e6:.0f} us", flush=True
    )
    cells: dict[tuple[int, int, int, str], list[tuple[float, ...]]] = {}
    # (envs, daemon --workers, --spin-wait): one env has one worker whatever is asked
    env_cells = [(n, w, sp) for n in a.envs for w in (a.workers if n > 1 else a.workers[:1])
                 for sp in a.spin_wait]
    for r in range(a.repeats):
        for k, (backend, precision, weights) in enumerate(runs):
            alone_perc.setdefault(k, []).append(
                perception_alone(a.threads, backend, n=200, weights=weights,
                                 precision=precision))
            for n_envs, workers, spin in env_cells:
                name = f"bench_fused_{os.getpid()}_{r}_{k}_{n_envs}_{workers}_{spin}"
                with spawn_daemon(name, n_envs, extra_args=daemon_args(
                        a.threads, backend, weights, precision, workers, spin)):
                    results, _ = run_envs(name, n_envs, a.steps, a.world, spin)
                r0 = results[0]
                cells.setdefault((k, n_envs, workers, spin), []).append((
                    sum(x["steps"] / x["wall"] for x in results), r0["wall"] / r0["steps"],
                    r0["physics"], r0["render"], r0["roundtrip"], r0["reset_s"]))
    print(
        "\n| backend | precision | envs | daemon workers | spin wait | steps/s (all envs) "
        "| x seed (20/s) "
        "| ms/step | physics ms | render ms | daemon round trip ms | perception alone ms "
        f"| round trip - perception ms | efficiency | reset ms | {a.envs[0]}-env steps/s / row 1 |"
    )
    print("|---" * 16 + "|", flush=True)
    base = None
    for k, (backend, precision, weights) in enumerate(runs):
        label = backend if weights is None else f"{backend}, {weights.name}"
        perc = float(np.median(alone_perc[k]))
        for n_envs, workers, spin in env_cells:
            agg, step_s, phys, rend, rt, reset_s = np.median(
                np.array(cells[(k, n_envs, workers, spin)]), axis=0)
            stages = phys + rend + perc + 2 * alone_ipc
            ratio = ""
            if n_envs == a.envs[0]:
                base = agg if base is None else base
                ratio = f"{agg / base:.2f}x"
            shown = "1" if n_envs == 1 else (str(workers) if workers else "auto")
            print(f"| {label} | {precision} | {n_envs} | {shown} | {spin} | {agg:.0f} | "
                  f"{agg / SEED_STEPS_PER_S:.1f}x | {step_s * 1e3:.2f} | {phys * 1e3:.2f} | "
                  f"{rend * 1e3:.2f} | {rt * 1e3:.2f} | {perc * 1e3:.2f} | "
                  f"{(rt - perc) * 1e3:.2f} | {stages / step_s:.2f} | {reset_s * 1e3:.1f} | "
                  f"{ratio} |", flush=True)  # fmt: skip
    print("\nms/step, physics, render, round trip and efficiency are those of env 0.")


def _int_list(text: str, low: int, what: str, example: str) -> list[int]:
    try:
        counts = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < low:
        raise argparse.ArgumentTypeError(
            f"give {what} separated by commas, e.g. {example}; got {text!r}")
    return counts


def env_counts(text: str) -> list[int]:
    """``--envs``: comma-separated positive env counts."""
    return _int_list(text, 1, "positive env counts", "1,2,8")


def worker_counts(text: str) -> list[int]:
    """``--workers``: comma-separated daemon worker counts (0: the daemon's default)."""
    return _int_list(text, 0, "worker counts >= 0", "1,0")


def spin_choices(text: str) -> list[str]:
    """``--spin-wait``: comma-separated auto / on / off."""
    values = [x.strip() for x in text.split(",") if x.strip()]
    if not values or any(v not in ("auto", "on", "off") for v in values):
        raise argparse.ArgumentTypeError(
            f"give auto, on or off separated by commas, e.g. auto,off; got {text!r}")
    return values


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=2000, help="steps per env")
    p.add_argument("--world", default="maze")
    p.add_argument("--threads", type=int, default=1, help="daemon threads")
    p.add_argument("--backends", default="torch,onnx", help="comma-separated, in run order")
    p.add_argument("--precision", default="int8",
                   help="comma-separated daemon --precision values, in run order (fp32,int8)")
    p.add_argument("--repeats", type=int, default=1,
                   help="interleaved rounds of all env rows; cells are medians")
    p.add_argument("--envs", type=env_counts, default=[1, 2],
                   help="comma-separated env counts of the env rows, each on its own daemon "
                   "slot (default 1,2); the last column compares the first count's rows")
    p.add_argument("--workers", type=worker_counts, default=[0],
                   help="comma-separated daemon --workers values for the rows of 2+ envs, "
                   "in run order (0: the daemon's default, a worker per core; 1: one loop "
                   "batching every slot), e.g. 1,0 to compare")
    p.add_argument("--spin-wait", type=spin_choices, default=["auto"],
                   help="comma-separated env spin_wait / av-daemon --spin-wait values, every "
                   "env row once per value, in run order (auto: spin where there are two "
                   "cores per slot; off: sleep at once), e.g. auto,off to compare")
    p.add_argument("--train-steps", type=int, default=5120,
                   help="rover-train --env fused steps per backend (0: skip)")
    p.add_argument("--skip-envs", action="store_true", help="only the training rows")
    p.add_argument("--weights", type=Path, action="append", default=[],
                   help="env rows also with the daemon on this weights file (repeatable), "
                   "in the same run, e.g. the previous network")
    a = p.parse_args()
    for w in a.weights:
        if not w.is_file():
            p.error(f"--weights {w}: no such file")
    backends = [b.strip() for b in a.backends.split(",") if b.strip()]

    if not a.skip_envs:
        env_rows(a, backends)
    if a.train_steps > 0:
        print(f"\nrover-train --env fused ({a.world}, PPO defaults, 1 env, "
              f"{a.train_steps} steps):\n")
        print("| backend, PPO update threads | training steps/s |\n|---|---|", flush=True)
        for b in backends:
            sps = train_speed(b, a.train_steps, a.threads, a.world)
            print(f"| {b}, update on 1 thread (default) | {sps:.0f} |", flush=True)
        # the PPO update on every core (pays only when the other cores are idle)
        b = backends[-1]
        sps = train_speed(b, a.train_steps, a.threads, a.world, ("--update-threads", "0"))
        print(f"| {b}, update on all cores (--update-threads 0) | {sps:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
