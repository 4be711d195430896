"""The robot's formats, on real files: episodes recorded as ROS 2 MCAP by a real
RoverEnv and a real fused env beside a real av-daemon, read back with rosbags' reader and with
the MCAP library's; a bag made of the committed real-footage crops played by the daemon's bag
source (against the video source on the same frames, and through a real av-daemon against the
perception in this process) and fused into a new bag by ``active_vision.bag_fuse``; every bad
input a named error that leaves no segment; the Foxglove layout's topics; the package without
the ``ros`` extra."""

from __future__ import annotations

import json
import math
import os
import sys
import time
import uuid
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import rover_env  # noqa: E402,F401  (registers the ids)
from active_vision.bag_source import BagSource, camera_frame  # noqa: E402
from active_vision.launcher import DaemonStartError, spawn_daemon, start_daemon  # noqa: E402
from active_vision.ros_formats import (  # noqa: E402
    FUSED_TOPICS,
    BagImageReader,
    BagReadError,
    McapWriter,
    NoImageTopicError,
    RosExtraMissingError,
    RosFormatError,
    TopicNotFoundError,
    UnsupportedEncodingError,
    header,
    image_message,
    message,
)
from active_vision.sources import OpenCVSource, SourceError  # noqa: E402
from fused_image import (  # noqa: E402
    CHANNEL_DEPTH,
    CHANNEL_GRAY,
    CHANNEL_HEATMAP,
    channel_to_depth,
)
from rover_env.constants import CAMERA_TOPIC, CMD_VEL_TOPIC, IMU_TOPIC, SCAN_TOPIC  # noqa: E402
from rover_train import record  # noqa: E402
from rover_train.record import EpisodeRecorder, RecordEpisodes  # noqa: E402
from shm_protocol import FrameReader, existing_segments  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CROPS = ROOT / "tests" / "data" / "real_footage"
LAYOUT = ROOT / "docs" / "foxglove_layout.json"
STEPS = 24
SEED = 7
FRAME_NS = 50_000_000  # the crops' bag: 20 images a second
BIG = (160, 120)  # the crops are stored larger than the daemon's frame, and not square

STATE_TOPICS = {
    CAMERA_TOPIC: "sensor_msgs/msg/Image", record.CHASE_TOPIC: "sensor_msgs/msg/Image",
    IMU_TOPIC: "sensor_msgs/msg/Imu", record.ODOM_TOPIC: "nav_msgs/msg/Odometry",
    record.TF_TOPIC: "tf2_msgs/msg/TFMessage", record.GOAL_TOPIC: "geometry_msgs/msg/PoseStamped",
    record.PEDESTRIANS_TOPIC: "geometry_msgs/msg/PoseArray",
}  # fmt: skip


def _read(path: Path) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(log time ns, message)] with rosbags' reader."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((ns, reader.deserialize(raw, conn.msgtype)))
    out["__types__"] = [(0, types)]
    return out


def _types(read: dict[str, list[tuple[int, object]]]) -> dict[str, str]:
    return read["__types__"][0][1]  # type: ignore[return-value]


def _pixels(msg: object) -> np.ndarray:
    m: object = msg
    h, w, enc = m.height, m.width, m.encoding  # type: ignore[attr-defined]
    data = np.asarray(m.data, dtype=np.uint8)  # type: ignore[attr-defined]
    if enc == "32FC1":
        return data.view("<f4").reshape(h, w)
    return data.reshape(h, w, 3)


