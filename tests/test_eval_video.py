"""rover-eval's and the demo's video frames: four labelled panels (chase, gray, heatmap,
depth) of 1024x256, the step, the distance and the goal's direction on every frame, and the
episode's outcome on its last frames only (held OUTCOME_HOLD_S)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from rover_train import evaluate
from rover_train.envs import make_env
from rover_train.evaluate import (
    OUTCOME_HOLD_S,
    VIDEO_PANEL,
    EpisodeResult,
    draw_outcome,
    episode_outcome,
    label_frame,
    run_episode,
)

STEPS = 6
TIMEOUT_RGB = (200, 110, 0)  # draw_outcome's banner colour for a timeout


class _FakeFused(gym.ObservationWrapper):
    """A LIDAR env whose observations also carry a ``fused_image`` (no daemon needed), so
    that frames have all four panels."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng(0)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        return {**obs, "fused_image": self.rng.random((96, 96, 3), dtype=np.float32)}


@pytest.fixture()
def env() -> Iterator[gym.Env]:
    e = _FakeFused(make_env("lidar", world="maze", render_mode="rgb_array"))
    try:
        yield e
    finally:
        e.close()


def _banner(frame: np.ndarray) -> np.ndarray:
    """The left end of the outcome banner's band (no text there)."""
    return frame[VIDEO_PANEL // 2 - 20 : VIDEO_PANEL // 2 - 14, 0:6].reshape(-1, 3)


def test_frames_are_labelled_and_the_outcome_only_ends_the_episode(
    env: gym.Env, monkeypatch: pytest.MonkeyPatch
) -> None:
    raw: list[np.ndarray] = []
    compose = evaluate._video_frame

    def keep_raw(e: Any, obs: Any) -> np.ndarray:
        frame = compose(e, obs)
        raw.append(frame.copy())
        return frame

    monkeypatch.setattr(evaluate, "_video_frame", keep_raw)
    frames: list[np.ndarray] = []
    env.action_space.seed(0)
    result = run_episode(env, lambda _obs: np.zeros(2, np.float32), 100000, STEPS, frames)
    assert result.timeout and result.steps == STEPS == len(raw)
    hold = round(OUTCOME_HOLD_S / float(env.unwrapped.control_dt))
    assert len(frames) == STEPS - 1 + hold
    assert all(f.shape == (VIDEO_PANEL, 4 * VIDEO_PANEL, 3) for f in frames)

    for labelled, plain in zip(frames, raw, strict=False):  # frames also holds the end
        # every panel's name is drawn at its top left, the step and distance at the bottom
        # left of the chase view, the goal arrow at its top right
        for i in range(4):
            x = i * VIDEO_PANEL
            assert not np.array_equal(labelled[:20, x : x + 40], plain[:20, x : x + 40]), i
        assert not np.array_equal(labelled[-20:, :120], plain[-20:, :120])
        assert not np.array_equal(labelled[20:60, -60 + VIDEO_PANEL : VIDEO_PANEL],
                                  plain[20:60, -60 + VIDEO_PANEL : VIDEO_PANEL])  # fmt: skip
        # and the picture between the labels is the composition's
        middle = slice(30, VIDEO_PANEL - 30)
        fused = slice(VIDEO_PANEL + 10, None)
        assert np.array_equal(labelled[middle, fused], plain[middle, fused])

    # the outcome (a timeout here) is on the last frame, held, and on no earlier one
    ends = [bool((_banner(f) == TIMEOUT_RGB).all()) for f in frames]
    assert ends == [False] * (STEPS - 1) + [True] * hold
    assert all(np.array_equal(f, frames[-1]) for f in frames[-hold:])


def test_label_frame_draws_text_and_arrow_towards_the_goal() -> None:
    plain = np.full((VIDEO_PANEL, 4 * VIDEO_PANEL, 3), 128, np.uint8)
    ahead = label_frame(plain.copy(), 7, 3.25, 0.0)
    left = label_frame(plain.copy(), 7, 3.25, np.pi / 2)
    assert not np.array_equal(ahead, plain)
    # only the arrow differs between the two: the goal ahead, the goal to the left
    diff = np.argwhere((ahead != left).any(axis=2))
    assert len(diff) and diff[:, 1].min() > VIDEO_PANEL - 50 and diff[:, 0].max() < 60
    collided = label_frame(plain.copy(), 7, 3.25, 0.0, collision=True)
    assert not np.array_equal(collided, ahead)
    # the outcome banner is drawn on a copy
    again = ahead.copy()
    done = draw_outcome(ahead, "success")
    assert not np.array_equal(done, ahead) and np.array_equal(ahead, again)


@pytest.mark.parametrize(
    ("success", "collided", "termination", "words"),
    [
        (True, False, "goal", "success"),
        (True, True, "goal", "success (collided)"),
        (False, False, "timeout", "timeout"),
        (False, True, "length", "timeout (collided)"),
        (False, True, "stuck_in_collision", "collision"),
        (False, False, "out_of_bounds", "out of bounds"),
    ],
)
def test_episode_outcome(success: bool, collided: bool, termination: str, words: str) -> None:
    r = EpisodeResult(success=success, collided=collided,
                      timeout=termination in ("timeout", "length"), termination=termination,
                      path_length=1.0, start_distance=1.0, time_to_goal=None, steps=1,
                      intrusion_steps=0, min_ped_distance=np.inf, ret=0.0)  # fmt: skip
    assert episode_outcome(r) == words
