"""Make the zoo's entries: each entry's recipe, and the command that runs it.

    python -m rover_train.imitation.distill lidar-maze        # LIDAR entry, no daemon
    rover-pair --name distill_fused_maze -- python -m rover_train.imitation.distill fused-maze
    python -m rover_train.imitation.distill --recipe rover_train/zoo/entries/lidar-maze.pt

An entry's recipe (:class:`DAggerRecipe`) is data: :data:`RECIPES` holds the one each entry
is made with, the entry's file stores the recipe that made it, and ``--recipe FILE`` remakes
a file from what it says (``zoo.command(name)``). Options given on the command line override
the recipe's values; the command line is generated from the recipe's fields.

The DAgger engine is :mod:`rover_train.imitation.dagger`. A fused entry is made in two
stages. Stage 1 fits the student's state network (pose, IMU, target, odometry: the same keys
in RoverEnv and RoverEnvFused, with the same dynamics, and the forward range scans read off
the fused image, :func:`rover_train.zoo.agent.depth_scan`) by DAgger in RoverEnv, which needs
no daemon and runs several times faster; the fused image the scans come from is the daemon's
own perception run in this process on the same rendered frame
(:class:`~rover_train.imitation.dagger.FusedView`). Stage 2 turns on the image branch (its
projection starts at zero, so the student starts as the stage-1 policy) and continues DAgger
in RoverEnvFused with the daemon in the loop, fitting the image branch.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from fused_image import FUSED_SIZE
from rover_env.pedestrians import DEFAULT_MODE
from rover_train.cli import (
    add_recipe_option,
    build_parser,
    instance_from,
    recipe_defaults,
    recipe_dict,
    recipe_from_dict,
    setup_logging,
)
from rover_train.imitation.dagger import (
    EXIT_NO_DAEMON,
    FUSED_ITERATIONS,
    FUSED_STEPS,
    MAX_SEED,
    MEMBER_DIR,
    SCAN_BANDS,
    DAggerConfig,
    WithFusedView,
    feature_spec,
    make_training_env,
    run_dagger,
    stage2_config,
)
from rover_train.imitation.expert import GAZES, MANNERS, SEES, VELOCITY_FROM
from rover_train.wrappers import WithPanHead, WithSeedTable
from rover_train.zoo.agent import StudentAgent, StudentNet
from rover_train.zoo.registry import (
    DIAGNOSTIC_SEED_BASE,
    ENTRIES,
    GAZE_KINDS,
    STUDENT_FUSED_KINDS,
    TABLE_KINDS,
)
from roverav_cli import Connection, Episodes, shared_field

log = logging.getLogger(__name__)

RECIPE_KEY = "recipe"
"""The key of an entry file's ``meta`` that holds its :class:`DAggerRecipe` (as a dict)."""

_D = DAggerConfig()


