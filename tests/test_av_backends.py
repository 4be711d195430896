"""Perception backends: ONNX Runtime against eager torch on rendered frames, the versioned
ONNX export and its cache, thread count, and the fall-back to torch without onnxruntime."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

from active_vision.backends import BackendError, OnnxNetwork, TorchNetwork  # noqa: E402
from active_vision.models import (  # noqa: E402
    DEFAULT_WEIGHTS,
    AVNet,
    AVNetConfig,
    load_model,
    save_weights,
)
from active_vision.onnx_export import (  # noqa: E402
    export_network,
    onnx_file_for,
    onnx_file_name,
    write_export_beside,
)
from active_vision.perception import Perception, PerceptionConfig  # noqa: E402
from active_vision.training import dataset as ds  # noqa: E402
from fused_image import CHANNEL_HEATMAP  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FRAMES_SEED = 515_151  # neither the training nor the evaluation split
TOLERANCE = 1e-3  # absolute, on every channel of the fused frame


@pytest.fixture(scope="module")
def rendered() -> np.ndarray:
    """Held-out-style frames: the dataset renderer, a seed no split uses."""
    return ds.render_dataset(ds.DatasetConfig(frames=12, seed=FRAMES_SEED)).rgb


def test_onnx_fused_frames_equal_torch_on_rendered_frames(rendered: np.ndarray) -> None:
    onnx = Perception(PerceptionConfig(backend="onnx", precision="fp32",
                                       max_batch=len(rendered)))
    torch_ = Perception(PerceptionConfig(backend="torch", max_batch=len(rendered)))
    assert (onnx.backend, torch_.backend) == ("onnx", "torch")
    ref = torch_(rendered).copy()
    # the comparison means something: the frames hold pedestrians the network finds
    assert ref[..., CHANNEL_HEATMAP].max() > 0.5
    batched = onnx(rendered).copy()
    assert np.abs(batched - ref).max() <= TOLERANCE
    for i in (0, 5, 11):  # batch 1 (its own I/O binding) gives the same frames
        assert np.abs(onnx(rendered[i]) - ref[i]).max() <= TOLERANCE


def test_onnx_depth_render_takes_the_fourth_channel(rendered: np.ndarray) -> None:
    rgbd = np.concatenate(
        [rendered[:3], np.arange(3 * 96 * 96, dtype=np.uint8).reshape(3, 96, 96, 1)], axis=-1)
    onnx = Perception(PerceptionConfig(backend="onnx", depth="render",
                                       precision="fp32"))(rgbd).copy()
    ref = Perception(PerceptionConfig(backend="torch", depth="render"))(rgbd)
    assert np.abs(onnx - ref).max() <= TOLERANCE
    np.testing.assert_allclose(onnx[..., 2], rgbd[..., 3] / 255.0, atol=1e-6)


def test_shipped_onnx_file_is_the_export_of_the_shipped_weights() -> None:
    shipped = DEFAULT_WEIGHTS.parent / onnx_file_name(DEFAULT_WEIGHTS, 96)
    assert shipped.is_file(), (
        f"{shipped.name} is missing next to {DEFAULT_WEIGHTS.name} (retrained weights?): "
        "run `python -m active_vision.onnx_export`")
    assert onnx_file_for() == shipped
    fp32 = [p for p in DEFAULT_WEIGHTS.parent.glob("*.onnx") if not p.name.endswith(".int8.onnx")]
    assert len(fp32) == 1, "stale exports shipped"


def test_other_weights_are_exported_once_into_the_cache(tmp_path: Path) -> None:
    torch.manual_seed(3)
    model = AVNet(AVNetConfig(widths=(8, 16, 24, 32))).eval()
    weights = save_weights(model, tmp_path / "small.pt")
    cache = tmp_path / "cache"
    path = onnx_file_for(weights, 64, cache_dir=cache)
    assert path.parent == cache and path.name == onnx_file_name(weights, 64)
    stamp = path.stat().st_mtime_ns
    assert onnx_file_for(weights, 64, cache_dir=cache) == path
    assert path.stat().st_mtime_ns == stamp  # found, not exported again
    # uint8 frames in, fused frames out, any batch: batch 3 through the export equals the
    # torch backend on the same weights file (the file holds fp16-rounded weights)
    net = OnnxNetwork(path, 64, threads=1, capacity=3)
    ref = TorchNetwork(load_model(weights), 64, capacity=3)
    frames = np.random.default_rng(3).integers(0, 256, (3, 64, 64, 3), dtype=np.uint8)
    net.input(3)[...] = frames
    ref.input(3)[...] = frames
    got, want = net.run(3), ref.run(3)
    assert got.shape == (3, 64, 64, 3) and got.dtype == np.float32
    assert np.abs(got - want).max() <= TOLERANCE
    # a changed weights file gets another name: the old export is never reused
    save_weights(AVNet(AVNetConfig(widths=(8, 16, 24, 32))), weights)
    assert onnx_file_name(weights, 64) != path.name


def test_a_file_of_another_export_version_is_refused_with_the_fix(tmp_path: Path) -> None:
    weights = save_weights(AVNet(AVNetConfig(widths=(8, 16, 24, 32))).eval(),
                           tmp_path / "small.pt")
    old = export_network(weights, 32, tmp_path / "network.onnx")  # float in, raw maps out
    with pytest.raises(BackendError, match="exported again"):
        OnnxNetwork(old, 32)
    with pytest.raises(BackendError, match="exported again"):  # right version, wrong size
        OnnxNetwork(onnx_file_for(weights, 64, cache_dir=tmp_path / "cache"), 32)


def test_onnx_thread_count_is_honoured_and_does_not_spin() -> None:
    net = Perception(PerceptionConfig(backend="onnx", threads=2)).net
    assert isinstance(net, OnnxNetwork)
    opts = net.session.get_session_options()
    assert opts.intra_op_num_threads == 2
    assert opts.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def _without_onnxruntime(code: str) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in a fresh interpreter where ``import onnxruntime`` fails."""
    prelude = "import sys; sys.modules['onnxruntime'] = None\n"
    return subprocess.run(
        [sys.executable, "-c", prelude + code], capture_output=True, text=True, timeout=120,
        cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )  # fmt: skip


