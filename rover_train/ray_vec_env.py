"""A Stable-Baselines3 ``VecEnv`` whose envs live in Ray actors, possibly on other machines.

    venv = RayVecEnv(WorkerConfig(kind="fused", world="maze", envs_per_worker=2), workers=4)
    model = PPO("MultiInputPolicy", venv, ...)      # the learner stays here, in the driver
    model.learn(100_000)
    venv.close()                                     # daemons stopped, every node swept

Worker ``w`` is a Ray actor (:class:`rover_train.ray_worker.EnvWorker`) hosting envs
``w*M ... w*M+M-1``; for fused envs it runs its own av-daemon with M slots on its node, so
shared memory never crosses machines: only actions go out and observations come back,
through Ray. ``step_async`` sends each worker its slice of the actions, ``step_wait``
gathers the answers in worker order.

Faults:

- A worker actor that dies (killed, out of memory, its node lost) is restarted by Ray
  (``max_restarts``). The driver notices the failed step, waits for the new incarnation,
  resets its envs, and reports each of them as a truncated episode
  (``TimeLimit.truncated``, ``terminal_observation`` = the last observation it had,
  ``info["worker_restarted"] = True``). Training goes on. Past ``max_restarts`` deaths of
  one worker, :class:`WorkerLostError` is raised.
- A daemon that dies inside a worker is restarted by that worker
  (:class:`rover_train.daemon_keeper.DaemonKeeper`); the env's interrupted step becomes a
  truncated episode (``DaemonRecovery``), as under rover-pair.
- Segments are named ``<prefix>_w<index>_<incarnation>``; :meth:`RayVecEnv.close` stops the
  workers (their daemons unlink their segments) and then sweeps ``<prefix>_*`` from
  ``/dev/shm`` on every live node, so nothing is left after a normal end, a Ctrl-C or a
  SIGTERM of ``rover-train``. A killed worker's daemon dies with it (Ray's raylet kills a
  dead worker's children); its restarted successor removes the segments it left, and any
  worker starting on a node removes dead ``rray*`` segments of runs killed outright.

Importing this module imports Ray (``pip install 'roverav[ray]'``); nothing else in roverav
does.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
import uuid
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import ray
from ray.exceptions import GetTimeoutError, RayActorError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)
from stable_baselines3.common.vec_env.util import dict_to_obs

from rover_train.ray_worker import (
    RUN_PREFIX_STEM,
    EnvWorker,
    WorkerConfig,
    sweep_segments,
    worker_config,
)
from shm_protocol import validate_name

log = logging.getLogger(__name__)

LOCAL_OBJECT_STORE_BYTES = 256 * 2**20
"""Object store of a local cluster started by ``--ray`` with no address (observations are a
few hundred KB per step; Ray's default, 30 % of RAM, is reserved in /dev/shm)."""
DEFAULT_MAX_RESTARTS = 3
DEFAULT_RESTART_TIMEOUT_S = 300.0
"""How long the driver waits for a restarted worker (a cold daemon start loads torch)."""
WORKER_CPUS = 1.0
"""CPUs each worker reserves for scheduling (its envs and its daemon share them)."""
CLOSE_TIMEOUT_S = 60.0


class WorkerLostError(RuntimeError):
    """A Ray env worker died more often than ``max_restarts``, or did not come back."""


def connect(address: str | None, num_cpus: int | None = None) -> bool:
    """Connect to the Ray cluster at ``address`` (``host:port``, ``auto`` or ``ray://...``), or
    start a local one when ``address`` is None or empty. Returns True when this call started
    (and so should shut down) Ray; False when Ray was already initialised here."""
    if ray.is_initialized():
        return False
    if address:
        ray.init(address=address, log_to_driver=True)
    else:
        cpus = max(os.cpu_count() or 1, num_cpus or 1)
        ray.init(num_cpus=cpus, object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                 include_dashboard=False)  # fmt: skip
    return True


@ray.remote(num_cpus=0)
def _sweep_node(prefix: str) -> tuple[str, list[str]]:
    return ray.get_runtime_context().get_node_id(), sweep_segments(prefix)


def sweep_all_nodes(prefix: str, timeout: float = CLOSE_TIMEOUT_S) -> dict[str, list[str]]:
    """Remove segments named ``prefix*`` on every live node; ``{node_id: removed names}``."""
    refs = [
        _sweep_node.options(
            scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)
        ).remote(prefix)
        for node in ray.nodes()
        if node.get("Alive")
    ]
    out: dict[str, list[str]] = {}
    try:
        for node_id, removed in ray.get(refs, timeout=timeout):
            out[node_id] = removed
    except ray.exceptions.RayError as exc:  # a timeout, or a node that went away meanwhile
        log.warning("sweeping /dev/shm for %r on every node did not finish: %s", prefix, exc)
    return out


