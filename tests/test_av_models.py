"""active_vision.models and active_vision.perception: weights files, shapes, channels, batching."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from active_vision.models import (
    DEFAULT_WEIGHTS,
    REGENERATE_COMMAND,
    AVNet,
    AVNetConfig,
    WeightsError,
    load_model,
    save_weights,
)
from active_vision.perception import Perception, PerceptionConfig, gray_of
from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP


@pytest.fixture(scope="module")
def random_model() -> AVNet:
    torch.manual_seed(0)
    return AVNet().eval()


def _frames(n: int, c: int = 3, size: int = 96, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(n, size, size, c), dtype=np.uint8)


def test_shipped_weights_are_small_and_load_weights_only() -> None:
    assert DEFAULT_WEIGHTS.is_file(), f"run `{REGENERATE_COMMAND}`"
    assert DEFAULT_WEIGHTS.stat().st_size < 2 * 1024 * 1024
    payload = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    assert payload["format"] == "roverav.avnet"
    model = load_model()
    assert not model.training


def test_missing_weights_error_names_file_and_command(tmp_path) -> None:
    missing = tmp_path / "nope.pt"
    with pytest.raises(WeightsError) as err:
        load_model(missing)
    assert str(missing) in str(err.value) and REGENERATE_COMMAND in str(err.value)


@pytest.mark.parametrize("content", [b"", b"not a torch file at all", b"PK\x03\x04garbage"])
def test_corrupt_weights_error_names_file_and_command(tmp_path, content: bytes) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_bytes(content)
    with pytest.raises(WeightsError) as err:
        load_model(bad)
    assert str(bad) in str(err.value) and REGENERATE_COMMAND in str(err.value)


def test_foreign_torch_file_is_rejected(tmp_path) -> None:
    other = tmp_path / "other.pt"
    torch.save({"state_dict": {"w": torch.zeros(3)}}, other)
    with pytest.raises(WeightsError, match="not a roverav.avnet weights file"):
        load_model(other)


def test_save_load_round_trip_and_bn_folding(tmp_path, random_model: AVNet) -> None:
    model = AVNet(AVNetConfig(widths=(8, 16, 24, 32)))
    # non-trivial batch-norm statistics, so folding is actually exercised
    model.train()
    with torch.no_grad():
        for _ in range(3):
            model(torch.rand(4, 3, 96, 96))
    model.eval()
    path = save_weights(model, tmp_path / "w.pt", {"note": "test"})
    x = torch.rand(2, 3, 96, 96)
    with torch.no_grad():
        ref = model.predict(x)
        unfused = load_model(path, fuse=False).predict(x)
        fused = load_model(path).predict(x)
    assert load_model(path).config.widths == (8, 16, 24, 32)
    # weights are stored as float16: small differences only
    assert torch.allclose(ref, unfused, atol=2e-2)
    assert torch.allclose(unfused, fused, atol=1e-4)


@pytest.mark.parametrize("full_res", [0, 4])
def test_full_resolution_stage_round_trip(tmp_path, full_res: int) -> None:
    """The full-resolution stage is saved in the file's config and survives BN folding; a
    version-2 file (no ``full_res`` key) loads as the layout without it."""
    torch.manual_seed(1)
    model = AVNet(AVNetConfig(widths=(8, 16, 24, 32), full_res=full_res))
    model.train()
    with torch.no_grad():
        for _ in range(3):
            model(torch.rand(4, 3, 96, 96))
    model.eval()
    path = save_weights(model, tmp_path / "w.pt")
    x = torch.rand(2, 3, 96, 96)
    with torch.no_grad():
        ref = load_model(path, fuse=False).predict(x)
        fused = load_model(path).predict(x)
    assert load_model(path).config.full_res == full_res
    assert hasattr(load_model(path), "dec0") == bool(full_res)
    assert torch.allclose(ref, fused, atol=1e-4)
    payload = torch.load(path, map_location="cpu", weights_only=True)
    payload["version"] = 2
    del payload["config"]["full_res"]
    torch.save(payload, tmp_path / "v2.pt")
    if full_res:
        with pytest.raises(WeightsError, match="does not match the network"):
            load_model(tmp_path / "v2.pt")
    else:
        assert load_model(tmp_path / "v2.pt").config.full_res == 0


def test_newer_weights_version_is_refused_with_the_command(tmp_path) -> None:
    path = save_weights(AVNet(AVNetConfig(widths=(8, 16, 24, 32), full_res=0)), tmp_path / "w.pt")
    payload = torch.load(path, map_location="cpu", weights_only=True)
    payload["version"] = 99
    torch.save(payload, path)
    with pytest.raises(WeightsError, match="has version 99") as err:
        load_model(path)
    assert REGENERATE_COMMAND in str(err.value)


def test_perception_output_layout_and_gray(random_model: AVNet) -> None:
    p = Perception(PerceptionConfig(threads=1), model=random_model)
    frames = _frames(3)
    out = p(frames)
    assert out.shape == (3, 96, 96, 3) and out.dtype == np.float32
    assert np.all((out >= 0) & (out <= 1))
    np.testing.assert_allclose(out[..., CHANNEL_GRAY], gray_of(frames), atol=1e-5)
    assert p.timings.frames == 3 and p.timings.batches == 1


def test_perception_batch_equals_single_frames(random_model: AVNet) -> None:
    p = Perception(PerceptionConfig(threads=1, max_batch=2), model=random_model)
    frames = _frames(5, seed=1)
    batch = p(frames).copy()  # grows the buffers from 2 to 5
    singles = np.stack([p(frames[i : i + 1])[0].copy() for i in range(5)])
    np.testing.assert_allclose(batch, singles, atol=1e-5)


def test_perception_reuses_its_output_buffer(random_model: AVNet) -> None:
    p = Perception(PerceptionConfig(threads=1), model=random_model)
    a = p(_frames(2, seed=2))
    b = p(_frames(2, seed=3))
    assert np.shares_memory(a, b)


def test_depth_render_uses_the_fourth_channel(random_model: AVNet) -> None:
    p = Perception(PerceptionConfig(threads=1, depth="render"), model=random_model)
    frames = _frames(2, c=4, seed=4)
    out = p(frames)
    np.testing.assert_allclose(out[..., CHANNEL_DEPTH], frames[..., 3] / 255.0, atol=1e-6)
    model_depth = Perception(PerceptionConfig(threads=1), model=random_model)(frames)
    np.testing.assert_allclose(out[..., CHANNEL_HEATMAP], model_depth[..., CHANNEL_HEATMAP],
                               atol=1e-6)
    with pytest.raises(ValueError, match="depth in channel 3"):
        p(_frames(1, c=3))


def test_other_input_sizes_are_resized(random_model: AVNet) -> None:
    p = Perception(PerceptionConfig(threads=1), model=random_model)
    out = p(_frames(2, size=160, seed=5))
    assert out.shape == (2, 96, 96, 3)


@pytest.mark.parametrize("bad", [np.zeros((1, 96, 96, 2), np.uint8),
                                 np.zeros((1, 96, 96, 3), np.float32),
                                 np.zeros((96,), np.uint8)])
def test_bad_frames_are_rejected(random_model: AVNet, bad: np.ndarray) -> None:
    p = Perception(PerceptionConfig(threads=1), model=random_model)
    with pytest.raises(ValueError, match="uint8 frames"):
        p(bad)


def test_log_depth_head_maps_to_the_shm_depth_convention() -> None:
    from active_vision.models import log_depth_to_channel
    from fused_image import depth_to_channel

    metres = torch.tensor([0.1, 0.5, 2.0, 9.99, 10.0, 50.0])
    got = log_depth_to_channel(torch.log(metres))
    np.testing.assert_allclose(got.numpy(), depth_to_channel(metres.numpy()), atol=1e-6)
    out = torch.empty(6)
    assert log_depth_to_channel(torch.log(metres), out=out) is out


def test_weights_of_another_version_are_rejected(tmp_path, random_model: AVNet) -> None:
    path = save_weights(random_model, tmp_path / "w.pt")
    payload = torch.load(path, weights_only=True)
    payload["version"] = 1
    torch.save(payload, path)
    with pytest.raises(WeightsError, match="version 1"):
        load_model(path)
