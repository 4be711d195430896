"""Resumable training: what a checkpoint holds, how a run stops on a signal, how it resumes.

A run directory (``rover-train --logdir RUN_DIR``) holds::

    run.json                            the run's arguments, requested steps, status, latest
                                        checkpoint (written at start and at every checkpoint)
    checkpoints/ppo_<steps>_steps.zip         the SB3 model: weights, optimiser, step counter
    checkpoints/ppo_<steps>_steps.state.pkl   everything else resume needs (below); written
                                              last, so its presence marks a complete checkpoint
    checkpoints/sac_<steps>_steps.replay.pkl  off-policy replay buffer (latest checkpoint only)

The state file holds the RNG states (Python, NumPy, torch, the action space), each env's
episode RNG (the env's ``np_random`` state just before the reset that began the episode in
flight), the learning-curve episode log, SB3's episode-info buffers and the TensorBoard run
name. ``rover-train --resume RUN_DIR`` loads the newest complete checkpoint and trains on,
in the same directory, to the run's requested total (``--timesteps`` given again extends it).

**Crashes and damaged files.** Every file here is written under a temporary name, synced to
disk, renamed into place and its directory synced (:func:`durable_path`), so a crash, a
power loss or a full disk leaves the old file or the whole new one, never a torn one under
the real name. The state file records the sizes of the checkpoint's other files. Resume
takes the newest checkpoint that loads: one whose state file is missing or unreadable,
whose ``.zip`` is short of its recorded size, not a zip or fails its CRCs, or that SB3
cannot load, is skipped with one warning line saying why, and the one before it is tried
(an off-policy run that falls back past its one replay buffer resumes with an empty one,
and says so). A ``run.json`` that is not JSON, lacks a field or has one of the wrong type
is a usage error (:class:`ResumeError`) naming the file, the problem and the repair.

**Boundaries.** Checkpoints are taken at rollout boundaries (the start of a rollout:
between PPO's update and its next collection; every ``train_freq`` steps off-policy), where
the model, the RNGs and the step counter agree. A stop in the middle of a PPO rollout
rewinds to the rollout's start: the partial rollout (at most ``n_steps`` per env) was never
learned from, so it is not counted and is collected again after the resume. Off-policy
algorithms keep everything: the replay buffer holds each step already taken (all but the
step the stop landed on).

**Episodes in flight.** The env's physics state is not saved. On resume each env restarts
the episode that was in flight from its start (same spawn, goal and pedestrians: its RNG
is restored to the state before that episode's reset). When every env was at an episode
start at the boundary (e.g. ``--length`` equal to PPO's ``--n-steps``), a resumed PPO run
is bit-for-bit the run that never stopped.

**Stopping.** :class:`GracefulStop` turns SIGINT/SIGTERM into a request that the training
callback answers at the next env step (SB3 then returns from ``learn``). When no step comes
(an env waiting on a dead daemon), after :data:`STOP_DEADLINE_S` it raises
:class:`TrainingInterrupted` — only while the model is collecting, never inside an update.
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import os
import pickle
import random
import re
import signal
import time
import zipfile
from collections.abc import Iterator
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import gymnasium as gym
import numpy as np

from rover_train.recipe import stored_args, write_recipe

log = logging.getLogger(__name__)

STATE_VERSION = 1
RUN_FILE = "run.json"
CHECKPOINT_DIR = "checkpoints"
STATE_SUFFIX = ".state.pkl"
REPLAY_SUFFIX = ".replay.pkl"
STOP_DEADLINE_S = 3.0
"""Seconds a stop request waits for the next env step before interrupting the collection."""
EPISODE_RNG_KEY = "episode_rng_state"
"""The reset-info key under which :class:`EpisodeRng` reports the RNG state of the episode."""


class ResumeError(RuntimeError):
    """A run cannot be resumed as asked (no run.json or a damaged one, no checkpoint that
    loads, or a flag that would change the run); rover-train reports it as a usage error."""


class TrainingInterrupted(Exception):
    """Raised out of ``model.learn`` when a stop request found no env step to stop at."""


# --- the env side: each episode's RNG state ---------------------------------------------------
def _rng_state(rng: np.random.Generator) -> dict[str, Any]:
    return copy.deepcopy(rng.bit_generator.state)


def _generator(state: dict[str, Any]) -> np.random.Generator:
    bit_generator = getattr(np.random, state["bit_generator"])()
    bit_generator.state = state
    return np.random.Generator(bit_generator)


class EpisodeRng(gym.Wrapper):
    """Reports, in each reset's info, the env's RNG state just before that reset drew from it,
    and can put such a state back (:meth:`restore_episode_rng`) so that the next
    ``reset()`` without a seed begins exactly that episode again."""

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        seed = kwargs.get("seed")
        if seed is not None:
            from gymnasium.utils import seeding

            state = _rng_state(seeding.np_random(seed)[0])
        else:
            state = _rng_state(self.unwrapped.np_random)
        obs, info = self.env.reset(**kwargs)
        return obs, {**info, EPISODE_RNG_KEY: state}

    def restore_episode_rng(self, state: dict[str, Any]) -> None:
        """Make the next unseeded ``reset()`` start the episode that began from ``state``."""
        self.unwrapped.np_random = _generator(state)


# --- the trainer side: RNGs, boundaries, checkpoints ------------------------------------------
def rng_states(model: Any) -> dict[str, Any]:
    """The global RNG states SB3 draws from, and the model's action-space RNG."""
    import torch

    states = {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": torch.get_rng_state(),
        "action_space": _rng_state(model.action_space.np_random),
    }
    if torch.cuda.is_available():
        states["torch_cuda"] = torch.cuda.get_rng_state_all()
    return states