# --- recording a LIDAR episode ----------------------------------------------------------
@pytest.fixture(scope="module")
def lidar_episode(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A seeded RoverEnv episode recorded step by step, with what the env showed beside."""
    path = tmp_path_factory.mktemp("rec") / "lidar.mcap"
    env = gym.make("roverav/RoverEnv-v0", world_n="inspect", render_mode="rgb_array",
                   render_size=(160, 120))
    env.action_space.seed(SEED)
    seen: dict[str, list] = {"camera": [], "chase": [], "lidar": [], "pose": [], "time": [],
                             "goal": [], "walkers": [], "imu": [], "velocities": []}

    def look(obs: dict) -> None:
        base = env.unwrapped
        seen["camera"].append(base.camera_frame())
        seen["chase"].append(env.render())
        seen["lidar"].append(obs["lidar"].copy())
        seen["pose"].append(obs["pose"].copy())
        seen["imu"].append(obs["imu"].copy())
        seen["velocities"].append(obs["velocities"].copy())
        seen["time"].append(base.sim.time)
        seen["goal"].append(tuple(base.goal))
        seen["walkers"].append(base.sim.pedestrian_positions)

    try:
        obs, info = env.reset(seed=SEED)
        with EpisodeRecorder(env, path) as rec:
            rec.reset(obs, info)
            look(obs)
            for _ in range(STEPS):
                obs, _, terminated, truncated, info = env.step(env.action_space.sample())
                rec.step(obs, info)
                look(obs)
                assert not (terminated or truncated)
            assert not path.exists()  # written under .part until closed
        max_range = env.unwrapped.max_lidar_range
        dt = env.unwrapped.control_dt
    finally:
        env.close()
    return {"path": path, "seen": seen, "read": _read(path), "max_range": max_range, "dt": dt}


def test_a_recorded_episode_has_the_topics_types_and_counts(lidar_episode: dict) -> None:
    read = lidar_episode["read"]
    types = _types(read)
    for topic, kind in {**STATE_TOPICS, SCAN_TOPIC: "sensor_msgs/msg/LaserScan",
                        CMD_VEL_TOPIC: "geometry_msgs/msg/Twist",
                        record.PATH_TOPIC: "nav_msgs/msg/Path",
                        record.TF_STATIC_TOPIC: "tf2_msgs/msg/TFMessage"}.items():
        assert types.get(topic) == kind, (topic, types.get(topic))
    for topic in (*STATE_TOPICS, SCAN_TOPIC):
        assert len(read[topic]) == STEPS + 1, topic  # the reset's observation and each step's
    assert len(read[CMD_VEL_TOPIC]) == STEPS
    assert len(read[record.PATH_TOPIC]) == math.ceil(STEPS / record.RecordConfig().path_every)
    every = record.RecordConfig().path_every
    path = read[record.PATH_TOPIC][-1][1].poses  # type: ignore[attr-defined]
    assert len(path) == 1 + math.ceil(STEPS / every)  # the start, every 10th step, the end
    odom = [m.pose.pose.position for _, m in read[record.ODOM_TOPIC]]  # type: ignore[attr-defined]
    for pose, k in zip(path, [*range(0, STEPS, every), STEPS], strict=True):
        assert (pose.pose.position.x, pose.pose.position.y) == (odom[k].x, odom[k].y)
    assert not set(FUSED_TOPICS.values()) & set(types)  # no fused image on RoverEnv


def test_timestamps_are_sim_time(lidar_episode: dict) -> None:
    read, seen, dt = lidar_episode["read"], lidar_episode["seen"], lidar_episode["dt"]
    expected = [round(t * 1e9) for t in seen["time"]]
    assert expected[0] == 0 and expected[-1] == round(STEPS * dt * 1e9)
    for topic in (*STATE_TOPICS, SCAN_TOPIC):
        logs = [ns for ns, _ in read[topic]]
        heads = [m.transforms[0].header if topic == record.TF_TOPIC  # type: ignore[attr-defined]
                 else m.header for _, m in read[topic]]  # type: ignore[attr-defined]
        stamps = [h.stamp.sec * 10**9 + h.stamp.nanosec for h in heads]
        assert logs == expected and stamps == expected, topic
        assert all(b > a for a, b in zip(logs, logs[1:], strict=False))
    # a command is stamped when the step applying it began
    assert [ns for ns, _ in read[CMD_VEL_TOPIC]] == expected[:-1]


def test_images_are_the_envs_frames(lidar_episode: dict) -> None:
    read, seen = lidar_episode["read"], lidar_episode["seen"]
    for key, topic in (("camera", CAMERA_TOPIC), ("chase", record.CHASE_TOPIC)):
        msgs = [m for _, m in read[topic]]
        assert all(m.encoding == "rgb8" for m in msgs)  # type: ignore[attr-defined]
        for k, (msg, frame) in enumerate(zip(msgs, seen[key], strict=True)):
            assert np.array_equal(_pixels(msg), frame), f"{topic} image {k}"
    assert seen["chase"][0].shape == (120, 160, 3)
    assert not np.array_equal(seen["camera"][0], seen["camera"][-1])  # the rover moved


def test_scan_odometry_goal_and_pedestrians_are_the_observations(lidar_episode: dict) -> None:
    read, seen, top = lidar_episode["read"], lidar_episode["seen"], lidar_episode["max_range"]
    for (_, scan), lidar in zip(read[SCAN_TOPIC], seen["lidar"], strict=True):
        n = len(lidar)
        assert scan.angle_increment == pytest.approx(2 * math.pi / n)  # type: ignore[attr-defined]
        assert scan.angle_min == pytest.approx(-math.pi + math.pi / n)  # type: ignore[attr-defined]
        assert scan.range_max == top  # type: ignore[attr-defined]
        want = np.where(lidar >= top, np.inf, lidar)
        assert np.array_equal(scan.ranges, want.astype(np.float32))  # type: ignore[attr-defined]
    assert any(np.isinf(s.ranges).any() for _, s in read[SCAN_TOPIC])  # type: ignore[attr-defined]
    for (_, odom), pose, imu, vel in zip(read[record.ODOM_TOPIC], seen["pose"], seen["imu"],
                                         seen["velocities"], strict=True):
        p, q = odom.pose.pose.position, odom.pose.pose.orientation  # type: ignore[attr-defined]
        assert np.allclose([p.x, p.y, p.z], pose, atol=1e-5)
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        assert yaw == pytest.approx(float(imu[2]), abs=1e-5)
        assert odom.twist.twist.linear.x == pytest.approx(float(vel[0]), abs=1e-5)  # type: ignore[attr-defined]
        assert odom.child_frame_id == record.BASE_FRAME  # type: ignore[attr-defined]
    for (_, tf), (_, odom) in zip(read[record.TF_TOPIC], read[record.ODOM_TOPIC], strict=True):
        t = tf.transforms[0]  # type: ignore[attr-defined]
        assert (t.header.frame_id, t.child_frame_id) == (record.ODOM_FRAME, record.BASE_FRAME)
        assert t.transform.translation.x == odom.pose.pose.position.x  # type: ignore[attr-defined]
    for (_, goal), want in zip(read[record.GOAL_TOPIC], seen["goal"], strict=True):
        g = goal.pose.position  # type: ignore[attr-defined]
        assert (g.x, g.y) == pytest.approx(want)
    for (_, people), walkers in zip(read[record.PEDESTRIANS_TOPIC], seen["walkers"], strict=True):
        got = np.array([[p.position.x, p.position.y] for p in people.poses])  # type: ignore[attr-defined]
        assert got.shape == walkers.shape and np.allclose(got, walkers)
    for _, cmd in read[CMD_VEL_TOPIC]:
        assert abs(cmd.linear.x) <= 1.0 + 1e-9  # type: ignore[attr-defined]
    imu = [m for _, m in read[IMU_TOPIC]]
    assert np.mean([m.linear_acceleration.z for m in imu]) == pytest.approx(9.81, abs=1.5)  # type: ignore[attr-defined]


def test_foxglove_reads_the_file_as_a_ros2_mcap(lidar_episode: dict) -> None:
    """The MCAP library's own reader (Foxglove's): profile, schemas, index and summary."""
    from mcap.reader import make_reader

    with open(lidar_episode["path"], "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        counts = {summary.channels[c].topic: n
                  for c, n in summary.statistics.channel_message_counts.items()}
        assert counts[CAMERA_TOPIC] == STEPS + 1 and counts[CMD_VEL_TOPIC] == STEPS
        assert summary.chunk_indexes  # seekable: Foxglove jumps through it
        last = max(m.log_time for _, _, m in reader.iter_messages())
    assert summary.statistics.message_end_time == last == round(STEPS * lidar_episode["dt"] * 1e9)


def test_rover_eval_record_writes_an_mcap_per_episode(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    from rover_train.evaluate import main

    out = tmp_path / "rec"
    assert main(["--random", "--env", "lidar", "--world", "maze", "--episodes", "2",
                 "--max-steps", "6", "--seed", "40", "--record", str(out)]) == 0
    assert "recorded 2 episodes" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["episode_40.mcap", "episode_41.mcap"]
    read = _read(out / "episode_41.mcap")
    assert len(read[record.CHASE_TOPIC]) == 7 and len(read[CMD_VEL_TOPIC]) == 6


def test_record_episodes_wrapper_names_files_by_seed(tmp_path: Path) -> None:
    env = RecordEpisodes(gym.make("roverav/RoverEnv-v0", world_n="inspect", length=5),
                         tmp_path, record.RecordConfig(camera=False, path_every=2))
    try:
        for seed in (3, 4):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(np.array([0.5, 0.0], np.float32))
                done = terminated or truncated
    finally:
        env.close()
    assert [p.name for p in env.paths] == ["episode_3.mcap", "episode_4.mcap"]
    read = _read(env.paths[1])
    assert CAMERA_TOPIC not in _types(read) and record.CHASE_TOPIC not in _types(read)
    assert len(read[SCAN_TOPIC]) == 6 and len(read[record.PATH_TOPIC]) == 3


# --- a bag of the committed real-footage crops ------------------------------------------
@pytest.fixture(scope="module")
def crops() -> list[np.ndarray]:
    """The real crops (RGB), stored larger and not square, as a robot's camera gives them."""
    index = json.loads((CROPS / "index.json").read_text())
    names = [e["file"] for e in index["person"]][:8] + [e["file"] for e in index["free"]][:4]
    return [cv2.resize(cv2.cvtColor(cv2.imread(str(CROPS / n)), cv2.COLOR_BGR2RGB), BIG,
                       interpolation=cv2.INTER_CUBIC) for n in names]


