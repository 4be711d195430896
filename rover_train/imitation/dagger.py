"""The DAgger engine: collect expert-labelled states, fit a student, repeat.

DAgger (Ross et al. 2011): iteration 0 drives with the expert; each later iteration drives
with the student (the expert's action is taken instead with probability beta, halved each
iteration), and the expert labels every state the student visits. The student is refit on
everything collected so far after each iteration. The zoo's recipes that drive it are
:mod:`rover_train.imitation.distill`.

Training episodes use reset seeds below ``DIAGNOSTIC_SEED_BASE`` (the diagnostic seeds start
there, the evaluation's at ``EVAL_SEED_BASE``) and run ``TRAIN_LENGTH`` steps, carrying on
past goals (the env draws a new one).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from fused_image import FUSED_SIZE
from rover_env.constants import DISCRETE_SPEED_LEVELS, PAN_LIMIT
from rover_env.gaze_discrete_env import CENTRE_WINDOW, PAN_WINDOWS
from rover_train.imitation.expert import ExpertConfig, PlannerExpert, table_action
from rover_train.progress import StatusLine
from rover_train.threads import available_cores
from rover_train.zoo.agent import (
    EnsembleNet,
    FeatureSpec,
    ObsHistory,
    StudentAgent,
    StudentNet,
    action_classes,
    encode_action,
    image_features,
    pan_classes,
    state_features,
)
from rover_train.zoo.registry import DIAGNOSTIC_SEED_BASE, EVAL_SEED_BASE

log = logging.getLogger("rover_train.imitation.dagger")

TRAIN_LENGTH = 600
NEAR_PEDESTRIAN = 2.0  # m (see sample_weight)
EXIT_NO_DAEMON = 1
FUSED_ITERATIONS = 6
FUSED_STEPS = 8_000
SCAN_BANDS = 16
"""Bands of a fused student's depth scan (``FeatureSpec.depth_scan``; 5.6 degrees each)."""
TRAINING_FRAME_TIMEOUT = 30.0
"""Seconds a training run's fused env waits for a frame (the env's default is 2 s). A run
is long and shares the machine, where a live daemon can go several seconds without
publishing under load; a 2 s timeout would end the run. A dead daemon is still reported at
once: the reader's liveness checks do not wait for the timeout."""
SEED_STRIDE = 10_000
"""Episode seeds of DAgger seed ``s`` start at ``s * SEED_STRIDE``, ..."""
ROUND_STRIDE = 1_000
"""... and round ``r``'s at ``+ r * ROUND_STRIDE``."""
MAX_SEED = DIAGNOSTIC_SEED_BASE // SEED_STRIDE - 1
"""The last DAgger seed whose episodes stay below the diagnostic seeds."""
MEMBER_DIR = Path("runs/distill")
"""Where an ensemble's members are saved as they finish (``DAggerRecipe.members``)."""


