"""Distil the privileged planner expert into zoo students with DAgger.

    python -m rover_train.imitation.distill lidar-maze     # LIDAR student, no daemon
    rover-pair --name distill_maze -- python -m rover_train.imitation.distill fused-maze

The DAgger engine is :mod:`rover_train.imitation.dagger`; this module holds the entries'
recipes and their command line.

A fused entry is made in two stages. Stage 1 fits the student's state network (pose, IMU,
target, odometry: the same keys in RoverEnv and RoverEnvFused, with the same dynamics, and
the forward range scans read off the fused image, :func:`rover_train.zoo.agent.depth_scan`)
by DAgger in RoverEnv, which needs no daemon and runs several times faster; the fused image
the scans come from is the daemon's own perception run in this process on the same rendered
frame (:class:`FusedView`). Stage 2 turns on the image branch (its projection starts at
zero, so the student starts as the stage-1 policy) and continues DAgger in RoverEnvFused
with the daemon in the loop, fitting the image branch.

Training episodes use reset seeds below ``DIAGNOSTIC_SEED_BASE`` (the diagnostic seeds start
there, the evaluation's at ``EVAL_SEED_BASE``) and run ``TRAIN_LENGTH`` steps, carrying on
past goals (the env draws a new one).
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from rover_env.constants import FUSED_SIZE
from rover_train.imitation.dagger import (
    EXIT_NO_DAEMON,
    FUSED_ITERATIONS,
    FUSED_STEPS,
    MAX_SEED,
    MEMBER_DIR,
    PEDESTRIAN_SCAN,
    SCAN_BANDS,
    DAggerConfig,
    WithFusedView,
    feature_spec,
    make_training_env,
    run_dagger,
    stage2_config,
)
from rover_train.imitation.expert import MANNERS, SEES
from rover_train.zoo.agent import (
    HEADS,
    StudentAgent,
    StudentNet,
)
from rover_train.zoo.registry import DIAGNOSTIC_SEED_BASE, ENTRIES


def teacher_sees_for(kind: str) -> str:
    """The labelling expert's ``sees`` for a student of ``kind``: ``camera`` for fused
    students (on 100 diagnostic episodes, fused-inspect 58 -> 70 % success and fused-maze
    45 -> 61 % against the all-round teacher; see benchmarks/RESULTS.md), ``all`` for LIDAR
    students, whose scan sees all round."""
    return "camera" if kind == "fused" else "all"


def teacher_manners_for(kind: str) -> str:
    """The labelling expert's manners for a student of ``kind``: ``firm`` for LIDAR
    students (the polite teacher set their ceiling, 80 % of the maze's evaluation episodes;
    firm reaches more goals with fewer collisions on the diagnostic seeds, see
    ``rover_train.imitation.expert.MANNERS``; its lidar-maze and lidar-inspect ensembles reached 89
    and 92 % of 200 diagnostic episodes against the polite teacher's 86 and 87 %, with more
    collided episodes: 12.5 and 10 % against 7.5 and 6.5 %), ``polite`` for fused students,
    whose point is to keep out of personal space."""
    return "firm" if kind == "lidar" else "polite"


def distill_entry(
    name: str,
    out: Path,
    cfg: DAggerConfig,
    fused_cfg: DAggerConfig | None = None,
    init: Path | None = None,
    shm_name: str | None = None,
    slot: int = 0,
    head: str = "bins",
    stage1_only: bool = False,
    depth_scan: int = SCAN_BANDS,
    pedestrian_scan: bool = PEDESTRIAN_SCAN,
    unmapped_scan: bool | None = None,
    members: int = 1,
    member_dir: Path = MEMBER_DIR,
    resume: bool = False,
) -> StudentAgent:
    """Make zoo entry ``name`` (see the module docstring) and save it to ``out``; a new
    student gets output ``head`` (and, fused, ``depth_scan`` bands of depth scan, and a
    pedestrian scan with ``pedestrian_scan``; LIDAR, the scan of the returns the map does not
    explain with ``unmapped_scan``, by default the entry's ``EntrySpec.unmapped_scan``).
    ``stage1_only`` (fused entries) saves the student after stage 1, without the daemon;
    ``init=`` that file later runs stage 2 alone. Stage 2 runs ``fused_cfg``, by default
    :func:`stage2_config` of ``cfg``.

    ``members`` > 1 makes an ensemble (:class:`rover_train.zoo.agent.EnsembleNet`): that
    many whole runs, seeds ``cfg.seed``, ``cfg.seed + 1``, ..., each saved to
    ``member_dir`` as it finishes; with ``resume``, a member whose file is there already is
    loaded instead of made again (a run stopped between members loses only the one it was
    making)."""
    entry = ENTRIES[name]
    if unmapped_scan is None:
        unmapped_scan = entry.unmapped_scan
    problem = members_problem(members, cfg.seed, init is not None, stage1_only)
    if problem:
        raise ValueError(problem)
    if members == 1:
        return _save_entry(
            _distill_one(name, cfg, fused_cfg, init, shm_name, slot, head, stage1_only,
                         depth_scan, pedestrian_scan, unmapped_scan, member_dir, resume),
            name, entry, out,
        )  # fmt: skip
    agents = []
    for i in range(members):
        seed = cfg.seed + i
        path = member_dir / f"{name}-seed{seed}.pt"
        if resume and path.is_file():
            print(f"distill {name}: member {i + 1}/{members} (seed {seed}) from {path}",
                  flush=True)  # fmt: skip
            agents.append(StudentAgent.load(path))
            continue
        print(f"distill {name}: member {i + 1}/{members} (seed {seed})", flush=True)
        member_fused = replace(fused_cfg, seed=seed) if fused_cfg is not None else None
        agent = _distill_one(name, replace(cfg, seed=seed), member_fused, None, shm_name, slot,
                             head, False, depth_scan, pedestrian_scan, unmapped_scan,
                             member_dir, resume)  # fmt: skip
        agents.append(_save_entry(agent, name, entry, path))
    return _save_entry(StudentAgent.ensemble(agents), name, entry, out)


def members_problem(members: int, seed: int, init: bool, stage1_only: bool) -> str | None:
    """What is wrong with making ``members`` students from ``seed`` (with ``--init`` /
    ``--stage1-only`` given or not), or None."""
    if members < 1:
        return f"--members must be >= 1, got {members}"
    if members > 1 and (init or stage1_only):
        return (
            "--init and --stage1-only work on one student; an ensemble (--members) is made "
            "from scratch, its members saved in --member-dir as they finish (--resume)"
        )
    if seed + members - 1 > MAX_SEED:
        return (
            f"--seed {seed} with --members {members} uses seeds up to {seed + members - 1}; "
            f"training episodes of seeds above {MAX_SEED} would reach the diagnostic seeds "
            f"({DIAGNOSTIC_SEED_BASE}+)"
        )
    return None


def _distill_one(
    name: str,
    cfg: DAggerConfig,
    fused_cfg: DAggerConfig | None,
    init: Path | None,
    shm_name: str | None,
    slot: int,
    head: str,
    stage1_only: bool,
    depth_scan: int,
    pedestrian_scan: bool,
    unmapped_scan: bool = False,
    checkpoint_dir: Path | None = None,
    resume: bool = False,
) -> StudentAgent:
    """One student of entry ``name`` (see :func:`distill_entry`), not saved. A fused
    student made from scratch saves its stage-1 network in ``checkpoint_dir`` (a stage 2
    that fails, its daemon gone for good, loses only stage 2); with ``resume`` that file,
    if there, replaces stage 1."""
    entry = ENTRIES[name]
    torch.manual_seed(cfg.seed)
    stage1_file = (
        checkpoint_dir / f"{name}-seed{cfg.seed}.stage1.pt"
        if checkpoint_dir is not None and entry.kind == "fused" and init is None
        else None
    )
    if resume and stage1_file is not None and stage1_file.is_file():
        print(f"distill {name}: stage 1 from {stage1_file}", flush=True)
        init = stage1_file
    if entry.kind == "lidar":
        env = make_training_env("lidar", entry.world)
        try:
            if init is not None:
                agent = StudentAgent.load(init)
            else:
                agent = StudentAgent(StudentNet(
                    feature_spec("lidar", env, head, unmapped_scan=unmapped_scan)
                ))
            run_dagger(env, entry.world, agent, cfg, label=f"distill {name}")
        finally:
            env.close()
    else:
        if init is not None:
            agent = StudentAgent.load(init)
        else:
            # stage 1: the state network in RoverEnv (fast, no daemon), the depth scan
            # read off the fused image computed in this process
            env = make_training_env("lidar", entry.world, size=FUSED_SIZE)
            if depth_scan:
                env = WithFusedView(env)
            try:
                fused_spec = replace(
                    feature_spec("lidar", env, head, depth_scan=depth_scan,
                                 pedestrian_scan=pedestrian_scan),
                    lidar_points=0,
                    image=True,
                    min_speed=-0.6,
                )
                state_agent = StudentAgent(StudentNet(replace(fused_spec, image=False)))
                run_dagger(env, entry.world, state_agent, cfg, label=f"distill {name} stage 1")
            finally:
                env.close()
            net = StudentNet(fused_spec)
            net.load_state_dict(state_agent.net.state_dict(), strict=False)
            agent = StudentAgent(net)
            if stage1_file is not None:
                _save_entry(agent, name, entry, stage1_file)
        if stage1_only:
            return agent
        # stage 2: everything, with the daemon's fused images
        env = make_training_env("fused", entry.world, shm_name=shm_name, slot=slot)
        try:
            stage2 = fused_cfg if fused_cfg is not None else stage2_config(cfg)
            run_dagger(env, entry.world, agent, stage2, label=f"distill {name} stage 2")
        finally:
            env.close()
    return agent


def _save_entry(agent: StudentAgent, name: str, entry: Any, out: Path) -> StudentAgent:
    agent.meta = {"name": name, "command": entry.command, "kind": entry.kind, "world": entry.world}
    out.parent.mkdir(parents=True, exist_ok=True)
    agent.save(out)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)", flush=True)
    return agent


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    p = argparse.ArgumentParser(
        prog="rover_train.imitation.distill", description=__doc__.split("\n")[0]
    )
    p.add_argument("entry", choices=sorted(ENTRIES))
    p.add_argument("--out", type=Path, help="default: the zoo's entry file")
    p.add_argument("--init", type=Path, help="start from this student file (fine-tune)")
    d = DAggerConfig()
    p.add_argument("--iterations", type=int, default=d.iterations)
    p.add_argument("--steps", type=int, default=d.steps, help="env steps per DAgger round")
    p.add_argument("--epochs", type=int, default=d.epochs)
    p.add_argument("--fused-iterations", type=int, default=FUSED_ITERATIONS,
                   help="stage-2 rounds of a fused entry (daemon in the loop)")
    p.add_argument("--fused-steps", type=int, default=FUSED_STEPS,
                   help="env steps per stage-2 round")
    p.add_argument("--synthetic-goals", type=int, default=150,
                   help="goals of expert-labelled states drawn without driving (0: none)")
    p.add_argument("--synthetic-per-goal", type=int, default=200)
    p.add_argument(
        "--near-weight", type=float, default=d.near_weight,
        help="loss weight of samples with a pedestrian within 2 m (1: no weighting)",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--head", choices=HEADS, default="bins",
                   help="a new student's output head (see rover_train.zoo.agent)")
    p.add_argument("--threads", type=int, default=1, help="torch threads while driving")
    p.add_argument(
        "--fit-threads", type=int, default=d.fit_threads,
        help="torch threads for the fits (0: all cores; the env and the daemon are idle then)",
    )  # fmt: skip
    p.add_argument(
        "--name", dest="shm_name", default=None,
        help="daemon name for fused entries (default: $ROVERAV_SHM_NAME, set by rover-pair)",
    )  # fmt: skip
    p.add_argument("--shm-name", dest="shm_name", help=argparse.SUPPRESS)
    p.add_argument("--slot", type=int, default=0)
    p.add_argument(
        "--stage1-only", action="store_true",
        help="fused entries: stop after stage 1 (no daemon needed) and save; run stage 2 "
        "later with --init FILE",
    )  # fmt: skip
    p.add_argument(
        "--depth-scan", type=int, default=SCAN_BANDS,
        help="a new fused student's bands of forward range scan read off the depth channel "
        "(0: none, the image branch alone sees what is ahead)",
    )  # fmt: skip
    p.add_argument(
        "--pedestrian-scan", action=argparse.BooleanOptionalAction, default=PEDESTRIAN_SCAN,
        help="with --depth-scan: a second scan of the pixels the heatmap marks as a pedestrian",
    )  # fmt: skip
    p.add_argument(
        "--unmapped-scan", action=argparse.BooleanOptionalAction, default=None,
        help="a new LIDAR student's second scan of the returns the world's map does not "
        "explain (the pedestrians); default: the entry's own (rover_train.zoo.registry)",
    )  # fmt: skip
    p.add_argument(
        "--teacher-sees", choices=SEES, default=None,
        help="pedestrians the labelling expert reacts to: all, or only those in the forward "
        "camera's view (what a fused student can see); default: camera for fused entries, "
        "all for LIDAR ones",
    )  # fmt: skip
    p.add_argument(
        "--teacher-manners", choices=sorted(MANNERS), default=None,
        help="the labelling expert's pedestrian terms (rover_train.imitation.expert.MANNERS); "
        "default: firm for LIDAR entries, polite for fused ones",
    )  # fmt: skip
    p.add_argument(
        "--members", type=int, default=None,
        help="students in the entry: more than 1 makes an ensemble of that many whole runs "
        "(seeds --seed, --seed+1, ...), their mean log-probabilities acting; default: the "
        "entry's own count (rover_train.zoo.registry.MEMBERS)",
    )  # fmt: skip
    p.add_argument(
        "--member-dir", type=Path, default=MEMBER_DIR,
        help="where an ensemble's members, and a fused student's stage 1, are saved as they "
        "finish",
    )  # fmt: skip
    p.add_argument(
        "--resume", action="store_true",
        help="load the members and fused stage 1s already in --member-dir instead of making "
        "them again (a run stopped part-way loses only the part it was making)",
    )  # fmt: skip
    args = p.parse_args(argv)
    if args.members is None:
        args.members = 1 if args.init or args.stage1_only else ENTRIES[args.entry].members
    problem = members_problem(args.members, args.seed, args.init is not None, args.stage1_only)
    if problem:
        p.error(problem)
    if args.stage1_only and ENTRIES[args.entry].kind != "fused":
        p.error(f"--stage1-only is for fused entries; {args.entry} is made in one stage")
    torch.set_num_threads(args.threads)
    entry = ENTRIES[args.entry]
    cfg = DAggerConfig(
        iterations=args.iterations, steps=args.steps, epochs=args.epochs, seed=args.seed,
        synthetic_goals=args.synthetic_goals, synthetic_per_goal=args.synthetic_per_goal,
        near_weight=args.near_weight, fit_threads=args.fit_threads,
        teacher_sees=args.teacher_sees or teacher_sees_for(entry.kind),
        teacher_manners=args.teacher_manners or teacher_manners_for(entry.kind),
    )  # fmt: skip
    fused_cfg = stage2_config(cfg, args.fused_iterations, args.fused_steps)
    from shm_protocol.errors import ShmError

    try:
        distill_entry(
            args.entry,
            args.out or entry.path,
            cfg,
            fused_cfg,
            init=args.init,
            shm_name=args.shm_name,
            slot=args.slot,
            head=args.head,
            stage1_only=args.stage1_only,
            depth_scan=args.depth_scan,
            pedestrian_scan=args.pedestrian_scan,
            unmapped_scan=args.unmapped_scan,
            members=args.members,
            member_dir=args.member_dir,
            resume=args.resume,
        )
    except ShmError as exc:
        print(f"{exc}\n\n{args.entry} needs the daemon: {entry.command}", file=sys.stderr)
        return EXIT_NO_DAEMON
    return 0


if __name__ == "__main__":
    sys.exit(main())
