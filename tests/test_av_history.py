"""Episode boundaries across the wire and the daemon's per-slot history (real processes).

The env marks each episode's first camera frame (trailer flag ``FLAG_EPISODE_START``); the
daemon clears that slot's K-frame history on it. In ``--heatmap predict`` mode channel 1 is
a function of the whole window, so a history that leaked across episodes, slots or a
daemon restart would change the fused images these tests compare bit for bit. The
predictor here is an untrained (seeded) PredictNet: its outputs depend on every frame of
the window, which is all these tests need.
"""

from __future__ import annotations

import dataclasses
import signal
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.daemon import Daemon

from active_vision.history import SlotHistory
from active_vision.predict import K, PredictNet, save_predictor
from rover_env.fused_env import RoverEnvFused
from shm_protocol import FrameReader, FrameTimeoutError, FrameWriter, WriterGoneError

ACTIONS = [np.array([0.8, 0.3 * np.sin(i)], np.float32) for i in range(12)]


def test_slot_history_pads_clears_and_keeps_slots_apart() -> None:
    h = SlotHistory(2, 3, (2,))
    with pytest.raises(ValueError, match="no frame"):
        h.window(0)
    h.push(0, np.array([1.0, 1.0]))
    np.testing.assert_array_equal(h.window(0)[:, 0], [1, 1, 1])  # oldest repeated
    for v in (2.0, 3.0, 4.0):
        h.push(0, np.array([v, v]))
    np.testing.assert_array_equal(h.window(0)[:, 0], [2, 3, 4])  # the last 3, oldest first
    h.push(1, np.array([9.0, 9.0]))
    np.testing.assert_array_equal(h.window(0)[:, 0], [2, 3, 4])  # slot 1 never mixes in
    h.push(0, np.array([5.0, 5.0]), episode_start=True)
    np.testing.assert_array_equal(h.window(0)[:, 0], [5, 5, 5])
    assert h.count(0) == 1 and h.count(1) == 1


def test_episode_start_flag_belongs_to_its_frame(shm_name: str) -> None:
    frame = np.zeros((4, 4, 3), np.uint8)
    w = FrameWriter(shm_name, shape=(4, 4, 3), dtype=np.uint8)
    try:
        _marks(w, FrameReader(shm_name), frame)
    finally:
        w.close(unlink=True)


def _marks(w: FrameWriter, r: FrameReader, frame: np.ndarray) -> None:
    with r:
        w.publish(frame, episode_start=True)
        assert r.wait_next(timeout=1.0).episode_start
        w.publish(frame)
        assert not r.wait_next(timeout=1.0).episode_start  # cleared by the next publish
        w.publish(frame, episode_start=True)
        w.publish(frame)  # a reader that missed the marked frame sees the later one unmarked
        assert not r.wait_next(timeout=1.0).episode_start


@pytest.fixture(scope="module")
def predictor_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    return save_predictor(PredictNet(), tmp_path_factory.mktemp("pred") / "predict.pt")


def _predict_daemon(predictor_file: Path, name: str, slots: int = 1) -> Daemon:
    return Daemon(name, slots=slots,
                  extra_args=("--heatmap", "predict", "--predict-weights", str(predictor_file)))


@pytest.fixture(scope="module")
def daemon(predictor_file: Path) -> Iterator[Daemon]:
    d = _predict_daemon(predictor_file, f"test_hist_{uuid.uuid4().hex[:8]}", slots=2).start()
    yield d
    d.stop()
    d.remove_leftovers()


def _env(name: str, slot: int = 0) -> RoverEnvFused:
    return RoverEnvFused(rl_obs_name=name, slot=slot, world_n="inspect", report_latency=False,
                         connection_check_timeout=10, frame_timeout=5.0)


