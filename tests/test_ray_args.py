"""rover-train's Ray flags and the worker's daemon keeper, without a Ray cluster."""

from __future__ import annotations

import importlib.util
import os
import signal
import sys

import pytest

from rover_train.daemon_keeper import DaemonKeeper
from rover_train.ray_worker import sweep_segments
from rover_train.train import TrainArgs, parse_args, validate
from shm_protocol import FrameReader, existing_segments


def test_ray_flag_takes_an_optional_address() -> None:
    assert parse_args([]).ray is None
    local = parse_args(["--ray", "--ray-workers", "3", "--envs-per-worker", "2"])
    assert (local.ray, local.ray_workers, local.envs_per_worker) == ("", 3, 2)
    assert parse_args(["--ray", "10.0.0.1:6379"]).ray == "10.0.0.1:6379"


def test_ray_flags_are_validated() -> None:
    problem = validate(TrainArgs(ray="", ray_workers=0))
    assert problem is not None and "--ray-workers" in problem
    problem = validate(TrainArgs(ray="", envs_per_worker=0))
    assert problem is not None and "--envs-per-worker" in problem
    ok = validate(TrainArgs(ray="", ray_workers=2, envs_per_worker=2))
    if importlib.util.find_spec("ray") is None:  # a core install says how to get Ray
        assert ok is not None and "roverav[ray]" in ok
    else:
        assert ok is None


def test_import_rover_train_does_not_import_ray() -> None:
    import subprocess

    code = "import sys, rover_train, rover_train.train; print('ray' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ), check=True).stdout  # fmt: skip
    assert out.strip() == "False"


def test_daemon_keeper_restarts_a_killed_daemon_on_the_same_segments(shm_name: str) -> None:
    keeper = DaemonKeeper(shm_name, 2, ["--threads", "1"], max_restarts=2).start()
    try:
        first = keeper.pid
        assert first is not None and len(existing_segments(shm_name)) == 4
        os.kill(first, signal.SIGKILL)
        assert keeper.wait_restarted(timeout=120)
        assert keeper.pid not in (None, first) and keeper.restarts == 1
        reader = FrameReader(shm_name, attach_timeout=5.0)
        try:
            assert reader.writer_pid == keeper.pid and reader.is_writer_alive()
        finally:
            reader.close()
    finally:
        left = keeper.stop()
    assert left == [] and existing_segments(shm_name) == []  # the daemon unlinked its own


def test_sweep_keeps_a_live_daemons_segments(shm_name: str) -> None:
    keeper = DaemonKeeper(shm_name, 1, ["--threads", "1"]).start()
    try:
        assert sweep_segments(shm_name, only_dead=True) == []
        assert len(existing_segments(shm_name)) == 2
    finally:
        keeper.stop()
    with pytest.raises(ValueError):
        sweep_segments("bad/name")


def test_ray_workers_build_the_pedestrians_and_task_of_the_flags() -> None:
    """rover-train --ray once dropped --pedestrian-mode and --n-pedestrians: its workers
    built the default crowd whatever the flags said."""
    from rover_train.ray_worker import EnvWorker, worker_config

    args = parse_args(["--ray", "--world", "maze", "--task", "nav", "--pedestrian-mode",
                       "oblivious", "--n-pedestrians", "5"])  # fmt: skip
    cfg = worker_config(args)
    assert (cfg.kind, cfg.world, cfg.task) == ("lidar", "maze", "nav")
    assert (cfg.pedestrian_mode, cfg.n_pedestrians) == ("oblivious", 5)
    worker = EnvWorker(cfg, 0, "rraytest")  # in this process: a LIDAR worker needs no Ray
    try:
        env = worker.envs[0].unwrapped
        assert env.options.pedestrian_mode == "oblivious"
        assert env.options.n_pedestrians == 5 and env.options.goal_ends_episode
        assert len(env.sim.pedestrians.positions) == 5
    finally:
        worker.close()
