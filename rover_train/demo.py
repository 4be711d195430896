"""The main job: a camera agent learns to drive from the reward, with the daemon in the loop.

Run under the supervisor so the daemon is there, one slot per env (``make demo`` does this):

    rover-pair --slots 8 -- python -m rover_train.demo --n-steps 256 --timesteps 200000 --points 4

PPO trains from scratch on RoverEnvFused's nav task (``rover-train``'s camera recipe,
:func:`camera_args`): the policy reads the camera scan (a rover-frame memory of what the
camera has seen, built from the daemon's fused images; ``rover_env.camera_scan``), the map
planner's next waypoint and the rover's state through an MLP, and drives the seed's
60-action table relative to the yaw, behind the collision shield (``rover_train.shield``:
the actions that would bring the rover onto what its camera has seen get no probability,
in training as in evaluation). A checkpoint is kept every ``--timesteps / --points``
steps. Then a seeded random policy and every checkpoint drive the same ``--episodes``
evaluation episodes (reset seeds from 100000, never used in training; each ends at the first
goal, a collision or ``--max-steps``), several at once over the daemon's slots: the learning
curve, measured on the evaluation episodes. The checkpoints act as in training, by
sampling their policy (seeded by ``--seed`` and each observation): the camera agent sees part
of the world, and its most likely action, repeated wherever its observations look alike,
drives it in circles and off the map (docs/decisions.md, "RL").

Leaves under ``--out`` (default ``runs/demo``):
- ``run/``: rover-train's run directory (``model.zip``, the checkpoints, ``metrics.json``,
  TensorBoard events). The same command again continues a stopped run from its newest
  checkpoint, or evaluates a finished one.
- ``curve.json`` and ``learning_curve.png``: evaluation success and collisions by training
  steps, with the training episodes' success beside them.
- ``eval.txt``: the trained agent beside the zoo's camera agent from the reward
  (``rl-fused-inspect`` or ``rl-fused-maze``, :data:`ZOO_REFERENCE`, on the same episodes)
  and random, and the curve.
- ``eval.mp4``: the trained agent's first ``--video-episodes`` (chase view beside the gray,
  heatmap and depth channels), and ``eval_still.png``.

The previous main job, a DAgger fine-tune of the zoo's fused student, is
``rover_train.imitation.demo``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rover_env.constants import CONTROL_DT
from rover_train import zoo
from rover_train.agents import RandomAgent
from rover_train.checkpoint import Checkpoint, ResumeError, RunRecord, find_checkpoints
from rover_train.envs import make_env
from rover_train.evaluate import (
    VIDEO_PANEL,
    evaluate_agent,
    format_comparison,
    load_policy,
    summarise,
    write_video,
)
from rover_train.progress import StatusLine
from rover_train.train import TrainArgs, train
from roverav_cli import EVAL_SEED_BASE, Episodes, add_group
from shm_protocol import default_name
from shm_protocol.names import default_slots

DEMO_WORLDS = ("inspect", "maze")
"""Worlds the demo trains in."""
ZOO_REFERENCE = {"inspect": "rl-fused-inspect", "maze": "rl-fused-maze"}
"""The zoo's camera agent from the reward for each demo world, measured beside the curve."""
_LABEL_ROWS = 24  # video rows holding the panels' names (rover_train.evaluate.label_frame)


CAMERA_N_STEPS = 512
"""Rollout steps per env before each PPO update in the camera recipe (4 envs: 2,048 samples an
update). ``make demo`` runs 8 envs of 256: the same 2,048 samples an update, and on two cores
more steps a second, since one env waits on the daemon while another steps."""


def camera_args(world: str, timesteps: int, slots: int, seed: int, logdir: Path,
                checkpoint_every: int, n_steps: int = CAMERA_N_STEPS) -> TrainArgs:  # fmt: skip
    """rover-train's camera recipe: PPO on RoverEnvFused's nav task, the camera scan, the
    map planner's waypoint and the state through an MLP (the image dropped from the policy),
    the relative table behind the collision shield (MaskablePPO on the shield's masks), a
    discount of 0.995 and ``n_steps``-step rollouts per env.

    The same as ``rover-train --env fused --world WORLD --task nav --camera-scan
    --drop-image --relative-table --shield --waypoint --gamma 0.995 --n-steps 512``.
    """
    return TrainArgs(
        env="fused", world=world, task="nav", camera_scan=True, drop_image=True,
        relative_table=True, shield=True, waypoint=True, gamma=0.995, n_steps=n_steps,
        timesteps=timesteps, slots=slots, seed=seed, logdir=logdir,
        checkpoint_every=checkpoint_every, progress=False, name=default_name(),
    )  # fmt: skip