def restore_rng_states(model: Any, states: dict[str, Any]) -> None:
    import torch

    random.setstate(states["python"])
    np.random.set_state(states["numpy"])
    torch.set_rng_state(states["torch"])
    model.action_space._np_random = _generator(states["action_space"])
    if "torch_cuda" in states and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["torch_cuda"])


@dataclass
class Boundary:
    """The counters and RNGs at the start of the latest rollout (a consistent place to stop)."""

    num_timesteps: int
    episode_num: int
    ep_info_buffer: list[Any]
    ep_success_buffer: list[Any]
    rng: dict[str, Any]
    env_rng: list[dict[str, Any] | None]
    episodes_logged: int


def is_off_policy(model: Any) -> bool:
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    return isinstance(model, OffPolicyAlgorithm)


def checkpoint_stem(algo: str, steps: int) -> str:
    return f"{algo}_{steps}_steps"


# --- files a crash cannot leave half-written ---------------------------------------------------
def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def durable_path(path: Path) -> Iterator[Path]:
    """A temporary name beside ``path`` for the block to write; when the block ends without
    an error the file is flushed to disk (fsync), renamed to ``path`` and the directory
    synced, so ``path`` holds either its old contents or all of the new ones, whatever a
    crash, a power loss or a full disk cuts short. On an error the temporary file goes."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        yield tmp
        _fsync(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync(path.parent)


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`durable_path`."""
    with durable_path(path) as tmp:
        tmp.write_bytes(data)


