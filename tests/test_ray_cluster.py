"""rover-train on a real multi-node Ray cluster on this machine: a head and two worker nodes,
each a separate raylet with its own resources; env workers pinned to nodes, each worker with
its own av-daemon; a killed worker, a killed daemon, Ctrl-C, and no segment left behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="the Ray tests need the extra: pip install 'roverav[ray]'")

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
SHM = Path("/dev/shm")
NODE_MB = 100 * 2**20
# Not "test_": the suite's session fixture removes new "test_*" segments when a session
# ends, and on a shared machine another session would unlink a running worker's segments.
TEST_PREFIX = "rraytest"


def _segments(prefix: str) -> list[str]:
    return sorted(n for n in os.listdir(SHM) if n.startswith((prefix, "." + prefix)))


def _wait_gone(names: list[str], timeout: float = 20.0) -> list[str]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = [n for n in names if (SHM / n).exists()]
        if not left:
            return []
        time.sleep(0.2)
    return left


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """Head (1 CPU) plus nodes "node_a" and "node_b" (2 logical CPUs each, 100 MB stores)."""
    from ray.cluster_utils import Cluster

    old_path = os.environ.get("PYTHONPATH")
    # raylets and their workers are separate processes: they must import this checkout
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), old_path) if p)
    os.environ.setdefault("MUJOCO_GL", "egl")
    c = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "object_store_memory": NODE_MB, "include_dashboard": False})  # fmt: skip
    try:
        for res in ("node_a", "node_b"):
            c.add_node(num_cpus=2, resources={res: 1}, object_store_memory=NODE_MB)
        c.wait_for_nodes()
        ray.init(address=c.address)
        yield c
    finally:
        ray.shutdown()
        c.shutdown()
        if old_path is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old_path


def _node_of(resource: str) -> str:
    return next(n["NodeID"] for n in ray.nodes() if n["Alive"] and resource in n["Resources"])


def _venv(workers: int, m: int, nodes: list[str] | None = None, **kw: Any) -> Any:
    """A fused RayVecEnv; worker w pinned to the node with custom resource ``nodes[w]``."""
    from rover_train.ray_vec_env import RayVecEnv
    from rover_train.ray_worker import WorkerConfig

    cfg = WorkerConfig(kind="fused", world="maze", envs_per_worker=m, length=400)
    if nodes is not None:
        kw["worker_options"] = [{"resources": {n: 1}} for n in nodes]
    return RayVecEnv(cfg, workers, prefix=f"{TEST_PREFIX}{uuid.uuid4().hex[:6]}", **kw)


def test_fused_ppo_across_nodes_survives_a_killed_worker(cluster: Any) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from rover_train.policies import RoverExtractor

    venv = _venv(2, 1, ["node_a", "node_b"])
    try:
        before = venv.describe_workers()
        assert [d["node_id"] for d in before] == [_node_of("node_a"), _node_of("node_b")]
        assert all(d["daemon_pid"] and _pid_alive(d["daemon_pid"]) for d in before)
        assert _segments(before[0]["name"]) and _segments(before[1]["name"])

        class KillWorker0(BaseCallback):
            restarted: list[int] = []

            def _on_step(self) -> bool:
                # in the second rollout, after an update; a whole rollout follows the restart
                if self.num_timesteps >= 300 and not venv.worker_deaths[0] and not self.restarted:
                    os.kill(before[0]["pid"], signal.SIGKILL)
                    self.restarted.append(-1)  # killed; the next step finds it dead
                for i, info in enumerate(self.locals["infos"]):
                    if info.get("worker_restarted"):
                        assert info["TimeLimit.truncated"] and self.locals["dones"][i]
                        assert info["terminal_observation"]["fused_image"].shape == (96, 96, 3)
                        self.restarted.append(i)
                return True

        cb = KillWorker0()
        model = PPO("MultiInputPolicy", venv, n_steps=128, batch_size=128, n_epochs=1, seed=0,
                    policy_kwargs={"features_extractor_class": RoverExtractor})  # fmt: skip
        model.learn(total_timesteps=768, callback=cb)  # three rollouts of 2 x 128 steps
        assert model.num_timesteps >= 768
        assert venv.worker_deaths == [1, 0] and cb.restarted[1:] == [0]
        after = venv.describe_workers()
        assert after[0]["pid"] != before[0]["pid"] and after[0]["node_id"] == before[0]["node_id"]
        assert after[0]["name"] != before[0]["name"] and after[1] == before[1]
        # the dead worker's daemon died with it; its segments are gone (its successor swept)
        assert not _wait_gone(_segments(before[0]["name"]))
        assert not _pid_alive(before[0]["daemon_pid"])
    finally:
        venv.close()
    assert _segments(venv.prefix) == []


def test_a_daemon_killed_inside_a_worker_is_restarted(cluster: Any) -> None:
    venv = _venv(1, 2, ["node_b"])
    try:
        (d,) = venv.describe_workers()
        assert len(_segments(d["name"])) == 4  # two slots: fused + camera each
        venv.reset()
        actions = np.zeros((2, 2), dtype=np.float32)
        for _ in range(5):
            venv.step(actions)
        os.kill(d["daemon_pid"], signal.SIGKILL)
        errors, good_after = 0, 0
        for _ in range(400):
            obs, _rew, dones, infos = venv.step(actions)
            if any("daemon_error" in i for i in infos):
                errors += 1
                assert all(dones[j] for j, i in enumerate(infos) if "daemon_error" in i)
            elif errors:
                good_after += 1
                if good_after >= 10:
                    break
        assert errors >= 1 and good_after >= 10
        assert obs["fused_image"].shape == (2, 96, 96, 3) and obs["fused_image"].max() > 0
        (d2,) = venv.describe_workers()
        assert d2["daemon_restarts"] == 1 and d2["daemon_pid"] != d["daemon_pid"]
        assert d2["pid"] == d["pid"] and venv.worker_deaths == [0]
    finally:
        venv.close()
    assert _segments(venv.prefix) == []


def _train_cli(cluster: Any, logdir: Path, *args: str) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROVERAV_LOG_LEVEL="INFO")
    return subprocess.Popen(
        [sys.executable, "-m", "rover_train.train", "--ray", cluster.address, "--env", "fused",
         "--world", "maze", "--ray-workers", "2", "--n-steps", "128", "--batch-size", "64",
         "--n-epochs", "1", "--logdir", str(logdir), "--no-progress", *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env=env,
    )  # fmt: skip


def test_rover_train_cli_on_the_cluster_then_ctrl_c(cluster: Any, tmp_path: Path) -> None:
    ours = set(_segments("rray"))  # run prefixes are rray<hex>; others' runs may exist
    proc = _train_cli(cluster, tmp_path / "done", "--timesteps", "256")  # one rollout
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    assert json.loads((tmp_path / "done" / "metrics.json").read_text())["timesteps"] >= 256
    assert (tmp_path / "done" / "model.zip").is_file()
    assert set(_segments("rray")) <= ours, out

    proc = _train_cli(cluster, tmp_path / "stopped", "--timesteps", "1000000")
    deadline = time.monotonic() + 180
    while len(set(_segments("rray")) - ours) < 4 and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[0]
        time.sleep(0.2)
    assert len(set(_segments("rray")) - ours) == 4  # two workers' daemons are serving
    time.sleep(3.0)  # into the learning loop
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    # Ctrl-C saves a checkpoint and exits 130 (rover_train.checkpoint), under Ray as locally
    assert proc.returncode == 130, out
    assert "rover-train --resume" in out, out
    assert list((tmp_path / "stopped" / "checkpoints").glob("*.zip")), out
    assert set(_segments("rray")) <= ours, out


def test_a_worker_whose_node_is_lost_comes_back_on_another_node(cluster: Any) -> None:
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    node_c = cluster.add_node(num_cpus=1, resources={"node_c": 1}, object_store_memory=NODE_MB)
    cluster.wait_for_nodes()
    # prefers node_c while it lives; Ray may restart it on any node once node_c is gone
    soft = NodeAffinitySchedulingStrategy(_node_of("node_c"), soft=True)
    venv = _venv(1, 1, worker_options=[{"scheduling_strategy": soft}])
    try:
        (d,) = venv.describe_workers()
        assert d["node_id"] == _node_of("node_c")
        venv.reset()
        actions = np.zeros((1, 2), dtype=np.float32)
        for _ in range(3):
            venv.step(actions)
        cluster.remove_node(node_c)
        _obs, _rew, dones, infos = venv.step(actions)
        assert dones[0] and infos[0]["worker_restarted"] and infos[0]["TimeLimit.truncated"]
        (d2,) = venv.describe_workers()
        assert d2["node_id"] != d["node_id"] and venv.worker_deaths == [1]
        _obs, _rew, dones, infos = venv.step(actions)
        assert "worker_restarted" not in infos[0]
        # the lost node's worker and daemon died with its raylet; no segment of theirs is left
        assert not _wait_gone(_segments(d["name"]))
    finally:
        venv.close()
    assert _segments(venv.prefix) == []
