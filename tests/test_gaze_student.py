"""Gaze students: a zoo student that also chooses where the camera looks."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from helpers.observations import gaze_obs
from helpers.tiny_distill import tiny_entry

from fused_image import FUSED_SIZE
from rover_env.constants import PAN_LIMIT
from rover_train import zoo
from rover_train.imitation.dagger import (
    DAggerConfig,
    Dataset,
    WithFusedView,
    collect,
    fit,
    make_training_env,
    teacher_config,
)
from rover_train.imitation.distill import RECIPES
from rover_train.imitation.expert import PlannerExpert
from rover_train.wrappers import WithPanHead
from rover_train.zoo.agent import (
    PAN_BINS,
    FeatureSpec,
    StudentAgent,
    StudentNet,
    decode_action,
    encode_action,
    head_log_probs,
    pan_classes,
    state_features,
)

GAZE = FeatureSpec(centre=(0.0, 0.0), scale=5.0, gaze=True)


@pytest.mark.parametrize("pan", [-PAN_LIMIT, -0.4, 0.0, 0.13, PAN_LIMIT])
def test_the_pan_head_decodes_its_class_back_to_the_pan_target(pan: float) -> None:
    target = encode_action(np.array([0.7, 0.2, pan]), GAZE)
    k = int(pan_classes(torch.from_numpy(target)[None])[0])
    logits = np.full(GAZE.n_outputs, -20.0)
    logits[GAZE.n_drive + k] = 20.0
    logits[0] = 20.0  # some driving class
    action = decode_action(logits, GAZE)
    assert action.shape == (3,)
    half_bin = PAN_LIMIT / (PAN_BINS - 1)
    assert abs(action[2] - pan) <= half_bin + 1e-6
    assert -PAN_LIMIT <= action[2] <= PAN_LIMIT


def test_a_gaze_student_sees_the_pan_and_refuses_labels_without_one() -> None:
    fixed = FeatureSpec(centre=(0.0, 0.0), scale=5.0)
    assert GAZE.state_dim == fixed.state_dim + 1
    assert GAZE.n_outputs == fixed.n_outputs + PAN_BINS
    assert GAZE.action_size == 3 and fixed.action_size == 2
    left, right = state_features(gaze_obs(0.5), GAZE), state_features(gaze_obs(-0.5), GAZE)
    assert not np.array_equal(left, right)
    np.testing.assert_array_equal(state_features(gaze_obs(0.5), fixed),
                                  state_features(gaze_obs(-0.5), fixed))  # fmt: skip
    with pytest.raises(ValueError, match="no pan target"):
        encode_action(np.array([0.5, 0.0]), GAZE)


def test_each_head_is_normalised_on_its_own_in_an_ensemble() -> None:
    torch.manual_seed(0)
    a, b = StudentAgent(StudentNet(GAZE)), StudentAgent(StudentNet(GAZE))
    both = StudentAgent.ensemble([a, b])
    state = torch.randn(3, GAZE.state_dim)
    out = both.net(state)
    drive, pan = out[:, : GAZE.n_drive].exp().sum(-1), out[:, GAZE.n_drive :].exp().sum(-1)
    # each head of the mean of log-probabilities is a normalised geometric mean: <= 1, and
    # exactly 1 for one student twice
    assert torch.all(drive <= 1 + 1e-5) and torch.all(pan <= 1 + 1e-5)
    same = StudentAgent.ensemble([a, a]).net(state)
    torch.testing.assert_close(same, head_log_probs(a.net(state), GAZE))
    torch.testing.assert_close(same[:, GAZE.n_drive :].exp().sum(-1), torch.ones(3))


def test_fit_teaches_the_pan_head_where_to_look() -> None:
    """Two states that differ only in where the camera looks, labelled with the same driving
    and opposite pan targets: the fitted head looks where each label says."""
    net = StudentNet(GAZE, hidden=32)
    data = Dataset.empty(GAZE)
    for pan, look in ((0.5, -0.8), (-0.5, 0.8)):
        for _ in range(20):
            data.add(state_features(gaze_obs(pan), GAZE), encode_action(np.array([0.7, 0.0, look]),
                     GAZE), 1.0)  # fmt: skip
    fit(net, data, DAggerConfig(epochs=80, batch=8), torch.Generator().manual_seed(0))
    for pan, look in ((0.5, -0.8), (-0.5, 0.8)):
        out = net(torch.from_numpy(state_features(gaze_obs(pan), GAZE))[None])[0].detach().numpy()
        assert abs(decode_action(out, GAZE)[2] - look) < 0.1


def test_the_gaze_teacher_labels_pan_targets_and_the_fixed_one_none() -> None:
    """Collected in the gaze env's action (RoverEnv under the pan head, the fused image off
    the turned camera): the gaze teacher turns the camera, and the images follow it."""
    env = WithFusedView(WithPanHead(make_training_env("lidar", "moon", size=FUSED_SIZE,
                                                      pedestrian_mode="crossing")))  # fmt: skip
    try:
        spec = replace(GAZE, image=True, depth_scan=16, history=True, min_speed=-0.6)
        for gaze, turns in (("active", True), ("fixed", False)):
            cfg = DAggerConfig(teacher_sees="camera", teacher_gaze=gaze)
            data = Dataset.empty(spec)
            collect(env, PlannerExpert("moon", teacher_config(cfg)), None, 1.0, 120, data, 7,
                    np.random.default_rng(0))  # fmt: skip
            pans = np.array([t[3] for t in data.targets])
            gazes = np.array([s[spec.state_dim - 3 - spec.range_points - 1] for s in data.states])
            assert (np.abs(pans).max() > 0.2) == turns
            assert (np.abs(gazes).max() > 0.1) == turns  # the camera turned with the labels
    finally:
        env.close()


@pytest.mark.parametrize("gaze, fixed", [("fused-gaze-moon", "fused-moon"),
                                         ("fused-gaze-inspect", "fused-inspect")])
def test_a_gaze_recipe_needs_the_gaze_teacher_that_sees_through_its_camera(
    gaze: str, fixed: str
) -> None:
    recipe = RECIPES[gaze]
    assert recipe.teacher_gaze == "active" and recipe.teacher_sees == "camera"
    assert recipe.problem() is None
    # the pair differs in the camera alone, and drives one scenario
    assert replace(RECIPES[fixed], entry=recipe.entry, teacher_gaze="active") == recipe
    assert zoo.ENTRIES[gaze].env_kwargs == zoo.ENTRIES[fixed].env_kwargs
    assert zoo.ENTRIES[gaze].kind == "fused-gaze" and zoo.ENTRIES[fixed].kind == "fused"
    assert "--teacher-gaze active" in (replace(recipe, teacher_gaze="fixed").problem() or "")
    assert "--teacher-sees camera" in (replace(recipe, teacher_sees="all").problem() or "")
    command = zoo.command(gaze)
    assert command.startswith(f"rover-pair --name distill_{gaze.replace('-', '_')} -- ")


def test_a_gaze_entry_is_distilled_in_two_stages_and_drives_the_gaze_env(tmp_path) -> None:
    """A tiny run of fused-gaze-moon's recipe, stage 2 with a real daemon: the student file
    turns the camera of the entry's env, which is the moon crossing scenario."""
    with tiny_entry("fused-gaze-moon", tmp_path) as (agent, daemon):
        assert agent.spec.gaze and agent.spec.image
        env = zoo.make_env("fused-gaze-moon", rl_obs_name=daemon, slot=0)
        try:
            base = env.unwrapped
            assert base.world_name == "moon" and len(base.sim.pedestrian_positions) == 3
            assert base.pedestrian_mode == "crossing"
            obs, _ = env.reset(seed=zoo.EVAL_SEED_BASE)
            agent.reset()
            for _ in range(5):
                action = agent.act(obs)
                assert action.shape == (3,) and env.action_space.contains(action)
                obs, *_ = env.step(action)
            assert "gaze" in obs
        finally:
            env.close()
    assert math.isfinite(float(agent.act(obs)[2]))
