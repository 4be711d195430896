"""Discrete students: zoo students that drive the seed's action tables, Discrete(60)
and the gaze env's Discrete(180), learnt from the planner expert's nearest table action."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from helpers.observations import gaze_obs
from helpers.tiny_distill import tiny_entry

from rover_env import RoverEnv
from rover_env.controller import wrap_angle
from rover_env.discrete_env import DIRECTION_ANGLES, SPEED_LEVELS, decode_action, nearest_action
from rover_env.gaze_discrete_env import (
    CENTRE_WINDOW,
    PAN_LEFT,
    PAN_NONE,
    PAN_RIGHT,
    PAN_WINDOWS,
    decode_gaze_action,
    encode_gaze_action,
    moved_window,
    nearest_gaze_action,
)
from rover_train import zoo
from rover_train.imitation.dagger import DAggerConfig, Dataset, feature_spec, fit
from rover_train.imitation.distill import RECIPES
from rover_train.imitation.expert import ExpertConfig, PlannerExpert
from rover_train.imitation.finetune import STARTS
from rover_train.wrappers import WithPanHead, WithSeedTable
from rover_train.zoo import agent as student
from rover_train.zoo.agent import (
    FeatureSpec,
    ObsHistory,
    StudentAgent,
    StudentNet,
    action_classes,
    encode_action,
    pan_classes,
    state_features,
)

TABLE = FeatureSpec(centre=(0.0, 0.0), scale=5.0, gaze=True, table=True, history=True)


def test_every_table_cell_is_the_nearest_action_to_its_own_command() -> None:
    for a in range(60):
        s, d = decode_action(a)
        speed, heading = float(SPEED_LEVELS[s]), float(DIRECTION_ANGLES[d])
        assert nearest_action(speed, heading) == a
        # a command up to just under half a cell away, and any turn round, is the same cell
        assert nearest_action(speed + 0.07, heading + 0.25 + 2 * math.pi) == a
        assert nearest_action(speed - 0.07, heading - 0.25 - 4 * math.pi) == a


@pytest.mark.parametrize("window, target, move", [
    (CENTRE_WINDOW, 0.05, PAN_NONE), (CENTRE_WINDOW, 0.9, PAN_LEFT),
    (CENTRE_WINDOW, -0.4, PAN_RIGHT), (4, 1.0, PAN_NONE), (4, -1.0, PAN_RIGHT), (0, 0.3, PAN_LEFT),
])  # fmt: skip
def test_the_gaze_label_steps_one_window_towards_the_target(window: int, target: float,
                                                            move: int) -> None:  # fmt: skip
    a = nearest_gaze_action(0.6, 0.5, target, window)
    assert a // 3 == nearest_action(0.6, 0.5) and decode_gaze_action(a)[2] == move
    assert moved_window(window, move) == (window if move == PAN_NONE else
                                          window + (1 if move == PAN_LEFT else -1))  # fmt: skip
    with pytest.raises(ValueError, match="window must be in 0..4"):
        nearest_gaze_action(0.6, 0.5, target, 5)


def test_the_table_wrapper_steers_to_compass_headings_and_steps_the_camera() -> None:
    env = WithSeedTable(WithPanHead(RoverEnv(world_n="inspect", n_pedestrians=0)))
    try:
        assert env.action_space.n == 180
        _, info = env.reset(seed=3)
        assert info["pan_window"] == CENTRE_WINDOW
        north = int(np.argmin(np.abs(DIRECTION_ANGLES - math.pi / 2)))
        for _ in range(3):  # three moves left: two windows, then clamped at +60 deg
            _, _, _, _, info = env.step(encode_gaze_action(1, north, PAN_LEFT))
        assert info["pan_window"] == 4 and info["pan_target"] == pytest.approx(PAN_WINDOWS[4])
        for _ in range(60):  # stood still (speed level 1: 0 m/s), turning to face north
            _, _, _, _, info = env.step(encode_gaze_action(1, north, PAN_NONE))
        base = env.unwrapped
        assert abs(wrap_angle(base.orientation[2] - math.pi / 2)) < 0.1
        assert info["pan"] == pytest.approx(PAN_WINDOWS[4], abs=1e-6)  # the servo got there
        _, info = env.reset(seed=4)
        assert info["pan_window"] == CENTRE_WINDOW
    finally:
        env.close()
    plain = WithSeedTable(RoverEnv(world_n="inspect", n_pedestrians=0))
    try:
        assert plain.action_space.n == 60
        plain.reset(seed=3)
        _, _, _, _, info = plain.step(4 * 12 + north)
        assert "pan_window" not in info
    finally:
        plain.close()
    with pytest.raises(ValueError, match="speed, relative heading"):
        WithSeedTable(WithSeedTable(RoverEnv(world_n="inspect")))


def test_the_gaze_teacher_drives_the_table_to_the_goal_turning_the_camera() -> None:
    env = WithSeedTable(WithPanHead(RoverEnv(world_n="inspect", pedestrian_mode="crowd")))
    expert = PlannerExpert("inspect", ExpertConfig.with_manners("polite", sees="camera",
                                                                 gaze="active"))  # fmt: skip
    try:
        env.reset(seed=100_003)
        expert.reset()
        windows, goal = set(), False
        for _ in range(600):
            action = expert.act_env(env)
            assert action.shape == () and env.action_space.contains(action)
            _, _, terminated, truncated, info = env.step(action)
            windows.add(info["pan_window"])
            if info.get("goals_reached", 0):
                goal = True
                break
            assert not (terminated or truncated)
        assert goal and len(windows) > 1
    finally:
        env.close()


def test_a_table_student_heads_are_the_cells_and_the_moves_and_it_acts_with_an_integer(
) -> None:  # fmt: skip
    fixed = replace(TABLE, gaze=False)
    continuous = replace(TABLE, table=False)
    assert (TABLE.n_drive, TABLE.n_pan, fixed.n_outputs, fixed.n_pan) == (60, 3, 60, 0)
    assert TABLE.action_size == fixed.action_size == 1
    # the gaze table student also sees how fast the camera turns (one more history feature)
    assert TABLE.state_dim == continuous.state_dim + 1
    assert fixed.state_dim == replace(continuous, gaze=False).state_dim
    target = torch.from_numpy(encode_action(np.int64(85), TABLE))[None]  # cell 28, left
    assert int(action_classes(target, TABLE)[0]) == 28 and int(pan_classes(target, TABLE)[0]) == 1
    assert int(action_classes(target, fixed)[0]) == 85
    with pytest.raises(ValueError, match="an integer"):
        encode_action(np.array([0.6, 0.1, 0.0], np.float32), TABLE)
    logits = np.zeros(63)
    logits[28], logits[60 + PAN_LEFT] = 3.0, 1.0
    action = student.decode_action(logits, TABLE)
    assert action.shape == () and int(action) == 85
    assert int(student.decode_action(logits[:60], fixed)) == 28


def test_the_pan_turn_feature_follows_the_camera() -> None:
    history = ObsHistory(TABLE)
    turns = [float(history.features(gaze_obs(pan))[-1]) for pan in (0.0, 0.0, 0.1, 0.2, 0.1)]
    step = math.radians(180.0) * 0.05
    assert turns[:2] == [0.0, 0.0]
    assert turns[2:] == pytest.approx([0.1 / step, 0.1 / step, -0.1 / step], abs=1e-5)
    history.reset()
    assert float(history.features(gaze_obs(0.5))[-1]) == 0.0


def test_fit_teaches_a_table_student_the_labelled_action() -> None:
    torch.manual_seed(0)  # the initial weights: not those left by whichever test ran before
    net = StudentNet(TABLE, hidden=32)
    data = Dataset.empty(TABLE)
    for pan, a in ((0.5, 85), (-0.5, 12)):
        for _ in range(20):
            data.add(state_features(gaze_obs(pan), TABLE, ObsHistory(TABLE)),
                     encode_action(a, TABLE), 1.0)  # fmt: skip
    fit(net, data, DAggerConfig(epochs=60, batch=8), torch.Generator().manual_seed(0))
    for pan, a in ((0.5, 85), (-0.5, 12)):
        state = state_features(gaze_obs(pan), TABLE, ObsHistory(TABLE))
        out = net(torch.from_numpy(state)[None])[0].detach().numpy()
        assert int(student.decode_action(out, TABLE)) == a


def test_a_discrete_env_makes_a_discrete_student() -> None:
    env = WithSeedTable(RoverEnv(world_n="inspect"))
    try:
        spec = feature_spec("lidar", env)
        assert spec.table and spec.max_speed == 1.0 and spec.min_speed == -0.2
    finally:
        env.close()


def test_the_table_pair_differs_in_the_camera_alone_and_is_not_fine_tuned() -> None:
    gaze, fixed = RECIPES["fused-gaze-discrete-inspect"], RECIPES["discrete-inspect"]
    assert gaze.problem() is None and fixed.problem() is None
    assert replace(fixed, entry=gaze.entry, teacher_gaze="active") == gaze
    assert zoo.ENTRIES[gaze.entry].env_kwargs == zoo.ENTRIES["fused-inspect"].env_kwargs
    assert zoo.ENTRIES[fixed.entry].env_kwargs == zoo.ENTRIES["fused-inspect"].env_kwargs
    assert "--teacher-gaze active" in (replace(gaze, teacher_gaze="fixed").problem() or "")
    assert not {gaze.entry, fixed.entry} & set(STARTS)


def test_a_table_gaze_entry_is_distilled_in_two_stages_and_drives_the_discrete_env(
    tmp_path,
) -> None:
    """A tiny run of the Discrete(180) entry's recipe, stage 2 with a real daemon: the
    student's integer actions drive the entry's env, RoverEnvFusedGazeDiscrete."""
    with tiny_entry("fused-gaze-discrete-inspect", tmp_path) as (agent, daemon):
        assert agent.spec.table and agent.spec.gaze
        env = zoo.make_env("fused-gaze-discrete-inspect", rl_obs_name=daemon, slot=0)
        try:
            assert env.action_space.n == 180
            obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
            agent.reset()
            for _ in range(5):
                action = agent.act(obs)
                assert env.action_space.contains(int(action))
                obs, *_ = env.step(action)
        finally:
            env.close()


def test_gaze_value_drives_discrete_students_only_through_the_table(tmp_path) -> None:
    from rover_train.imitation.gaze_value import student_act

    fixed = tmp_path / "fixed.pt"
    StudentAgent(StudentNet(replace(TABLE, gaze=False, history=False))).save(fixed)
    gaze = tmp_path / "gaze.pt"
    StudentAgent(StudentNet(replace(TABLE, history=False))).save(gaze)
    with pytest.raises(SystemExit, match="give --table"):
        student_act(fixed, False)
    with pytest.raises(SystemExit, match="not a Discrete\\(180\\) gaze student"):
        student_act(fixed, True, table=True)
    _, act = student_act(fixed, False, table=True)
    a = act(gaze_obs(0.0))
    assert a % 3 == PAN_NONE and 0 <= a < 180  # the Discrete(60) cell, the camera kept
    _, held = student_act(gaze, True, hold_camera=True, table=True)
    assert held(gaze_obs(0.0)) % 3 == PAN_NONE
    _, act = student_act(gaze, True, table=True)
    assert held(gaze_obs(0.0)) // 3 == act(gaze_obs(0.0)) // 3