def _encoded(rgb: np.ndarray, encoding: str) -> tuple[np.ndarray, int]:
    """(data, channels) of ``rgb`` in a raw Image encoding."""
    conv = {"rgb8": None, "bgr8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGB2RGBA,
            "bgra8": cv2.COLOR_RGB2BGRA, "mono8": cv2.COLOR_RGB2GRAY}[encoding]
    out = rgb if conv is None else cv2.cvtColor(rgb, conv)
    return out, 1 if out.ndim == 2 else out.shape[2]


def _raw_image(rgb: np.ndarray, encoding: str, ns: int, pad: int = 0) -> object:
    data, ch = _encoded(rgb, encoding)
    h, w = data.shape[:2]
    rows = np.zeros((h, w * ch + pad), np.uint8)  # rows padded: step > width * channels
    rows[:, : w * ch] = data.reshape(h, w * ch)
    return message("sensor_msgs/msg/Image", header=header(ns, "front"), height=h, width=w,
                   encoding=encoding, is_bigendian=0, step=w * ch + pad,
                   data=rows.reshape(-1))


def _compressed(rgb: np.ndarray, fmt: str, ns: int) -> object:
    ok, buf = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", cv2.cvtColor(rgb,
                                                                            cv2.COLOR_RGB2BGR))
    assert ok
    return message("sensor_msgs/msg/CompressedImage", header=header(ns, "front"),
                   format=f"rgb8; {fmt} compressed bgr8", data=buf.reshape(-1))


ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")