def save_still(video: Path, png: Path) -> None:
    """The video frame that shows the most pedestrian heatmap (else the middle one), as PNG.

    Frames are the chase view beside the gray, heatmap and depth panels (equal widths); the
    score skips the panels' name labels at the top.
    """
    import cv2

    cap = cv2.VideoCapture(str(video))
    best, best_score, frames = None, -1.0, []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
        score = float(frame[_LABEL_ROWS:, 2 * VIDEO_PANEL : 3 * VIDEO_PANEL].mean())
        if score > best_score:
            best, best_score = frame, score
    cap.release()
    if best is None:
        return
    if best_score < 1.0:  # no pedestrian anywhere: the middle frame
        best = frames[len(frames) // 2]
    cv2.imwrite(str(png), best)


def quiet_logs() -> None:
    """A normal run shows status lines and warnings, not library INFO chatter."""
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    for name in ("OpenGL", "OpenGL.acceleratesupport", "shm_protocol", "rover_env"):
        logging.getLogger(name).setLevel(logging.WARNING)


def checkpoints(run_dir: Path) -> list[Checkpoint]:
    """The run's readable checkpoints, oldest first (a damaged one is left out)."""
    found = [c for c in find_checkpoints(run_dir) if isinstance(c, Checkpoint)]
    return sorted(found, key=lambda c: int(c.state["num_timesteps"]))


def training_success(episodes: list[dict[str, Any]], bins: int) -> list[dict[str, float]]:
    """The training episodes' success in ``bins`` equal spans of steps (empty spans left out)."""
    if not episodes:
        return []
    last = max(e["timestep"] for e in episodes)
    width = max(last / bins, 1.0)
    spans: dict[int, list[float]] = {}
    for e in episodes:
        spans.setdefault(min(int(e["timestep"] // width), bins - 1), []).append(e["success"])
    return [{"steps": (k + 0.5) * width, "success": sum(v) / len(v), "episodes": len(v)}
            for k, v in sorted(spans.items())]  # fmt: skip


def plot_curve(curve: list[dict[str, Any]], training: list[dict[str, float]],
               reference: dict[str, Any] | None, path: Path, title: str) -> None:  # fmt: skip
    """Evaluation success and collisions by training steps, training success beside them,
    and the zoo's entry (``reference``) on the same episodes as a level line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    steps = [p["steps"] for p in curve]
    ax.plot(steps, [100 * p["success_rate"] for p in curve], "o-", color="g",
            label="evaluation: reached the goal")  # fmt: skip
    ax.plot(steps, [100 * p["collision_rate"] for p in curve], "s--", color="r",
            label="evaluation: touched something")  # fmt: skip
    if training:
        ax.plot([t["steps"] for t in training], [100 * t["success"] for t in training], "-",
                color="0.6", label="training episodes: reached the goal")  # fmt: skip
    if reference is not None:
        ax.axhline(100 * reference["success_rate"], color="b", linestyle=":",
                   label=f"{reference['policy']}: reached the goal")  # fmt: skip
    ax.set_xlabel("training env steps (0: the random policy)")
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(-5, 105)
    ax.legend(loc="center right", fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


@dataclass(frozen=True)
class PointJob:
    """One point of the learning curve to measure: a policy (a checkpoint's file, or None for
    the seeded random policy; or the zoo entry ``entry``) on the evaluation episodes, on one
    daemon slot."""

    world: str
    name: str
    slot: int
    model: str | None
    seed: int
    episodes: int
    max_steps: int
    entry: str | None = None

    def run(self, frames: list[Any] | None = None, video_episodes: int = 0) -> dict[str, Any]:
        """The point's summary (``rover_train.evaluate.summarise``); ``frames`` gets the
        video of its first ``video_episodes`` episodes."""
        env = make_env("fused", world=self.world, name=self.name, slot=self.slot, task="nav",
                       camera_scan=True, render_mode="rgb_array" if frames is not None else None)
        try:
            agent: Any
            if self.entry is not None:  # as the zoo drives it (rover_train.zoo.load)
                agent, label = zoo.load(self.entry), self.entry
            elif self.model is None:
                agent, label = RandomAgent(env.action_space, self.seed), "random"
            else:
                agent = load_policy(Path(self.model), env, "ppo", deterministic=False,
                                    seed=self.seed)  # fmt: skip
                label = Path(self.model).stem
            return summarise(evaluate_agent(
                env, agent, self.episodes, EVAL_SEED_BASE, self.max_steps, frames,
                video_episodes, StatusLine(f"demo eval ({label})",
                                           self.episodes * self.max_steps)))  # fmt: skip
        finally:
            env.close()


_worker_slot = 0  # the daemon slot of this evaluation worker process (_take_slot)


def _take_slot(slots: Any) -> None:
    """A worker's initializer: its own daemon slot for as long as it lives."""
    global _worker_slot
    _worker_slot = int(slots.get())
    quiet_logs()
    import torch

    torch.set_num_threads(1)


def _run_point(job: PointJob) -> dict[str, Any]:
    return dataclasses.replace(job, slot=_worker_slot).run()


def evaluate_points(jobs: list[PointJob], slots: int, frames: list[Any],
                    video_episodes: int) -> list[dict[str, Any]]:  # fmt: skip
    """Each job's summary, in order. The last job (the trained
    agent) runs here, on slot 0, keeping its video; the others run at the same time in
    worker processes on slots 1 to ``slots - 1`` (one at a time here when there is one slot).
    Each episode is driven the same on any slot (its reset seed, and each sampled action
    seeded by the observation), so the curve does not depend on how the points were spread.
    """
    import concurrent.futures
    import multiprocessing

    last = dataclasses.replace(jobs[-1], slot=0)
    others = jobs[:-1]
    summaries: list[dict[str, Any]] = [{} for _ in jobs]
    if slots > 1 and others:
        ctx = multiprocessing.get_context("forkserver")
        free = ctx.Queue()
        for slot in range(1, slots):
            free.put(slot)
        with concurrent.futures.ProcessPoolExecutor(slots - 1, mp_context=ctx,
                                                    initializer=_take_slot,
                                                    initargs=(free,)) as pool:  # fmt: skip
            futures = {pool.submit(_run_point, j): i for i, j in enumerate(others)}
            summaries[-1] = last.run(frames, video_episodes)
            for future in concurrent.futures.as_completed(futures):
                summaries[futures[future]] = future.result()
    else:
        for i, job in enumerate(others):
            summaries[i] = job.run()
        summaries[-1] = last.run(frames, video_episodes)
    return summaries


def format_curve(curve: list[dict[str, Any]]) -> str:
    """The learning curve as a Markdown table (one row per evaluated policy)."""
    lines = ["| training steps | policy | success | touched something | timeouts |",
             "|---:|---|---:|---:|---:|"]  # fmt: skip
    for p in curve:
        lines.append(f"| {p['steps']:,} | {p['policy']} | {p['success_rate']:.0%} | "
                     f"{p['collision_rate']:.0%} | {p['timeouts']} |")  # fmt: skip
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rover_train.demo", description=__doc__.split("\n")[0])
    add_group(p, Episodes, only=("world", "episodes", "max_steps")).description = (
        "the world trained in (inspect or maze; default inspect); a random policy and each "
        "checkpoint are evaluated on the same evaluation episodes")
    p.add_argument("--timesteps", type=int, default=250_000,
                   help="PPO env steps over all envs (0: evaluate the run in --out as it is)")
    p.add_argument("--points", type=int, default=5,
                   help="checkpoints evaluated along the run (the curve's points after random)")
    p.add_argument("--n-steps", type=int, default=CAMERA_N_STEPS,
                   help=f"rollout steps per env before each PPO update (default "
                        f"{CAMERA_N_STEPS}; make demo: 256 over 8 envs)")
    p.add_argument("--seed", type=int, default=0, help="seeds training and the random policy")
    p.add_argument("--video-episodes", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    return p  # fmt: skip


def _earlier_run(run_dir: Path) -> dict[str, Any] | None:
    """The arguments of the run already in ``run_dir`` (None when there is none)."""
    if not (run_dir / "run.json").is_file():
        return None
    return RunRecord.load(run_dir).args


def main(argv: Sequence[str] | None = None) -> int:
    quiet_logs()
    p = _parser()
    args = p.parse_args(argv)
    args.world = args.world or "inspect"
    if args.world not in DEMO_WORLDS:
        p.error(f"--world {args.world}: the demo trains in {' or '.join(DEMO_WORLDS)}")
    if args.points < 1:
        p.error(f"--points {args.points}: give 1 or more")
    if args.n_steps < 2:
        p.error(f"--n-steps {args.n_steps}: PPO needs 2 or more rollout steps per env")
    run_dir = args.out / "run"
    try:
        earlier = _earlier_run(run_dir)
    except ResumeError as exc:  # a damaged run.json: named, with its fix; nothing touched
        p.error(f"{run_dir} holds a run that cannot be continued: {exc}")
    if earlier is not None and earlier.get("world") != args.world:
        p.error(f"{run_dir} holds a run in the {earlier.get('world')} world: give "
                f"--world {earlier.get('world')} to continue it, or another --out")  # fmt: skip
    import torch

    torch.set_num_threads(1)
    t_start = time.monotonic()
    if args.timesteps > 0:
        every = max(1, args.timesteps // args.points)
        targs = camera_args(args.world, args.timesteps, default_slots(), args.seed, run_dir, every,
                            args.n_steps)  # fmt: skip
        if earlier is not None:  # a stopped or finished run: continued, nothing lost
            targs.resume = run_dir
            print(f"demo: continuing the run in {run_dir} from its newest checkpoint",
                  flush=True)  # fmt: skip
        print(f"demo: PPO from scratch on RoverEnvFused ({args.world}) with the camera scan, "
              f"{args.timesteps:,} steps on {targs.slots} env(s)", flush=True)  # fmt: skip
        result = train(targs)
        if result["status"] != "complete":
            print(f"demo: training stopped at {result['timesteps']:,} steps; the same command "
                  "continues it", flush=True)  # fmt: skip
            return int(result["exit_status"]) or 1
    found = checkpoints(run_dir)
    if not found:
        p.error(f"no checkpoint in {run_dir}: train first (--timesteps)")
    t_train = time.monotonic() - t_start

    seeds = f"seeds {EVAL_SEED_BASE}..{EVAL_SEED_BASE + args.episodes - 1}"
    entry = ZOO_REFERENCE[args.world]
    jobs = [PointJob(args.world, default_name(), 0, None, args.seed, args.episodes,
                     args.max_steps),
            PointJob(args.world, default_name(), 0, None, args.seed, args.episodes,
                     args.max_steps, entry=entry)]  # fmt: skip
    jobs += [PointJob(args.world, default_name(), 0, str(ck.model_path), args.seed,
                      args.episodes, args.max_steps) for ck in found]  # fmt: skip
    frames: list[Any] = []
    summaries = evaluate_points(jobs, default_slots(), frames, args.video_episodes)
    curve = [{"steps": 0, "policy": f"random (seed {args.seed})", **summaries[0]}]
    curve += [{"steps": int(ck.state["num_timesteps"]), "policy": ck.model_path.name, **sm}
              for ck, sm in zip(found, summaries[2:], strict=True)]  # fmt: skip
    reference = {"policy": f"zoo entry {entry}", **summaries[1]}
    random, trained = curve[0], curve[-1]
    title = f"RoverEnvFused ({args.world}) nav task, {seeds}, at most {args.max_steps} steps"
    report = "\n\n".join([
        format_comparison([(f"PPO, {trained['steps']:,} steps", trained),
                           (f"zoo entry {entry}", reference),
                           (f"random policy (seed {args.seed})", random)], title),
        "Learning curve (the same episodes):\n\n" + format_curve(curve),
    ])  # fmt: skip
    (args.out / "eval.txt").write_text(report + "\n")
    log_file = run_dir / "metrics.json"
    episodes = json.loads(log_file.read_text())["episode_log"] if log_file.is_file() else []
    training = training_success(episodes, 20)
    plot_curve(curve, training, reference, args.out / "learning_curve.png",
               f"PPO from scratch, camera scan, {args.world}: {seeds}")  # fmt: skip
    if frames:
        write_video(frames, args.out / "eval.mp4", 1.0 / CONTROL_DT)
        save_still(args.out / "eval.mp4", args.out / "eval_still.png")
    wall = time.monotonic() - t_start
    (args.out / "curve.json").write_text(json.dumps({
        "world": args.world, "episodes": args.episodes, "seed_base": EVAL_SEED_BASE,
        "max_steps": args.max_steps, "curve": curve, "reference": reference,
        "training": training,
        "train_wall_s": t_train, "wall_s": wall}, indent=2))  # fmt: skip
    print(report)
    print(f"demo: done in {wall / 60:.1f} min; outputs in {args.out}/: run/ curve.json "
          "learning_curve.png eval.txt eval.mp4 eval_still.png", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
