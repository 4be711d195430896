"""The gaze teacher: the planner expert's camera policy, its camera-restricted
driving through a turned camera, the pan head for envs without one, and the reward option
that charges pedestrians in the rover's heading instead of the image's centre."""

from __future__ import annotations

import json
import math
import uuid
from pathlib import Path

import numpy as np
import pytest
from helpers.daemon import Daemon

from rover_env import RoverEnv
from rover_env.gaze_env import RoverEnvFusedGaze
from rover_env.reward import RewardConfig, heading_center_sum, heatmap_center_sum
from rover_env.simulation import RoverSim
from rover_train.imitation.expert import ExpertConfig, PlannerExpert, in_camera_view
from rover_train.imitation.gaze import GazeConfig
from rover_train.wrappers import WithPanHead

DEG = math.pi / 180.0
# the maze's open south corridor, facing east; the plan runs straight for 2.5 m from here
START, GOAL = (-3.0, -4.0), (3.0, -4.0)
FAR = [(-5.0, 5.0), (-5.5, 5.0), (-4.5, 5.0)]  # pedestrians out of the way (north-west room)
LEFT_BESIDE = (-2.7, -2.85)  # 75 deg left, 1.15 m beside the way: outside the fixed view


def _env(**kw: object) -> WithPanHead:
    return WithPanHead(RoverEnv(world_n="maze", pedestrian_mode="pacing", **kw))


def _pose(env: WithPanHead, pedestrians: list[tuple[float, float]]) -> None:
    env.reset(seed=3, options={"rover_pose": (*START, 0.0), "goal": GOAL})
    for i, (x, y) in enumerate(pedestrians):
        env.unwrapped.sim.place_pedestrian(i, x, y, -math.pi / 2)


def test_camera_teacher_reacts_to_what_the_turned_camera_shows() -> None:
    """``sees="camera"`` follows the pan: a pedestrian beside the way that the camera facing
    ahead misses changes nothing, the same pedestrian with the camera turned to it changes
    the action exactly as it does the all-seeing teacher's."""
    peds = np.array([LEFT_BESIDE])
    x, y = START
    assert not in_camera_view(x, y, 0.0, peds)[0]
    assert in_camera_view(x, y, 0.0, peds, pan=60 * DEG)[0]
    assert not in_camera_view(x, y, 0.0, peds, pan=-60 * DEG)[0]
    camera = PlannerExpert("maze", ExpertConfig(sees="camera"))
    everyone = PlannerExpert("maze", ExpertConfig(sees="all"))
    clear = camera.act(START, 0.0, GOAL, None, time=0.0)
    acts = {}
    for pan in (0.0, 60 * DEG, -60 * DEG):
        camera.reset()
        acts[pan] = camera.act(START, 0.0, GOAL, peds, time=0.0, pan=pan)
    seen = everyone.act(START, 0.0, GOAL, peds, time=0.0)
    assert not np.allclose(seen, clear)  # this pedestrian matters to a teacher that sees it
    np.testing.assert_allclose(acts[0.0], clear)
    np.testing.assert_allclose(acts[-60 * DEG], clear)
    np.testing.assert_allclose(acts[60 * DEG], seen)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_gaze_teacher_turns_to_a_pedestrian_beside_its_path(side: float) -> None:
    """A pedestrian standing beside the way, outside the fixed camera's view: the gaze
    teacher's pan target turns towards it (left for one on the left, right for one on the
    right), and driving on, its camera shows it; the fixed teacher's never does."""
    px, py = LEFT_BESIDE[0], START[1] + side * (LEFT_BESIDE[1] - START[1])
    seen_by: dict[str, list[bool]] = {}
    for gaze in ("fixed", "active"):
        env = _env()
        try:
            _pose(env, [(px, py), *FAR[1:]])
            expert = PlannerExpert("maze", ExpertConfig(sees="camera", gaze=gaze))
            sim = env.unwrapped.sim
            assert not sim.pedestrians_in_view()[0]
            action = expert.act_env(env)
            assert action.shape == (3,)
            if gaze == "active":
                assert expert.gaze.reason == "pedestrian" and expert.gaze.focus == 0
                assert side * action[2] > 20 * DEG
            else:
                assert action[2] == 0.0
            seen = []
            for _ in range(12):
                *_, info = env.step(expert.act_env(env))
                seen.append(info["nearest_pedestrian_in_view"])
            seen_by[gaze] = seen
        finally:
            env.close()
    assert not any(seen_by["fixed"])
    assert any(seen_by["active"][:8])  # the servo turns 9 deg a step