def _episode(env: RoverEnvFused, seed: int, steps: int = len(ACTIONS)) -> list[np.ndarray]:
    obs, _ = env.reset(seed=seed)
    images = [obs["fused_image"]]
    for a in ACTIONS[:steps]:
        obs, *_ = env.step(a)
        images.append(obs["fused_image"])
    return images


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_predict_mode_is_reproducible_per_seed_and_slots_do_not_leak(daemon: Daemon) -> None:
    with _env(daemon.name, 0) as a, _env(daemon.name, 1) as b:
        reference = _episode(a, seed=11)
        # the prediction moves with the window: consecutive heatmaps are not all alike
        assert not all(np.array_equal(reference[0][..., 1], r[..., 1]) for r in reference[1:])
        # slot 1 runs the same episode while slot 0 runs another, steps interleaved
        obs_b, _ = b.reset(seed=11)
        a.reset(seed=12)
        images_b = [obs_b["fused_image"]]
        for act in ACTIONS:
            a.step(-act)
            obs_b, *_ = b.step(act)
            images_b.append(obs_b["fused_image"])
        assert _same(images_b, reference)
        # slot 0 starts seed 11 again right after seed 12's frames: the flag cut them off
        assert _same(_episode(a, seed=11), reference)


def test_daemon_restart_mid_episode_starts_an_empty_history(predictor_file: Path) -> None:
    d = _predict_daemon(predictor_file, f"test_histkill_{uuid.uuid4().hex[:8]}").start()
    try:
        with _env(d.name) as env:
            reference = _episode(env, seed=11)
            obs, _ = env.reset(seed=11)
            for a in ACTIONS[:3]:
                env.step(a)
            d.stop(signal.SIGKILL)
            with pytest.raises((WriterGoneError, FrameTimeoutError)):
                env.step(ACTIONS[3])  # physics advanced; its fused frame never came
            d.start()
            after = [env.step(a)[0]["fused_image"] for a in ACTIONS[4:]]
            first = 5  # reference index of the first frame after the restart
            # right after the restart the window holds only frames the new daemon saw ...
            assert not np.array_equal(after[0], reference[first])
            # ... and once it is refilled with this episode's frames it matches again
            assert _same(after[K:], reference[first + K:])
            # a new episode after the restart is the same episode as before it
            assert _same(_episode(env, seed=11), reference)
    finally:
        d.stop()
        d.remove_leftovers()


def test_preview_shows_the_prediction_beside_the_detection() -> None:
    from active_vision.preview import compose

    camera = np.zeros((96, 96, 3), np.uint8)
    fused = np.zeros((96, 96, 3), np.float32)
    detect = np.ones((96, 96), np.float32)
    assert compose(camera, fused, scale=1).shape == (110, 4 * 96, 3)
    img = compose(camera, fused, scale=1, detect=detect)
    assert img.shape == (110, 5 * 96, 3)
    # the 4th tile is the detection (all ones: bright), the 3rd the prediction (zeros: dark)
    assert img[14:, 3 * 96:4 * 96].mean() > 100 > img[14:, 2 * 96:3 * 96].mean()