@dataclass
class RunRecord:
    """``run.json``: how the run was started and where it stands."""

    args: dict[str, Any]
    """The run's arguments (``TrainArgs`` as plain JSON)."""
    timesteps: int
    """The total steps requested."""
    status: str = "running"
    """running, interrupted (by SIGINT/SIGTERM), complete, or failed."""
    latest_checkpoint: str | None = None
    """Stem of the newest complete checkpoint in ``checkpoints/``."""
    num_timesteps: int = 0
    """Steps counted into the model at that checkpoint."""
    resumes: int = 0
    """How many times the run was resumed."""
    tb_log_name: str = ""
    """The TensorBoard run name (``tb/<name>_1``), kept across resumes."""
    history: list[dict[str, Any]] = field(default_factory=list)
    """One entry per start or resume: time, steps at start, how it ended."""

    @classmethod
    def load(cls, run_dir: Path) -> RunRecord:
        """The run's record; :class:`ResumeError` naming the file, what is wrong and the fix
        when it is missing, not JSON, or lacks a field or has one of the wrong type."""
        path = run_dir / RUN_FILE
        try:
            text = path.read_text()
            data = json.loads(text)
        except FileNotFoundError:
            raise ResumeError(
                f"--resume {run_dir}: no {RUN_FILE} there. --resume takes the --logdir of a run "
                f"started by this rover-train (it writes {RUN_FILE} and checkpoints with a "
                f"{STATE_SUFFIX} beside each .zip); to train on from a bare model .zip, start a "
                "new run instead."
            ) from None
        except ValueError as exc:  # JSONDecodeError, or bytes that are not text
            found = "is empty" if not path.stat().st_size else f"is not valid JSON ({exc})"
            raise ResumeError(f"{path} {found}: the file was damaged. "
                              + _record_fix(run_dir)) from None  # fmt: skip
        problem = _record_problem(data)
        if problem:
            raise ResumeError(f"{path} {problem}. " + _record_fix(run_dir))
        return cls(**{**data, "args": stored_args(data["args"])})

    def save(self, run_dir: Path) -> None:
        from dataclasses import asdict

        atomic_write(run_dir / RUN_FILE, json.dumps(asdict(self), indent=2).encode())


_RECORD_FIELDS: dict[str, tuple[tuple[type, ...], str]] = {
    "args": ((dict,), "the run's arguments, an object"),
    "timesteps": ((int,), "the total steps requested, an integer"),
    "status": ((str,), "a string"),
    "latest_checkpoint": ((str, type(None)), "a checkpoint stem or null"),
    "num_timesteps": ((int,), "an integer"),
    "resumes": ((int,), "an integer"),
    "tb_log_name": ((str,), "a string"),
    "history": ((list,), "a list"),
}
"""What :meth:`RunRecord.load` accepts for each field of ``run.json``."""


def _record_problem(data: Any) -> str | None:
    """What is wrong with ``run.json``'s parsed contents, or None."""
    if not isinstance(data, dict):
        return (f"holds {type(data).__name__}, expected an object with the fields "
                f"{list(_RECORD_FIELDS)}")  # fmt: skip
    required = [n for n, f in RunRecord.__dataclass_fields__.items()
                if f.default is MISSING and f.default_factory is MISSING]  # fmt: skip
    missing = [n for n in required if n not in data]
    if missing:
        return "lacks " + ", ".join(f'"{n}" ({_RECORD_FIELDS[n][1]})' for n in missing)
    unknown = sorted(set(data) - set(_RECORD_FIELDS))
    if unknown:
        return f"has unknown field(s) {unknown} (a run.json holds {list(_RECORD_FIELDS)})"
    for name, value in data.items():
        types, what = _RECORD_FIELDS[name]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            return f'has "{name}": {json.dumps(value)}, expected {what}'
    return None


def _record_fix(run_dir: Path) -> str:
    """How to repair ``run.json``: by hand (from the copy in ``metrics.json`` when a part of
    the run finished), or by starting a new run."""
    metrics = run_dir / "metrics.json"
    copy_from = (f' ("args" and "timesteps_requested" in {metrics} hold the arguments and the '
                 "total of the part that last finished)" if metrics.is_file() else "")  # fmt: skip
    return (f"Repair it by hand{copy_from}, then run rover-train --resume {run_dir} again; or "
            "start a new run with another --logdir.")