def test_with_nobody_at_risk_it_looks_where_the_path_turns_else_it_scans() -> None:
    expert = PlannerExpert("maze", ExpertConfig(sees="camera", gaze="active"))
    cfg = expert.gaze.config
    # 0.5 m before the wall the plan turns north (left) round it
    action = expert.act_gaze((0.5, -4.0), 0.0, GOAL, np.array(FAR), 0.0, 0.0)
    assert expert.gaze.reason == "path" and action[2] > cfg.path_turn
    # a straight way ahead: a slow sweep from side to side, from where the camera is
    expert.reset()
    pan, pans = 0.0, []
    for k in range(100):  # 5 s
        pan = float(expert.act_gaze(START, 0.0, GOAL, np.array(FAR), 0.05 * k, pan)[2])
        assert expert.gaze.reason == "scan"
        pans.append(pan)
    steps = np.abs(np.diff(pans))
    assert steps.max() <= cfg.scan_rate * 0.05 + 1e-6 and steps.mean() > 0.5 * cfg.scan_rate * 0.05
    assert max(pans) == pytest.approx(cfg.scan_amplitude)
    assert min(pans) == pytest.approx(-cfg.scan_amplitude)
    # the fixed teacher's camera stays ahead; a plain env gets the 2-value action
    fixed = PlannerExpert("maze", ExpertConfig(sees="camera"))
    assert fixed.act_gaze((0.5, -4.0), 0.0, GOAL, np.array(FAR), 0.0, 0.0)[2] == 0.0
    env = RoverEnv(world_n="maze", pedestrian_mode="pacing")
    try:
        env.reset(seed=0)
        assert expert.act_env(env).shape == (2,)
    finally:
        env.close()
    with pytest.raises(ValueError, match="gaze"):
        ExpertConfig(gaze="wander")
    assert GazeConfig().pan_limit == pytest.approx(60 * DEG)


def test_pan_head_turns_the_camera_as_the_gaze_env_does() -> None:
    """WithPanHead: the camera turns towards the target at 180 deg/s (9 deg a step), the
    target is clipped to +-60 deg, ``gaze`` reports the pan, and every reset faces ahead."""
    env = _env()
    try:
        obs, info = env.reset(seed=1)
        assert obs["gaze"][0] == 0.0 and info["pan"] == 0.0
        for k in range(1, 9):
            obs, *_, info = env.step(np.array([0.0, 0.0, 2.0], np.float32))
            assert info["pan"] == pytest.approx(min(9 * k, 60) * DEG)
            assert info["pan_target"] == pytest.approx(60 * DEG)
            assert obs["gaze"][0] == pytest.approx(info["pan"])
        assert env.unwrapped.sim.camera_heading == pytest.approx(
            env.unwrapped.orientation[2] + 60 * DEG, abs=1e-3
        )
        assert env.steps == 8
        obs, info = env.reset(seed=1)
        assert obs["gaze"][0] == 0.0 and env.unwrapped.sim.camera_pan == 0.0 and env.steps == 0
        with pytest.raises(ValueError, match="3 finite"):
            env.step(np.zeros(2, np.float32))
    finally:
        env.close()