class RayVecEnv(VecEnv):
    """``workers`` Ray actors with ``cfg.envs_per_worker`` envs each, as one SB3 ``VecEnv``.

    :param cfg: what each worker builds.
    :param workers: number of worker actors.
    :param max_restarts: Ray restarts of each worker actor after it dies.
    :param worker_options: per-worker Ray actor options merged over the defaults (e.g.
        ``[{"resources": {"node_a": 1}}, ...]`` to pin worker w to a node).
    :param restart_timeout: seconds to wait for a restarted worker to answer.
    :param owns_ray: shut Ray down in :meth:`close` (set when the caller started it).
    :param prefix: segment name prefix of this run (default ``rray<6 hex>``, unique).
    """

    def __init__(
        self,
        cfg: WorkerConfig,
        workers: int,
        max_restarts: int = DEFAULT_MAX_RESTARTS,
        worker_options: Sequence[dict[str, Any]] | None = None,
        restart_timeout: float = DEFAULT_RESTART_TIMEOUT_S,
        owns_ray: bool = False,
        prefix: str | None = None,
    ) -> None:
        if workers < 1 or cfg.envs_per_worker < 1:
            raise ValueError(f"need at least 1 worker and 1 env per worker, got {workers} "
                             f"workers x {cfg.envs_per_worker} envs")  # fmt: skip
        if worker_options is not None and len(worker_options) != workers:
            raise ValueError(f"worker_options has {len(worker_options)} entries for "
                             f"{workers} workers; give one dict per worker")  # fmt: skip
        if not ray.is_initialized():
            raise RuntimeError("Ray is not initialised: call rover_train.ray_vec_env.connect() "
                               "(or ray.init) before building a RayVecEnv")  # fmt: skip
        self.cfg = cfg
        self.m = cfg.envs_per_worker
        self.max_restarts = max_restarts
        self.restart_timeout = restart_timeout
        self.owns_ray = owns_ray
        self.prefix = validate_name(prefix or f"{RUN_PREFIX_STEM}{uuid.uuid4().hex[:6]}")
        """Every segment of this run starts with it (``<prefix>_w<index>_...``)."""
        self.worker_deaths = [0] * workers
        """Deaths of each worker seen by the driver (each one restarted by Ray)."""
        self._closed = False
        remote_cls = ray.remote(EnvWorker)
        self.workers = []
        for w in range(workers):
            opts: dict[str, Any] = {
                "num_cpus": WORKER_CPUS,
                "max_restarts": max_restarts,
                "max_task_retries": 0,
                "scheduling_strategy": "SPREAD",
            }
            if worker_options is not None:
                opts.update(worker_options[w])
            self.workers.append(remote_cls.options(**opts).remote(cfg, w, self.prefix))
        try:
            obs_space, act_space, metadata = ray.get(self.workers[0].spaces.remote())
            ray.get([wk.describe.remote() for wk in self.workers])  # every worker is up
        except BaseException:
            self.close()
            raise
        super().__init__(workers * self.m, obs_space, act_space)
        self.metadata = metadata
        self._futures: list[Any] = []
        self._last_obs: Any = None

    # -- the vector env -----------------------------------------------------------------
    def _slice(self, w: int) -> slice:
        return slice(w * self.m, (w + 1) * self.m)

    def _concat(self, parts: Sequence[Any]) -> VecEnvObs:
        first = parts[0]
        if isinstance(first, dict):
            obs = {k: np.concatenate([p[k] for p in parts]) for k in first}
        else:
            obs = np.concatenate(parts)
        self._last_obs = obs
        return dict_to_obs(self.observation_space, obs)

    def reset(self) -> VecEnvObs:
        refs = [wk.reset.remote(self._seeds[self._slice(w)], self._options[self._slice(w)])
                for w, wk in enumerate(self.workers)]  # fmt: skip
        parts = []
        for w, ref in enumerate(refs):
            try:
                obs, infos = ray.get(ref)
            except RayActorError as exc:
                obs, infos = self._await_restart(w, exc)
            parts.append(obs)
            self.reset_infos[self._slice(w)] = infos
        self._reset_seeds()
        self._reset_options()
        return self._concat(parts)

    def step_async(self, actions: np.ndarray) -> None:
        self._futures = [wk.step.remote(actions[self._slice(w)])
                         for w, wk in enumerate(self.workers)]  # fmt: skip

    def step_wait(self) -> VecEnvStepReturn:
        parts, rewards, dones, infos = [], [], [], []
        for w, ref in enumerate(self._futures):
            try:
                obs, rew, done, info = ray.get(ref)
            except RayActorError as exc:
                obs, rew, done, info = self._truncated_by_restart(w, exc)
            for j, i in enumerate(info):
                if "reset_info" in i:
                    self.reset_infos[w * self.m + j] = i.pop("reset_info")
            parts.append(obs)
            rewards.append(rew)
            dones.append(done)
            infos.extend(info)
        self._futures = []
        return self._concat(parts), np.concatenate(rewards), np.concatenate(dones), infos

    # -- faults ---------------------------------------------------------------------------
    def _await_restart(self, w: int, exc: BaseException) -> tuple[Any, list[dict[str, Any]]]:
        """Worker ``w`` died: count it, wait for Ray's restart, reset its envs."""
        self.worker_deaths[w] += 1
        if self.worker_deaths[w] > self.max_restarts:
            raise WorkerLostError(
                f"env worker {w} died {self.worker_deaths[w]} times, more than max_restarts="
                f"{self.max_restarts}; last error: {exc}. Look at the Ray logs of its node "
                f"(/tmp/ray/session_latest/logs) for why, or raise max_restarts."
            ) from exc
        log.warning("env worker %d died (%s); waiting for Ray to restart it (%d/%d)",
                    w, type(exc).__name__, self.worker_deaths[w], self.max_restarts)  # fmt: skip
        deadline = time.monotonic() + self.restart_timeout
        while True:
            left = deadline - time.monotonic()
            try:
                return ray.get(self.workers[w].reset.remote([None] * self.m, [{}] * self.m),
                               timeout=max(left, 0.1))  # fmt: skip
            except RayActorError as again:
                if time.monotonic() > deadline:
                    raise WorkerLostError(f"env worker {w} did not come back within "
                                          f"{self.restart_timeout:.0f} s: {again}") from again
                time.sleep(0.5)
            except GetTimeoutError as late:
                raise WorkerLostError(f"env worker {w} did not come back within "
                                      f"{self.restart_timeout:.0f} s") from late

    def _truncated_by_restart(
        self, w: int, exc: BaseException
    ) -> tuple[Any, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """The step of worker ``w`` was lost with the worker: its envs' episodes end
        (truncated, not failed) and start again in the restarted worker."""
        obs, reset_infos = self._await_restart(w, exc)
        infos = []
        for j in range(self.m):
            i = w * self.m + j
            terminal = None
            if self._last_obs is not None:
                terminal = ({k: v[i] for k, v in self._last_obs.items()}
                            if isinstance(self._last_obs, dict) else self._last_obs[i])  # fmt: skip
            infos.append({"TimeLimit.truncated": True, "terminal_observation": terminal,
                          "worker_restarted": True, "reset_info": reset_infos[j]})  # fmt: skip
        return obs, np.zeros(self.m, dtype=np.float32), np.ones(self.m, dtype=bool), infos

    # -- the rest of the VecEnv interface -------------------------------------------------
    def _by_worker(self, indices: VecEnvIndices) -> dict[int, list[int]]:
        groups: dict[int, list[int]] = {}
        for i in self._get_indices(indices):
            groups.setdefault(i // self.m, []).append(i % self.m)
        return groups

    def _gather(self, refs: Iterable[Any]) -> list[Any]:
        out: list[Any] = []
        for part in ray.get(list(refs)):
            out.extend(part)
        return out

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._gather(self.workers[w].get_attr.remote(attr_name, js)
                            for w, js in self._by_worker(indices).items())  # fmt: skip

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        ray.get([self.workers[w].set_attr.remote(attr_name, value, js)
                 for w, js in self._by_worker(indices).items()])  # fmt: skip

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:  # fmt: skip
        return self._gather(self.workers[w].env_method.remote(method_name, method_args,
                                                              method_kwargs, js)
                            for w, js in self._by_worker(indices).items())  # fmt: skip

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return self._gather(self.workers[w].env_is_wrapped.remote(wrapper_class, js)
                            for w, js in self._by_worker(indices).items())  # fmt: skip

    def describe_workers(self) -> list[dict[str, Any]]:
        """Each worker's pid, node id, segment name, daemon pid and daemon restarts."""
        return ray.get([wk.describe.remote() for wk in self.workers])

    def close(self) -> None:
        """Stop every worker (and its daemon), sweep ``<prefix>*`` from every node's
        ``/dev/shm``, and shut Ray down when this env started it."""
        if self._closed:
            return
        self._closed = True
        refs = [wk.close.remote() for wk in self.workers]
        for w, ref in enumerate(refs):
            try:
                left = ray.get(ref, timeout=CLOSE_TIMEOUT_S)
                if left:
                    log.warning("worker %d: removed segments its daemon left: %s", w, left)
            except (RayActorError, GetTimeoutError, ray.exceptions.RayTaskError) as exc:
                log.warning("worker %d did not close cleanly: %s", w, exc)
        for wk in self.workers:
            ray.kill(wk, no_restart=True)
        swept = {n: r for n, r in sweep_all_nodes(f"{self.prefix}_").items() if r}
        if swept:
            log.warning("removed leftover segments: %s", swept)
        if self.owns_ray:
            ray.shutdown()


def _stop_on_sigterm() -> None:
    """Let SIGTERM stop the driver like Ctrl-C (``KeyboardInterrupt``), so ``finally`` blocks
    close the workers and sweep the nodes; only where SIGTERM still has its default action."""
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return

    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    signal.signal(signal.SIGTERM, _interrupt)


def make_ray_vec_env(args: Any) -> RayVecEnv:
    """The ``RayVecEnv`` of a ``rover-train --ray`` run (``args`` is its ``TrainArgs``):
    connects to (or starts) the cluster; the env shuts a cluster it started down on close."""
    _stop_on_sigterm()
    owns = connect(args.ray or None, num_cpus=int(args.ray_workers * WORKER_CPUS))
    cfg = worker_config(args)
    try:
        venv = RayVecEnv(cfg, args.ray_workers, owns_ray=owns)
    except BaseException:
        if owns:
            ray.shutdown()
        raise
    for d in venv.describe_workers():
        log.info("worker %d: pid %d on node %s, segments %r", d["index"], d["pid"],
                 (d["node_id"] or "?")[:12], d["name"])  # fmt: skip
    return venv


__all__ = ["RayVecEnv", "make_ray_vec_env", "WorkerLostError", "connect", "sweep_all_nodes"]