@pytest.fixture(scope="module")
def crop_bag(tmp_path_factory: pytest.TempPathFactory, crops: list[np.ndarray]) -> Path:
    """/camera/image_raw (rgb8), the same frames in every other encoding read, compressed,
    and a non-image topic."""
    path = tmp_path_factory.mktemp("bag") / "crops.mcap"
    with McapWriter(path) as w:
        for i, rgb in enumerate(crops):
            ns = 1_700_000_000 * 10**9 + i * FRAME_NS  # wall-clock stamps, as a robot's
            w.write(CAMERA_TOPIC, image_message(rgb, ns, "front"), ns)
            for enc in ENCODINGS[1:]:
                w.write(f"/enc/{enc}", _raw_image(rgb, enc, ns, pad=3), ns)
            for fmt in ("jpeg", "png"):
                w.write(f"/enc/{fmt}", _compressed(rgb, fmt, ns), ns)
            w.write("/chatter", message("std_msgs/msg/String", data=f"frame {i}"), ns)
    return path


def _bag_frames(spec: str) -> dict[int, np.ndarray]:
    src = BagSource(spec, slots=2, size=96, loop=False, realtime=False)
    got: dict[int, np.ndarray] = {}
    try:
        while not src.finished:
            frames = src.poll(0.01)
            if frames:
                assert [f.slot for f in frames] == [0, 1]  # every slot gets the frame
                got[frames[0].seq] = frames[0].data
    finally:
        src.close()
    return got


