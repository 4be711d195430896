"""av-daemon as a real subprocess: ready line, segment layouts, fused frames for camera
frames written here (a rendered pedestrian), shutdown, refusal, take-over, slots, video."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from active_vision.perception import gray_of  # noqa: E402
from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP  # noqa: E402
from shm_protocol import (  # noqa: E402
    FrameReader,
    FrameWriter,
    camera_name,
    slot_name,
)

ROOT = Path(__file__).resolve().parents[1]
SHM = Path("/dev/shm")


def _name() -> str:
    return f"test_av_{uuid.uuid4().hex[:8]}"


def _segments(name: str) -> list[str]:
    return sorted(p.name for p in SHM.iterdir() if p.name.startswith(name))


class Daemon:
    """A daemon subprocess; ``stop()`` sends SIGTERM and returns (status, stderr)."""

    def __init__(self, name: str, *args: str) -> None:
        self.name = name
        self.workers = 1
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "active_vision", "--name", name, "--threads", "1", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
        )
        self.ready_line = self.proc.stdout.readline() if self.proc.stdout else ""

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        _, err = self.proc.communicate(timeout=20)
        return self.proc.returncode, err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=20)


def _cleanup(name: str) -> None:
    for seg in _segments(name):
        (SHM / seg).unlink(missing_ok=True)


@pytest.fixture(scope="module")
def frames() -> dict[str, np.ndarray]:
    """A rendered frame with a pedestrian 3 m ahead (and its mask), and one without."""
    from rover_env.simulation import RoverSim

    sim = RoverSim(world="inspect", camera_size=(96, 96))
    try:
        for seed in range(20):
            sim.reset(np.random.default_rng(seed))
            x, y, _ = sim.position
            yaw = sim.yaw
            for i in range(sim.pedestrian_positions.shape[0]):  # all behind the rover
                sim.place_pedestrian(i, x - 4 * math.cos(yaw) + i, y - 4 * math.sin(yaw), 0.0)
            empty = sim.render_camera(depth=True, segmentation=True)
            sim.place_pedestrian(0, x + 3 * math.cos(yaw), y + 3 * math.sin(yaw), yaw + 2.0)
            ped = sim.render_camera(depth=True, segmentation=True)
            if ped.pedestrian_mask.sum() >= 100 and not empty.pedestrian_mask.any():
                return {"ped": ped.rgb, "mask": ped.pedestrian_mask, "empty": empty.rgb,
                        "ped_depth": ped.depth}
    finally:
        sim.close()
    raise AssertionError("no seed gave a clear view of a pedestrian")


@pytest.fixture(scope="module", params=["1", "2"], ids=["one-loop", "two-workers"])
def daemon2(request: pytest.FixtureRequest) -> Iterator[Daemon]:
    """One daemon with two slots, shared by the tests that only talk to it: one loop over
    both slots (``--workers 1``), and a worker thread per slot."""
    name = _name()
    d = Daemon(name, "--slots", "2", "--workers", request.param)
    d.workers = int(request.param)
    try:
        yield d
    finally:
        d.stop()
        _cleanup(name)


def _heat_on_off(fused: np.ndarray, mask: np.ndarray) -> tuple[float, float, int]:
    """On the pedestrian: the heatmap's 90th percentile and the fraction of pixels >= 0.5;
    away from it (more than 3 px): the pixels >= 0.5 (evaluate.py counts a blob of 5 as a
    detection)."""
    heat = fused[..., CHANNEL_HEATMAP]
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    on = heat[mask]
    return (float(np.percentile(on, 90)), float(np.mean(on >= 0.5)),
            int(np.count_nonzero(heat[~grown] >= 0.5)))


def _assert_pedestrian_found(fused: np.ndarray, mask: np.ndarray) -> None:
    high, covered, off = _heat_on_off(fused, mask)
    assert high > 0.8, f"heatmap on the pedestrian peaks at {high:.2f} (90th percentile)"
    assert covered > 0.25, f"only {covered:.0%} of the pedestrian is >= 0.5"
    assert off < 5, f"{off} pixels >= 0.5 away from the pedestrian"


def test_ready_line_and_segment_layouts(daemon2: Daemon) -> None:
    assert "ready" in daemon2.ready_line, daemon2.proc.stderr.read() if daemon2.proc.stderr else ""
    assert f"workers={daemon2.workers} " in daemon2.ready_line
    name = daemon2.name
    assert _segments(name) == sorted(
        [name, f"{name}_1", camera_name(name), camera_name(slot_name(name, 1))]
    )
    for i in range(2):
        with FrameReader(slot_name(name, i)) as fused:
            assert fused.shape == (96, 96, 3) and fused.dtype == np.float32
            assert fused.is_writer_alive() and fused.writer_pid == daemon2.proc.pid
        with FrameReader(camera_name(slot_name(name, i))) as cam:
            assert cam.shape == (96, 96, 3) and cam.dtype == np.uint8


def test_camera_frame_comes_back_fused_with_the_pedestrian(daemon2: Daemon, frames) -> None:
    name = daemon2.name
    cam = FrameWriter(camera_name(name), create=False)
    fused = FrameReader(name)
    try:
        seq = cam.publish(frames["ped"])
        out = fused.wait_for(source_seq=seq, timeout=10.0)
    finally:
        cam.close()
        fused.close()
    assert out.source_seq == seq
    np.testing.assert_allclose(out.data[..., CHANNEL_GRAY], gray_of(frames["ped"]), atol=1e-5)
    _assert_pedestrian_found(out.data, frames["mask"])
    depth = out.data[..., CHANNEL_DEPTH]
    assert 0.55 < float(np.median(depth[frames["mask"]])) < 0.9  # 3 m -> 0.7


def test_two_slots_are_independent(daemon2: Daemon, frames) -> None:
    name = daemon2.name
    cams = [FrameWriter(camera_name(slot_name(name, i)), create=False) for i in range(2)]
    readers = [FrameReader(slot_name(name, i)) for i in range(2)]
    try:
        for _ in range(3):  # slot 1's frame numbers run ahead of slot 0's
            s1 = cams[1].publish(frames["empty"])
            readers[1].wait_for(source_seq=s1, timeout=10.0)
        s0 = cams[0].publish(frames["ped"])
        s1 = cams[1].publish(frames["empty"])
        assert s1 > s0
        out0 = readers[0].wait_for(source_seq=s0, timeout=10.0)
        out1 = readers[1].wait_for(source_seq=s1, timeout=10.0)
    finally:
        for c in cams:
            c.close()
        for r in readers:
            r.close()
    assert out0.source_seq == s0 and out1.source_seq == s1
    _assert_pedestrian_found(out0.data, frames["mask"])
    assert np.count_nonzero(out1.data[..., CHANNEL_HEATMAP] >= 0.5) < 5


def test_second_daemon_on_the_same_name_is_refused(daemon2: Daemon) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run(
        [sys.executable, "-m", "active_vision", "--name", daemon2.name, "--threads", "1"],
        capture_output=True, text=True, timeout=60, cwd=ROOT, env=env,
    )
    assert res.returncode == 1
    assert "already serves" in res.stderr and "ready" not in res.stdout
    assert daemon2.proc.poll() is None
    with FrameReader(daemon2.name) as fused:
        assert fused.is_writer_alive()


def test_depth_render_and_sigterm_leaves_no_segment(frames) -> None:
    name = _name()
    d = Daemon(name, "--depth", "render")
    try:
        assert "ready" in d.ready_line
        cam = FrameWriter(camera_name(name), create=False)
        assert cam.shape == (96, 96, 4)
        frame = np.zeros((96, 96, 4), np.uint8)
        frame[..., :3] = frames["ped"]
        frame[..., 3] = np.round(255 * np.clip(1 - frames["ped_depth"] / 10.0, 0, 1))
        with FrameReader(name) as fused:
            out = fused.wait_for(source_seq=cam.publish(frame), timeout=10.0)
        cam.close()
        np.testing.assert_allclose(out.data[..., CHANNEL_DEPTH], frame[..., 3] / 255.0,
                                   atol=1e-6)
        status, err = d.stop()
    finally:
        d.kill()
        leftover = _segments(name)
        _cleanup(name)
    assert status == 0, err
    assert leftover == []


def test_segments_of_a_killed_daemon_are_taken_over_in_place(frames) -> None:
    name = _name()
    first = Daemon(name)
    try:
        assert "ready" in first.ready_line
        cam = FrameWriter(camera_name(name), create=False)
        fused = FrameReader(name)
        fused.wait_for(source_seq=cam.publish(frames["empty"]), timeout=10.0)
        inodes = {s: (SHM / s).stat().st_ino for s in _segments(name)}
        first.kill()  # SIGKILL: no clean-up
        assert _segments(name) == sorted(inodes)
        second = Daemon(name, "--stale-after", "1.0")
        try:
            assert "ready" in second.ready_line, second.proc.stderr.read()
            assert {s: (SHM / s).stat().st_ino for s in _segments(name)} == inodes
            # the env's writer and reader from before the crash keep working
            seq = cam.publish(frames["ped"])
            out = fused.wait_for(source_seq=seq, timeout=10.0)
            assert out.source_seq == seq
            assert fused.writer_pid == second.proc.pid
            cam.close()
            fused.close()
            status, err = second.stop()
            assert status == 0, err
        finally:
            second.kill()
    finally:
        first.kill()
        leftover = _segments(name)
        _cleanup(name)
    assert leftover == []


def test_missing_weights_fail_before_ready(tmp_path) -> None:
    name = _name()
    d = Daemon(name, "--weights", str(tmp_path / "missing.pt"))
    status, err = d.stop()
    assert status == 1 and "ready" not in d.ready_line
    assert "python -m active_vision.training.train" in err
    assert _segments(name) == []


def test_video_source_and_png_preview(tmp_path, frames) -> None:
    video = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"mp4v"), 20.0, (192, 192))
    big = cv2.resize(frames["ped"], (192, 192), interpolation=cv2.INTER_NEAREST)
    for _ in range(10):
        writer.write(cv2.cvtColor(big, cv2.COLOR_RGB2BGR))
    writer.release()
    preview = tmp_path / "preview.png"
    name = _name()
    d = Daemon(name, "--source", f"video:{video}", "--preview", str(preview))
    try:
        assert "ready" in d.ready_line
        assert _segments(name) == [name]  # no camera segment with a video source
        with FrameReader(name) as fused:
            first = fused.wait_next(timeout=10.0)
            later = fused.wait_next(timeout=10.0)
        assert later.source_seq > first.source_seq >= 1
        # the video frame went through mp4 compression and two resizes: high on it is enough
        assert _heat_on_off(later.data, frames["mask"])[0] > 0.5
        deadline = time.monotonic() + 10
        while not preview.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        img = cv2.imread(str(preview))
        assert img is not None and img.shape == (3 * 96 + 14, 4 * 3 * 96, 3)
        status, err = d.stop()
        assert status == 0, err
    finally:
        d.kill()
        leftover = _segments(name)
        _cleanup(name)
    assert leftover == []