def save_checkpoint(model: Any, run_dir: Path, algo: str, extra: dict[str, Any],
                    args: dict[str, Any] | None = None) -> str:
    """Write model, replay buffer (off-policy) and state; returns the checkpoint's stem.
    With ``args`` (the run's arguments) the model .zip holds their recipe
    (:func:`rover_train.recipe.write_recipe`), so ``rover-eval ENTRY --file`` and ``rover-train
    --recipe`` take a checkpoint as they take a finished model.

    ``extra`` holds what the trainer adds to the state (episode log, env RNGs, ...). Each file
    is written through :func:`durable_path` (on disk before it takes its name), the state
    file last, with the sizes of the others: a checkpoint without a state file is
    incomplete, and one whose files differ from those sizes was cut short afterwards.
    """
    ckdir = run_dir / CHECKPOINT_DIR
    ckdir.mkdir(parents=True, exist_ok=True)
    stem = checkpoint_stem(algo, int(model.num_timesteps))
    zip_path = ckdir / f"{stem}.zip"
    with durable_path(zip_path) as tmp:
        model.save(tmp)
        if args is not None:
            write_recipe(tmp, args)
    state = {"version": STATE_VERSION, "num_timesteps": int(model.num_timesteps),
             "saved_at": time.time(), **extra}  # fmt: skip
    files = {zip_path.name: zip_path.stat().st_size}
    replay = ckdir / f"{stem}{REPLAY_SUFFIX}"
    if is_off_policy(model):
        with durable_path(replay) as tmp:
            model.save_replay_buffer(tmp)
        state["replay_buffer"] = replay.name
        files[replay.name] = replay.stat().st_size
    state["files"] = files
    atomic_write(ckdir / f"{stem}{STATE_SUFFIX}", pickle.dumps(state))
    for old in ckdir.glob(f"*{REPLAY_SUFFIX}"):  # one replay buffer on disk is enough, and
        if old != replay:  # the one before goes only once this checkpoint is complete
            old.unlink(missing_ok=True)
    return stem


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint whose files passed :func:`find_checkpoints`' checks."""

    model_path: Path
    state: dict[str, Any]
    replay_problem: str | None = None
    """Why the replay buffer the state names cannot be used (None: it can, or none named)."""

    @property
    def stem(self) -> str:
        return self.model_path.stem


@dataclass(frozen=True)
class SkippedCheckpoint:
    """A checkpoint that cannot be resumed from, and why."""

    stem: str
    why: str

    def __str__(self) -> str:
        return f"skipping checkpoint {self.stem}: {self.why}"


_STEM_STEPS = re.compile(r"_(\d+)_steps$")
_MODEL_MEMBERS = ("data", "policy.pth")
"""What SB3's ``load`` needs from a model ``.zip``."""


def find_checkpoints(run_dir: Path) -> Iterator[Checkpoint | SkippedCheckpoint]:
    """The run's checkpoints, newest first (by the step count in their names), each either a
    :class:`Checkpoint` that passed the checks (state file readable, model ``.zip`` of the
    size the state recorded and whole: its CRCs hold) or a :class:`SkippedCheckpoint`
    saying why not. Lazy: the checks stop where the caller stops."""
    ckdir = run_dir / CHECKPOINT_DIR
    stems: dict[str, int] = {}
    for path in ckdir.glob("*.zip"):
        stems[path.stem] = 0
    for path in ckdir.glob(f"*{STATE_SUFFIX}"):
        stems[path.name[: -len(STATE_SUFFIX)]] = 0
    for stem in list(stems):
        match = _STEM_STEPS.search(stem)
        if match is None or stem.startswith("."):
            del stems[stem]
        else:
            stems[stem] = int(match.group(1))
    for stem in sorted(stems, key=lambda s: stems[s], reverse=True):
        yield _check_checkpoint(ckdir, stem)