def test_the_bag_source_gives_the_video_sources_frames(tmp_path: Path, crop_bag: Path,
                                                       crops: list[np.ndarray]) -> None:
    """The same frames as a lossless video through OpenCVSource, and as a bag."""
    video = tmp_path / "crops.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"FFV1"), 30.0, BIG)
    assert writer.isOpened()
    for rgb in crops:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    src = OpenCVSource(f"video:{video}", slots=1, size=96, loop=False)
    from_video: dict[int, np.ndarray] = {}
    try:
        while not src.finished:
            for f in src.poll(0.2):
                from_video[f.seq] = f.data
    finally:
        src.close()
    from_bag = _bag_frames(f"bag:{crop_bag}")
    assert sorted(from_bag) == list(range(1, len(crops) + 1))
    assert sorted(from_video) == sorted(from_bag)
    for seq, frame in from_bag.items():
        assert frame.shape == (96, 96, 3) and frame.dtype == np.uint8
        assert np.array_equal(frame, from_video[seq]), f"frame {seq}"
        assert np.array_equal(frame, camera_frame(crops[seq - 1], 96))


@pytest.mark.parametrize("encoding", ENCODINGS[1:] + ("jpeg", "png"))
def test_every_encoding_read_gives_the_same_frames(crop_bag: Path, encoding: str) -> None:
    rgb = _bag_frames(f"bag:{crop_bag}")
    got = _bag_frames(f"bag:{crop_bag}#/enc/{encoding}")
    assert sorted(got) == sorted(rgb)
    with BagImageReader(crop_bag, CAMERA_TOPIC) as reader:
        full = [img.rgb for img in reader.frames()]
    for seq, frame in got.items():
        want = rgb[seq]
        if encoding == "mono8":  # the full image's gray, resized, in all three channels
            gray = camera_frame(cv2.cvtColor(full[seq - 1], cv2.COLOR_RGB2GRAY), 96)
            assert all(np.array_equal(frame[..., c], gray) for c in range(3))
        elif encoding == "jpeg":  # lossy
            assert np.abs(frame.astype(int) - want).mean() < 4.0
        else:
            assert np.array_equal(frame, want), f"{encoding} frame {seq}"


def test_the_source_plays_at_the_bags_pace_and_loops(crop_bag: Path) -> None:
    src = BagSource(f"bag:{crop_bag}", slots=1, size=96, loop=True)
    n = src.count
    seqs, t0 = [], time.monotonic()
    try:
        while len(seqs) < n + 3:
            seqs += [f.seq for f in src.poll(0.2)]
    finally:
        src.close()
    took = time.monotonic() - t0
    assert seqs[:n] == list(range(1, n + 1)) and seqs[n] == n + 1  # the repeat counts on
    assert (n - 1) * FRAME_NS / 1e9 - 0.02 <= took < (n + 2) * FRAME_NS / 1e9 + 1.0