def test_predictive_ground_truth_and_baselines_on_driving_sequences() -> None:
    from active_vision.predict import Predictor
    from active_vision.training import predict_train as pt

    data = pt.render_sequences(seed=99, episodes=3)
    assert len(data.target_row) > 10
    # the future occupancy includes every pixel a pedestrian covers now
    assert np.all(data.future[data.now])
    win = pt.windows(data, threads=1)
    assert win.shape == (len(data.target_row), K, 96, 96, 3)
    # the windows are the daemon's: SlotHistory fed the episode's frames up to the target,
    # also near an episode's start, where its first frame is repeated
    fused = pt.fused_frames(data, threads=1)
    early = dataclasses.replace(data, target_row=data.episode_row + 1)
    for d, w in ((data, win), (early, fused[pt.window_rows(early)])):
        hist = SlotHistory(1, K, fused.shape[1:])
        for t, (row, first) in enumerate(zip(d.target_row, d.episode_row, strict=True)):
            hist.clear(0)
            for r in range(max(first, row - K + 1), row + 1):
                hist.push(0, fused[r])
            np.testing.assert_array_equal(w[t], hist.window(0))
    # a window ends with its target's own fused frame, and starts within its episode
    first = data.target_row == data.episode_row + 4
    assert np.all(data.episode_row <= data.target_row)
    torch.manual_seed(0)
    m = pt.evaluate_predictor(Predictor(PredictNet().eval()), data, win)
    for k in ("predict_iou", "detect_baseline_iou", "oracle_now_iou"):
        assert 0.0 <= m[k] <= 1.0, (k, m)
    assert set(m["per_world"]) == set(data.worlds)
    lo, hi = m["margin_interval"]
    assert -1.0 <= lo <= hi <= 1.0
    rows = pt.figure_rows(m)  # what both CLIs print: a header, "all", one row a world
    assert [r.split()[0] for r in rows[1:]] == ["all", *data.worlds]
    assert f"{lo:+.3f} .. {hi:+.3f}" in rows[1]
    assert first.any()


def test_margin_interval_is_over_whole_episodes() -> None:
    """The predict - detect interval resamples episodes: identical episodes give the point
    margin itself; episodes that disagree give an interval around the pooled margin, and
    more of them (the same mix) a narrower one."""
    from active_vision.training.predict_train import margin_interval

    # per episode: (predictor, detection, now) x (intersection, union)
    good = np.array([[60, 100], [30, 100], [50, 100]])  # margin +0.30
    bad = np.array([[20, 100], [30, 100], [50, 100]])  # margin -0.10
    lo, hi = margin_interval(np.stack([good] * 10))
    assert lo == pytest.approx(0.30) and hi == pytest.approx(0.30)
    few = margin_interval(np.stack([good, bad] * 5))
    many = margin_interval(np.stack([good, bad] * 50))
    assert few[0] < 0.10 < few[1]  # pooled: (80 - 60) / 200 = +0.10
    assert many[0] < 0.10 < many[1]
    assert many[1] - many[0] < 0.5 * (few[1] - few[0])
    assert np.isnan(margin_interval(np.zeros((0, 3, 2), np.int64))).all()


def test_shipped_predictor_loads_and_outputs_probabilities() -> None:
    from active_vision.predict import DEFAULT_PREDICT_WEIGHTS, Predictor, load_predictor

    assert DEFAULT_PREDICT_WEIGHTS.is_file()
    model = load_predictor()
    assert model.k == K
    window = np.random.default_rng(0).random((2, K, 96, 96, 3), dtype=np.float32)
    out = Predictor(model)(window)
    assert out.shape == (2, 96, 96) and out.dtype == np.float32
    assert np.all((out >= 0.0) & (out <= 1.0))
    with pytest.raises(ValueError, match="windows shaped"):
        Predictor(model)(window[:, :3])


def test_predictors_are_chosen_on_their_own_validation_episodes(tmp_path: Path) -> None:
    """``--split validation`` renders and scores episodes of their own seed, never the
    training or held-out ones, and an unknown split is refused by name."""
    from active_vision.training import predict_train as pt
    from active_vision.training.dataset import HELDOUT_SEED, TRAIN_SEED, VALIDATION_SEED

    assert len({VALIDATION_SEED, HELDOUT_SEED, TRAIN_SEED}) == 3
    m = pt.evaluate_heldout(data_dir=tmp_path, episodes=3, threads=1, split="validation")
    assert pt.sequence_path(tmp_path, VALIDATION_SEED, 3).is_file()
    assert not pt.sequence_path(tmp_path, HELDOUT_SEED, 3).exists()
    assert 0.0 <= m["predict_iou"] <= 1.0
    with pytest.raises(ValueError, match="split must be one of"):
        pt.evaluate_heldout(data_dir=tmp_path, episodes=3, split="test")