def test_missing_onnxruntime_falls_back_to_torch_with_one_log_line() -> None:
    res = _without_onnxruntime(
        "import logging; logging.basicConfig(level=logging.WARNING)\n"
        "from active_vision import Perception, PerceptionConfig\n"
        "from active_vision.backends import BackendError\n"
        "print('backend', Perception(PerceptionConfig(backend='auto')).backend)\n"
        "try:\n"
        "    Perception(PerceptionConfig(backend='onnx'))\n"
        "except BackendError as exc:\n"
        "    print('onnx refused:', exc)\n"
    )
    assert res.returncode == 0, res.stderr
    assert "backend torch" in res.stdout
    assert "onnx refused:" in res.stdout and "pip install onnxruntime" in res.stdout
    lines = [ln for ln in res.stderr.splitlines() if "onnxruntime" in ln]
    assert len(lines) == 1, res.stderr


def test_daemon_without_onnxruntime_serves_with_torch() -> None:
    name = f"test_avb_{uuid.uuid4().hex[:8]}"
    code = (
        "import sys, runpy; sys.modules['onnxruntime'] = None\n"
        f"sys.argv = ['av-daemon', '--name', '{name}', '--backend', 'auto']\n"
        "runpy.run_module('active_vision', run_name='__main__')\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    assert "ready" in ready and "backend=torch" in ready, err
    assert proc.returncode == 0, err
    assert len([ln for ln in err.splitlines() if "onnxruntime" in ln]) == 1, err
    assert not [p for p in os.listdir("/dev/shm") if p.startswith(name)]


def test_daemon_backend_flag_is_validated_and_explicit_onnx_without_it_fails() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "active_vision", "--backend", "tensorrt"], capture_output=True,
        text=True, timeout=60, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )  # fmt: skip
    assert res.returncode == 2 and "--backend" in res.stderr
    name = f"test_avb_{uuid.uuid4().hex[:8]}"
    res = _without_onnxruntime(
        "from active_vision.daemon import main\n"
        f"sys.exit(main(['--name', '{name}', '--backend', 'onnx']))\n"
    )
    assert res.returncode == 1
    assert "needs onnxruntime" in res.stderr and "--backend torch" in res.stderr
    assert "ready" not in res.stdout


def test_unknown_backend_and_onnx_with_a_model_object_are_named_errors() -> None:
    with pytest.raises(BackendError, match="auto, onnx, torch"):
        Perception(PerceptionConfig(backend="tensorrt"))
    with pytest.raises(BackendError, match="PerceptionConfig.weights"):
        Perception(PerceptionConfig(backend="onnx"), model=AVNet().eval())
    assert Perception(PerceptionConfig(backend="auto"), model=AVNet().eval()).backend == "torch"


def test_export_beside_retrained_weights_replaces_the_stale_file(tmp_path: Path) -> None:
    small = AVNetConfig(widths=(8, 16, 24, 32))
    weights = save_weights(AVNet(small).eval(), tmp_path / "w.pt")
    first = write_export_beside(weights, 32)
    save_weights(AVNet(small).eval(), weights, {"retrained": 1})  # new bytes, new sha256
    second = write_export_beside(weights, 32)
    assert first != second and first.name.startswith("w-") and second.name.startswith("w-")
    assert sorted(p.name for p in tmp_path.glob("*.onnx")) == [second.name]
    assert onnx_file_for(weights, 32, export=False) == second