def test_the_daemon_over_a_bag_publishes_the_perception_of_its_frames(
        crop_bag: Path, crops: list[np.ndarray], shm_name: str) -> None:
    from active_vision.perception import Perception, PerceptionConfig

    with spawn_daemon(shm_name, 1, extra_args=["--threads", "1", "--source",
                                               f"bag:{crop_bag}#{CAMERA_TOPIC}"]) as daemon:
        assert existing_segments(shm_name) == [shm_name]  # no camera segment
        with FrameReader(shm_name) as fused:
            got = [fused.wait_next(timeout=10.0) for _ in range(8)]
        ready = next(line for line in daemon.tail if "ready" in line)
    perception = Perception(PerceptionConfig(threads=1))
    assert f"backend={perception.backend}" in ready
    assert f"precision={perception.precision}" in ready
    seqs = [f.source_seq for f in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) >= 8
    for f in got:
        frame = camera_frame(crops[(f.source_seq - 1) % len(crops)], 96)
        want = perception(frame[None])[0]
        assert np.allclose(f.data, want, atol=1e-5), f"fused frame of image {f.source_seq}"
    assert existing_segments(shm_name) == []


def test_bag_fuse_writes_the_channels_beside_the_images(tmp_path: Path, crop_bag: Path,
                                                        crops: list[np.ndarray]) -> None:
    from active_vision.bag_fuse import main
    from active_vision.perception import Perception, PerceptionConfig

    out = tmp_path / "fused.mcap"
    assert main([str(crop_bag), str(out), "--topic", "/enc/bgr8", "--batch", "5",
                 "--log-level", "WARNING"]) == 0
    src, dst = _read(crop_bag), _read(out)
    assert set(_types(dst)) == {"/enc/bgr8", *FUSED_TOPICS.values()}
    with BagImageReader(crop_bag, "/enc/bgr8") as r_in, BagImageReader(out, "/enc/bgr8") as r_out:
        assert [i.raw for i in r_in.frames()] == [i.raw for i in r_out.frames()]  # as they were
    times = [ns for ns, _ in src["/enc/bgr8"]]
    perception = Perception(PerceptionConfig(threads=1))
    want = perception(np.stack([camera_frame(rgb, 96) for rgb in crops]))
    for channel, topic in FUSED_TOPICS.items():
        msgs = dst[topic]
        assert [ns for ns, _ in msgs] == times
        for k, (_, msg) in enumerate(msgs):
            assert msg.encoding == "32FC1" and msg.header.frame_id == "front"  # type: ignore[attr-defined]
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == times[k]  # type: ignore[attr-defined]
            plane = want[k, :, :, channel]
            if channel == CHANNEL_DEPTH:
                plane = channel_to_depth(plane)
            assert np.allclose(_pixels(msg), plane, atol=1e-5), f"{topic} image {k}"
    depth = np.stack([_pixels(m) for _, m in dst[FUSED_TOPICS[CHANNEL_DEPTH]]])
    assert depth.min() >= 0.0 and depth.max() <= 10.0 and depth.max() > 1.0  # metres
    assert max(_pixels(m).max() for _, m in dst[FUSED_TOPICS[CHANNEL_HEATMAP]]) > 0.5