@dataclass
class DAggerConfig:
    """One DAgger run."""

    iterations: int = 8
    """Collection rounds (the first one drives with the expert)."""
    steps: int = 20_000
    """Env steps per round."""
    epochs: int = 10
    """Passes over the aggregate data set after each round."""
    batch: int = 256
    lr: float = 1e-3
    beta0: float = 0.5
    """Chance the expert drives in round 1 (halved each round; round 0 is all expert)."""
    seed: int = 0
    """Seeds the torch init and the episode seeds (``seed * SEED_STRIDE + ...``; at most
    ``MAX_SEED``)."""
    first_round_expert: bool = True
    """Round 0 drives with the expert (off when starting from a trained student)."""
    status_every: float = 5.0
    """Seconds between status lines."""
    synthetic_goals: int = 0
    """Before round 0, add expert-labelled states drawn without driving: this many goals
    (state students only; see :func:`synthetic_samples`)."""
    synthetic_per_goal: int = 200
    near_weight: float = 3.0
    """Loss weight of samples with a pedestrian near (:func:`sample_weight`)."""
    image_only: bool = False
    """Fit only the image branch (CNN and its projection), keeping the state network: for
    a fused student whose routing was learnt in stage 1 from far more data than a fused
    round gives (refitting everything on the fused rounds alone made it forget)."""
    teacher_sees: str = "all"
    """Which pedestrians the expert labelling the states reacts to (``ExpertConfig.sees``):
    ``all``, or ``camera`` (those in the forward camera's view, what a fused student sees;
    :func:`teacher_sees_for` gives each kind of entry its default)."""
    teacher_manners: str = "polite"
    """The labelling expert's pedestrian terms (``rover_train.imitation.expert.MANNERS``):
    :func:`teacher_manners_for` gives each kind of entry its default."""
    teacher_velocity: str = "updates"
    """How the labelling expert estimates the pedestrians' velocities
    (``ExpertConfig.velocity_from``): ``updates`` or ``steps`` (the shipped students'
    teacher; their recipes say so)."""
    teacher_gaze: str = "fixed"
    """Where the labelling expert points the camera in a gaze env (``ExpertConfig.gaze``):
    ``fixed`` ahead, or ``active``, the gaze teacher (gaze students learn its pan targets)."""
    fit_threads: int = 2
    """Torch threads for the fits, at most the cores this process may use (0: all of them).
    Collection keeps the caller's count: there the env, the expert and the av-daemon share
    the cores; during a fit they are idle. A fixed count (not "all cores") keeps a run's
    result the same on machines with more cores."""


@dataclass
class Dataset:
    """Aggregated (features, expert target) pairs of one feature spec; images stored
    pooled as uint8."""

    spec: FeatureSpec
    states: list[np.ndarray]
    images: list[np.ndarray]
    targets: list[np.ndarray]
    weights: list[float]
    """Per-sample loss weight (:func:`sample_weight`)."""

    @classmethod
    def empty(cls, spec: FeatureSpec) -> Dataset:
        return cls(spec, [], [], [], [])

    def add(self, state: np.ndarray, target: np.ndarray, weight: float,
            image: np.ndarray | None = None) -> None:
        self.states.append(state)
        self.targets.append(target)
        self.weights.append(weight)
        if image is not None:
            self.images.append(image)

    def __len__(self) -> int:
        return len(self.targets)

    def tensors(
        self,
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor, torch.Tensor]:
        """States, images (None without), targets, weights."""
        s = torch.from_numpy(np.stack(self.states))
        t = torch.from_numpy(np.stack(self.targets))
        i = torch.from_numpy(np.stack(self.images)) if self.images else None
        w = torch.tensor(self.weights, dtype=torch.float32)
        return s, i, t, w


class FusedView:
    """The fused image the av-daemon computes from an env's forward camera frame
    (``env.camera_frame()``), computed in this process: the same network (the shipped AVNet,
    the daemon's default backend) on the same rendered frame, so the same image. Stage 1 of
    a fused entry drives RoverEnv with no daemon; with this its student's depth scan
    (``FeatureSpec.depth_scan``) is the one it will read in stage 2, errors of the network's
    depth included. The perception is made on first use (a renderer-side object, like the
    sim's GL context)."""

    def __init__(self) -> None:
        self._perception: Any = None

    def __call__(self, env: Any) -> np.ndarray:
        """The fused image of the unwrapped roverav ``env``'s camera now."""
        if self._perception is None:
            from active_vision.perception import Perception, PerceptionConfig

            h, w = env.camera_size
            if h != w:
                raise ValueError(f"the fused image is square; this env renders {h}x{w}")
            self._perception = Perception(PerceptionConfig(size=h, threads=None, max_batch=1))
        return self._perception(env.camera_frame()[None])[0].copy()