# --- the reward option ----------------------------------------------------------------------
def test_heading_center_sum_matches_the_rendered_pedestrian_mask() -> None:
    """heading_center_sum against the true pedestrian mask's centre columns with the camera
    facing ahead: the same order for a pedestrian 2-4 m ahead, 0 for one beside or behind."""
    sim = RoverSim("maze", pedestrian_mode="pacing")
    try:
        sim.set_rover_pose(0.0, 0.0, 0.0)
        for i in range(sim.pedestrians.n):
            sim.place_pedestrian(i, -4.0 - i, -4.0, 0.0)
        ratios = []
        for ahead, left in ((2.0, 0.0), (3.0, 0.1), (4.0, -0.1)):
            sim.place_pedestrian(0, ahead, left, math.pi)
            mask = sim.render_camera(segmentation=True).pedestrian_mask
            assert mask is not None
            truth = heatmap_center_sum(mask.astype(np.float32))
            model = heading_center_sum(0.0, 0.0, 0.0, sim.pedestrian_positions)
            assert truth > 20.0
            ratios.append(model / truth)
        assert 0.6 < min(ratios) and max(ratios) < 1.7, ratios
        for x, y in ((2.0, 1.0), (-2.0, 0.0), (0.0, 2.0)):
            assert heading_center_sum(0.0, 0.0, 0.0, np.array([[x, y]])) == 0.0
        # the rover's heading, not the world's x axis: the same pedestrian seen turned
        assert heading_center_sum(0.0, 0.0, math.pi / 2, np.array([[0.0, 3.0]])) == (
            pytest.approx(heading_center_sum(0.0, 0.0, 0.0, np.array([[3.0, 0.0]])))
        )
    finally:
        sim.close()
    with pytest.raises(ValueError, match="pedestrian_penalty_frame"):
        RewardConfig(pedestrian_penalty_frame="camera")


def test_looking_away_lowers_the_seed_penalty_but_not_the_heading_one() -> None:
    """A pedestrian stands 2 m ahead in the rover's way. The seed's heatmap penalty (image
    frame) falls to almost nothing when the camera turns 60 deg away; with
    ``pedestrian_penalty_frame="heading"`` it stays what it was."""
    daemon = Daemon(f"test_gazeteach_{uuid.uuid4().hex[:8]}").start()
    penalties: dict[str, dict[float, float]] = {}
    try:
        for frame in ("image", "heading"):
            config = RewardConfig.fused(pedestrian_penalty_frame=frame)
            with RoverEnvFusedGaze(world_n="maze", pedestrian_mode="pacing", pan_rate=None,
                                   rl_obs_name=daemon.name, connection_check_timeout=20,
                                   reward_config=config) as env:  # fmt: skip
                env.reset(seed=1, options={"rover_pose": (0.0, 0.0, 0.0), "goal": (-3.0, 3.0)})
                for i in range(env.sim.pedestrians.n):
                    env.sim.place_pedestrian(i, -4.0 - i, -4.0, 0.0)
                env.sim.place_pedestrian(0, 2.0, 0.0, math.pi)
                penalties[frame] = {}
                for pan in (0.0, math.pi / 3, 0.0, -math.pi / 3):
                    *_, info = env.step(np.array([0.0, 0.0, pan], np.float32))
                    penalties[frame][pan] = info["reward_heatmap"]
    finally:
        daemon.stop()
        daemon.remove_leftovers()
    image, heading = penalties["image"], penalties["heading"]
    assert image[0.0] < -1.0
    assert abs(image[math.pi / 3]) < 0.2 * abs(image[0.0])
    assert abs(image[-math.pi / 3]) < 0.2 * abs(image[0.0])
    assert heading[0.0] < -1.0
    assert heading[math.pi / 3] == pytest.approx(heading[0.0], rel=0.02)
    assert heading[-math.pi / 3] == pytest.approx(heading[0.0], rel=0.02)
    # the same order as the seed's term when the camera looks ahead
    assert 0.2 < heading[0.0] / image[0.0] < 5.0