# --- bad input --------------------------------------------------------------------------
def _bad_bags(tmp: Path, crop_bag: Path) -> dict[str, tuple[str, type[RosFormatError], str]]:
    """name -> (source spec, error, words the message must hold)."""
    no_image = tmp / "no_image.mcap"
    with McapWriter(no_image) as w:
        w.write("/chatter", message("std_msgs/msg/String", data="hi"), 1)
        w.write("/odom_only", message("geometry_msgs/msg/Point", x=1.0, y=2.0, z=0.0), 2)
    depth16 = tmp / "depth16.mcap"
    with McapWriter(depth16) as w:
        w.write(CAMERA_TOPIC, message("sensor_msgs/msg/Image", header=header(1, "c"), height=2,
                                      width=2, encoding="16UC1", is_bigendian=0, step=4,
                                      data=np.zeros(8, np.uint8)), 1)
    tiff = tmp / "tiff.mcap"
    with McapWriter(tiff) as w:
        w.write(CAMERA_TOPIC, message("sensor_msgs/msg/CompressedImage", header=header(1, "c"),
                                      format="tiff", data=np.zeros(8, np.uint8)), 1)
    data = crop_bag.read_bytes()
    truncated = tmp / "truncated.mcap"
    truncated.write_bytes(data[: len(data) * 2 // 3])
    garbage = tmp / "garbage.mcap"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, np.uint8).tobytes())
    return {
        "no image topic": (f"bag:{no_image}", NoImageTopicError, "/chatter (std_msgs/msg/String)"),
        "topic not in it": (f"bag:{crop_bag}#/front/image", TopicNotFoundError,
                            f"{CAMERA_TOPIC} (sensor_msgs/msg/Image)"),
        "not an image": (f"bag:{crop_bag}#/chatter", NoImageTopicError, "not an image"),
        "16-bit encoding": (f"bag:{depth16}", UnsupportedEncodingError, "'16UC1'"),
        "tiff": (f"bag:{tiff}", UnsupportedEncodingError, "'tiff'"),
        "truncated": (f"bag:{truncated}", BagReadError, "truncated or corrupt"),
        "garbage": (f"bag:{garbage}", BagReadError, "truncated or corrupt"),
        "missing": (f"bag:{tmp / 'nowhere.mcap'}", BagReadError, "no bag at"),
    }


BAD = ("no image topic", "topic not in it", "not an image", "16-bit encoding", "tiff",
       "truncated", "garbage", "missing")


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_a_named_error_and_the_daemon_leaves_no_segment(
        case: str, tmp_path: Path, crop_bag: Path) -> None:
    from active_vision.daemon import Daemon, DaemonConfig, DaemonError

    spec, error, words = _bad_bags(tmp_path, crop_bag)[case]
    with pytest.raises(error) as caught:
        BagSource(spec, slots=1, size=96)
    assert words in str(caught.value)
    assert isinstance(caught.value, SourceError)
    if "expected" not in str(caught.value):  # what was expected, unless the words say it
        assert "its topics" in str(caught.value) or "image topics" in str(caught.value)
    name = f"test_bag_{uuid.uuid4().hex[:8]}"
    daemon = Daemon(DaemonConfig(name=name, source=spec, threads=1))
    try:
        with pytest.raises(DaemonError, match=words.replace("(", r"\(").replace(")", r"\)")):
            daemon.start()
        assert existing_segments(name) == []
    finally:
        daemon.shutdown()


def test_the_av_daemon_command_fails_at_start_and_removes_its_segments(
        tmp_path: Path, crop_bag: Path, shm_name: str) -> None:
    spec, _, words = _bad_bags(tmp_path, crop_bag)["topic not in it"]
    with pytest.raises(DaemonStartError) as caught:
        start_daemon(shm_name, 1, extra_args=["--threads", "1", "--source", spec])
    assert "has no topic '/front/image'" in str(caught.value) and words in str(caught.value)
    assert existing_segments(shm_name) == []


def test_bag_fuse_on_a_bad_bag_exits_1_and_writes_nothing(tmp_path: Path, crop_bag: Path,
                                                          capsys: pytest.CaptureFixture) -> None:
    from active_vision.bag_fuse import main

    bad = _bad_bags(tmp_path, crop_bag)
    out = tmp_path / "out.mcap"
    for case in ("truncated", "16-bit encoding"):
        spec = bad[case][0].partition(":")[2]
        assert main([spec, str(out), "--log-level", "ERROR"]) == 1
        assert bad[case][2] in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("out")) == []


