"""The main job before the camera agent learnt from the reward (``rover_train.demo`` now):
fine-tune the zoo's fused navigator with the daemon in the loop, evaluate it.

Run under the supervisor so the daemon is there (``make demo-finetune`` does this):

    rover-pair -- python -m rover_train.imitation.demo --timesteps 24000

It starts from the shipped zoo entry ``fused-<world>`` (a student distilled from the
privileged planner expert, see ``rover_train.imitation.distill``), fine-tunes it for ``--timesteps``
env steps of DAgger on RoverEnvFused with the daemon's fused images, then evaluates the
zoo entry as shipped, the fine-tuned student and a seeded random policy on the same
``--episodes`` evaluation episodes (reset seeds from 100000, never used in training; each
ends at the first goal, a termination or ``--max-steps``). The recorded episodes cost
several times an evaluation step for the chase render and the labels (the main job's
time: benchmarks/RESULTS.md, "The main job").

Leaves under ``--out`` (default ``runs/demo``): ``student.pt`` (the fine-tuned agent,
loadable with ``rover_train.zoo.StudentAgent.load``), ``metrics.json``,
``learning_curve.png``, ``eval.txt`` (the table: the zoo entry before fine-tuning, the
fine-tuned student and random, side by side), ``eval.mp4`` (the fine-tuned student's first
``--video-episodes``: chase view with the goal's direction beside the gray, heatmap and
depth channels, labelled with the step, the distance to the goal and the outcome) and
``eval_still.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rover_train import zoo
from rover_train.agents import RandomAgent
from rover_train.demo import quiet_logs, save_still
from rover_train.evaluate import (
    evaluate_agent,
    format_comparison,
    summarise,
    write_video,
)
from rover_train.imitation.dagger import (
    DAggerConfig,
    make_training_env,
    run_dagger,
    stage2_config,
)
from rover_train.imitation.distill import RECIPES
from rover_train.progress import StatusLine
from roverav_cli import Episodes, add_group
from shm_protocol import default_name


def plot_curve(
    history: list[dict[str, float]],
    trained: dict[str, Any],
    random: dict[str, Any],
    path: Path,
    before: dict[str, Any] | None = None,
) -> None:
    """Success of the fine-tuning rounds' episodes against env steps, with the evaluation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    steps = [h["steps"] for h in history]
    success = [100 * h["success"] for h in history]
    ax.plot(steps, success, "o-", label="DAgger rounds (training episodes, end of round)")
    if before is not None:
        ax.axhline(100 * before["success_rate"], color="b", ls="-.", label="zoo entry, evaluation")
    ax.axhline(100 * trained["success_rate"], color="g", ls="--", label="fine-tuned, evaluation")
    ax.axhline(100 * random["success_rate"], color="r", ls=":", label="random, evaluation")
    ax.set_xlabel("fine-tuning env steps (daemon in the loop)")
    ax.set_ylabel("episodes reaching the goal (%)")
    ax.set_ylim(-5, 105)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("fused navigator: fine-tuned from the zoo entry")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rover_train.imitation.demo", description=__doc__.split("\n")[0]
    )
    add_group(p, Episodes, only=("world", "episodes", "max_steps")).description = (
        "the zoo entry fused-WORLD (inspect or maze; default maze) is fine-tuned, then it, "
        "the result and a random policy are evaluated on the evaluation seeds")
    p.add_argument(
        "--timesteps", type=int, default=24000, help="fine-tuning env steps (0: evaluate only)"
    )
    p.add_argument("--rounds", type=int, default=6, help="DAgger rounds the steps are split in")
    p.add_argument("--seed", type=int, default=0, help="seeds fine-tuning and the random policy")
    p.add_argument("--video-episodes", type=int, default=2)
    p.add_argument(
        "--fit-threads", type=int, default=DAggerConfig.fit_threads,
        help="torch threads for the fine-tune's fits (0: all cores; collection uses 1)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    return p


def main(argv: Sequence[str] | None = None) -> int:
    quiet_logs()
    p = _parser()
    args = p.parse_args(argv)
    args.world = args.world or "maze"
    if args.world not in ("inspect", "maze"):
        p.error(f"--world {args.world}: the demo fine-tunes fused-inspect or fused-maze")
    import torch

    torch.set_num_threads(1)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    name = f"fused-{args.world}"
    shm = default_name()
    t_start = time.monotonic()
    agent = zoo.load(name)
    print(f"demo: starting from zoo entry {name} ({zoo.command(name)})", flush=True)

    history: list[dict[str, float]] = []
    if args.timesteps > 0:
        env = make_training_env("fused", args.world, name=shm)
        try:
            rounds = max(1, args.rounds)
            cfg = stage2_config(
                DAggerConfig(
                    epochs=4,
                    lr=3e-4,
                    seed=args.seed + 1,
                    fit_threads=args.fit_threads,
                    teacher_sees=RECIPES[name].teacher_sees,
                    teacher_velocity=RECIPES[name].teacher_velocity,
                ),
                iterations=rounds,
                steps=max(1, args.timesteps // rounds),
            )
            run_dagger(env, args.world, agent, cfg, label="demo fine-tune", history=history)
        finally:
            env.close()
    agent.meta = {**agent.meta, "fine_tuned_steps": args.timesteps}
    agent.save(out / "student.pt")
    # evaluate the file the user keeps: it stores fp16 weights, and the in-memory fp32
    # student drove some episodes differently (mean seed return -235 against -295)
    agent = zoo.StudentAgent.load(out / "student.pt")
    t_train = time.monotonic() - t_start

    env = zoo.make_env(name, rl_obs_name=shm, render_mode="rgb_array")
    frames: list[Any] = []
    try:
        total = args.episodes * args.max_steps
        before_res = evaluate_agent(
            env, zoo.load(name), args.episodes, zoo.EVAL_SEED_BASE, args.max_steps,
            status=StatusLine("demo eval (zoo entry)", total),
        )  # fmt: skip
        trained_res = evaluate_agent(
            env, agent, args.episodes, zoo.EVAL_SEED_BASE, args.max_steps, frames,
            args.video_episodes, StatusLine("demo eval (trained)", total),
        )  # fmt: skip
        random_res = evaluate_agent(
            env, RandomAgent(env.action_space, args.seed), args.episodes, zoo.EVAL_SEED_BASE,
            args.max_steps, status=StatusLine("demo eval (random)", total),
        )  # fmt: skip
        fps = 1.0 / float(env.unwrapped.control_dt)
    finally:
        env.close()
    before, trained, random = map(summarise, (before_res, trained_res, random_res))
    seeds = f"seeds {zoo.EVAL_SEED_BASE}..{zoo.EVAL_SEED_BASE + args.episodes - 1}"
    report = format_comparison(
        [
            (f"zoo {name} (before)", before),
            (f"fine-tuned ({args.timesteps} steps)", trained),
            (f"random policy (seed {args.seed})", random),
        ],
        f"{name} on {seeds}, at most {args.max_steps} steps each",
    )
    (out / "eval.txt").write_text(report + "\n")
    if frames:
        write_video(frames, out / "eval.mp4", fps)
        save_still(out / "eval.mp4", out / "eval_still.png")
    plot_curve(history, trained, random, out / "learning_curve.png", before)
    wall = time.monotonic() - t_start
    metrics = {
        "entry": name,
        "fine_tune_steps": args.timesteps,
        "history": history,
        "before": before,
        "trained": trained,
        "random": random,
        "train_wall_s": t_train,
        "wall_s": wall,
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    print(report)
    print(
        f"demo: done in {wall / 60:.1f} min; outputs in {out}/: student.pt metrics.json "
        "learning_curve.png eval.txt eval.mp4 eval_still.png",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