def test_gaze_value_reports_every_teacher_with_intervals() -> None:
    """rover_train.imitation.gaze_value (benchmarks/gaze_value.py's rows), shortened: one row
    per teacher, each figure inside its interval, and the paired difference of the same
    episodes."""
    from rover_env.scenarios import select_scenarios
    from rover_train.imitation.gaze_value import TEACHERS, compare
    from rover_train.zoo import EVAL_SEED_BASE

    c = compare(select_scenarios("inspect-crowd-3")[0], episodes=2, seed=EVAL_SEED_BASE,
                max_steps=40)  # fmt: skip
    report = json.loads(json.dumps(c.report(), default=float))
    assert list(report["rows"]) == list(TEACHERS)
    for row in report["rows"].values():
        assert row["episodes"] == 2 and 0 < row["steps"] <= 80
        for key in ("success", "pedestrian_collisions", "intrusion", "nearest_in_view"):
            value, lo, hi = row[key]
            assert lo - 1e-9 <= value <= hi + 1e-9 and 0.0 <= lo and hi <= 1.0
    assert set(report["gaze_minus_fixed"]) == {"success", "pedestrian_collisions",
                                               "nearest_in_view"}  # fmt: skip
    assert report["gaze_student_minus_fixed_student"] is None
    for row in report["rows"].values():  # the diagnostic counts the episodes with a contact
        never, contacts = row["contacts_never_in_view"]
        assert 0 <= never <= contacts <= 2
    two = compare(select_scenarios("inspect-crowd-3")[0], episodes=2, seed=EVAL_SEED_BASE,
                  max_steps=10, teachers=("fixed teacher", "gaze teacher"))  # fmt: skip
    assert [label for label, _ in two.rows] == ["fixed teacher", "gaze teacher"]
    with pytest.raises(ValueError, match="unknown teacher row"):
        compare(select_scenarios("inspect-crowd-3")[0], episodes=2, seed=EVAL_SEED_BASE,
                max_steps=10, teachers=("psychic teacher",))  # fmt: skip


def test_gaze_value_holds_a_gaze_students_camera_ahead_only_when_asked() -> None:
    """hold_camera overrules the gaze student's pan target (0: ahead) and nothing else;
    without a gaze student it is refused with the fix."""
    from rover_env.scenarios import select_scenarios
    from rover_train.imitation.gaze_value import compare, make_env, student_act, student_path

    path = student_path("fused-gaze-moon")
    env = make_env(select_scenarios("moon-crossing-3")[0], 40, fused_view=True)
    try:
        looking, held = student_act(path, True), student_act(path, True, hold_camera=True)
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            looking[0](), held[0]()  # each agent from its own reset, the same observation
            a, b = looking[1](obs), held[1](obs)
            assert b[2] == 0.0 and np.array_equal(a[:2], b[:2])
            obs = env.step(a)[0]
    finally:
        env.close()
    with pytest.raises(ValueError, match="give student_gaze"):
        compare(select_scenarios("moon-crossing-3")[0], 2, 0, 40, hold_camera=True)


def test_gaze_value_clips_both_students_where_the_gaze_one_sees_more(tmp_path: Path) -> None:
    """The clip's episode is the one the gaze student finished seeing the nearest pedestrian
    most more often; the clip stacks both students' frames; without both students it is
    refused."""
    from PIL import Image

    from rover_env.scenarios import select_scenarios
    from rover_train.evaluate import EpisodeResult
    from rover_train.imitation.gaze_value import Episode, clip_episode, student_path, write_clip

    def episode(success: bool, steps: int, seen: int) -> Episode:
        result = EpisodeResult(success=success, collided=False, timeout=not success,
                               termination="goal" if success else "timeout", path_length=1.0,
                               start_distance=1.0, time_to_goal=1.0 if success else None,
                               steps=steps, intrusion_steps=0, min_ped_distance=2.0,
                               ret=0.0)  # fmt: skip
        return Episode(result, seen)

    students = {"gaze student": "g", "fixed student": "f"}
    results = {
        "g": [episode(True, 100, 30), episode(False, 100, 90), episode(True, 100, 60)],
        "f": [episode(True, 100, 20), episode(True, 100, 10), episode(True, 100, 20)],
    }
    assert clip_episode(results, students) == 2  # episode 1 gains most, but did not finish

    out = tmp_path / "clip.gif"
    line = write_clip(select_scenarios("moon-crossing-3")[0],
                      {"gaze student": (student_path("fused-gaze-moon"), True),
                       "fixed student": (student_path("fused-moon"), False)},
                      seed=0, max_steps=12, path=out, lead=2, length=8)  # fmt: skip
    assert str(out) in line
    with Image.open(out) as gif:
        # 8 steps, every other one (Pillow may merge identical frames); two 128-px strips
        assert 2 <= gif.n_frames <= 4 and gif.size[1] == 2 * 128
    with pytest.raises(ValueError, match="both students: no fixed student"):
        clip_episode({"g": results["g"]}, {"gaze student": "g"})
