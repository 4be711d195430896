"""Building roverav envs for training and evaluation (single and vectorised), and the tasks
(:data:`TASKS`) that say what an episode is."""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from roverav_cli import EVAL_MAX_STEPS
from shm_protocol.names import default_name

if TYPE_CHECKING:
    from rover_env.reward import RewardConfig
    from rover_train.zoo.registry import RENAMED_KINDS as RENAMED_KINDS
    from rover_train.zoo.registry import stored_kind as stored_kind

log = logging.getLogger(__name__)

_FROM_REGISTRY = ("RENAMED_KINDS", "stored_kind")


def __getattr__(name: str) -> Any:
    # re-exported from the zoo's registry on first use: the registry imports rover_env
    # (MuJoCo), which the command lines' argument parsing does without
    if name in _FROM_REGISTRY:
        from rover_train.zoo.registry import RENAMED_KINDS, stored_kind

        return {"RENAMED_KINDS": RENAMED_KINDS, "stored_kind": stored_kind}[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


ENV_IDS = {
    "lidar": "roverav/RoverEnv-v0",
    "lidar-discrete": "roverav/RoverEnvDiscrete-v0",
    "fused": "roverav/RoverEnvFused-v0",
    "fused-discrete": "roverav/RoverEnvFusedDiscrete-v0",
    "fused-gaze": "roverav/RoverEnvFusedGaze-v0",
    "fused-gaze-discrete": "roverav/RoverEnvFusedGazeDiscrete-v0",
}
FUSED_KINDS = ("fused", "fused-discrete", "fused-gaze", "fused-gaze-discrete")
DISCRETE_KINDS = ("lidar-discrete", "fused-discrete", "fused-gaze-discrete")  # Discrete actions


@dataclass(frozen=True)
class Task:
    """What an episode is: the env keywords a task sets (``rover-train --task``,
    ``rover-eval --task``)."""

    name: str
    description: str
    goal_ends_episode: bool = False
    """The env option: the first goal ends the episode (else a new goal is drawn)."""
    length: int | None = None
    """Steps per episode; None: the env's own (2000 LIDAR, 6000 fused)."""
    reward: dict[str, float | bool] = field(default_factory=dict)
    """``RewardConfig`` fields the task sets (the rest stay the env's own)."""
    lidar_reward: dict[str, float] = field(default_factory=dict)
    """``RewardConfig`` fields the task sets on the LIDAR envs only (LIDAR terms)."""

    def reward_config(self, kind: str) -> RewardConfig | None:
        """The env's ``reward_config`` under this task (None: the env's default)."""
        fused = kind in FUSED_KINDS
        fields = self.reward if fused else {**self.reward, **self.lidar_reward}
        if not fields:
            return None
        from rover_env.reward import RewardConfig

        return dataclasses.replace(RewardConfig.fused() if fused else RewardConfig(), **fields)


NAV_LENGTH = EVAL_MAX_STEPS
"""The nav task's episode: the evaluator's (rover-eval counts success at the first goal
within 600 steps, 30 s; the planner expert needs about 10 s)."""
NAV_PROGRESS_SCALE = 10.0
"""The nav task's progress reward per metre nearer the goal (the seed's: 0.45). At the seed's
0.45 a step's progress is worth 0.02 against the goal's 100, too little for PPO from scratch
to learn to drive at the goal (docs/decisions.md, "RL")."""
NAV_CLEARANCE = 0.6
"""Metres: inside this LIDAR minimum the nav task charges ``NAV_CLEARANCE_PENALTY`` per metre
per step (a collision is below 0.3 m), so that a policy learns to keep off the scenery
before it touches it, which ending at the first collision alone does not teach. The fused
envs can pay it from a LIDAR scan the simulator casts for the reward alone
(``RewardConfig.clearance_penalty``), but the task leaves it off there: a camera agent cannot
see most of the walls that would charge it, and with the term it learns to stand still
(docs/decisions.md, "RL"; benchmarks/RESULTS.md, "Learning: a camera agent from the reward")."""
NAV_CLEARANCE_PENALTY = -2.0
NAV_PERSONAL_SPACE = 1.2
"""Metres (rover centre to person centre, ``rover_env.constants.PERSONAL_SPACE_M``): inside
this the nav task charges ``NAV_PERSONAL_SPACE_PENALTY`` per metre per step, on every env
kind, from the simulator's pedestrian positions; touching a person ends the episode as a
collision does (``RewardConfig.contact_is_collision``)."""
NAV_PERSONAL_SPACE_PENALTY = -1.0
"""Per metre inside ``NAV_PERSONAL_SPACE``, per step: at contact (about 0.6 m) -0.6 a step,
about what 5 cm of progress pays, so keeping a metre from a person beats brushing past. On
the fused envs it replaces the seed's heatmap term (``heatmap_center_scale`` 0 under the
task): that term charges about -2 to -3 a step for a person a metre ahead in the image's
centre columns, and some whatever their distance, so it dwarfed the progress and the goal
(PPO from scratch on the fused maze returned -100 to -140 an episode), and looking away
lowers it."""
DEFAULT_TASK = "seed"
TASKS = {
    "seed": Task("seed", "the seed's: goal after goal until a failure or the env's length "
                 "(2000 steps LIDAR, 6000 fused)"),
    "nav": Task("nav", f"one goal: the episode ends at it (success, the goal reward), at "
                f"the first collision (the stuck-in-collision penalty) or after {NAV_LENGTH} "
                f"steps, as the evaluators count success; touching a person or the "
                f"scenery is a collision; progress pays {NAV_PROGRESS_SCALE:g} per metre; "
                f"a person within {NAV_PERSONAL_SPACE:g} m costs "
                f"{NAV_PERSONAL_SPACE_PENALTY:g} per metre inside it per step, in place of "
                f"the fused envs' heatmap term; LIDAR envs pay {NAV_CLEARANCE_PENALTY:g} "
                f"per metre that the LIDAR minimum lies inside {NAV_CLEARANCE:g} m",
                goal_ends_episode=True, length=NAV_LENGTH,
                reward={"collision_limit": 0, "distance_delta_scale": NAV_PROGRESS_SCALE,
                        "heatmap_center_scale": 0.0, "contact_is_collision": True,
                        "personal_space_distance": NAV_PERSONAL_SPACE,
                        "personal_space_penalty": NAV_PERSONAL_SPACE_PENALTY},
                lidar_reward={"clearance_distance": NAV_CLEARANCE,
                              "clearance_penalty": NAV_CLEARANCE_PENALTY}),
}  # fmt: skip
"""The tasks by name: ``seed`` (the default, the seed env's behaviour) and ``nav`` (the RL
task that matches the evaluation episodes)."""


def get_task(name: str) -> Task:
    """The task called ``name``; ``ValueError`` naming the choices for another."""
    try:
        return TASKS[name]
    except KeyError:
        raise ValueError(
            f"unknown task {name!r}; choose one of: "
            + "; ".join(f"{t.name} ({t.description})" for t in TASKS.values())
        ) from None


def env_kwargs(
    kind: str,
    world: str,
    slot: int = 0,
    name: str | None = None,
    length: int | None = None,
    connect_timeout: float | None = None,
    render_mode: str | None = None,
    pedestrian_mode: str | None = None,
    n_pedestrians: int | None = None,
    size: tuple[int, int] | None = None,
    frame_timeout: float | None = None,
    report_latency: bool = False,
    task: str = DEFAULT_TASK,
    camera_scan: bool = False,
) -> dict[str, Any]:
    """Constructor keywords for env ``kind`` (a key of ``ENV_IDS``); ``size`` is the forward
    camera's (height, width); ``frame_timeout`` (fused kinds) the seconds to wait for each
    fused frame; ``report_latency`` (fused kinds) puts the wall-clock ``frame_latency_ms``
    in ``info``; ``task`` (a key of :data:`TASKS`) sets ``goal_ends_episode`` and the
    length, which ``length`` overrides; ``camera_scan`` (fused kinds) adds the camera scan
    to the observation (``rover_env.camera_scan``)."""
    if kind not in ENV_IDS:
        raise ValueError(f"unknown env kind {kind!r}; choose one of {sorted(ENV_IDS)}")
    the_task = get_task(task)
    kwargs: dict[str, Any] = {"world_n": world}
    if length is None:
        length = the_task.length
    if length is not None:
        kwargs["length"] = length
    if the_task.goal_ends_episode:
        kwargs["goal_ends_episode"] = True
    reward_config = the_task.reward_config(kind)
    if reward_config is not None:
        kwargs["reward_config"] = reward_config
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    if pedestrian_mode is not None:
        kwargs["pedestrian_mode"] = pedestrian_mode
    if n_pedestrians is not None:
        kwargs["n_pedestrians"] = n_pedestrians
    if size is not None:
        kwargs["size"] = tuple(size)
    if kind in FUSED_KINDS:
        kwargs["rl_obs_name"] = name or default_name()
        kwargs["slot"] = slot
        if connect_timeout is not None:
            kwargs["connection_check_timeout"] = connect_timeout
        if frame_timeout is not None:
            kwargs["frame_timeout"] = frame_timeout
        if report_latency:
            kwargs["report_latency"] = True
        if camera_scan:
            kwargs["camera_scan"] = True
    elif camera_scan:
        raise ValueError(
            f"camera_scan is built from the fused image: the fused env kinds {FUSED_KINDS} "
            f"take it, not {kind!r} (whose lidar key already sees all around)"
        )
    elif frame_timeout is not None:
        raise ValueError(f"frame_timeout is for the fused env kinds {FUSED_KINDS}, not {kind!r}")
    return kwargs


def make_env(kind: str, env_checker: bool = True, **kwargs: Any) -> gym.Env:
    """``gymnasium.make`` the env of ``kind`` with :func:`env_kwargs` keywords.

    ``env_checker=False`` leaves out Gymnasium's passive checker (see :func:`env_factory`).
    """
    import rover_env  # noqa: F401  (registers the roverav/ ids)

    return gym.make(ENV_IDS[kind], disable_env_checker=not env_checker,
                    **env_kwargs(kind, **kwargs))  # fmt: skip


class DaemonRecovery(gym.Wrapper):
    """Lets a training run outlive a daemon crash.

    A fused env raises when its daemon dies or stalls mid-episode. This wrapper turns that
    into the end of the episode (``truncated=True``, ``info["daemon_error"]`` says why), and
    its ``reset()`` retries for up to ``recover_timeout`` seconds while rover-pair restarts
    the daemon on the same segments. Truncation, not termination: the episode did not fail,
    so value bootstrapping stays correct. Errors a daemon restart cannot fix (a daemon of
    another ``--size``: ``LayoutError``; the slot taken by another env: ``SegmentBusyError``)
    are raised at once.
    """

    def __init__(self, env: gym.Env, recover_timeout: float = 60.0):
        super().__init__(env)
        self.recover_timeout = recover_timeout
        self._last_obs: Any = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        from shm_protocol.errors import LayoutError, SegmentBusyError, ShmError

        deadline = time.monotonic() + self.recover_timeout
        tries = 0
        while True:
            try:
                obs, info = self.env.reset(**kwargs)
                self._last_obs = obs
                if tries:
                    log.warning("reset: the daemon is back after %d retries", tries)
                return obs, info
            except (LayoutError, SegmentBusyError):
                raise
            except ShmError as exc:
                if time.monotonic() > deadline:
                    raise
                # once per outage at WARNING; the retries every 0.5 s at DEBUG
                (log.debug if tries else log.warning)(
                    "reset: daemon not available (%s); retrying for up to %.0f s",
                    exc, self.recover_timeout)  # fmt: skip
                tries += 1
                time.sleep(0.5)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        from shm_protocol.errors import ShmError

        try:
            obs, reward, terminated, truncated, info = self.env.step(action)
        except ShmError as exc:
            log.warning("step: %s; ending the episode (truncated) and waiting for the daemon", exc)
            return self._last_obs, 0.0, False, True, {"daemon_error": str(exc)}
        self._last_obs = obs
        return obs, reward, terminated, truncated, info


def policy_view(env: gym.Env, world: str, waypoint: bool = False, drop_image: bool = False,
                relative_table: bool = False, pan_head: bool = False) -> gym.Env:  # fmt: skip
    """``env`` as a policy trained with these rover-train flags sees and drives it:
    ``WithWaypoint`` (``--waypoint``), then ``DropImage`` (``--drop-image``), then
    ``RelativeTable`` (``--relative-table``, its two heads with ``--pan-head``)
    (:mod:`rover_train.wrappers`)."""
    if waypoint:
        from rover_train.waypoint import WithWaypoint

        env = WithWaypoint(env, world)
    if drop_image or relative_table:
        from rover_train.wrappers import DropImage, RelativeTable

        if drop_image:
            env = DropImage(env)
        if relative_table:
            env = RelativeTable(env, pan_head=pan_head)
    return env


def env_factory(
    kind: str,
    monitor_dir: str | None = None,
    append_monitor: bool = False,
    waypoint: bool = False,
    drop_image: bool = False,
    relative_table: bool = False,
    pan_head: bool = False,
    **kwargs: Any,
) -> Callable[[], gym.Env]:
    """A picklable thunk for SB3 vector envs; the env (and its renderer) is built in the worker.

    The stack is ``Monitor(EpisodeRng([DaemonRecovery(]env[)]))``, with :func:`policy_view`'s
    wrappers (``waypoint``, ``drop_image``, ``relative_table``, ``pan_head``) around the env;
    ``EpisodeRng`` lets a resumed run restart each episode in flight from its start.
    ``append_monitor`` appends to the slot's ``monitor.csv`` (a resumed run) instead of
    starting it afresh. Fused envs
    are made with ``report_latency=True``: the trainer logs ``charts/frame_latency_ms``.
    """

    def _thunk() -> gym.Env:
        from stable_baselines3.common.monitor import Monitor

        from rover_train.checkpoint import EpisodeRng

        if kind in FUSED_KINDS:
            # Gymnasium 1.4's passive checker breaks when an env's first reset raises (the
            # daemon is down at that moment, which DaemonRecovery retries): its first step
            # then fails unpacking the reset data it never got. The envs' own tests run the
            # full check_env.
            env = DaemonRecovery(
                make_env(kind, env_checker=False, **{"report_latency": True, **kwargs})
            )
        else:
            env = make_env(kind, **kwargs)
        env = policy_view(env, kwargs["world"], waypoint, drop_image, relative_table, pan_head)
        env = EpisodeRng(env)
        filename = None
        if monitor_dir is not None:
            filename = os.path.join(monitor_dir, f"slot{kwargs.get('slot', 0)}")
        return Monitor(env, filename=filename, override_existing=not append_monitor)

    return _thunk
