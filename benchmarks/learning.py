"""Does it learn? The learners side by side, PPO against the random policy, and learning
curves of the zoo's recipe.

    python -m benchmarks.learning --table maze --row PPO=runs/rl-maze --row DAgger=zoo:lidar-maze
    python -m benchmarks.learning                      # lidar: 3 seeds x 100k steps; fused: 2 x 20k
    python -m benchmarks.learning --lidar-steps 30000 --seeds 1 --fused-steps 0   # quick look
    python -m benchmarks.learning --curves --world maze --budget 160000 --points 8 --episodes 30

``--curves`` trains, in one run and with the same env-step budget on RoverEnv, the zoo's
recipe (DAgger from the planner expert, ``rover_train.imitation.distill``) and rover-train's PPO
defaults, evaluating both after every ``budget / points`` steps on the same evaluation
episodes (the zoo's seeds and 600-step rule). DAgger also gets the recipe's 30,000
expert-labelled states drawn without driving (not env steps; their time is in its wall
clock). It prints a table (steps, wall-clock s of training, success, collisions, SPL) and
writes the curves to ``docs/learning_curves.png``.

``--table WORLD`` is the one table of what each learner reached: every ``--row LABEL=SOURCE``
is evaluated on the same evaluation episodes (rover-eval's: seeds from 100000, 600 steps,
the first goal ends an episode) and shown with the env steps and the wall-clock time its
training took. A SOURCE is a rover-train run directory (its ``model.zip``, or the newest
checkpoint of a run stopped early; steps from its ``metrics.json``, time from the parts of the
run in its ``run.json``), a student file (a DAgger student: steps from its recipe; a fine-tuned
one, ``rover_train.imitation.finetune``: its own steps and time plus its start's), or
``zoo:NAME`` for a zoo entry's file. Training time is in the artefacts where they record it
(rover-train's runs and fine-tunes; a DAgger student's file does not).

Without ``--table`` or ``--curves``: for each seed it trains with rover-train's own code,
then evaluates the trained policy and the random policy on the same fixed evaluation seeds
(rover-eval's code) and prints one table. The fused part starts its own av-daemon on a
private segment name.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from active_vision.launcher import spawn_daemon
from rover_train import evaluate
from rover_train.agents import RandomAgent
from rover_train.envs import make_env
from rover_train.train import TrainArgs, train

EPISODE_SEED_BASE = 5000  # the seed-comparison table's episodes: reset(seed=5000 + i)


def evaluate_policy(
    kind: str, world: str, model: Path | None, episodes: int, max_steps: int, shm: str
) -> dict:
    env = make_env(kind, world=world, name=shm)
    try:
        agent = (evaluate.load_policy(model, env, "ppo") if model
                 else RandomAgent(env.action_space, EPISODE_SEED_BASE))  # fmt: skip
        results = evaluate.evaluate_agent(env, agent, episodes, EPISODE_SEED_BASE, max_steps)
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
            evaluate.run_episode(env, act, EPISODE_SEED_BASE + i, max_steps, None)
            for i in range(episodes)
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
                checkpoint_every=0, progress=False, name=shm, length=1000,
                slots=4 if kind == "lidar" else 1,
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


def _eval_episodes(env: object, act: object, episodes: int) -> dict:
    from rover_train.zoo import EVAL_MAX_STEPS, EVAL_SEED_BASE

    results = [
        evaluate.run_episode(env, act, EVAL_SEED_BASE + i, EVAL_MAX_STEPS, None)
        for i in range(episodes)
    ]
    return evaluate.summarise(results)


def curve_dagger(world: str, budget: int, points: int, episodes: int) -> list[dict]:
    """One student of the zoo's LIDAR entry for ``world`` made as its command makes its first
    member (seed 0, its teacher's manners, its features), evaluated after each round."""
    from rover_train.imitation.dagger import feature_spec, make_training_env, run_dagger
    from rover_train.imitation.distill import RECIPES
    from rover_train.zoo import StudentAgent, StudentNet

    recipe = RECIPES[f"lidar-{world}"]
    env = make_training_env("lidar", world)
    eval_env = make_env("lidar", world=world)
    rows: list[dict] = []
    history: list[dict] = []
    try:
        import torch

        torch.manual_seed(0)  # as distill seeds a member (seed 0) before building it
        spec = feature_spec("lidar", env, unmapped_scan=recipe.unmapped_scan)
        agent = StudentAgent(StudentNet(spec))

        def on_round(steps: int, student: StudentAgent) -> None:
            s = _eval_episodes(eval_env, student.act, episodes)
            rows.append({"steps": steps, **s})

        cfg = replace(recipe.dagger(), iterations=points, steps=budget // points,
                      status_every=30.0)
        run_dagger(env, world, agent, cfg, "curve dagger", history, on_round)
    finally:
        env.close()
        eval_env.close()
    for row, h in zip(rows, history, strict=True):
        row["wall_s"] = h["wall_s"]
    return rows


def curve_ppo(world: str, budget: int, points: int, episodes: int) -> list[dict]:
    from rover_train.train import build_model, build_vec_env

    rows: list[dict] = []
    eval_env = make_env("lidar", world=world)
    with tempfile.TemporaryDirectory() as tmp:
        args = TrainArgs(
            env="lidar", world=world, timesteps=budget, logdir=Path(tmp), checkpoint_every=0,
            progress=False, length=1000, slots=4,
        )  # fmt: skip
        venv = build_vec_env(args, Path(tmp))
        try:
            model = build_model(args, venv, Path(tmp) / "tb")
            wall = 0.0
            for k in range(points):
                t0 = time.perf_counter()
                model.learn(budget // points, reset_num_timesteps=k == 0)
                wall += time.perf_counter() - t0
                s = _eval_episodes(
                    eval_env, lambda o: model.predict(o, deterministic=True)[0], episodes
                )
                rows.append({"steps": model.num_timesteps, "wall_s": wall, **s})
                print(f"curve ppo: {model.num_timesteps} steps, success "
                      f"{s['success_rate']:.0%}", flush=True)  # fmt: skip
        finally:
            venv.close()
            eval_env.close()
    return rows


def curves(world: str, budget: int, points: int, episodes: int, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = {
        "DAgger from the planner expert (zoo recipe)": curve_dagger(
            world, budget, points, episodes
        ),
        "PPO, rover-train defaults": curve_ppo(world, budget, points, episodes),
    }
    print("\n| recipe | env steps | train wall s | success | collisions | SPL |\n"
          "|---|---|---|---|---|---|")  # fmt: skip
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for label, rows in results.items():
        for r in rows:
            print(f"| {label} | {r['steps']} | {r['wall_s']:.0f} | {r['success_rate']:.0%} | "
                  f"{r['collision_rate']:.0%} | {r['spl']:.2f} |")  # fmt: skip
        ax.plot(
            [r["steps"] for r in rows], [100 * r["success_rate"] for r in rows], "o-",
            label=f"{label} ({rows[-1]['wall_s']:.0f} s)",
        )  # fmt: skip
    ax.set_xlabel("env steps (RoverEnv)")
    ax.set_ylabel(f"evaluation success (%), {episodes} episodes")
    ax.set_ylim(-5, 105)
    ax.set_title(f"learning curves, {world}, same budget (train wall-clock in brackets)")
    ax.legend(fontsize=8, loc="center right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=100)
    print(f"wrote {png}")


def dagger_steps(recipe: dict) -> int:
    """Env steps a DAgger recipe drives: each member's rounds (synthetic states apart)."""
    return int(recipe["members"]) * int(recipe["iterations"]) * int(recipe["steps"])


def _rl_entry(model: Path, world: str) -> str:
    """The zoo RL entry a model is evaluated as: the camera agents' (``rl-fused-WORLD``: the
    fused env with the camera scan, actions sampled) for a model trained on a fused env,
    else the LIDAR agents' (``rl-lidar-WORLD``)."""
    from rover_train.recipe import read_recipe

    return f"rl-{'fused' if read_recipe(model)['env'].startswith('fused') else 'lidar'}-{world}"


def table_source(source: str, world: str) -> tuple[str, object, int, str]:
    """A table row's (zoo entry whose env it drives, agent, env steps, training wall-clock)."""
    import json

    from rover_train import zoo

    if source.startswith("zoo:"):
        source = str(zoo.ENTRIES[source[4:]].path)
    path = Path(source)
    if path.is_dir():
        metrics = json.loads((path / "metrics.json").read_text())
        model = path / "model.zip"
        if not model.is_file():  # a run stopped early: its newest checkpoint
            model = max((path / "checkpoints").glob("*_steps.zip"),
                        key=lambda f: int(f.stem.split("_")[-2]))  # fmt: skip
        entry = _rl_entry(model, world)
        agent = zoo.load(entry, model)
        # metrics.json times the last part of a resumed run; run.json has every part
        parts = json.loads((path / "run.json").read_text()).get("history", [])
        done = [p["ended_at"] - p["started_at"] for p in parts if p.get("ended_at")]
        minutes = (sum(done) if done else float(metrics["wall_time_s"])) / 60
        return entry, agent, int(metrics["timesteps"]), f"{minutes:.0f} min"
    if path.suffix == ".zip":
        entry = _rl_entry(path, world)
        agent = zoo.load(entry, path)
        return entry, agent, int(agent.model.num_timesteps), "-"
    agent = zoo.StudentAgent.load(path)
    recipe = agent.meta.get("recipe") or {}
    entry = str(agent.meta.get("name") or f"lidar-{world}")
    if "finetune" in agent.meta:
        start = zoo.StudentAgent.read_meta(zoo.ENTRIES[recipe["start"]].path)["recipe"]
        done = agent.meta["finetune"]
        clock = f"DAgger's + {float(done['wall_s']) / 60:.0f} min"
        return entry, agent, dagger_steps(start) + int(done["steps"]), clock
    return entry, agent, dagger_steps(recipe), "-"


def table(world: str, rows: list[str], episodes: int, seed: int) -> None:
    """Evaluate each ``LABEL=SOURCE`` on the same episodes and print one table (a fused row
    attaches to the daemon of ``$ROVERAV_SHM_NAME``: run under rover-pair)."""
    from rover_train.suite import wilson_interval

    def pct(k: int, n: int) -> str:
        lo, hi = wilson_interval(k, n)
        return f"{100 * k / n:.1f} % [{100 * lo:.0f}-{100 * hi:.0f}]"

    print(f"{world}: {episodes} evaluation episodes from seed {seed} (600 steps, the first "
          "goal ends an episode); brackets: 95 % Wilson intervals\n")  # fmt: skip
    print("| learner | env steps | training wall-clock | success | episodes with a collision "
          "| timeouts | SPL |\n|---|---:|---:|---|---|---:|---:|", flush=True)  # fmt: skip
    for row in rows:
        label, _, source = row.partition("=")
        entry, agent, steps, clock = table_source(source, world)
        env = evaluate.entry_env(entry, world_n=world)
        try:
            s = evaluate.summarise(evaluate.evaluate_agent(env, agent, episodes, seed))
        finally:
            env.close()
        n = s["episodes"]
        ok, hit = round(s["success_rate"] * n), round(s["collision_rate"] * n)
        print(f"| {label} | {steps:,} | {clock} | {pct(ok, n)} | {pct(hit, n)} | "
              f"{s['timeouts']} | {s['spl']:.2f} |", flush=True)  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--table", metavar="WORLD", help="evaluate the --row sources in WORLD")
    p.add_argument("--row", action="append", default=[], metavar="LABEL=SOURCE",
                   help="--table: a run directory, a model .zip, a student .pt or zoo:NAME")
    p.add_argument("--seed", type=int, default=100_000, help="--table: the first episode seed")
    p.add_argument("--curves", action="store_true", help="DAgger vs PPO learning curves")
    p.add_argument("--budget", type=int, default=30_000, help="--curves: env steps each")
    p.add_argument("--points", type=int, default=3, help="--curves: evaluations per curve")
    p.add_argument(
        "--png", type=Path, default=Path(__file__).resolve().parents[1] / "docs/learning_curves.png"
    )
    p.add_argument("--world", default="maze")
    p.add_argument("--lidar-steps", type=int, default=400_000)
    p.add_argument("--fused-steps", type=int, default=20_000)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--fused-seeds", type=int, default=2)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--max-steps", type=int, default=600)
    a = p.parse_args()
    if a.table:
        if not a.row or any("=" not in r for r in a.row):
            p.error("--table needs one or more --row LABEL=SOURCE")
        import torch

        torch.set_num_threads(1)
        table(a.table, a.row, a.episodes, a.seed)
        return 0
    if a.curves:
        import torch

        torch.set_num_threads(1)
        curves(a.world, a.budget, a.points, a.episodes, a.png)
        return 0
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
