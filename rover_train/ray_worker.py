"""One env worker of a Ray run: M envs, and for fused envs an av-daemon with M slots beside them.

:class:`EnvWorker` is a plain class; :mod:`rover_train.ray_vec_env` turns it into a Ray actor
(``ray.remote(EnvWorker)``), so this module imports no Ray and can be used and tested on its
own. The worker steps its envs in turn and auto-resets them as SB3's ``DummyVecEnv`` does
(``terminal_observation`` and ``TimeLimit.truncated`` in the info of a finished episode).

Segment names are unique per worker *and per incarnation*: ``<prefix>_w<index>_<4 hex>``.
A worker that Ray restarts after a crash therefore never races the dying daemon of its
previous life for a name; it removes the segments that daemon left (dead writer) on start,
and the driver sweeps every node for ``<prefix>_*`` when the run ends. (When a worker
process dies, Ray's raylet kills its child processes with SIGKILL, so a daemon cannot
always unlink its own segments: these sweeps are what guarantee the clean-up.)
"""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rover_train.envs import DEFAULT_TASK, FUSED_KINDS, env_factory
from shm_protocol import SHM_DIR, remove_segments, validate_name, writer_alive
from shm_protocol.names import CAMERA_SUFFIX

log = logging.getLogger(__name__)


RUN_PREFIX_STEM = "rray"
"""Default run prefixes are ``rray<6 hex>``; a worker removes dead ``rray*`` segments."""


@dataclass
class WorkerConfig:
    """What every worker of a run builds (the same for all workers)."""

    kind: str
    """Env kind: lidar, fused or discrete (``rover_train.envs.ENV_IDS``)."""
    world: str
    """World name."""
    envs_per_worker: int = 1
    """Envs hosted by each worker (daemon slots per worker)."""
    length: int | None = None
    """Episode length override."""
    task: str = DEFAULT_TASK
    """What an episode is (``rover_train.envs.TASKS``)."""
    pedestrian_mode: str | None = None
    """Who walks (``rover_env`` ``pedestrian_mode``; None: the env's default)."""
    n_pedestrians: int | None = None
    """How many walk (None: the world's default)."""
    connect_timeout: float = 30.0
    """Seconds an env waits for its daemon's segments."""
    waypoint: bool = False
    """The map planner's waypoint in the observation (``rover-train --waypoint``)."""
    camera_scan: bool = False
    """The camera scan in the observation (``rover-train --camera-scan``)."""
    daemon_args: tuple[str, ...] = ("--threads", "1")
    """Extra av-daemon flags."""
    daemon_max_restarts: int = 3
    """How often a worker restarts a daemon that exits."""
    daemon_ready_timeout: float = 120.0
    """Seconds to wait for a daemon's ready line."""


def worker_config(args: Any) -> WorkerConfig:
    """The workers' config of a ``rover-train --ray`` run (``args``: its ``TrainArgs``): the
    same env, world, task and pedestrians as a local run of those flags."""
    return WorkerConfig(
        kind=args.env,
        world=args.world,
        envs_per_worker=args.envs_per_worker,
        length=args.length,
        task=args.task,
        pedestrian_mode=args.pedestrian_mode,
        n_pedestrians=args.n_pedestrians,
        connect_timeout=max(args.connect_timeout, 30.0),
        waypoint=args.waypoint,
        camera_scan=getattr(args, "camera_scan", False),
    )


def sweep_segments(prefix: str, only_dead: bool = False) -> list[str]:
    """Unlink the segments in ``/dev/shm`` whose names start with ``prefix`` (and their
    hidden creation temporaries). With ``only_dead``, a fused segment whose writer is alive
    (a running daemon) is kept together with its camera twin, and creation temporaries are
    kept. Returns the removed names."""
    validate_name(prefix)
    try:
        names = sorted(os.listdir(SHM_DIR))
    except FileNotFoundError:
        return []
    ours = [n for n in names if n.startswith(prefix) or n.startswith("." + prefix)]
    keep: set[str] = set()
    if only_dead:
        for n in ours:
            if n.startswith("."):  # a creation temporary: its daemon is starting right now
                keep.add(n)
            elif not n.endswith(CAMERA_SUFFIX) and writer_alive(n):
                keep |= {n, n + CAMERA_SUFFIX}
    return remove_segments([n for n in ours if n not in keep])


def _stack(observations: Sequence[Any]) -> Any:
    """Per-env observations (dicts of arrays, or arrays) stacked on a new first axis."""
    first = observations[0]
    if isinstance(first, dict):
        return {k: np.stack([o[k] for o in observations]) for k in first}
    return np.stack(observations)


