"""rover-train: train a Stable-Baselines3 policy on a roverav env.

    rover-train --env lidar --world maze --timesteps 200000
    rover-pair --slots 2 -- rover-train --env fused --timesteps 50000   # --slots 2 from rover-pair
    rover-train --env lidar --task nav --algo recurrent-ppo   # one goal per episode, an LSTM

    rover-train --resume runs/train      # after Ctrl-C: the same run, to its requested steps

Everything that runs is visible top to bottom: parse the arguments, build the vector env
(env i on daemon slot i), build or resume the model with the ``RoverExtractor`` (a CNN for
``fused_image``, an MLP for the other keys), learn with checkpoints and TensorBoard scalars,
then write ``model.zip``, ``metrics.json`` and ``learning_curve.png`` into ``--logdir``.

SIGINT (Ctrl-C) or SIGTERM (rover-pair stopping it) writes a final checkpoint within
seconds and exits with status 130 or 143; ``--resume RUN_DIR`` continues that run exactly
(see :mod:`rover_train.checkpoint` for what is saved and what "exactly" means).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rover_train.algos import ALGOS, ON_POLICY, RECURRENT, algo_class, contrib_missing, policy_name
from rover_train.checkpoint import (
    Checkpoint,
    Checkpointer,
    GracefulStop,
    ResumeError,
    RunRecord,
    SkippedCheckpoint,
    TrainingInterrupted,
    atomic_write,
    checkpoint_stem,
    durable_path,
    find_checkpoints,
    ignore_stop_signals,
    is_off_policy,
    latest_checkpoint,
    make_checkpoint_callback,
    restore_rng_states,
)
from rover_train.cli import build_parser, parse_into, plain
from rover_train.envs import (
    DEFAULT_TASK,
    DISCRETE_KINDS,
    ENV_IDS,
    FUSED_KINDS,
    NAV_LENGTH,
    TASKS,
    env_factory,
    get_task,
)
from rover_train.recipe import (
    OPERATIONAL_FIELDS,
    RecipeError,
    read_recipe,
    recipe_of,
    write_recipe,
)

# rover_env's DEFAULT_WORLD and DEFAULT_MODE, as roverav_cli keeps them: parsing and
# validating the arguments imports neither MuJoCo nor torch (a usage error is refused in a
# fraction of a second); both load when a run starts
from roverav_cli import DEFAULT_PEDESTRIAN_MODE as DEFAULT_MODE
from roverav_cli import DEFAULT_WORLD, Connection, Episodes, pedestrian_count, shared_field

log = logging.getLogger("rover_train")

EXIT_NO_DAEMON = 1


def crowd_sizes_arg(text: str) -> str:
    """Parse ``--crowd-sizes``: pedestrian counts, comma-separated (returned normalised)."""
    try:
        sizes = [pedestrian_count(part) for part in text.split(",")]
    except (argparse.ArgumentTypeError, ValueError) as exc:
        raise argparse.ArgumentTypeError(
            f"--crowd-sizes takes pedestrian counts separated by commas, e.g. 3,10 ({exc})"
        ) from None
    return ",".join(str(n) for n in sizes)


@dataclass
class TrainArgs:
    """Arguments of one training run (the CLI is generated from these fields)."""

    env: str = field(default="lidar", metadata={"choices": tuple(ENV_IDS)})
    """Which env: lidar (RoverEnv), lidar-discrete (RoverEnvDiscrete), fused
    (RoverEnvFused), fused-discrete (its Discrete(60) twin), fused-gaze or
    fused-gaze-discrete (the same, also turning the camera)."""
    world: str = shared_field(Episodes, "world")
    """World (roverav_cli.Episodes; None, the default, is the recipe's or DEFAULT_WORLD)."""
    pedestrian_mode: str = shared_field(Episodes, "pedestrian_mode")
    """How the pedestrians walk (roverav_cli.Episodes; None is the recipe's or DEFAULT_MODE)."""
    n_pedestrians: int | None = shared_field(Episodes, "n_pedestrians")
    """Pedestrians per world, 0 to 20 (default: the world's 3)."""
    crowd_sizes: str | None = field(default=None, metadata={"parse": crowd_sizes_arg,
                                                            "metavar": "N,N,..."})
    """Train among crowds of several sizes: a comma-separated list of pedestrian counts (0 to
    20), env i walking among the (i mod length)-th, e.g. 3,10 (half the envs among the default
    crowd, half among 10). In place of --n-pedestrians; with --slots a multiple of its length
    each size gets the same share of the steps."""
    task: str = field(default=DEFAULT_TASK, metadata={"choices": tuple(TASKS)})
    """What an episode is: seed (the seed's: goal after goal until a failure or the env's
    length, 2000 lidar / 6000 fused) or nav (the RL task, the evaluators' episode: it ends
    at the first goal, with the goal reward and is_success, at the first collision or after
    600 steps; progress pays 10 per metre, and LIDAR envs charge clearance under 0.6 m)."""
    waypoint: bool = False
    """Add the map planner's next waypoint to the observation (the ``waypoint`` key: distance
    and bearing of the point the planner expert steers at, on the world's map;
    rover_train.waypoint). The maze's RL entry uses it."""
    camera_scan: bool = False
    """Fused envs: add the camera scan to the observation (the ``camera_scan`` key: per
    bearing sector around the rover, the nearest scenery and person the camera has seen and
    how long ago it looked; rover_env.camera_scan). A camera agent learns from it what the
    90° image forgets; the policy reads it like the LIDAR."""
    drop_image: bool = False
    """Fused envs: the policy does not see ``fused_image`` (with --camera-scan it reads the scan
    and the state through an MLP instead of the pixels through a CNN; the daemon still
    perceives every frame). rover_train.wrappers.DropImage."""
    relative_table: bool = False
    """--env fused or fused-gaze: Discrete(60) actions, the seed's 5 speeds x 12 headings
    relative to the yaw (RoverEnvDiscrete's table), for PPO and DQN from scratch; on
    fused-gaze Discrete(300), each with one of the 5 pan windows (-60 to +60 deg) as the
    camera's target, so the policy learns where to look from the reward.
    rover_train.wrappers.RelativeTable."""
    pan_head: bool = False
    """With --env fused-gaze --relative-table: the table as two heads, MultiDiscrete([60, 5])
    (a drive of the relative table, a pan window), instead of Discrete(300). Each head learns
    from the whole reward; with --shield only the drive head is masked."""
    shield: bool = False
    """With --camera-scan --relative-table and --algo ppo: train behind the collision shield
    (rover_train.shield): sb3-contrib's MaskablePPO, the shield's mask of the table actions
    that keep the rover's body off what its camera has seen, applied to the policy in the
    rollouts and the updates, so the policy learns over the actions it will be allowed.
    rover-eval and the zoo drive such a model behind the same shield."""
    clearance_from: int | None = None
    """Fused envs, --task nav: charge the LIDAR envs' clearance term (NAV_CLEARANCE_PENALTY
    per metre of the LIDAR minimum inside NAV_CLEARANCE, from a scan the simulator casts for
    the reward, never an input) from this many training steps on; 0 charges it from the
    start. Off by default on the fused kinds: from the start a camera agent learnt to stand
    still. A curriculum: first to reach the goal, then to keep off the scenery."""
    clearance_footprints: bool = False
    """With --clearance-from: measure the clearance term from the map's obstacle footprints
    too (RewardConfig.clearance_footprints), which cover what the LIDAR's plane passes under,
    as the inspect world's panel edges."""
    personal_space_distance: float | None = None
    """--task nav: the distance (m, rover centre to person centre) inside which the nav task's
    personal-space term charges, from the first step, instead of NAV_PERSONAL_SPACE (1.2 m)."""
    clearance_distance: float | None = None
    """With --clearance-from: the distance (m, from the rover's centre) inside which the
    clearance term charges, instead of the nav task's NAV_CLEARANCE (0.6 m). The rover's
    half-diagonal is 0.31 m."""
    algo: str = field(default="ppo", metadata={"choices": ALGOS})
    """ppo (all envs), recurrent-ppo (all envs: PPO with an LSTM policy, from sb3-contrib),
    sac (lidar, fused) or dqn (discrete)."""
    timesteps: int = 100_000
    """Total environment steps to train for (over all envs)."""
    slots: int = shared_field(Connection, "slots")
    """Parallel envs; env i uses daemon slot i (roverav_cli.Connection)."""
    seed: int = 0
    """Training seed: of the model and of env i's first reset (seed + i). Not rover-eval's
    --seed (the evaluation seeds, from 100000, which training stays clear of)."""
    device: str = "cpu"
    """Torch device for the policy: cpu or cuda."""
    logdir: Path = Path("runs/train")
    """Run directory: model, metrics, curve, checkpoints, TensorBoard events."""
    checkpoint_every: int = 25_000
    """Save a checkpoint every this many environment steps (0: only at the end and on a
    stop)."""
    resume: Path | None = None
    """A run directory (an earlier --logdir) to continue from its newest checkpoint, with its
    own arguments, to its requested --timesteps (give --timesteps again to extend it)."""
    recipe: Path | None = None
    """A model .zip that rover-train wrote (a zoo RL entry, a run's model.zip): train it anew
    with the arguments stored in it; flags given as well override those."""
    progress: bool = True
    """Show a progress bar."""
    name: str = shared_field(Connection, "name")
    """Daemon segment base name (fused envs; roverav_cli.Connection)."""
    length: int | None = None
    """Episode length override (default: the task's, nav 600; seed: the env's own, 2000 lidar
    / 6000 fused)."""
    connect_timeout: float = 10.0
    """Seconds to wait for the daemon's segments before giving up (fused envs)."""
    vec_env: str = field(default="auto", metadata={"choices": ("auto", "subproc", "dummy")})
    """auto (subprocesses for several fused envs, one process otherwise), subproc or dummy."""
    ray: str | None = field(default=None, metadata={"nargs": "?", "const": "",
                                                   "metavar": "ADDRESS"})  # fmt: skip
    """Step the envs in Ray actors: ADDRESS of a cluster's head (host:6379, auto), or no
    ADDRESS to start a local one. Each worker runs its own av-daemon (fused envs). Needs
    pip install 'roverav[ray]'."""
    ray_workers: int = 2
    """With --ray: env worker actors, spread over the cluster's nodes (av-daemon's --workers
    are its serving threads)."""
    envs_per_worker: int = 1
    """With --ray: envs per worker (its daemon serves that many slots)."""
    threads: int = 1
    """Torch intra-op threads of the trainer (small nets on CPU run best on one; the daemon
    and the env workers need the other cores)."""
    update_threads: int = 1
    """PPO and recurrent-ppo: torch threads for the gradient epochs, while envs and daemon
    are idle (0: every core this process may use). More than 1 pays only on an otherwise
    idle machine: with other work on the cores a 2-thread update is slower. Rollouts
    keep --threads."""
    log_level: str = shared_field(Connection, "log_level")
    """Log level (roverav_cli.Connection)."""
    # --- algorithm hyperparameters (written to metrics.json) -----------------------------
    learning_rate: float | None = None
    """Adam learning rate (default: ppo and sac 3e-4, dqn 1e-4)."""
    gamma: float = 0.99
    """Discount factor (all algorithms)."""
    batch_size: int | None = None
    """Minibatch size (default: ppo 256, recurrent-ppo 256, sac 256, dqn 32)."""
    n_steps: int = 1024
    """PPO and recurrent-ppo: rollout length per env."""
    n_epochs: int = 10
    """PPO and recurrent-ppo: optimisation epochs per rollout."""
    gae_lambda: float = 0.95
    """PPO and recurrent-ppo: GAE lambda."""
    clip_range: float = 0.2
    """PPO and recurrent-ppo: policy clip range."""
    ent_coef: float = 0.0
    """PPO and recurrent-ppo: entropy bonus coefficient."""
    buffer_size: int | None = None
    """SAC/DQN: replay buffer size (default: sac 100000, dqn 50000)."""
    learning_starts: int = 1_000
    """SAC/DQN: environment steps collected before the first update."""
    exploration_fraction: float = 0.3
    """DQN: fraction of training over which epsilon anneals."""
    train_freq: int | None = None
    """SAC/DQN: update the model every this many vector steps, each a step of every env
    (default: Stable-Baselines3's, sac 1, dqn 4)."""
    gradient_steps: int | None = None
    """SAC/DQN: gradient steps per update, -1 for as many as the env steps collected since
    the last one (default 1). On 2 cores SAC's one per vector step is the bottleneck of a
    fused run (34 steps/s beside a PPO run)."""

    def __post_init__(self) -> None:
        # the shared --world and --pedestrian-mode default to None: "the recipe's own" under
        # --recipe or --resume; a run itself always names them
        if self.world is None:
            self.world = DEFAULT_WORLD
        if self.pedestrian_mode is None:
            self.pedestrian_mode = DEFAULT_MODE


_ALGO_DEFAULTS: dict[str, dict[str, Any]] = {
    "ppo": {"learning_rate": 3e-4, "batch_size": 256},
    "recurrent-ppo": {"learning_rate": 3e-4, "batch_size": 256},
    "sac": {"learning_rate": 3e-4, "batch_size": 256, "buffer_size": 100_000},
    "dqn": {"learning_rate": 1e-4, "batch_size": 32, "buffer_size": 50_000},
}


def hyperparameters(args: TrainArgs) -> dict[str, Any]:
    """The keyword arguments the algorithm is built with (what ``metrics.json`` records)."""
    d = _ALGO_DEFAULTS[args.algo]
    hp: dict[str, Any] = {"learning_rate": args.learning_rate or d["learning_rate"],
                          "gamma": args.gamma,
                          "batch_size": args.batch_size or d["batch_size"]}  # fmt: skip
    if args.algo in ON_POLICY:
        hp.update(n_steps=args.n_steps, n_epochs=args.n_epochs, gae_lambda=args.gae_lambda,
                  clip_range=args.clip_range, ent_coef=args.ent_coef)  # fmt: skip
    else:
        hp.update(buffer_size=args.buffer_size or d["buffer_size"],
                  learning_starts=args.learning_starts)  # fmt: skip
        if args.train_freq is not None:
            hp["train_freq"] = args.train_freq
        if args.gradient_steps is not None:
            hp["gradient_steps"] = args.gradient_steps
        if args.algo == "dqn":
            hp["exploration_fraction"] = args.exploration_fraction
    return hp


_EPILOG = (
    "Under rover-pair, --name and --slots default to the supervisor's. SIGINT/SIGTERM "
    "save a checkpoint and exit 130/143; --resume RUN_DIR continues the run."
)
RESUME_OPERATIONAL = OPERATIONAL_FIELDS
"""Fields a resumed run takes from this invocation (flags, or rover-pair's environment)."""
RESUME_EXTENDABLE = ("timesteps", "checkpoint_every", "slots")
"""Fields a resumed run keeps from the run unless given again on the command line."""


def recipe_args(given: TrainArgs, argv: Sequence[str] | None) -> TrainArgs:
    """The arguments stored in ``given.recipe``, with this invocation's operational fields
    and every flag given on the command line in place of the stored value."""
    assert given.recipe is not None
    saved = recipe_of(read_recipe(given.recipe))
    explicit = explicit_fields(argv)
    fields: dict[str, Any] = {}
    for name in TrainArgs.__dataclass_fields__:
        value = getattr(given, name)
        if name in saved and name not in explicit:
            value = saved[name]
        fields[name] = value
    return TrainArgs(**fields)


def _parser() -> Any:
    return build_parser(TrainArgs, "rover-train", __doc__.split("\n")[0], epilog=_EPILOG)


def parse_args(argv: Sequence[str] | None = None) -> TrainArgs:
    p = _parser()
    args = parse_into(TrainArgs, p, argv)
    if args.resume is not None and args.recipe is not None:
        p.error("--resume continues a run and --recipe starts one: give one of them")
    if args.recipe is not None:
        try:
            args = recipe_args(args, argv)
        except RecipeError as exc:
            p.error(f"--recipe: {exc}")
    if args.resume is not None:
        try:
            args = resume_args(args, argv)
        except ResumeError as exc:
            p.error(str(exc))
    problem = validate(args)
    if problem:
        p.error(problem)
    return args


def explicit_fields(argv: Sequence[str] | None) -> dict[str, Any]:
    """The fields given on the command line (not defaulted), parsed."""
    import argparse

    p = _parser()
    for action in p._actions:  # default=SUPPRESS: only what argv gives lands in the namespace
        action.default = argparse.SUPPRESS
    return vars(p.parse_args(argv))


def resume_args(given: TrainArgs, argv: Sequence[str] | None) -> TrainArgs:
    """The arguments of the run in ``given.resume``, with this invocation's operational
    fields and any of :data:`RESUME_EXTENDABLE` given again; :class:`ResumeError` when a flag
    would change what the run is (its env, algorithm, seed, hyperparameters)."""
    assert given.resume is not None
    run_dir = given.resume
    if not run_dir.is_dir():
        raise ResumeError(f"--resume {run_dir}: expected a run directory (an earlier --logdir),"
                          " found " + ("a file" if run_dir.exists() else "nothing"))  # fmt: skip
    saved = RunRecord.load(run_dir).args
    explicit = explicit_fields(argv)
    fields: dict[str, Any] = {}
    for name, f in TrainArgs.__dataclass_fields__.items():
        if name in RESUME_OPERATIONAL:
            fields[name] = getattr(given, name)
        elif name in RESUME_EXTENDABLE and name in explicit:
            fields[name] = explicit[name]
        elif name in ("resume", "logdir"):
            fields[name] = run_dir
        elif name == "recipe":  # the run is under way: where it started does not matter
            fields[name] = None
        else:
            value = saved.get(name, f.default)
            if isinstance(getattr(given, name), Path) and value is not None:
                value = Path(value)
            if name in explicit and explicit[name] != value:
                flag = "--" + name.replace("_", "-")
                raise ResumeError(
                    f"--resume continues a run as it was started: {flag} was {value!r} in "
                    f"{run_dir}, this command gives {explicit[name]!r}. Drop {flag}, or start a "
                    "new run with another --logdir."
                )
            fields[name] = value
    return TrainArgs(**fields)


def validate(args: TrainArgs) -> str | None:
    """A message naming what is wrong with ``args`` and how to fix it, or None."""
    discrete = args.env in DISCRETE_KINDS or args.relative_table
    if args.algo == "dqn" and not discrete:
        return (
            "--algo dqn needs a discrete action space: use --env lidar-discrete|fused-discrete|"
            "fused-gaze-discrete "
            "(or --algo ppo/sac)"
        )
    if args.algo == "sac" and discrete:
        return (
            "--algo sac needs continuous actions: use --env lidar|fused|fused-gaze, "
            "or --algo ppo/dqn"
        )
    if args.camera_scan and args.env not in FUSED_KINDS:
        return (
            f"--camera-scan is built from the fused image: use --env with one of "
            f"{', '.join(FUSED_KINDS)} (--env {args.env} has the LIDAR, which sees all round)"
        )
    if args.drop_image and args.env not in FUSED_KINDS:
        return f"--drop-image takes the fused image out: use it with a fused --env, not {args.env}"
    if args.relative_table and args.env not in ("fused", "fused-gaze"):
        return ("--relative-table puts Discrete(60) over a continuous fused env: use --env fused "
                "or fused-gaze (lidar-discrete has the same table already)")
    if args.pan_head and not (args.env == "fused-gaze" and args.relative_table):
        return ("--pan-head splits the gaze env's relative table into a drive head and a pan "
                f"head: give --env fused-gaze --relative-table (got --env {args.env}"
                f"{'' if args.relative_table else ', no --relative-table'})")  # fmt: skip
    if args.pan_head and args.algo not in ON_POLICY:
        return (f"--pan-head's two heads (MultiDiscrete) are for --algo ppo or recurrent-ppo "
                f"(got --algo {args.algo})")  # fmt: skip
    if args.shield and not (args.camera_scan and args.relative_table and args.algo == "ppo"):
        return ("--shield masks the relative table's actions by the camera scan, for PPO: give "
                "--camera-scan --relative-table with --algo ppo (got "
                f"--algo {args.algo}{'' if args.camera_scan else ', no --camera-scan'}"
                f"{'' if args.relative_table else ', no --relative-table'})")  # fmt: skip
    if args.clearance_from is not None and (args.env not in FUSED_KINDS or args.task != "nav"
                                            or args.clearance_from < 0):
        return (f"--clearance-from adds the nav task's clearance term to a fused env from a step "
                f"count >= 0: use it with a fused --env and --task nav (LIDAR envs pay it from "
                f"the start), got --env {args.env} --task {args.task} "
                f"--clearance-from {args.clearance_from}")  # fmt: skip
    if args.clearance_distance is not None and (args.clearance_from is None
                                                or not args.clearance_distance > 0):
        return (f"--clearance-distance sets the reach of the term --clearance-from adds: give "
                f"--clearance-from STEPS too, and a distance > 0 m (got "
                f"{args.clearance_distance})")  # fmt: skip
    if args.personal_space_distance is not None and (args.task != "nav"
                                                     or not args.personal_space_distance > 0):
        return (f"--personal-space-distance sets the reach of the nav task's personal-space "
                f"term: use it with --task nav and a distance > 0 m (got --task {args.task}, "
                f"{args.personal_space_distance})")  # fmt: skip
    if args.clearance_footprints and args.clearance_from is None:
        return ("--clearance-footprints measures the clearance term --clearance-from adds: give "
                "--clearance-from STEPS too")  # fmt: skip
    if args.crowd_sizes is not None and (args.n_pedestrians is not None or args.ray is not None):
        return ("--crowd-sizes gives each env its own crowd: leave out --n-pedestrians (every "
                "env the same) and --ray (its workers take one --n-pedestrians)")  # fmt: skip
    if args.slots < 1 or args.timesteps < 1:
        return f"--slots and --timesteps must be at least 1, got {args.slots} and {args.timesteps}"
    if args.task not in TASKS:  # the CLI's choices say so too; TrainArgs built in code
        return f"--task must be one of {', '.join(TASKS)}, got {args.task!r}"
    return (contrib_missing(args.algo, args.shield) or _validate_ray(args) or _validate_values(args)
            or _validate_device(args))  # fmt: skip


def crowd_size(args: TrainArgs, env_index: int) -> int | None:
    """The pedestrian count of env ``env_index``: its share of --crowd-sizes, else
    --n-pedestrians (None: the world's own)."""
    if args.crowd_sizes is None:
        return args.n_pedestrians
    sizes = [int(n) for n in args.crowd_sizes.split(",")]
    return sizes[env_index % len(sizes)]


def n_envs(args: TrainArgs) -> int:
    """How many envs the run steps: --slots, or with --ray workers x envs per worker."""
    return args.ray_workers * args.envs_per_worker if args.ray is not None else args.slots


def _validate_ray(args: TrainArgs) -> str | None:
    """--ray: worker counts, and Ray itself (an extra: the core install does not have it)."""
    if args.ray is None:
        return None
    if args.ray_workers < 1 or args.envs_per_worker < 1:
        return (f"--ray-workers and --envs-per-worker must be at least 1, got {args.ray_workers} "
                f"and {args.envs_per_worker}")  # fmt: skip
    import importlib.util

    if importlib.util.find_spec("ray") is None:
        return "--ray needs Ray, which is not installed: pip install 'roverav[ray]'"
    return None


def _validate_values(args: TrainArgs) -> str | None:
    """Lengths, segment name and --resume (a complete checkpoint to continue from): each
    message names the value and the fix."""
    from shm_protocol import InvalidNameError, camera_name, slot_name

    if args.length is not None and args.length < 1:
        return (f"--length must be at least 1 step (or omit it for the task's: nav {NAV_LENGTH}, "
                f"seed the env's own), got {args.length}")  # fmt: skip
    rollout = args.n_steps * n_envs(args)
    if args.algo in ON_POLICY and rollout < 2:
        return (
            f"--n-steps must be at least 2 for --algo {args.algo} (a rollout of n_steps x "
            f"slots > 1 steps), got --n-steps {args.n_steps} with {n_envs(args)} env(s)"
        )
    batch = args.batch_size or _ALGO_DEFAULTS[args.algo]["batch_size"]
    if args.algo in RECURRENT and batch > 0 and rollout % batch == 1:
        return (
            f"--batch-size {batch} leaves a minibatch of 1 step from a rollout of {rollout} "
            f"(n_steps {args.n_steps} x {n_envs(args)} env(s)): {args.algo} normalises the "
            "advantages per minibatch, which is NaN for one step. Choose a --batch-size that "
            f"divides {rollout}, or another --n-steps"
        )
    positive = {
        "--batch-size": args.batch_size,
        "--n-epochs": args.n_epochs,
        "--buffer-size": args.buffer_size,
        "--learning-rate": args.learning_rate,
        "--train-freq": args.train_freq,
    }
    for flag, value in positive.items():
        if value is not None and not value > 0:
            return f"{flag} must be > 0 (or omit it for the algorithm's default), got {value}"
    if args.gradient_steps is not None and (args.gradient_steps == 0 or args.gradient_steps < -1):
        return (f"--gradient-steps must be >= 1, or -1 for one per env step, got "
                f"{args.gradient_steps}")  # fmt: skip
    if not 0.0 < args.gamma <= 1.0:
        return f"--gamma is a discount factor in (0, 1], got {args.gamma}"
    if args.env in FUSED_KINDS:
        try:
            camera_name(slot_name(args.name, args.slots - 1))
        except InvalidNameError as exc:
            return f"--name: {exc}"
    if args.resume is not None:
        try:
            latest_checkpoint(args.resume)
        except ResumeError as exc:
            return str(exc)
    return None


def _validate_device(args: TrainArgs) -> str | None:
    if args.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            return f"--device {args.device}: torch sees no CUDA device here; use --device cpu"
    return None


def check_daemon(args: TrainArgs) -> str | None:
    """For fused envs: None when a live daemon serves every slot, else what to do about it."""
    if args.env not in FUSED_KINDS or args.ray is not None:  # Ray workers run their own
        return None
    from rover_env import served_slots

    served = served_slots(args.name, timeout=args.connect_timeout)
    if served >= args.slots:
        return None
    found = (
        f"the av-daemon serving '{args.name}' has {served} slot(s)"
        if served
        else f"no live av-daemon serves '{args.name}' (waited {args.connect_timeout:g} s)"
    )
    return (
        f"{found}, and rover-train --env {args.env} needs at least {args.slots}. Either start "
        f"it in another terminal:\n    av-daemon --name {args.name} --slots {args.slots}\n"
        f"or let rover-pair run both:\n    rover-pair --name {args.name} "
        f"--slots {args.slots} -- rover-train {' '.join(sys.argv[1:])}"
    )


def _in_worker(thunk: Any) -> Any:
    """Build an env in a vector-env worker process that leaves SIGINT/SIGTERM to the trainer
    (which saves, then closes its workers in order)."""
    ignore_stop_signals()
    return thunk()


def build_vec_env(args: TrainArgs, monitor_dir: Path, append_monitor: bool = False) -> Any:
    """The run's vector env (subprocesses, one process or Ray actors); with --shield it also
    answers MaskablePPO's action masks."""
    venv = _build_vec_env(args, monitor_dir, append_monitor)
    if not args.shield:
        return venv
    from rover_train.shield import shield_for, shielded_vec_env

    return shielded_vec_env(venv, shield_for(plain(args), "this run"))


def _build_vec_env(args: TrainArgs, monitor_dir: Path, append_monitor: bool) -> Any:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if args.ray is not None:
        from rover_train.ray_vec_env import make_ray_vec_env

        return make_ray_vec_env(args)

    thunks = [
        env_factory(
            args.env,
            monitor_dir=str(monitor_dir),
            world=args.world,
            pedestrian_mode=args.pedestrian_mode,
            n_pedestrians=crowd_size(args, i),
            slot=i,
            name=args.name,
            length=args.length,
            task=args.task,
            connect_timeout=args.connect_timeout,
            append_monitor=append_monitor,
            waypoint=args.waypoint,
            camera_scan=args.camera_scan,
            drop_image=args.drop_image,
            relative_table=args.relative_table,
            pan_head=args.pan_head,
        )
        for i in range(args.slots)
    ]
    # A LIDAR env steps in well under a millisecond: in-process beats subprocess round trips.
    # A fused env waits on the daemon each step: subprocesses overlap those waits.
    subproc = args.vec_env == "subproc" or (
        args.vec_env == "auto" and args.slots > 1 and args.env in FUSED_KINDS
    )
    if not subproc:
        return DummyVecEnv(thunks)
    return SubprocVecEnv([functools.partial(_in_worker, t) for t in thunks],
                         start_method="forkserver")  # fmt: skip


def build_model(args: TrainArgs, venv: Any, tb_dir: Path) -> Any:
    """A new model for ``args`` (resumed runs are loaded by :func:`resume_model`)."""
    from rover_train.policies import RoverExtractor

    cls = algo_class(args.algo, masked=args.shield)
    common: dict[str, Any] = {
        "policy": policy_name(args.algo),
        "env": venv,
        "seed": args.seed,
        "device": args.device,
        "tensorboard_log": str(tb_dir),
        "policy_kwargs": {"features_extractor_class": RoverExtractor},
        "verbose": 0,
    }
    return cls(**hyperparameters(args), **common)


def resume_model(args: TrainArgs, venv: Any, tb_dir: Path) -> tuple[Any, dict[str, Any]]:
    """The newest checkpoint of run ``args.logdir``, loaded onto ``venv`` with its RNGs, replay
    buffer and env episode RNGs restored; returns the model and the checkpoint's state."""
    cls = algo_class(args.algo, masked=args.shield)
    model, found, skipped = None, None, 0
    for found in find_checkpoints(args.logdir):  # newest first; say why each newer one is not
        if isinstance(found, SkippedCheckpoint):
            log.warning("resume: %s", found)
            skipped += 1
            continue
        try:  # seed=None: loading must not reseed the RNGs and envs; their states go back below
            model = cls.load(found.model_path, env=venv, device=args.device,
                             tensorboard_log=str(tb_dir), seed=None)  # fmt: skip
            break
        except Exception as exc:
            skipped += 1
            log.warning("resume: %s", SkippedCheckpoint(found.stem, f"Stable-Baselines3 cannot "
                        f"load {found.model_path.name} ({type(exc).__name__}: {exc})"))  # fmt: skip
    if model is None or not isinstance(found, Checkpoint):
        latest_checkpoint(args.logdir)  # raises the ResumeError that lists what is wrong
        raise ResumeError(f"--resume {args.logdir}: no checkpoint there loads (see above)")
    path, state = found.model_path, found.state
    log.info(
        "resuming from %s (%d steps)%s",
        path,
        state["num_timesteps"],
        f": the newest checkpoint that loads ({skipped} skipped)" if skipped else "",
    )
    if is_off_policy(model) and state.get("replay_buffer"):
        try:
            if found.replay_problem:
                raise FileNotFoundError(found.replay_problem)
            model.load_replay_buffer(path.parent / state["replay_buffer"])
        except Exception as exc:
            log.warning("resume: replay buffer not loaded (%s): resuming with an empty one, "
                        "refilled from here on", exc)  # fmt: skip
    restore_rng_states(model, state["rng"])
    env_rng = state["env_rng"]
    if len(env_rng) == venv.num_envs and all(r is not None for r in env_rng):
        for i, rng in enumerate(env_rng):
            venv.env_method("restore_episode_rng", rng, indices=[i])
    else:  # another --slots, or no episode had begun: start the envs as a new run would
        log.warning("resume: env episode RNGs not restorable (%d saved for %d envs); "
                    "reseeding the envs with --seed", len(env_rng), venv.num_envs)  # fmt: skip
        venv.seed(args.seed)
    return model, state


def make_metrics_callback() -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    from rover_env.constants import PERSONAL_SPACE_M

    class RoverMetrics(BaseCallback):
        """Logs episode return, success, collisions, intrusions and frame latency."""

        def __init__(self) -> None:
            super().__init__()
            self.episodes: list[dict[str, float]] = []
            self._acc: list[dict[str, float]] = []

        def _on_training_start(self) -> None:
            self._acc = [self._blank() for _ in range(self.training_env.num_envs)]

        @staticmethod
        def _blank() -> dict[str, float]:
            return {"collisions": 0.0, "intrusions": 0.0, "latency_sum": 0.0, "latency_n": 0.0}

        def _on_step(self) -> bool:
            for i, info in enumerate(self.locals["infos"]):
                acc = self._acc[i]
                acc["collisions"] += float(bool(info.get("collision", False)))
                acc["intrusions"] += float(
                    info.get("min_pedestrian_distance", np.inf) < PERSONAL_SPACE_M
                )
                if "frame_latency_ms" in info:
                    acc["latency_sum"] += float(info["frame_latency_ms"])
                    acc["latency_n"] += 1
                if "episode" not in info:
                    continue
                ep = {
                    "timestep": float(self.num_timesteps),
                    "return": float(info["episode"]["r"]),
                    "length": float(info["episode"]["l"]),
                    "success": float(info.get("goals_reached", 0) > 0),
                    "goals": float(info.get("goals_reached", 0)),
                    "collisions": acc["collisions"],
                    "intrusions": acc["intrusions"],
                    "termination": info.get("termination_reason") or "length",
                    "truncated_by_fault": float("daemon_error" in info),
                }
                if acc["latency_n"]:
                    ep["frame_latency_ms"] = acc["latency_sum"] / acc["latency_n"]
                self.episodes.append(ep)
                self._acc[i] = self._blank()
                recent = self.episodes[-20:]
                self.logger.record("charts/episodic_return", ep["return"])
                self.logger.record("charts/episodic_length", ep["length"])
                self.logger.record("charts/success_rate", np.mean([e["success"] for e in recent]))
                self.logger.record("charts/collisions", ep["collisions"])
                self.logger.record("charts/personal_space_intrusions", ep["intrusions"])
                if "frame_latency_ms" in ep:
                    self.logger.record("charts/frame_latency_ms", ep["frame_latency_ms"])
            return True

    return RoverMetrics()


def make_clearance_switch(at_steps: int, task: str, footprints: bool = False,
                          distance: float | None = None) -> Any:  # fmt: skip
    """A callback that adds ``task``'s LIDAR-only reward terms (the nav task's clearance term;
    measured from the map's footprints too with ``footprints``, charged inside ``distance``
    when given) to every env once the run has taken ``at_steps`` steps (at once on a run
    resumed past them); the rest of each env's reward constants stay its own."""
    terms: dict[str, Any] = {**get_task(task).lidar_reward}
    if footprints:
        terms["clearance_footprints"] = True
    if distance is not None:
        terms["clearance_distance"] = distance
    return make_reward_switch(at_steps, terms, "the clearance term is on")


def make_reward_switch(at_steps: int, terms: dict[str, Any], what: str) -> Any:
    """A callback that sets the ``RewardConfig`` fields ``terms`` on every env once the run has
    taken ``at_steps`` steps (at once on a run resumed past them, and at the start with 0),
    logging ``what``; the env's other reward constants stay its own."""
    from stable_baselines3.common.callbacks import BaseCallback

    class RewardSwitch(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.switched = False

        def _switch(self) -> None:
            venv = self.training_env
            for i, cfg in enumerate(venv.get_attr("reward_config")):
                venv.env_method("set_reward_config", dataclasses.replace(cfg, **terms),
                                indices=[i])  # fmt: skip
            self.switched = True
            log.info("step %d: %s (%s)", self.num_timesteps, what, terms)

        def _on_training_start(self) -> None:
            if self.num_timesteps >= at_steps:
                self._switch()

        def _on_step(self) -> bool:
            if not self.switched and self.num_timesteps >= at_steps:
                self._switch()
            return True

    return RewardSwitch()


def save_learning_curve(episodes: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    if episodes:
        x = np.array([e["timestep"] for e in episodes])
        y = np.array([e["return"] for e in episodes])
        ax.plot(x, y, ".", alpha=0.35, label="episode return")
        k = max(1, min(20, len(y) // 5))
        if len(y) >= k:
            smooth = np.convolve(y, np.ones(k) / k, mode="valid")
            ax.plot(x[k - 1 :], smooth, "-", lw=2, label=f"mean of {k}")
        ax.legend(loc="best")
    else:
        ax.text(
            0.5, 0.5, "no episode finished within the budget", ha="center", transform=ax.transAxes
        )
    ax.set_xlabel("environment steps")
    ax.set_ylabel("return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def train(args: TrainArgs) -> dict[str, Any]:
    """Run (or resume) one training job; returns the metrics written to ``metrics.json``.

    ``metrics["status"]`` is ``complete``, or ``interrupted`` when SIGINT/SIGTERM stopped it
    (a checkpoint is written either way; ``metrics["exit_status"]`` is 0, 130 or 143).
    """
    import torch
    from stable_baselines3.common.callbacks import CallbackList

    from rover_train.threads import PhaseThreads

    torch.set_num_threads(max(args.threads, 1))
    run_dir = args.logdir
    run_dir.mkdir(parents=True, exist_ok=True)
    monitor_dir = run_dir / "monitor"
    monitor_dir.mkdir(exist_ok=True)
    resuming = args.resume is not None
    if resuming:
        record = RunRecord.load(run_dir)
        record.args, record.timesteps = plain(args), args.timesteps
        record.resumes += 1
    else:
        record = RunRecord(args=plain(args), timesteps=args.timesteps,
                           tb_log_name=f"{args.algo}_{args.env}")  # fmt: skip
    stop = GracefulStop()
    metrics_cb = make_metrics_callback()
    checkpointer = Checkpointer(run_dir, args.algo, args.checkpoint_every, stop,
                                metrics_cb.episodes, record)  # fmt: skip
    wall = 0.0
    with stop.installed():
        venv = build_vec_env(args, monitor_dir, append_monitor=resuming)
        broken = False
        try:
            if resuming:
                model, state = resume_model(args, venv, run_dir / "tb")
                record.num_timesteps = int(state["num_timesteps"])  # the one that loaded
                record.latest_checkpoint = checkpoint_stem(args.algo, record.num_timesteps)
                metrics_cb.episodes.extend(state["episode_log"])
                env_rng = state["env_rng"]
            else:
                model = build_model(args, venv, run_dir / "tb")
                env_rng = [None] * venv.num_envs
            checkpointer.attach(model, env_rng)
            start_steps = int(model.num_timesteps)
            record.history.append({"started_at": time.time(), "steps_at_start": start_steps})
            record.status = "running"
            record.save(run_dir)
            remaining = args.timesteps - start_steps
            callbacks = [metrics_cb, make_checkpoint_callback(checkpointer)]
            if args.clearance_from is not None:
                callbacks.append(make_clearance_switch(args.clearance_from, args.task,
                                                       args.clearance_footprints,
                                                       args.clearance_distance))  # fmt: skip
            if args.personal_space_distance is not None:
                callbacks.append(make_reward_switch(
                    0, {"personal_space_distance": args.personal_space_distance},
                    "the personal space's reach"))  # fmt: skip
            if args.algo in ON_POLICY and args.update_threads != args.threads:
                callbacks.append(PhaseThreads(max(args.threads, 1), max(args.update_threads, 0)))
            start = time.perf_counter()
            if remaining > 0 and not stop.requested:
                try:
                    with stop.learning_block():
                        model.learn(
                            total_timesteps=remaining,
                            callback=CallbackList(callbacks),
                            progress_bar=args.progress,
                            reset_num_timesteps=not resuming,
                            tb_log_name=record.tb_log_name,
                        )
                except TrainingInterrupted:
                    broken = True  # a worker may still be answering the step we left
            wall = time.perf_counter() - start
            if stop.requested:
                dropped = checkpointer.rewind_to_boundary()
                checkpointer.save("stop", status="interrupted")
                log.warning("stopped at %d of %d steps (%d collected steps not yet learned from "
                            "will be collected again); resume with: rover-train --resume %s",
                            model.num_timesteps, args.timesteps, dropped, run_dir)  # fmt: skip
            else:
                checkpointer.save("final", status="complete")
                with durable_path(run_dir / "model.zip") as tmp:
                    model.save(tmp)
                    write_recipe(tmp, plain(args))
        except BaseException:
            record.status = "failed"
            record.save(run_dir)
            broken = True
            if checkpointer.model is not None and stop.phase == "collect":
                # failed while stepping envs (say, a daemon that never came back): the model
                # is as it was at the rollout's start, so that boundary is worth keeping
                try:
                    checkpointer.rewind_to_boundary()
                    checkpointer.save("failure", status="failed")
                except Exception:  # the original error matters more than this save
                    log.exception("could not write a checkpoint after the failure")
            raise
        finally:
            if record.history:
                record.history[-1].update(ended_at=time.time(), status=record.status,
                                          steps_at_end=int(record.num_timesteps))  # fmt: skip
            record.save(run_dir)
            _close(venv, broken)
    episodes = metrics_cb.episodes
    recent = episodes[-20:]
    trained = int(model.num_timesteps) - start_steps
    metrics: dict[str, Any] = {
        "env": args.env,
        "env_id": ENV_IDS[args.env],
        "world": args.world,
        "task": args.task,
        "algo": args.algo,
        "status": record.status,
        "exit_status": stop.exit_status() if stop.requested else 0,
        "timesteps": int(model.num_timesteps),
        "timesteps_requested": args.timesteps,
        "resumes": record.resumes,
        "wall_time_s": round(wall, 2),  # this part's (since the start or the last --resume)
        "wall_time_total_s": round(sum(h["ended_at"] - h["started_at"] for h in record.history
                                       if "ended_at" in h), 2),  # every part's, resumes too
        "steps_per_s": round(trained / wall, 1) if wall > 0 and trained > 0 else None,
        "episodes": len(episodes),
        "episodes_truncated_by_faults": int(sum(e.get("truncated_by_fault", 0) for e in episodes)),
        "mean_return_last20": float(np.mean([e["return"] for e in recent])) if recent else None,
        "success_rate_last20": float(np.mean([e["success"] for e in recent])) if recent else None,
        "hyperparameters": hyperparameters(args),
        "args": plain(args),
        "episode_log": episodes,
    }
    atomic_write(run_dir / "metrics.json", json.dumps(metrics, indent=2).encode())
    save_learning_curve(
        episodes,
        run_dir / "learning_curve.png",
        f"{args.algo.upper()} on {ENV_IDS[args.env]} ({args.world})",
    )
    return metrics


def _close(venv: Any, broken: bool) -> None:
    """Close the vector env; after an interrupted step, kill its workers instead of waiting
    for an answer that may not come."""
    if broken and hasattr(venv, "processes"):
        for proc in venv.processes:
            proc.kill()
        for proc in venv.processes:
            proc.join(5.0)
        return
    venv.close()


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=args.log_level,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")  # fmt: skip
    problem = check_daemon(args)
    if problem:
        print(problem, file=sys.stderr)
        return EXIT_NO_DAEMON
    try:
        metrics = train(args)
    except ResumeError as exc:  # every checkpoint failed to load (their files looked whole)
        print(f"rover-train: error: {exc}", file=sys.stderr)
        return 2
    if metrics["status"] == "interrupted":
        print(
            f"stopped {metrics['algo']} on {metrics['env_id']} at {metrics['timesteps']} of "
            f"{metrics['timesteps_requested']} steps; checkpoint in {args.logdir}/checkpoints. "
            f"Continue with: rover-train --resume {args.logdir}"
        )
        return int(metrics["exit_status"])
    print(
        f"trained {metrics['algo']} on {metrics['env_id']} ({metrics['world']}): "
        f"{metrics['timesteps']} steps in {metrics['wall_time_s']} s "
        f"({metrics['steps_per_s']} steps/s), {metrics['episodes']} episodes; "
        f"wrote {args.logdir}/model.zip, metrics.json, learning_curve.png"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
