"""PPO from a distilled student (issue 38, item 3): ``rover_train.imitation.finetune``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from rover_train import zoo
from rover_train.imitation.finetune import (
    FineTuner,
    FineTuneRecipe,
    FineTuneRun,
    StudentInterface,
    _make_env,
    advantages,
    finetune,
    main,
    ppo_losses,
    read_recipe,
)
from rover_train.zoo.agent import (
    SPEED_LEVELS,
    action_classes,
    class_action,
    encode_action,
    state_features,
)

TINY = FineTuneRecipe(start="lidar-maze", timesteps=128, envs=1, n_steps=64, epochs=1,
                      minibatch=32, value_warmup=1)  # fmt: skip


def _spec():
    agent = zoo.load("lidar-maze")
    assert isinstance(agent, zoo.StudentAgent)
    return agent.spec


def test_each_class_is_driven_as_the_action_of_that_class() -> None:
    spec = _spec()
    actions = np.stack([class_action(k, spec) for k in range(spec.n_outputs)])
    targets = torch.as_tensor(np.stack([encode_action(a, spec) for a in actions]))
    assert action_classes(targets).tolist() == list(range(spec.n_outputs))
    assert actions[:, 0].min() >= spec.min_speed and actions[:, 0].max() <= spec.max_speed
    with pytest.raises(ValueError, match="outside the head's"):
        class_action(len(SPEED_LEVELS) * 32, spec)


def test_the_interface_shows_the_students_features_and_takes_its_classes() -> None:
    spec = _spec()
    env = _make_env(TINY, spec)
    try:
        assert isinstance(env, StudentInterface)
        assert env.action_space.n == spec.n_outputs
        assert env.unwrapped.reward_config.collision_limit == 0  # the nav task's
        obs, _ = env.reset(seed=3)
        assert obs.shape == (spec.state_dim,) and env.observation_space.contains(obs)
        raw = env.env.unwrapped._observe()  # what the student would compute from itself
        agent = zoo.load("lidar-maze")
        agent.reset()
        assert np.allclose(obs, state_features(raw, spec, agent.history), atol=1e-6)
        x0 = env.unwrapped.position.copy()
        forward = 8 * 32 + 16  # full speed, the bin just left of straight ahead
        for _ in range(10):
            env.step(forward)
        assert np.linalg.norm(env.unwrapped.position[:2] - x0[:2]) > 0.2  # it drove
    finally:
        env.close()


def test_gae_matches_a_hand_computation() -> None:
    rewards = np.array([[1.0], [0.0], [2.0]], np.float32)
    values = np.array([[0.5], [0.2], [1.0]], np.float32)
    dones = np.array([[0.0], [1.0], [0.0]], np.float32)  # the episode ends at step 1
    last = np.array([3.0], np.float32)
    g, lam = 0.9, 0.8
    d2 = 2.0 + g * 3.0 - 1.0
    d1 = 0.0 - 0.2  # ended: no bootstrap, and nothing flows back across the end
    d0 = 1.0 + g * 0.2 - 0.5
    expected = np.array([[d0 + g * lam * d1], [d1], [d2]])
    assert np.allclose(advantages(rewards, values, dones, last, g, lam), expected)


def test_the_kl_term_is_zero_at_the_start_and_grows_as_the_actor_moves() -> None:
    agent = zoo.load("lidar-maze")
    assert isinstance(agent, zoo.StudentAgent)
    spec = agent.spec
    import copy

    start = copy.deepcopy(agent.net).eval()
    net = copy.deepcopy(agent.net)
    critic = torch.nn.Linear(spec.state_dim, 1)
    gen = torch.Generator().manual_seed(0)
    obs = torch.randn(64, spec.state_dim, generator=gen) * 0.3
    batch = {"obs": obs, "actions": torch.zeros(64, dtype=torch.long),
             "logp": torch.zeros(64), "advantages": torch.randn(64, generator=gen),
             "returns": torch.zeros(64)}  # fmt: skip
    kl_at_start = ppo_losses(net, critic, start, batch, 0.1, 1.0)["kl"].item()
    assert kl_at_start == pytest.approx(0, abs=1e-5)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=gen))
    losses = ppo_losses(net, critic, start, batch, 0.1, 1.0)
    assert losses["kl"].item() > 0.01
    assert losses["total"].item() == pytest.approx((losses["policy"] + losses["kl"]).item())


def test_recipe_problems_are_named() -> None:
    assert TINY.problem() is None
    assert "less than one rollout" in replace(TINY, timesteps=10).problem()
    assert "--kl-end" in replace(TINY, kl_end=2.0).problem()
    assert "diagnostic seeds" in replace(TINY, seed=60).problem()
    assert TINY.beta(0) == TINY.kl_start
    assert TINY.beta(TINY.timesteps) == pytest.approx(TINY.kl_end)


@pytest.fixture(scope="module")
def tuned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, FineTuneRun]:
    out = tmp_path_factory.mktemp("ft") / "tuned.pt"
    run = FineTuneRun(out=out)
    finetune(TINY, run)
    return out, run


def test_a_run_writes_a_student_the_zoo_loads_with_its_recipe(tuned) -> None:
    out, run = tuned
    agent = zoo.load("lidar-maze-rl", out)
    assert isinstance(agent, zoo.StudentAgent)
    assert read_recipe(out) == TINY
    assert agent.meta["finetune"]["steps"] == TINY.timesteps
    rows = (run.run_dir / "progress.csv").read_text().splitlines()
    assert rows[0].startswith("steps,") and len(rows) == 1 + TINY.timesteps // 64
    env = zoo.make_env("lidar-maze-rl")
    try:
        obs, _ = env.reset(seed=0)
        assert env.action_space.contains(agent.act(obs))
    finally:
        env.close()


def test_the_critic_alone_learns_during_the_warmup(tuned) -> None:
    tuner = FineTuner(replace(TINY, timesteps=64), FineTuneRun(out=tuned[0].with_name("w.pt")))
    try:
        actor = list(tuner.net.parameters())
        before = [p.detach().clone() for p in actor]
        critic_before = [p.detach().clone() for p in tuner.critic.parameters()]
        batch, _ = tuner.collect()
        tuner.update(batch, critic_only=True)
        assert all(torch.equal(a, b) for a, b in zip(before, actor, strict=True))
        critic_now = tuner.critic.parameters()
        assert not all(torch.equal(a, b) for a, b in zip(critic_before, critic_now, strict=True))
        tuner.update(batch, critic_only=False)
        assert not all(torch.equal(a, b) for a, b in zip(before, actor, strict=True))
    finally:
        tuner.close()


def test_resume_goes_on_to_more_steps_and_refuses_another_recipe(tmp_path: Path) -> None:
    run = FineTuneRun(out=tmp_path / "tuned.pt")
    finetune(TINY, run)
    with pytest.raises(ValueError, match="another recipe"):
        finetune(replace(TINY, learning_rate=1e-3), replace(run, resume=True))
    with pytest.raises(ValueError, match="past --timesteps"):
        finetune(replace(TINY, timesteps=64), replace(run, resume=True))
    out = str(run.out)
    assert main(["--recipe", out, "--out", out, "--resume"]) == 0  # the same steps: done
    blob = torch.load(run.run_dir / "checkpoint.pt", weights_only=False)
    assert blob["steps"] == TINY.timesteps and blob["rollouts"] == 2  # no rollout was added
    assert main(["--recipe", out, "--out", out, "--resume", "--timesteps", "192"]) == 0
    blob = torch.load(run.run_dir / "checkpoint.pt", weights_only=False)
    assert blob["steps"] == 192 and blob["rollouts"] == 3  # one more rollout, from the last
    assert read_recipe(run.out).timesteps == 192
    assert len((run.run_dir / "progress.csv").read_text().splitlines()) == 1 + 3
    with pytest.raises(FileNotFoundError, match="no checkpoint.pt"):
        finetune(TINY, FineTuneRun(out=tmp_path / "other.pt", resume=True))


def test_the_zoo_names_the_command_that_remakes_it(tuned) -> None:
    spec = zoo.ENTRIES["lidar-maze-rl"]
    assert spec.trainer == zoo.FINETUNE and spec.start == "lidar-maze"
    if spec.path.is_file():
        assert zoo.command("lidar-maze-rl").endswith(
            f"--recipe {zoo.shown_path(spec.path)} --out {zoo.shown_path(spec.path)}"
        )
    else:
        assert "--start lidar-maze" in zoo.command("lidar-maze-rl")
