"""PPO from a distilled student: ``rover_train.imitation.finetune``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from rover_train import zoo
from rover_train.imitation.finetune import (
    IMAGE_VALUES,
    FineTuner,
    FineTuneRecipe,
    FineTuneRun,
    StudentInterface,
    _make_env,
    action_log_prob,
    advantages,
    finetune,
    head_log_probs_of,
    main,
    ppo_losses,
    read_recipe,
)
from rover_train.zoo.agent import (
    PAN_ANGLES,
    PAN_BINS,
    SPEED_LEVELS,
    action_classes,
    class_action,
    encode_action,
    head_log_probs,
    image_features,
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


# --- fused and gaze students: the fused image computed in the worker, the pan head learnt ---

GAZE_TINY = FineTuneRecipe(start="fused-gaze-moon", timesteps=128, envs=1, n_steps=64,
                           epochs=1, minibatch=32, value_warmup=1)  # fmt: skip


def test_a_recipe_trains_among_its_start_entrys_pedestrians_unless_told() -> None:
    assert GAZE_TINY.env_kwargs() == {"world": "moon", "pedestrian_mode": "crossing",
                                      "n_pedestrians": 3}  # fmt: skip
    told = replace(GAZE_TINY, pedestrian_mode="crowd", n_pedestrians=10)
    assert told.env_kwargs() == {"world": "moon", "pedestrian_mode": "crowd", "n_pedestrians": 10}
    assert TINY.env_kwargs()["world"] == "maze"
    assert "--n-pedestrians must be 0 to 20" in replace(TINY, n_pedestrians=21).problem()


def test_a_gaze_student_sees_its_image_and_turns_the_camera_by_its_pan_class() -> None:
    agent = zoo.load("fused-gaze-moon")
    assert isinstance(agent, zoo.StudentAgent)
    spec = agent.spec
    env = _make_env(GAZE_TINY, spec)
    try:
        assert isinstance(env, StudentInterface)
        assert list(env.action_space.nvec) == [spec.n_drive, PAN_BINS]
        obs, _ = env.reset(seed=5)
        assert obs.shape == (spec.state_dim + IMAGE_VALUES,)
        # what the student computes from the env's own observation, rebuilt by hand
        fused_view, pan_head = env.env, env.env.env
        raw = fused_view.observation(pan_head._observation(env.unwrapped._observe()))
        agent.reset()
        state = state_features(raw, spec, agent.history)
        assert np.allclose(obs[: spec.state_dim], state, atol=1e-6)
        assert np.array_equal(obs[spec.state_dim :], image_features(raw).ravel())
        # the flat observation gives the network what StudentAgent.act gives it
        flat = torch.as_tensor(obs)[None]
        expected = head_log_probs(
            agent.net(torch.as_tensor(state)[None], torch.as_tensor(image_features(raw))[None]),
            spec,
        )
        heads = head_log_probs_of(agent.net, flat)
        assert torch.allclose(torch.cat(heads, dim=1), expected, atol=1e-5)
        assert np.array_equal(env.env_action([3, 0])[:2], class_action(3, spec))
        assert env.env_action([3, 0])[2] == pytest.approx(PAN_ANGLES[0])
        for _ in range(15):  # stand still, pan class 0: the camera turns to the left limit
            _, _, term, trunc, info = env.step([2 * 32 + 16, 0])
            assert not (term or trunc)
        assert info["pan"] == pytest.approx(PAN_ANGLES[0], abs=1e-3)
        with pytest.raises(ValueError, match="outside the pan head"):
            env.step([0, PAN_BINS])
    finally:
        env.close()


def test_a_lidar_students_interface_refuses_a_fused_student() -> None:
    from rover_train.envs import make_env

    spec = zoo.load("fused-moon").spec
    env = make_env("lidar", world="moon", env_checker=False)
    try:
        with pytest.raises(ValueError, match="'fused_image'.*_make_env"):
            StudentInterface(env, spec)
    finally:
        env.close()


def test_the_log_probability_of_a_pair_is_the_sum_over_the_heads() -> None:
    gen = torch.Generator().manual_seed(1)
    drive = torch.randn(4, 6, generator=gen).log_softmax(dim=1)
    pan = torch.randn(4, 3, generator=gen).log_softmax(dim=1)
    actions = torch.tensor([[0, 2], [5, 1], [3, 0], [1, 1]])
    got = action_log_prob([drive, pan], actions)
    want = torch.stack([drive[i, a] + pan[i, b] for i, (a, b) in enumerate(actions.tolist())])
    assert torch.allclose(got, want)
    assert torch.allclose(
        action_log_prob([drive], actions[:, 0]), drive.gather(1, actions[:, :1])[:, 0]
    )


def test_both_heads_of_a_gaze_student_count_in_the_kl_term() -> None:
    import copy

    agent = zoo.load("fused-gaze-moon")
    spec = agent.spec
    start = copy.deepcopy(agent.net).eval()
    net = copy.deepcopy(agent.net)
    gen = torch.Generator().manual_seed(0)
    n = 16
    state = torch.randn(n, spec.state_dim, generator=gen) * 0.3
    image = torch.randint(0, 256, (n, IMAGE_VALUES), generator=gen).float()
    batch = {"obs": torch.cat([state, image], dim=1),
             "actions": torch.zeros(n, 2, dtype=torch.long), "logp": torch.zeros(n),
             "advantages": torch.randn(n, generator=gen), "returns": torch.zeros(n)}  # fmt: skip
    critic = torch.nn.Linear(spec.state_dim, 1)
    assert ppo_losses(net, critic, start, batch, 0.1, 1.0)["kl"].item() == pytest.approx(
        0, abs=1e-5
    )
    with torch.no_grad():  # move the pan head alone: the KL must see it
        net.out.weight[spec.n_drive :] += 0.5 * torch.randn(
            PAN_BINS, net.out.weight.shape[1], generator=gen
        )
    assert ppo_losses(net, critic, start, batch, 0.1, 1.0)["kl"].item() > 0.01


def test_a_fine_tuned_gaze_student_is_a_gaze_student_of_its_entry(tmp_path: Path) -> None:
    out = tmp_path / "gaze.pt"
    finetune(GAZE_TINY, FineTuneRun(out=out))
    agent = zoo.load("fused-gaze-moon", out)
    assert isinstance(agent, zoo.StudentAgent) and agent.spec.gaze and agent.spec.image
    assert agent.meta["kind"] == "fused-gaze" and agent.meta["name"] == "fused-gaze-moon-rl"
    assert read_recipe(out) == GAZE_TINY
    # its recipe (pedestrians: the start entry's) goes through the command line again
    assert main(["--recipe", str(out), "--out", str(out), "--resume"]) == 0
    env = _make_env(GAZE_TINY, agent.spec).env  # the dict observations the agent acts on
    try:
        obs, _ = env.reset(seed=0)
        action = agent.act(obs)
        assert action.shape == (3,) and env.action_space.contains(action)
    finally:
        env.close()


def test_each_shipped_fine_tune_is_its_start_entrys_kind_and_remakes_from_its_file() -> None:
    shipped = [n for n in zoo.names() if zoo.ENTRIES[n].trainer == zoo.FINETUNE]
    assert {"fused-moon-rl", "fused-gaze-moon-rl"} <= set(shipped)
    for name in shipped:
        spec = zoo.ENTRIES[name]
        recipe = read_recipe(spec.path)
        assert recipe.start == spec.start and recipe.problem() is None
        start = zoo.ENTRIES[spec.start]
        assert (spec.kind, spec.world, spec.env_kwargs) == (start.kind, start.world,
                                                            start.env_kwargs)  # fmt: skip
        agent = zoo.load(name)
        assert agent.meta["kind"] == spec.kind and agent.spec == zoo.load(spec.start).spec
        assert agent.meta["finetune"]["steps"] >= recipe.timesteps
        path = zoo.shown_path(spec.path)
        assert zoo.command(name) == (
            f"python -m rover_train.imitation.finetune --recipe {path} --out {path}"
        )