@dataclass(frozen=True)
class DAggerRecipe:
    """Everything that decides what a zoo entry's file holds (its command line is generated
    from these fields)."""

    entry: str = field(default="", metadata={"cli": False})
    """The zoo entry (a key of ``rover_train.zoo.ENTRIES``): its kind and world."""
    members: int = 1
    """Students in the entry: more than 1 makes an ensemble of that many whole runs (seeds
    ``seed``, ``seed + 1``, ...), their mean log-probabilities acting."""
    seed: int = _D.seed
    """Seeds the torch init and the episode seeds of the first member."""
    iterations: int = _D.iterations
    """DAgger rounds (stage 1 of a fused entry)."""
    steps: int = _D.steps
    """Env steps per round."""
    epochs: int = _D.epochs
    """Passes over the aggregate data set after each round."""
    batch: int = _D.batch
    """Samples per optimiser step of a fit."""
    lr: float = _D.lr
    """Learning rate of the fits."""
    beta0: float = _D.beta0
    """Chance the expert drives in round 1 (halved each round; round 0 is all expert)."""
    synthetic_goals: int = _D.synthetic_goals
    """Goals of expert-labelled states drawn without driving, before round 0 (0: none)."""
    synthetic_per_goal: int = _D.synthetic_per_goal
    """Expert-labelled states drawn per synthetic goal."""
    near_weight: float = _D.near_weight
    """Loss weight of samples with a pedestrian within 2 m (1: no weighting)."""
    teacher_sees: str = field(default=_D.teacher_sees, metadata={"choices": SEES})
    """Pedestrians the labelling expert reacts to: all, or only those in the forward
    camera's view (what a fused student can see)."""
    teacher_manners: str = field(default=_D.teacher_manners,
                                 metadata={"choices": tuple(sorted(MANNERS))})
    """The labelling expert's pedestrian terms (``rover_train.imitation.expert.MANNERS``)."""
    teacher_velocity: str = field(default=_D.teacher_velocity,
                                  metadata={"choices": VELOCITY_FROM})
    """How the labelling expert estimates the pedestrians' velocities: over the last change
    of their positions (``updates``) or between control steps (``steps``, which reads 0 and
    twice the speed on alternate steps: the shipped students' teacher)."""
    teacher_gaze: str = field(default=_D.teacher_gaze, metadata={"choices": GAZES})
    """Where the labelling expert points the camera: a gaze entry learns the ``active``
    gaze teacher's pan targets (``rover_train.imitation.gaze``)."""
    fused_iterations: int = FUSED_ITERATIONS
    """Stage-2 rounds of a fused entry (daemon in the loop)."""
    fused_steps: int = FUSED_STEPS
    """Env steps per stage-2 round."""
    depth_scan: int = SCAN_BANDS
    """A fused student's bands of forward range scan read off the depth channel (0: none,
    the image branch alone sees what is ahead)."""
    pedestrian_mode: str = shared_field(Episodes, "pedestrian_mode")
    """How the pedestrians of the training episodes walk (``RoverEnv``'s
    ``pedestrian_mode``; None, the flag's default: the recipe's, else DEFAULT_MODE)."""
    n_pedestrians: int | None = shared_field(Episodes, "n_pedestrians")
    """Pedestrians in the training episodes, 0 to 20 (default: the world's 3)."""
    unmapped_scan: bool = False
    """A LIDAR student's second scan of the returns the world's map does not explain (the
    pedestrians; ``rover_train.zoo.agent.unmapped_scan``)."""
    threads: int = 1
    """Torch threads while driving (the float order of the student's actions)."""
    fit_threads: int = _D.fit_threads
    """Torch threads for the fits, at most the cores this process may use (0: all)."""
    init: Path | None = None
    """Start from this student file (a fine-tune) instead of a new student."""
    stage1_only: bool = False
    """Fused entries: stop after stage 1 (no daemon needed) and save; run stage 2 later
    with ``init`` set to that file."""

    def __post_init__(self) -> None:
        if self.pedestrian_mode is None:  # the shared flag's "not given": the env's default
            object.__setattr__(self, "pedestrian_mode", DEFAULT_MODE)

    @property
    def kind(self) -> str:
        return ENTRIES[self.entry].kind

    @property
    def world(self) -> str:
        return ENTRIES[self.entry].world

    def dagger(self, seed: int | None = None) -> DAggerConfig:
        """The DAgger rounds of stage 1 (all of a LIDAR entry), for member seed ``seed``."""
        return DAggerConfig(
            iterations=self.iterations, steps=self.steps, epochs=self.epochs,
            batch=self.batch, lr=self.lr, beta0=self.beta0,
            seed=self.seed if seed is None else seed,
            synthetic_goals=self.synthetic_goals, synthetic_per_goal=self.synthetic_per_goal,
            near_weight=self.near_weight, teacher_sees=self.teacher_sees,
            teacher_manners=self.teacher_manners, teacher_gaze=self.teacher_gaze,
            teacher_velocity=self.teacher_velocity,
            fit_threads=self.fit_threads,
        )  # fmt: skip

    def fused_dagger(self, seed: int | None = None) -> DAggerConfig:
        """The DAgger rounds of a fused entry's stage 2."""
        return stage2_config(self.dagger(seed), self.fused_iterations, self.fused_steps)

    def problem(self) -> str | None:
        """What is wrong with this recipe, or None."""
        if self.entry not in ENTRIES:
            return f"no zoo entry {self.entry!r}; choose one of {sorted(ENTRIES)}"
        if self.members < 1:
            return f"--members must be >= 1, got {self.members}"
        if self.members > 1 and (self.init is not None or self.stage1_only):
            return (
                "--init and --stage1-only work on one student; an ensemble (--members) is "
                "made from scratch, its members saved in --member-dir as they finish (--resume)"
            )
        if self.seed + self.members - 1 > MAX_SEED:
            return (
                f"--seed {self.seed} with --members {self.members} uses seeds up to "
                f"{self.seed + self.members - 1}; training episodes of seeds above {MAX_SEED} "
                f"would reach the diagnostic seeds ({DIAGNOSTIC_SEED_BASE}+)"
            )
        if self.stage1_only and self.kind not in STUDENT_FUSED_KINDS:
            return f"--stage1-only is for fused entries; {self.entry} is made in one stage"
        if self.kind in GAZE_KINDS and self.teacher_gaze != "active":
            return (f"{self.entry} learns where to look from the gaze teacher: "
                    f"--teacher-gaze active (got {self.teacher_gaze})")
        if self.kind in GAZE_KINDS and self.teacher_sees != "camera":
            return (f"{self.entry}'s teacher must react to what its camera shows for looking "
                    f"to matter: --teacher-sees camera (got {self.teacher_sees})")
        if self.init is not None and not self.init.is_file():
            return f"--init {self.init}: no such student file"
        return None