class EnvWorker:
    """Hosts ``cfg.envs_per_worker`` envs (and their daemon) in one process.

    :param cfg: the run's worker configuration.
    :param index: this worker's index; its envs are ``index * M ... index * M + M - 1``.
    :param prefix: the run's segment prefix (unique per run).
    """

    def __init__(self, cfg: WorkerConfig, index: int, prefix: str) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        self.cfg = cfg
        self.index = index
        self.name = validate_name(f"{prefix}_w{index}_{uuid.uuid4().hex[:4]}")
        self.keeper = None
        if cfg.kind in FUSED_KINDS:
            from rover_train.daemon_keeper import DaemonKeeper

            # a dead predecessor of this worker, or any run killed outright on this node
            # (kill -9 of a driver: Ray kills its workers and their daemons with SIGKILL)
            stale = sweep_segments(f"{prefix}_w{index}_", only_dead=True)
            stale += sweep_segments(RUN_PREFIX_STEM, only_dead=True)
            if stale:
                log.warning("worker %d: removed segments whose daemon is dead: %s",
                            index, ", ".join(stale))  # fmt: skip
            self.keeper = DaemonKeeper(self.name, cfg.envs_per_worker, cfg.daemon_args,
                                       max_restarts=cfg.daemon_max_restarts,
                                       ready_timeout=cfg.daemon_ready_timeout).start()  # fmt: skip
        self.envs = []
        try:
            for j in range(cfg.envs_per_worker):
                thunk = env_factory(cfg.kind, monitor_dir=None, world=cfg.world, slot=j,
                                    name=self.name, length=cfg.length, task=cfg.task,
                                    pedestrian_mode=cfg.pedestrian_mode,
                                    n_pedestrians=cfg.n_pedestrians,
                                    connect_timeout=cfg.connect_timeout,
                                    waypoint=cfg.waypoint,
                                    camera_scan=cfg.camera_scan)  # fmt: skip
                self.envs.append(thunk())
        except BaseException:
            self.close()
            raise
        log.info("worker %d (pid %d): %d %s env(s) on %r", index, os.getpid(), len(self.envs),
                 cfg.kind, self.name)  # fmt: skip

    # -- what the driver asks -----------------------------------------------------------
    def spaces(self) -> tuple[Any, Any, dict[str, Any]]:
        """(observation space, action space, metadata) of the envs."""
        env = self.envs[0]
        return env.observation_space, env.action_space, dict(env.metadata)

    def describe(self) -> dict[str, Any]:
        """Where this worker runs: pid, Ray node id, segment name, daemon pid and restarts."""
        node_id = None
        try:
            import ray

            node_id = ray.get_runtime_context().get_node_id()
        except Exception:  # noqa: BLE001  (outside Ray there is no node)
            pass
        keeper = self.keeper
        return {"index": self.index, "pid": os.getpid(), "node_id": node_id, "name": self.name,
                "daemon_pid": None if keeper is None else keeper.pid,
                "daemon_restarts": 0 if keeper is None else keeper.restarts}  # fmt: skip

    def reset(
        self, seeds: Sequence[int | None], options: Sequence[dict[str, Any]]
    ) -> tuple[Any, list[dict[str, Any]]]:
        """Reset every env (``seeds[j]``, ``options[j]``); stacked observations and infos."""
        obs, infos = [], []
        for env, seed, opts in zip(self.envs, seeds, options, strict=True):
            o, info = env.reset(seed=seed, **({"options": opts} if opts else {}))
            obs.append(o)
            infos.append(info)
        return _stack(obs), infos

    def step(self, actions: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray, list[dict]]:
        """Step every env with its action; finished episodes are reset (SB3 semantics)."""
        n = len(self.envs)
        obs_list: list[Any] = []
        rewards = np.zeros(n, dtype=np.float32)
        dones = np.zeros(n, dtype=bool)
        infos: list[dict[str, Any]] = []
        for j, env in enumerate(self.envs):
            obs, reward, terminated, truncated, info = env.step(actions[j])
            rewards[j] = reward
            dones[j] = terminated or truncated
            info["TimeLimit.truncated"] = truncated and not terminated
            if dones[j]:
                info["terminal_observation"] = obs
                obs, reset_info = env.reset()
                info["reset_info"] = reset_info
            obs_list.append(obs)
            infos.append(info)
        return _stack(obs_list), rewards, dones, infos

    def get_attr(self, attr_name: str, indices: Sequence[int]) -> list[Any]:
        return [self.envs[j].get_wrapper_attr(attr_name) for j in indices]

    def set_attr(self, attr_name: str, value: Any, indices: Sequence[int]) -> None:
        for j in indices:
            setattr(self.envs[j], attr_name, value)

    def env_method(self, method_name: str, args: tuple, kwargs: dict, indices: Sequence[int]
                   ) -> list[Any]:  # fmt: skip
        return [self.envs[j].get_wrapper_attr(method_name)(*args, **kwargs) for j in indices]

    def env_is_wrapped(self, wrapper_class: type, indices: Sequence[int]) -> list[bool]:
        from stable_baselines3.common.env_util import is_wrapped

        return [is_wrapped(self.envs[j], wrapper_class) for j in indices]

    def close(self) -> list[str]:
        """Close the envs, stop the daemon; returns segments that had to be removed by hand."""
        for env in self.envs:
            try:
                env.close()
            except Exception as exc:  # noqa: BLE001  (closing must reach the daemon)
                log.warning("worker %d: closing an env failed: %s", self.index, exc)
        self.envs = []
        left: list[str] = []
        if self.keeper is not None:
            left = self.keeper.stop()
            self.keeper = None
        return left


__all__ = ["RUN_PREFIX_STEM", "EnvWorker", "WorkerConfig", "sweep_segments"]