def _check_checkpoint(ckdir: Path, stem: str) -> Checkpoint | SkippedCheckpoint:
    zip_path, state_path = ckdir / f"{stem}.zip", ckdir / f"{stem}{STATE_SUFFIX}"
    if not state_path.is_file():
        return SkippedCheckpoint(stem, f"no {state_path.name}: the run stopped while writing "
                                       "this checkpoint")  # fmt: skip
    if not zip_path.is_file():
        return SkippedCheckpoint(stem, f"{zip_path.name} is missing")
    try:
        state = pickle.loads(state_path.read_bytes())
    except Exception as exc:  # a damaged pickle raises almost anything
        return SkippedCheckpoint(stem, f"{state_path.name} cannot be read ({type(exc).__name__}: "
                                       f"{exc}): damaged")  # fmt: skip
    if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
        version = state.get("version") if isinstance(state, dict) else None
        return SkippedCheckpoint(stem, f"{state_path.name} is state version {version}, this "
                                       f"rover-train reads version {STATE_VERSION}")  # fmt: skip
    files = state.get("files", {})  # sizes at saving (older checkpoints lack them)
    problem = _file_problem(zip_path, files.get(zip_path.name)) or _zip_problem(zip_path)
    if problem:
        return SkippedCheckpoint(stem, problem)
    replay_problem = None
    if state.get("replay_buffer"):
        replay = ckdir / state["replay_buffer"]
        replay_problem = _file_problem(replay, files.get(replay.name))
        if replay_problem and not replay.exists():
            replay_problem += " (only the newest checkpoint keeps its replay buffer)"
    return Checkpoint(zip_path, state, replay_problem)


def _file_problem(path: Path, size: int | None) -> str | None:
    """Missing, or not the size the state file recorded for it."""
    if not path.is_file():
        return f"{path.name} is missing"
    found = path.stat().st_size
    if size is not None and found != size:
        return (f"{path.name} is {found} bytes, {size} were written: cut short (a crash, a "
                "power loss or a full disk)")  # fmt: skip
    return None


def _zip_problem(path: Path) -> str | None:
    """Why ``path`` is not a whole SB3 model archive, or None."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
            names = set(archive.namelist())
    except Exception as exc:  # BadZipFile, zlib.error, EOFError, ...
        return (f"{path.name} is not a readable zip file ({exc}; {path.stat().st_size} bytes): "
                "cut short or damaged")  # fmt: skip
    if bad is not None:
        return f"{path.name}: {bad} fails its CRC check: damaged"
    missing = [m for m in _MODEL_MEMBERS if m not in names]
    if missing:
        return f"{path.name} lacks {missing}: not a Stable-Baselines3 model"
    return None


def latest_checkpoint(run_dir: Path) -> tuple[Checkpoint, list[SkippedCheckpoint]]:
    """The newest checkpoint that passes :func:`find_checkpoints`' checks, and the newer
    ones skipped to reach it; :class:`ResumeError` naming each one's problem if none does."""
    skipped: list[SkippedCheckpoint] = []
    for found in find_checkpoints(run_dir):
        if isinstance(found, Checkpoint):
            return found, skipped
        skipped.append(found)
    ckdir = run_dir / CHECKPOINT_DIR
    if not skipped:
        raise ResumeError(
            f"--resume {run_dir}: no complete checkpoint in {ckdir} (a .zip with its "
            f"{STATE_SUFFIX}). The run stopped before its first checkpoint: start it again."
        )
    raise ResumeError(
        f"--resume {run_dir}: no checkpoint in {ckdir} can be resumed from: "
        + "; ".join(f"{s.stem}: {s.why}" for s in skipped)
        + ". Start the run again (with another --logdir, or after moving this one aside)."
    )