def _recipe(entry: str, **kw: Any) -> DAggerRecipe:
    kind = ENTRIES[entry].kind
    # The labelling expert by kind: a fused student learns from a teacher that sees only
    # what the camera shows (a yield it cannot see teaches it to back off from nothing) and
    # keeps personal space (polite); a LIDAR student, whose scan sees all round, from one that
    # sees every pedestrian (docs/decisions.md, "Imitation and the zoo").
    teacher = {"teacher_sees": "camera" if kind in STUDENT_FUSED_KINDS else "all",
               "teacher_manners": "polite"}  # fmt: skip
    if kind in GAZE_KINDS:
        teacher["teacher_gaze"] = "active"  # the gaze teacher turns the camera
    # an entry made for a scenario (ENTRIES' env keywords) is trained among its pedestrians
    crowd = {k: v for k, v in ENTRIES[entry].env_kwargs.items()
             if k in ("pedestrian_mode", "n_pedestrians")}  # fmt: skip
    # the fused students were taught by an expert that differenced its velocity estimate
    # over control steps (benchmarks/RESULTS.md, "The planner expert"); an entry remade with
    # the held estimate says teacher_velocity="updates" here
    return DAggerRecipe(entry=entry, synthetic_goals=150,
                        **{"teacher_velocity": "steps", **teacher, **crowd, **kw})


# made among the default scenario's people, fitted on one thread (the float order, so the
# weights, depend on the thread count)
_CROWD = {"pedestrian_mode": "crowd", "fit_threads": 1}
# the LIDAR students, remade for the contact targets: taught among 10 people by the polite
# expert with the held velocity estimate, which keeps within them (benchmarks/RESULTS.md, "The
# planner expert"); taught among 3, its students did not keep clear among 10
# (docs/decisions.md, "Imitation and the zoo")
_KEEPS_CLEAR = {"teacher_velocity": "updates", "n_pedestrians": 10}

RECIPES: dict[str, DAggerRecipe] = {
    "lidar-inspect": _recipe("lidar-inspect", members=2, **_KEEPS_CLEAR, **_CROWD),
    "lidar-maze": _recipe("lidar-maze", members=2, unmapped_scan=True, **_KEEPS_CLEAR, **_CROWD),
    "fused-inspect": _recipe("fused-inspect", **_CROWD),
    "fused-gaze-inspect": _recipe("fused-gaze-inspect", **_CROWD),
    "discrete-inspect": _recipe("discrete-inspect", members=2, **_CROWD),
    "fused-gaze-discrete-inspect": _recipe("fused-gaze-discrete-inspect", members=2, **_CROWD),
    "fused-maze": _recipe("fused-maze", members=3, **_CROWD),
    "fused-moon": _recipe("fused-moon"),
    "fused-gaze-moon": _recipe("fused-gaze-moon"),
}
"""The recipe each zoo entry is made with. The main entries are made among the crowd of 3 (the
default), the LIDAR pair among 10 of its people (see ``_KEEPS_CLEAR``). Ensembles (members):
the LIDAR pair's and fused-maze's were chosen on the diagnostic seeds (fused-maze's three
among the pacers, and kept); the table pair's two because single draws of the Discrete(180)
recipe differ widely (docs/decisions.md, "Imitation and the zoo"; benchmarks/RESULTS.md,
"Looking, for the students"). lidar-maze's students see the unmapped scan (why:
docs/decisions.md, "Imitation and the zoo"). fused-moon and fused-gaze-moon (moon crossings)
are a pair of one recipe: the camera fixed ahead, or turned by the student as the gaze teacher
turns it (the fixed-against-gaze comparison). The pair made among 10 people was retired
(``rover_train.zoo.registry.RETIRED``); its recipes are in its files."""