class WithFusedView(gym.ObservationWrapper):
    """Adds ``fused_image`` (:class:`FusedView`) to RoverEnv observations: stage 1 of a fused
    entry, whose student reads its depth scan off it. The env must render frames of the
    fused env's size (``size=FUSED_SIZE``)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        h, w = env.unwrapped.camera_size
        if (h, w) != tuple(FUSED_SIZE):
            raise ValueError(
                f"the env renders {h}x{w} frames; a fused student reads the fused env's "
                f"{FUSED_SIZE[0]}x{FUSED_SIZE[1]} image: make it with size={tuple(FUSED_SIZE)}"
            )
        self.observation_space = gym.spaces.Dict(
            {**env.observation_space.spaces,
             "fused_image": gym.spaces.Box(0.0, 1.0, (h, w, 3), np.float32)}
        )  # fmt: skip
        self.view = FusedView()

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        return {**observation, "fused_image": self.view(self.env.unwrapped)}


def sample_weight(position: Any, pedestrians: Any, near_weight: float) -> float:
    """Loss weight of a sample: ``near_weight`` with a pedestrian within
    ``NEAR_PEDESTRIAN`` m of ``position``, else 1. Those are the states where the expert's
    local planner switches between passing, waiting and backing off: rare (a fifth of the
    samples) and where the students' collisions happened (pedestrians at 0.4-0.6 m in 10 of
    16 collided lidar-inspect episodes, the student driving on where the expert reversed)."""
    if pedestrians is None or len(pedestrians) == 0:
        return 1.0
    d = np.hypot(*(np.asarray(pedestrians, dtype=np.float64)[:, :2] - position[:2]).T)
    return near_weight if float(d.min()) < NEAR_PEDESTRIAN else 1.0


def feature_spec(kind: str, env: Any, history: bool = True, depth_scan: int = 0,
                 unmapped_scan: bool = False) -> FeatureSpec:
    """The feature spec of a student for ``kind`` (lidar, fused, or state) in ``env``'s world,
    with ``depth_scan`` bands of scan (fused students) and ``unmapped_scan`` (LIDAR
    students); a discrete ``env`` (the seed's table) makes a discrete student."""
    base = env.unwrapped
    rect = base.world.goal
    centre = ((rect.x[0] + rect.x[1]) / 2, (rect.y[0] + rect.y[1]) / 2)
    scale = max(rect.x[1] - rect.x[0], rect.y[1] - rect.y[0]) / 2
    table = isinstance(env.action_space, gym.spaces.Discrete)
    if table:
        low, high = DISCRETE_SPEED_LEVELS[:1], DISCRETE_SPEED_LEVELS[-1:]
    else:
        low, high = env.action_space.low, env.action_space.high
    return FeatureSpec(
        centre=centre,
        scale=scale,
        lidar_points=base.lidar_points if kind == "lidar" else 0,
        image=kind == "fused",
        max_speed=float(high[0]),
        min_speed=float(low[0]),
        history=history,
        depth_scan=depth_scan,
        unmapped_scan=unmapped_scan and kind == "lidar",
        world=base.world.name,
        table=table,
    )


def collect(
    env: Any,
    expert: PlannerExpert,
    agent: StudentAgent | None,
    beta: float,
    n_steps: int,
    data: Dataset,
    seed_base: int,
    rng: np.random.Generator,
    status: StatusLine | None = None,
    near_weight: float = 1.0,
) -> dict[str, float]:
    """Drive ``n_steps`` (student with prob. 1 - beta per step, else the expert), label
    every state with the expert, append to ``data``. Returns episode statistics."""
    spec = data.spec
    episodes = successes = 0
    steps = 0
    while steps < n_steps:
        obs, _ = env.reset(seed=seed_base + episodes)
        expert.reset()
        history = ObsHistory(spec)
        if agent is not None:
            agent.reset()
        first_goal = False
        for _ in range(TRAIN_LENGTH):
            label = expert.act_env(env)
            base = env.unwrapped
            data.add(
                state_features(obs, spec, history if spec.history else None),
                encode_action(label, spec),
                sample_weight(base.position, base.sim.pedestrian_positions, near_weight),
                image_features(obs) if spec.image else None,
            )
            # the student acts every step (its own history must see every observation)
            student = agent.act(obs) if agent is not None else label
            action = label if agent is None or rng.random() < beta else student
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            if status is not None:
                status.step()
            if info.get("goals_reached", 0) > 0 and not first_goal:
                first_goal = True
            if terminated or truncated or steps >= n_steps:
                break
        episodes += 1
        successes += first_goal
        if status is not None:
            status.episode(first_goal)
    return {"episodes": episodes, "success": successes / max(episodes, 1)}


def synthetic_samples(
    env: Any,
    expert: PlannerExpert,
    data: Dataset,
    n_goals: int,
    per_goal: int,
    rng: np.random.Generator,
    near_weight: float = 1.0,
) -> None:
    """Append expert-labelled states drawn without driving (state-space coverage).

    For each of ``n_goals`` goals drawn like the env draws them, ``per_goal`` rover poses
    uniform over the free part of the goal square plus a metre (random yaw and odometry),
    with each pedestrian, half of the time, stood somewhere 0.8-3 m from the rover. The
    observation keys are computed as the env computes them (the LIDAR by ray casting in the
    env's own sim), the label is the expert's action. Only for students without the image
    (the fused image needs the daemon and a real trajectory).
    """
    spec = data.spec
    if spec.image:
        raise ValueError("synthetic samples have no fused image: use them for state students")
    base = env.unwrapped
    world, sim = base.world, base.sim
    area = world.goal.expanded(1.0)
    env.reset(seed=int(rng.integers(EVAL_SEED_BASE)))
    n_peds = len(sim.pedestrian_positions)
    view = env.view if isinstance(env, WithFusedView) else FusedView()
    for _ in range(n_goals):
        goal = world.sample_free(rng, world.goal, 0.3)
        for _ in range(per_goal):
            x, y = world.sample_free(rng, area, 0.36)
            yaw = float(rng.uniform(-np.pi, np.pi))
            sim.set_rover_pose(x, y, yaw)
            peds = None
            if n_peds:
                for i in range(n_peds):
                    if rng.random() < 0.5:
                        r, a = rng.uniform(0.8, 3.0), rng.uniform(-np.pi, np.pi)
                        px, py = x + r * np.cos(a), y + r * np.sin(a)
                    else:
                        px, py = x + 40.0, y + 40.0 + i  # out of the way
                    sim.place_pedestrian(i, px, py, float(rng.uniform(-np.pi, np.pi)))
                peds = sim.pedestrian_positions
            expert.reset()
            pan = 0.0
            if spec.gaze:
                if spec.table:  # half of the time at rest in another of the table's windows
                    window = (int(rng.integers(len(PAN_WINDOWS))) if rng.random() < 0.5
                              else CENTRE_WINDOW)  # fmt: skip
                    pan = PAN_WINDOWS[window]
                else:  # the camera anywhere in its range half of the time
                    pan = float(rng.uniform(-PAN_LIMIT, PAN_LIMIT)) if rng.random() < 0.5 else 0.0
                sim.set_camera_pan(pan)
                label = expert.act_gaze((x, y), yaw, goal, peds, None, pan)
                if spec.table:
                    label = table_action(label, yaw, window)
            else:
                label = expert.act((x, y), yaw, goal, peds, None)
                if spec.table:
                    label = table_action(label, yaw)
            dist = float(np.hypot(goal[0] - x, goal[1] - y))
            bearing = float(np.angle(np.exp(1j * (np.arctan2(goal[1] - y, goal[0] - x) - yaw))))
            obs = {
                "pose": np.array([x, y, sim.position[2]], np.float32),
                "imu": np.array([0.0, 0.0, yaw], np.float32),
                "target": np.array([dist, bearing], np.float32),
                "velocities": np.array(
                    [rng.uniform(-0.2, 1.0), rng.uniform(-1.5, 1.5)], np.float32
                ),
            }
            if spec.lidar_points:
                obs["lidar"] = sim.lidar(base.lidar_points, base.max_lidar_range)
            if spec.gaze:
                obs["gaze"] = np.array([pan], np.float32)
            if spec.depth_scan:
                obs["fused_image"] = view(base)
            past = ObsHistory(spec).absent() if spec.history else None
            data.add(
                state_features(obs, spec, past),
                encode_action(label, spec),
                sample_weight(np.array([x, y]), peds, near_weight),
            )
    sim.set_camera_pan(0.0)


def fit(net: StudentNet | EnsembleNet, data: Dataset, cfg: DAggerConfig,
        gen: torch.Generator) -> float:
    """Refit ``net`` on ``data`` (cross-entropy on the class of the expert's action, plus a
    gaze student's on the class of its pan target; samples weighted). Returns the last epoch's mean
    loss. An ensemble's members are refit one after the other, each on its own sample
    order (mean of their losses)."""
    if isinstance(net, EnsembleNet):
        return float(np.mean([fit(m, data, cfg, gen) for m in net.members]))
    states, images, encoded, weights = data.tensors()
    targets = action_classes(encoded, net.spec)
    pans = pan_classes(encoded, net.spec) if net.spec.n_pan else None
    n_drive = net.spec.n_drive
    loss_fn = nn.CrossEntropyLoss(reduction="none")
    if cfg.image_only and net.spec.image:
        params = list(net.cnn.parameters()) + list(net.img_proj.parameters())
    else:
        params = list(net.parameters())
    opt = torch.optim.Adam(params, lr=cfg.lr)
    net.train()
    n = len(targets)
    mean = 0.0
    for _ in range(cfg.epochs):
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for start in range(0, n, cfg.batch):
            idx = order[start : start + cfg.batch]
            img = images[idx] if (images is not None and net.spec.image) else None
            if img is not None:
                # random shifts of up to 2 pooled pixels (augmentation)
                dx, dy = torch.randint(-2, 3, (2,), generator=gen).tolist()
                img = torch.roll(img, shifts=(dy, dx), dims=(2, 3))
            pred = net(states[idx], img)
            per_sample = loss_fn(pred[:, :n_drive], targets[idx])
            if pans is not None:  # a gaze student's pan head: its own cross-entropy
                per_sample = per_sample + loss_fn(pred[:, n_drive:], pans[idx])
            w = weights[idx]
            loss = (per_sample * w).sum() / w.sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        mean = total / n
    net.eval()
    return mean


def fit_threads(requested: int) -> int:
    """``requested`` torch threads for a fit, capped at the available cores (0: all)."""
    if requested < 0:
        raise ValueError(f"fit_threads must be >= 0 (0: all cores), got {requested}")
    cores = available_cores()
    return min(requested, cores) if requested else cores


def run_dagger(
    env: Any,
    world: str,
    agent: StudentAgent,
    cfg: DAggerConfig,
    label: str = "dagger",
    history: list[dict[str, float]] | None = None,
    on_round: Callable[[int, StudentAgent], None] | None = None,
) -> StudentAgent:
    """DAgger on ``env`` starting from ``agent`` (trained in place); returns it.

    :param history: if given, one dict per round is appended: ``round``, ``steps`` (env
        steps so far), ``success`` (first-goal success of that round's episodes),
        ``episodes``, ``beta``, ``loss``, ``wall_s`` (since the start).
    :param on_round: called with (env steps so far, agent) after each round's fit (e.g. to
        evaluate); its time is not counted in ``wall_s``.
    """
    expert = PlannerExpert(world, teacher_config(cfg))
    data = Dataset.empty(agent.spec)
    rng = np.random.default_rng(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    start = time.monotonic()
    paused = 0.0
    if cfg.synthetic_goals:
        synthetic_samples(
            env, expert, data, cfg.synthetic_goals, cfg.synthetic_per_goal, rng, cfg.near_weight
        )
        print(
            f"{label}: {len(data)} synthetic expert-labelled states in "
            f"{time.monotonic() - start:.0f} s",
            flush=True,
        )
    status = StatusLine(label, cfg.iterations * cfg.steps, every=cfg.status_every)
    for it in range(cfg.iterations):
        if it == 0 and cfg.first_round_expert:
            driver, beta = None, 1.0
        else:
            driver = agent
            beta = cfg.beta0 * 0.5 ** (it - (1 if cfg.first_round_expert else 0))
        seed_base = cfg.seed * SEED_STRIDE + it * ROUND_STRIDE
        if seed_base + ROUND_STRIDE > DIAGNOSTIC_SEED_BASE:
            raise ValueError(
                f"DAgger seed {cfg.seed}, round {it + 1}: training episode seeds would reach "
                f"the diagnostic seeds ({DIAGNOSTIC_SEED_BASE}+); use seeds 0-{MAX_SEED} (at "
                f"most {SEED_STRIDE // ROUND_STRIDE} rounds)"
            )
        t0 = time.monotonic()
        stats = collect(
            env, expert, driver, beta, cfg.steps, data, seed_base, rng, status, cfg.near_weight
        )
        t1 = time.monotonic()
        collect_threads = torch.get_num_threads()
        torch.set_num_threads(fit_threads(cfg.fit_threads))
        try:
            loss = fit(agent.net, data, cfg, gen)
        finally:
            torch.set_num_threads(collect_threads)
        print(
            f"{label}: round {it + 1}/{cfg.iterations}: drove {stats['episodes']} episodes "
            f"(beta {beta:.2f}, first-goal success {stats['success']:.0%}) in "
            f"{t1 - t0:.0f} s; fit {len(data)} samples in {time.monotonic() - t1:.0f} s, "
            f"loss {loss:.4f}",
            flush=True,
        )
        if history is not None:
            history.append(
                {
                    "round": it + 1,
                    "steps": (it + 1) * cfg.steps,
                    "success": stats["success"],
                    "episodes": stats["episodes"],
                    "beta": beta,
                    "loss": loss,
                    "wall_s": time.monotonic() - start - paused,
                }
            )
        if on_round is not None:
            t2 = time.monotonic()
            on_round((it + 1) * cfg.steps, agent)
            paused += time.monotonic() - t2
    return agent


def teacher_config(cfg: DAggerConfig) -> ExpertConfig:
    """The expert that labels ``cfg``'s states."""
    return ExpertConfig.with_manners(cfg.teacher_manners, sees=cfg.teacher_sees,
                                     gaze=cfg.teacher_gaze,
                                     velocity_from=cfg.teacher_velocity)  # fmt: skip


def stage2_config(
    cfg: DAggerConfig, iterations: int = FUSED_ITERATIONS, steps: int = FUSED_STEPS
) -> DAggerConfig:
    """The DAgger rounds that train a fused student's image branch with the daemon in the
    loop (stage 2, and the demo's fine-tune): ``cfg`` with ``iterations`` rounds of ``steps``,
    the student driving from the first round (beta 0.3), no synthetic states, and only the
    image branch refit (see ``DAggerConfig.image_only``)."""
    return replace(
        cfg,
        iterations=iterations,
        steps=steps,
        synthetic_goals=0,
        image_only=True,
        first_round_expert=False,
        beta0=0.3,
    )


def make_training_env(kind: str, world: str, **kwargs: Any) -> Any:
    """A training env of ``kind`` in ``world``; a fused one waits ``TRAINING_FRAME_TIMEOUT``
    for each fused frame (``frame_timeout=`` overrides)."""
    from rover_train.envs import FUSED_KINDS, make_env

    if kind in FUSED_KINDS:
        kwargs.setdefault("frame_timeout", TRAINING_FRAME_TIMEOUT)
    return make_env(kind, world=world, length=TRAIN_LENGTH, **kwargs)


