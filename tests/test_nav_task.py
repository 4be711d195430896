"""The nav task: ``goal_ends_episode`` on the envs, ``--task`` on rover-train and
rover-eval, and ``--algo recurrent-ppo`` (a tiny run that checkpoints and resumes)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path
from typing import cast

import numpy as np
import pytest

from rover_env import RoverEnv
from rover_env.reward import GOAL, STUCK_IN_COLLISION, RewardConfig
from rover_train.envs import (
    NAV_CLEARANCE,
    NAV_CLEARANCE_PENALTY,
    NAV_LENGTH,
    NAV_PERSONAL_SPACE,
    NAV_PROGRESS_SCALE,
    TASKS,
    env_kwargs,
    get_task,
    make_env,
)
from rover_train.train import TrainArgs, parse_args, validate
from rover_train.zoo import EVAL_MAX_STEPS

SEED = 2  # inspect: this spawn has 12 m of free LIDAR straight ahead (asserted below)
GOAL_AHEAD_M = 1.2
FORWARD = np.array([1.0, 0.0], dtype=np.float32)  # full speed, keep the heading


def _drive_to_goal(env: RoverEnv) -> list[tuple[float, bool, bool, dict]]:
    """Reset on SEED with the goal GOAL_AHEAD_M straight ahead, drive at it until the goal
    is reached or the episode ends; every step's (reward, terminated, truncated, info)."""
    obs, _ = env.reset(seed=SEED)
    n = len(obs["lidar"])
    assert obs["lidar"][n // 2 - 2 : n // 2 + 2].min() > 3 * GOAL_AHEAD_M  # nothing ahead
    x, y, yaw = float(obs["pose"][0]), float(obs["pose"][1]), float(obs["imu"][2])
    goal = (x + GOAL_AHEAD_M * math.cos(yaw), y + GOAL_AHEAD_M * math.sin(yaw))
    obs, _ = env.reset(seed=SEED, options={"goal": goal})
    steps = []
    for _ in range(200):
        _, reward, terminated, truncated, info = env.step(FORWARD)
        steps.append((reward, terminated, truncated, info))
        if terminated or truncated or info["goals_reached"]:
            break
    return steps


def test_goal_ends_the_episode_on_the_step_it_is_reached() -> None:
    ended = RoverEnv(world_n="inspect", n_pedestrians=0, goal_ends_episode=True)
    seed = RoverEnv(world_n="inspect", n_pedestrians=0)
    try:
        assert ended.goal_ends_episode and not seed.goal_ends_episode
        a, b = _drive_to_goal(ended), _drive_to_goal(seed)
        assert len(a) == len(b) > 1  # the same drive: the goal falls on the same step
        for _, terminated, truncated, info in a[:-1]:
            assert not terminated and not truncated and not info["is_success"]
            assert info["distance_to_goal"] >= ended.reward_config.success_distance
        reward, terminated, truncated, info = a[-1]
        assert terminated and not truncated
        assert info["termination_reason"] == GOAL and info["is_success"]
        assert info["goals_reached"] == 1 and info["distance_to_goal"] < 0.5
        assert info["reward_goal"] == ended.reward_config.goal_reward
        assert info["reward_termination"] == 0.0
        assert reward > ended.reward_config.goal_reward  # the goal plus the step's progress
        with pytest.raises(RuntimeError, match="reset"):
            ended.step(FORWARD)
        # the seed's behaviour (the default): the same step pays the same, the episode goes on
        s_reward, s_terminated, s_truncated, s_info = b[-1]
        assert s_info["goals_reached"] == 1 and s_info["is_success"]
        assert not s_terminated and not s_truncated and s_info["termination_reason"] == ""
        assert s_reward == pytest.approx(reward)
        assert s_info["goal"] != info["goal"]  # a new goal was drawn
        seed.step(FORWARD)  # and the episode goes on
    finally:
        ended.close()
        seed.close()


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_goal_ends_episode_refuses_what_is_not_a_bool(value: object) -> None:
    with pytest.raises(TypeError, match="goal_ends_episode must be True or False"):
        RoverEnv(goal_ends_episode=value)


def test_tasks_set_the_env_keywords() -> None:
    assert NAV_LENGTH == EVAL_MAX_STEPS  # the evaluators' episode
    nav = env_kwargs("lidar", "maze", task="nav")
    assert nav["goal_ends_episode"] is True and nav["length"] == NAV_LENGTH
    assert env_kwargs("lidar", "maze", task="nav", length=50)["length"] == 50  # --length wins
    seed = env_kwargs("lidar", "maze")
    assert "goal_ends_episode" not in seed and "length" not in seed  # the env's own
    reward = nav["reward_config"]
    assert reward.collision_limit == 0 and reward.distance_delta_scale == NAV_PROGRESS_SCALE
    assert reward.clearance_distance == NAV_CLEARANCE
    assert reward.clearance_penalty == NAV_CLEARANCE_PENALTY < 0
    assert reward.goal_reward == RewardConfig().goal_reward  # the rest is the env's own
    assert "reward_config" not in seed
    fused = env_kwargs("fused", "maze", task="nav")
    assert fused["goal_ends_episode"] is True and fused["length"] == NAV_LENGTH
    f_reward = fused["reward_config"]  # the fused envs' own constants under the task's
    assert f_reward.stuck_window == RewardConfig.fused().stuck_window
    assert f_reward.collision_limit == 0 and f_reward.distance_delta_scale == NAV_PROGRESS_SCALE
    assert f_reward.clearance_penalty == 0  # a camera agent learnt to stand with it
    with pytest.raises(ValueError, match="unknown task 'navigate'.*seed.*nav"):
        get_task("navigate")


def _drive_into_the_scenery(task: str) -> list[dict]:
    """Full speed straight on from seed 0 in the maze (no pedestrians) until the episode
    ends or 40 steps after the first collision; every step's info, with its LIDAR minimum
    as ``lidar_min``."""
    env = make_env("lidar", world="maze", task=task, n_pedestrians=0)
    infos: list[dict] = []
    try:
        env.reset(seed=0)
        first = None
        for step in range(NAV_LENGTH):
            obs, _, terminated, truncated, info = env.step(FORWARD)
            infos.append({**info, "lidar_min": float(obs["lidar"].min())})
            if info["collision"] and first is None:
                first = step
            if terminated or truncated or (first is not None and step > first + 40):
                break
    finally:
        env.close()
    return infos


def test_nav_task_ends_at_the_first_collision_and_pays_progress_by_its_scale() -> None:
    nav, seed = _drive_into_the_scenery("nav"), _drive_into_the_scenery("seed")
    first = next(i for i, info in enumerate(seed) if info["collision"])
    assert len(seed) > first + 40  # the seed's task drives on against the wall
    assert len(nav) == first + 1  # the same drive, ended by the first collision
    last = nav[-1]
    assert last["collision"] and last["termination_reason"] == STUCK_IN_COLLISION
    assert last["reward_termination"] == RewardConfig().general_penalty
    for n, s in zip(nav[:first], seed[:first], strict=True):  # the same steps, rescaled
        assert n["reward_progress"] == pytest.approx(
            s["reward_progress"] * NAV_PROGRESS_SCALE / RewardConfig().distance_delta_scale)
    assert sum(info["reward_progress"] for info in nav[:first]) > 1.0  # it drove nearer


def test_nav_task_charges_lidar_clearance_before_the_collision() -> None:
    nav, seed = _drive_into_the_scenery("nav"), _drive_into_the_scenery("seed")
    assert all(info["reward_clearance"] == 0.0 for info in seed)  # not in the seed
    inside = 0
    for info in nav[:-1]:  # the last step returns its termination penalty alone
        expected = NAV_CLEARANCE_PENALTY * max(0.0, NAV_CLEARANCE - info["lidar_min"])
        assert info["reward_clearance"] == pytest.approx(expected, abs=1e-6)
        inside += info["lidar_min"] < NAV_CLEARANCE
    assert inside >= 3  # charged on the approach, before the wall is touched
    assert nav[-2]["reward_clearance"] < NAV_CLEARANCE_PENALTY * (NAV_CLEARANCE - 0.4)
    for info in nav[:-1]:
        parts = sum(v for k, v in info.items() if k.startswith("reward_"))
        assert parts == pytest.approx(info["reward"])  # the term is in the reward


def test_clearance_config_is_checked() -> None:
    with pytest.raises(ValueError, match="clearance_penalty is a penalty: it must be <= 0"):
        RewardConfig(clearance_distance=0.6, clearance_penalty=2.0)
    with pytest.raises(ValueError, match="clearance_distance must be >= 0"):
        RewardConfig(clearance_distance=-0.1)
    assert RewardConfig().clearance_penalty == 0.0  # the seed's reward has no such term
    assert RewardConfig.fused().clearance_penalty == 0.0


def test_cli_task_flag_builds_envs_that_end_at_the_goal() -> None:
    args = parse_args(["--task", "nav"])
    assert args.task == "nav" and TASKS[args.task].goal_ends_episode
    assert parse_args([]).task == "seed"
    import rover_train.envs as envs

    env = envs.make_env(args.env, world=args.world, task=args.task, n_pedestrians=0)
    try:
        base = cast(RoverEnv, env.unwrapped)
        assert base.goal_ends_episode and base.length == NAV_LENGTH
    finally:
        env.close()


def test_cli_refuses_an_unknown_task(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        parse_args(["--task", "navigate"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--task" in err and "'navigate'" in err and "nav" in err
    assert "--task must be one of seed, nav" in str(validate(TrainArgs(task="navigate")))


def test_recurrent_ppo_validation() -> None:
    assert validate(TrainArgs(algo="recurrent-ppo")) is None
    problem = validate(TrainArgs(algo="recurrent-ppo", n_steps=1))
    assert problem is not None and "--n-steps must be at least 2" in problem
    problem = validate(TrainArgs(algo="recurrent-ppo", n_steps=65, batch_size=64))
    assert problem is not None and "minibatch of 1 step" in problem and "65" in problem
    assert validate(TrainArgs(algo="ppo", n_steps=65, batch_size=64)) is None  # PPO copes


def test_recurrent_ppo_nav_run_checkpoints_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """In-process (one interpreter start instead of four): train, resume, evaluate."""
    from rover_train import evaluate
    from rover_train.train import train

    caplog.set_level(logging.INFO, logger="rover_train")
    small = ["--env", "lidar", "--algo", "recurrent-ppo", "--task", "nav", "--n-steps", "64",
             "--batch-size", "32", "--n-epochs", "1", "--no-progress", "--checkpoint-every", "64",
             "--logdir", str(tmp_path)]  # fmt: skip
    metrics = train(parse_args([*small, "--timesteps", "128"]))
    assert metrics["status"] == "complete"
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["recurrent-ppo_128_steps.state.pkl", "recurrent-ppo_128_steps.zip",
                     "recurrent-ppo_64_steps.state.pkl", "recurrent-ppo_64_steps.zip"]  # fmt: skip
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["algo"] == "recurrent-ppo" and metrics["task"] == "nav"
    # a resume keeps the task, and refuses another
    with pytest.raises(SystemExit) as refused:
        parse_args(["--resume", str(tmp_path), "--task", "seed", "--timesteps", "192"])
    assert refused.value.code == 2 and "--task was 'nav'" in capsys.readouterr().err
    resumed = parse_args(["--resume", str(tmp_path), "--timesteps", "192", "--no-progress"])
    assert resumed.task == "nav" and resumed.algo == "recurrent-ppo"
    caplog.clear()
    train(resumed)
    assert "resuming from" in caplog.text and "recurrent-ppo_128_steps.zip" in caplog.text
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["timesteps"] == 192 and metrics["resumes"] == 1
    assert metrics["task"] == "nav" and metrics["args"]["task"] == "nav"
    # rover-eval loads it as a recurrent policy and takes the task from metrics.json
    code = evaluate.main([str(tmp_path / "model.zip"), "--env", "lidar", "--episodes", "1",
                          "--max-steps", "20", "--json"])  # fmt: skip
    assert code == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["episodes"] == 1


def test_set_reward_config_turns_the_clearance_term_on_mid_episode() -> None:
    """The nav task's fused constants (no clearance term) on a LIDAR env, driven at a wall:
    nothing is charged until ``set_reward_config`` adds the term, then every step inside
    NAV_CLEARANCE pays it."""
    fused_nav = get_task("nav").reward_config("fused")
    assert fused_nav is not None and fused_nav.clearance_penalty == 0
    env = RoverEnv(world_n="maze", n_pedestrians=0, goal_ends_episode=True,
                   reward_config=fused_nav)  # fmt: skip
    try:
        env.reset(seed=0)
        before, after = [], []
        for step in range(NAV_LENGTH):
            if step == 10:
                env.set_reward_config(dataclasses.replace(
                    env.reward_config, **get_task("nav").lidar_reward))
            obs, _, terminated, truncated, info = env.step(FORWARD)
            (before if step < 10 else after).append((float(obs["lidar"].min()), info))
            if terminated or truncated:
                break
    finally:
        env.close()
    assert all(info["reward_clearance"] == 0.0 for _, info in before)
    charged = [info["reward_clearance"] for lidar_min, info in after[:-1]
               if lidar_min < NAV_CLEARANCE]  # fmt: skip
    assert len(charged) >= 3 and all(c < 0 for c in charged)  # charged on the approach
    assert after[-1][1]["collision"]  # the same drive ends at the wall


def test_set_reward_config_refuses_what_it_cannot_change() -> None:
    env = RoverEnv(world_n="inspect", n_pedestrians=0)
    try:
        with pytest.raises(ValueError, match="cannot change stuck_window"):
            env.set_reward_config(dataclasses.replace(env.reward_config, stuck_window=7))
        with pytest.raises(TypeError, match="takes a RewardConfig"):
            env.set_reward_config({"clearance_penalty": -2.0})  # type: ignore[arg-type]
        assert env.reward_config == RewardConfig()  # unchanged
    finally:
        env.close()


def test_clearance_from_is_for_the_fused_nav_task() -> None:
    ok = TrainArgs(env="fused", task="nav", clearance_from=400_000)
    assert validate(ok) is None
    for bad in (TrainArgs(env="lidar", task="nav", clearance_from=0),
                TrainArgs(env="fused", task="seed", clearance_from=0),
                TrainArgs(env="fused", task="nav", clearance_from=-1)):  # fmt: skip
        problem = validate(bad)
        assert problem is not None and "--clearance-from" in problem and "--task nav" in problem
    args = parse_args(["--env", "fused", "--task", "nav", "--clearance-from", "5"])
    assert args.clearance_from == 5
    alone = validate(TrainArgs(env="fused", task="nav", clearance_footprints=True))
    assert alone is not None and "give --clearance-from" in alone
    both = TrainArgs(env="fused", task="nav", clearance_from=0, clearance_footprints=True)
    assert validate(both) is None
    reach = TrainArgs(env="fused", task="nav", clearance_from=0, clearance_distance=0.8)
    assert validate(reach) is None
    assert validate(TrainArgs(env="lidar", task="nav", personal_space_distance=0.8)) is None
    for bad_space in (TrainArgs(env="lidar", task="seed", personal_space_distance=0.8),
                      TrainArgs(env="lidar", task="nav",
                                personal_space_distance=-1.0)):  # fmt: skip
        problem = validate(bad_space)
        assert problem is not None and "--personal-space-distance" in problem
    for bad_reach in (TrainArgs(env="fused", task="nav", clearance_distance=0.8),
                      TrainArgs(env="fused", task="nav", clearance_from=0,
                                clearance_distance=0.0)):  # fmt: skip
        problem = validate(bad_reach)
        assert problem is not None and "--clearance-distance" in problem


@pytest.mark.parametrize("at_steps, switched", [(64, True), (1_000, False)])
def test_clearance_switch_adds_the_term_to_every_env_at_its_step(
    at_steps: int, switched: bool
) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from rover_train.train import make_clearance_switch

    start = get_task("nav").reward_config("fused")
    venv = DummyVecEnv([lambda: RoverEnv(world_n="inspect", n_pedestrians=0,
                                         reward_config=start)] * 2)  # fmt: skip
    try:
        model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0)
        callback = make_clearance_switch(at_steps, "nav", distance=0.8)
        model.learn(total_timesteps=128, callback=callback)
        for cfg in venv.get_attr("reward_config"):
            assert cfg.clearance_penalty == (NAV_CLEARANCE_PENALTY if switched else 0.0)
            assert cfg.clearance_distance == (0.8 if switched else 0.0)  # its reach, given
            assert cfg.distance_delta_scale == NAV_PROGRESS_SCALE  # the rest is unchanged
        assert callback.switched is switched
    finally:
        venv.close()


def test_a_reward_switch_at_step_0_sets_its_terms_before_the_first_step() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    from rover_train.train import make_reward_switch

    start = get_task("nav").reward_config("lidar")
    assert start.personal_space_distance == NAV_PERSONAL_SPACE
    venv = DummyVecEnv([lambda: RoverEnv(world_n="inspect", reward_config=start)] * 2)
    try:
        model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0)
        seen: list[float] = []

        class Record(BaseCallback):
            def _on_step(self) -> bool:
                seen.extend(c.personal_space_distance for c in venv.get_attr("reward_config"))
                return True

        switch = make_reward_switch(0, {"personal_space_distance": 0.8}, "reach")
        model.learn(total_timesteps=64, callback=[switch, Record()])
        assert seen and set(seen) == {0.8}  # every step of every env, from the first
        assert all(c.clearance_distance == start.clearance_distance  # the rest is unchanged
                   for c in venv.get_attr("reward_config"))  # fmt: skip
    finally:
        venv.close()


def test_clearance_footprints_charge_what_the_lidar_plane_passes_under() -> None:
    """Inspect's panels overhang their plinths above the LIDAR's plane: 0.4 m from a panel's
    footprint the LIDAR reads the plinth about 0.3 m farther. With ``clearance_footprints``
    the clearance term charges the footprint's distance; without it, the LIDAR's."""
    cfg = dataclasses.replace(get_task("nav").reward_config("lidar"), clearance_footprints=True)
    env = RoverEnv(world_n="inspect", n_pedestrians=0, reward_config=cfg)
    try:
        env.reset(seed=0, options={"rover_pose": (-23.5, -25.0 - 0.544 - 0.4, math.pi / 2)})
        obs, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
        lidar_min = float(obs["lidar"].min())
        footprint = env.clearance_range(lidar_min)
        assert lidar_min > footprint + 0.2 and 0.3 < footprint < 0.5
        assert info["reward_clearance"] == pytest.approx(
            NAV_CLEARANCE_PENALTY * (NAV_CLEARANCE - footprint), abs=0.02)
        env.set_reward_config(dataclasses.replace(cfg, clearance_footprints=False))
        assert env.clearance_range(lidar_min) == lidar_min
    finally:
        env.close()