@dataclass(frozen=True)
class DistillRun:
    """Where a distillation writes and which daemon it uses: not part of the recipe."""

    out: Path | None = None
    """The entry file to write (default: the zoo's own file of the entry)."""
    member_dir: Path = MEMBER_DIR
    """Where an ensemble's members, and a fused student's stage 1, are saved as they
    finish."""
    resume: bool = False
    """Load the members and fused stage 1s already in ``member_dir`` instead of making them
    again (a run stopped part-way loses only the part it was making)."""
    name: str = shared_field(Connection, "name")
    """Daemon name for fused entries (roverav_cli.Connection)."""
    slot: int = 0
    """The daemon slot a fused entry's stage 2 uses."""


def read_recipe(path: Path) -> DAggerRecipe:
    """The recipe stored in the entry file ``path``."""
    meta = StudentAgent.read_meta(path)
    if RECIPE_KEY not in meta:
        raise ValueError(f"{path} holds no recipe (a file written before recipes were "
                         "stored); remake it with its entry's name instead")  # fmt: skip
    # a file written before the velocity estimate was a field was taught by ``steps``
    return recipe_from_dict(DAggerRecipe, {"teacher_velocity": "steps", **meta[RECIPE_KEY]})


def entry_command(recipe: DAggerRecipe, path: Path) -> str:
    """The command that remakes the file ``path`` from the recipe it stores."""
    return ENTRIES[recipe.entry].distill_command(f"--recipe {path}")


def distill_entry(recipe: DAggerRecipe, run: DistillRun | None = None) -> StudentAgent:
    """Make the entry of ``recipe`` (see the module docstring) and save it to ``run.out``
    (default: the zoo's file of the entry), the recipe in its ``meta``.

    ``members`` > 1 makes an ensemble (:class:`rover_train.zoo.agent.EnsembleNet`): that
    many whole runs, seeds ``seed``, ``seed + 1``, ..., each saved to ``run.member_dir`` as
    it finishes; with ``run.resume``, a member whose file is there already is loaded instead
    of made again (a run stopped between members loses only the one it was making)."""
    run = run or DistillRun()
    problem = recipe.problem()
    if problem:
        raise ValueError(problem)
    out = run.out or ENTRIES[recipe.entry].path
    if recipe.members == 1:
        return _save_entry(_distill_one(recipe, recipe.seed, run), recipe, out)
    agents = []
    name = recipe.entry
    for i in range(recipe.members):
        seed = recipe.seed + i
        path = run.member_dir / f"{name}-seed{seed}.pt"
        if run.resume and path.is_file():
            log.info("distill %s: member %d/%d (seed %d) from %s", name, i + 1,
                     recipe.members, seed, path)  # fmt: skip
            agents.append(StudentAgent.load(path))
            continue
        log.info("distill %s: member %d/%d (seed %d)", name, i + 1, recipe.members, seed)
        agent = _distill_one(recipe, seed, run)
        agents.append(_save_entry(agent, replace(recipe, seed=seed, members=1), path))
    return _save_entry(StudentAgent.ensemble(agents), recipe, out)