class Checkpointer:
    """Keeps the run's boundary state and writes its checkpoints (see the module docstring).

    :param run_dir: the run directory.
    :param algo: algorithm name (checkpoint file prefix).
    :param every: checkpoint at the first boundary at or after each multiple of this many
        steps (0: only the final and the stop checkpoints).
    :param stop: the signal handlers whose request the callback answers.
    :param episode_log: the learning curve's episode list (saved, truncated on a rewind).
    :param record: ``run.json``'s contents, updated at every checkpoint.
    """

    def __init__(self, run_dir: Path, algo: str, every: int, stop: GracefulStop,
                 episode_log: list[dict[str, Any]], record: RunRecord) -> None:  # fmt: skip
        self.run_dir = run_dir
        self.algo = algo
        self.every = every
        self.stop = stop
        self.episode_log = episode_log
        self.record = record
        self.model: Any = None
        self.env_rng: list[dict[str, Any] | None] = []
        self.boundary: Boundary | None = None
        self.saved_steps = -1
        self._next_due = every

    def attach(self, model: Any, env_rng: list[dict[str, Any] | None]) -> None:
        self.model = model
        self.env_rng = list(env_rng)
        self.saved_steps = int(model.num_timesteps) if self.record.latest_checkpoint else -1
        if self.every > 0:
            self._next_due = (int(model.num_timesteps) // self.every + 1) * self.every

    # called by the SB3 callback -------------------------------------------------------------
    def on_episode_reset(self, env_index: int, reset_info: dict[str, Any]) -> None:
        self.env_rng[env_index] = reset_info.get(EPISODE_RNG_KEY)

    def on_rollout_start(self) -> None:
        model = self.model
        if not is_off_policy(model):
            self.boundary = Boundary(
                num_timesteps=int(model.num_timesteps),
                episode_num=int(model._episode_num),
                ep_info_buffer=list(model.ep_info_buffer or ()),
                ep_success_buffer=list(model.ep_success_buffer or ()),
                rng=rng_states(model),
                env_rng=list(self.env_rng),
                episodes_logged=len(self.episode_log),
            )
        if self.every > 0 and model.num_timesteps >= self._next_due:
            self.save("periodic")
            self._next_due = (int(model.num_timesteps) // self.every + 1) * self.every
        self.stop.phase = "collect"  # after the save: the deadline never cuts a file short

    def on_rollout_end(self) -> None:
        self.stop.phase = "update"  # from here to the next rollout's start, and its checkpoint

    # writing ----------------------------------------------------------------------------------
    def rewind_to_boundary(self) -> int:
        """PPO stopped mid-rollout: put counters and the episode log back to the rollout's
        start; returns the steps taken back (collected, never learned from)."""
        b = self.boundary
        model = self.model
        if b is None or is_off_policy(model):
            return 0
        dropped = int(model.num_timesteps) - b.num_timesteps
        model.num_timesteps = b.num_timesteps
        model._episode_num = b.episode_num
        if model.ep_info_buffer is not None:
            model.ep_info_buffer.clear()
            model.ep_info_buffer.extend(b.ep_info_buffer)
        if model.ep_success_buffer is not None:
            model.ep_success_buffer.clear()
            model.ep_success_buffer.extend(b.ep_success_buffer)
        del self.episode_log[b.episodes_logged :]
        self.env_rng = list(b.env_rng)
        return dropped

    def save(self, why: str, status: str = "running") -> str | None:
        """A checkpoint of the model as it is now (after :meth:`rewind_to_boundary` on a
        stop); None when the newest checkpoint already holds this step."""
        model = self.model
        steps = int(model.num_timesteps)
        if steps == self.saved_steps:
            self.record.status = status
            self.record.save(self.run_dir)
            return None
        rng = self.boundary.rng if (why == "stop" and self.boundary is not None
                                    and not is_off_policy(model)) else rng_states(model)
        stem = save_checkpoint(model, self.run_dir, self.algo, {
            "rng": rng,
            "env_rng": list(self.env_rng),
            "episode_log": list(self.episode_log),
            "tb_log_name": self.record.tb_log_name,
            "why": why,
        }, self.record.args)  # fmt: skip
        self.saved_steps = steps
        self.record.latest_checkpoint = stem
        self.record.num_timesteps = steps
        self.record.status = status
        self.record.save(self.run_dir)
        log.info("checkpoint (%s) at %d steps: %s", why, steps, stem)
        return stem


def make_checkpoint_callback(checkpointer: Checkpointer) -> Any:
    """The SB3 callback that keeps boundaries, writes periodic checkpoints and stops on
    request."""
    from stable_baselines3.common.callbacks import BaseCallback

    class CheckpointCallback(BaseCallback):
        def _on_training_start(self) -> None:
            infos = list(getattr(self.training_env, "reset_infos", []) or [])
            for i, info in enumerate(infos):
                checkpointer.on_episode_reset(i, info)

        def _on_rollout_start(self) -> None:
            checkpointer.on_rollout_start()

        def _on_rollout_end(self) -> None:
            checkpointer.on_rollout_end()

        def _on_step(self) -> bool:
            dones = self.locals.get("dones")
            if dones is not None and np.any(dones):
                infos = self.training_env.reset_infos
                for i in np.flatnonzero(dones):
                    checkpointer.on_episode_reset(int(i), infos[i])
            return not checkpointer.stop.requested

    return CheckpointCallback()


# --- stopping on a signal ---------------------------------------------------------------------
class GracefulStop:
    """SIGINT/SIGTERM handlers that ask training to stop at the next step.

    ``phase`` is kept by the training callback: ``collect`` while envs are stepped (nothing
    in the model changes then, for PPO), ``update`` while the model learns. The deadline
    only interrupts a ``collect``.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, deadline: float = STOP_DEADLINE_S) -> None:
        self.deadline = deadline
        self.signum: int | None = None
        self.phase = "update"
        self.learning = False
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum
            log.warning("%s received: stopping at the next step and saving a checkpoint",
                        signal.Signals(signum).name)  # fmt: skip
            if self.learning:
                signal.setitimer(signal.ITIMER_REAL, self.deadline)
        else:
            log.warning("%s received again: the checkpoint is being written, one moment",
                        signal.Signals(signum).name)  # fmt: skip

    def _on_alarm(self, _signum: int, _frame: FrameType | None) -> None:
        if not self.learning:
            return
        if self.phase == "collect":
            log.warning("no env step within %.0f s of the stop request (an env waiting on "
                        "its daemon?): interrupting the collection", self.deadline)  # fmt: skip
            raise TrainingInterrupted
        signal.setitimer(signal.ITIMER_REAL, 0.5)  # inside an update: ask again shortly

    @contextlib.contextmanager
    def installed(self) -> Iterator[GracefulStop]:
        """Handlers installed for the block (and restored after it)."""
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}
        self._previous[signal.SIGALRM] = signal.signal(signal.SIGALRM, self._on_alarm)
        try:
            yield self
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            for sig, handler in self._previous.items():
                signal.signal(sig, handler)

    @contextlib.contextmanager
    def learning_block(self) -> Iterator[None]:
        """Marks ``model.learn``: the only time the deadline may interrupt."""
        self.learning = True
        self.phase = "collect"  # learn() begins by resetting the envs, before any update
        try:
            yield
        finally:
            self.learning = False
            signal.setitimer(signal.ITIMER_REAL, 0)

    def exit_status(self) -> int:
        """128 + the signal's number (130 SIGINT, 143 SIGTERM), the shell's convention."""
        assert self.signum is not None
        return 128 + int(self.signum)


def ignore_stop_signals() -> None:
    """For vector-env worker processes: leave SIGINT/SIGTERM to the trainer, which stops
    them in order after its checkpoint (a terminal's Ctrl-C and rover-pair's SIGTERM reach
    the whole process group)."""
    for sig in GracefulStop.SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


__all__ = [
    "CHECKPOINT_DIR",
    "EPISODE_RNG_KEY",
    "RUN_FILE",
    "STATE_SUFFIX",
    "Boundary",
    "Checkpoint",
    "Checkpointer",
    "EpisodeRng",
    "GracefulStop",
    "ResumeError",
    "RunRecord",
    "SkippedCheckpoint",
    "TrainingInterrupted",
    "atomic_write",
    "durable_path",
    "find_checkpoints",
    "ignore_stop_signals",
    "is_off_policy",
    "latest_checkpoint",
    "make_checkpoint_callback",
    "restore_rng_states",
    "rng_states",
    "save_checkpoint",
]