# --- a fused env beside a real daemon ---------------------------------------------------
def test_a_fused_episode_records_the_three_channels(tmp_path: Path, shm_name: str) -> None:
    with spawn_daemon(shm_name, 1, extra_args=["--threads", "1"]):
        env = RecordEpisodes(gym.make("roverav/RoverEnvFused-v0", world_n="maze",
                                      rl_obs_name=shm_name, slot=0), tmp_path)
        fused, cameras = [], []
        try:
            obs, _ = env.reset(seed=11)
            fused.append(obs["fused_image"])
            cameras.append(env.unwrapped.camera_frame())
            for _ in range(8):
                obs, *_ = env.step(np.array([0.6, 0.2], np.float32))
                fused.append(obs["fused_image"])
                cameras.append(env.unwrapped.camera_frame())
        finally:
            env.close()
    read = _read(tmp_path / "episode_11.mcap")
    assert SCAN_TOPIC not in _types(read)  # no LIDAR on the fused env
    for channel, topic in FUSED_TOPICS.items():
        assert _types(read)[topic] == "sensor_msgs/msg/Image"
        planes = [_pixels(m) for _, m in read[topic]]
        assert len(planes) == 9
        for plane, image in zip(planes, fused, strict=True):
            want = image[:, :, channel]
            if channel == CHANNEL_DEPTH:
                want = channel_to_depth(want)
            assert np.array_equal(plane, want)
    assert any(_pixels(m).max() > 0 for _, m in read[FUSED_TOPICS[CHANNEL_GRAY]])
    for (_, msg), frame in zip(read[CAMERA_TOPIC], cameras, strict=True):
        assert np.array_equal(_pixels(msg), frame)


# --- the layout, and the package without the extra --------------------------------------
def _panels(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict)
    return _panels(node["first"]) + _panels(node["second"])


def test_the_foxglove_layout_shows_what_a_recording_holds() -> None:
    layout = json.loads(LAYOUT.read_text())
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    images = [layout["configById"][p]["imageMode"]["imageTopic"] for p in panels
              if p.startswith("Image!")]
    assert sorted(images) == sorted([record.CHASE_TOPIC, CAMERA_TOPIC, *FUSED_TOPICS.values()])
    scene = next(layout["configById"][p] for p in panels if p.startswith("3D!"))
    assert {SCAN_TOPIC, record.PATH_TOPIC, record.ODOM_TOPIC} <= set(scene["topics"])
    assert scene["followTf"] == record.BASE_FRAME
    known = {*STATE_TOPICS, SCAN_TOPIC, record.PATH_TOPIC, *FUSED_TOPICS.values()}
    assert set(scene["topics"]) <= known


NO_EXTRA = """
import sys
sys.modules.update(rosbags=None, mcap=None)  # as if roverav[ros] were not installed
import active_vision.ros_formats, active_vision.bag_source, active_vision.bag_fuse
import active_vision.daemon, rover_train.record, rover_train.evaluate
from active_vision.daemon import parse_args
assert parse_args(["--source", "bag:x.mcap#/cam"]).source == "bag:x.mcap#/cam"
try:
    rover_train.evaluate.main(["--random", "--record", "out"])
except SystemExit as exc:
    print("EXIT", exc.code)
"""


def test_the_package_imports_without_the_ros_extra() -> None:
    import subprocess

    out = subprocess.run([sys.executable, "-c", NO_EXTRA], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "EXIT 2" in out.stdout  # rover-eval --record: a usage error naming the extra
    assert "--record: ROS 2 bags need the optional libraries" in out.stderr
    assert "pip install 'roverav[ros]'" in out.stderr


def test_without_the_extra_a_recording_or_a_bag_names_it(monkeypatch: pytest.MonkeyPatch,
                                                        tmp_path: Path) -> None:
    from active_vision import ros_formats

    for mod in ("rosbags.typesys", "rosbags.highlevel", "mcap.writer"):
        monkeypatch.setitem(sys.modules, mod, None)
    ros_formats.typestore.cache_clear()
    env = gym.make("roverav/RoverEnv-v0", world_n="maze")
    try:
        with pytest.raises(RosExtraMissingError, match=r"pip install 'roverav\[ros\]'"):
            EpisodeRecorder(env, tmp_path / "x.mcap")
        with pytest.raises(ImportError, match=r"pip install 'roverav\[ros\]'"):
            BagSource(f"bag:{tmp_path}", slots=1, size=96)
    finally:
        env.close()
        monkeypatch.undo()
        ros_formats.typestore.cache_clear()
    assert not list(tmp_path.iterdir())