def _distill_one(recipe: DAggerRecipe, seed: int, run: DistillRun) -> StudentAgent:
    """One student of ``recipe`` with DAgger seed ``seed``, not saved. A fused student made
    from scratch saves its stage-1 network in ``run.member_dir`` (a stage 2 that fails, its
    daemon gone for good, loses only stage 2); with ``run.resume`` that file, if there,
    replaces stage 1."""
    name, world = recipe.entry, recipe.world
    crowd = {"pedestrian_mode": recipe.pedestrian_mode, "n_pedestrians": recipe.n_pedestrians}
    cfg = recipe.dagger(seed)
    torch.manual_seed(seed)
    init = recipe.init
    gaze = recipe.kind in GAZE_KINDS
    table = recipe.kind in TABLE_KINDS
    stage1_file = (
        run.member_dir / f"{name}-seed{seed}.stage1.pt"
        if recipe.kind in STUDENT_FUSED_KINDS and init is None
        else None
    )
    if run.resume and stage1_file is not None and stage1_file.is_file():
        log.info("distill %s: stage 1 from %s", name, stage1_file)
        init = stage1_file
    if recipe.kind == "lidar":
        env = make_training_env("lidar", world, **crowd)
        try:
            if init is not None:
                agent = StudentAgent.load(init)
            else:
                agent = StudentAgent(StudentNet(
                    feature_spec("lidar", env, unmapped_scan=recipe.unmapped_scan)
                ))  # fmt: skip
            run_dagger(env, world, agent, cfg, label=f"distill {name}")
        finally:
            env.close()
        return agent
    if init is not None:
        agent = StudentAgent.load(init)
    else:
        # stage 1: the state network in RoverEnv (fast, no daemon), the depth scan read off
        # the fused image computed in this process
        # (a gaze student's under the gaze env's pan head, the depth scan off the turned camera;
        # a discrete student's through the seed's table, as its env takes it)
        env = make_training_env("lidar", world, size=FUSED_SIZE, **crowd)
        if gaze:
            env = WithPanHead(env)
        if table:
            env = WithSeedTable(env)
        if recipe.depth_scan:
            env = WithFusedView(env)
        try:
            fused_spec = replace(
                feature_spec("lidar", env, depth_scan=recipe.depth_scan),
                lidar_points=0,
                image=True,
                min_speed=-0.6,
                gaze=gaze,
            )
            state_agent = StudentAgent(StudentNet(replace(fused_spec, image=False)))
            run_dagger(env, world, state_agent, cfg, label=f"distill {name} stage 1")
        finally:
            env.close()
        net = StudentNet(fused_spec)
        net.load_state_dict(state_agent.net.state_dict(), strict=False)
        agent = StudentAgent(net)
        if stage1_file is not None:
            _save_entry(agent, replace(recipe, seed=seed, members=1, stage1_only=True),
                        stage1_file)  # fmt: skip
    if recipe.stage1_only:
        return agent
    # stage 2: everything, with the daemon's fused images
    env = make_training_env(recipe.kind, world, name=run.name, slot=run.slot, **crowd)
    try:
        run_dagger(env, world, agent, recipe.fused_dagger(seed),
                   label=f"distill {name} stage 2")  # fmt: skip
    finally:
        env.close()
    return agent


def _save_entry(agent: StudentAgent, recipe: DAggerRecipe, out: Path) -> StudentAgent:
    entry = ENTRIES[recipe.entry]
    agent.meta = {"name": recipe.entry, "kind": entry.kind, "world": entry.world,
                  RECIPE_KEY: recipe_dict(recipe)}  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    agent.save(out)
    log.info("wrote %s (%.0f KiB)", out, out.stat().st_size / 1024)
    return agent


def _parser(base: DAggerRecipe | None) -> Any:
    p = build_parser(
        (DAggerRecipe, DistillRun), "python -m rover_train.imitation.distill",
        __doc__.split("\n")[0], defaults={DAggerRecipe: base} if base else None,
    )  # fmt: skip
    p.add_argument("entry", nargs="?", choices=sorted(RECIPES),
                   help="the entry to make, from its recipe in RECIPES (or give --recipe)")
    add_recipe_option(p, "an entry file")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    stored, rest = recipe_defaults(argv, read_recipe)
    entry = next((a for a in rest if a in RECIPES), None)
    base = stored if stored is not None else RECIPES.get(entry or "")
    p = _parser(base)
    ns = p.parse_args(rest)
    if ns.entry is None and stored is None:
        p.error("name an entry (one of " + ", ".join(sorted(RECIPES)) + ") or give --recipe FILE")
    if stored is not None and ns.entry not in (None, stored.entry):
        p.error(f"--recipe is of {stored.entry}, not {ns.entry}")
    setup_logging(ns.log_level)
    recipe = replace(instance_from(DAggerRecipe, ns), entry=ns.entry or stored.entry)
    if (recipe.init is not None or recipe.stage1_only) and "--members" not in rest:
        recipe = replace(recipe, members=1)  # a fine-tune or a stage 1 is of one student
    problem = recipe.problem()
    if problem:
        p.error(problem)
    run = instance_from(DistillRun, ns)
    torch.set_num_threads(recipe.threads)
    from shm_protocol.errors import ShmError

    try:
        distill_entry(recipe, run)
    except ShmError as exc:
        print(f"{exc}\n\n{recipe.entry} needs the daemon: "
              f"{entry_command(recipe, run.out or ENTRIES[recipe.entry].path)}",
              file=sys.stderr)  # fmt: skip
        return EXIT_NO_DAEMON
    return 0


if __name__ == "__main__":
    sys.exit(main())
