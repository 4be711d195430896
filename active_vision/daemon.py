"""av-daemon: camera frames in, fused 96x96x3 observations out, over shared memory.

    av-daemon [--name rl_observation] [--slots N] [--size 96] [--depth model|render]
              [--backend auto|onnx|torch] [--precision auto|int8|fp32] [--threads 1]
              [--workers 0] [--spin-wait auto|on|off]
              [--source camera|video:PATH|device:N|bag:PATH[#TOPIC]] [--preview PATH]
              [--log-every 1000] [--stale-after 2.0] [--weights FILE] [--log-level INFO]
              [--heatmap detect|predict] [--predict-weights FILE]

(also ``python -m active_vision``). For each slot i it creates the fused segment
``slot_name(name, i)`` (float32 ``size x size x 3``, written by the daemon) and, with
``--source camera``, the camera segment ``camera_name(slot_name(name, i))`` (uint8
``size x size x 3``, or ``x 4`` with ``--depth render``: channel 3 is the renderer's depth
channel), which the env writes (``FrameWriter(..., create=False)``) and the daemon reads.
Then it prints one line starting with ``av-daemon ready`` (``READY_MARKER``, flushed) and serves:

1. waits for new camera frames on any slot (futex wake-ups, short timeouts; idle costs
   almost no CPU); with two cores for each env slot on the machine a worker of one slot
   first watches for its frame in a busy loop for up to 3 ms (``--spin-wait``, as the env
   does for its fused frame), so a frame that comes within it costs no wake-up;
2. runs :class:`~active_vision.perception.Perception` on every slot that has a new frame,
   as one batch, in ONNX Runtime or eager torch (``--backend``: ``auto``, the default, is
   ONNX Runtime when it is installed, else torch with one log line saying so; the ONNX file
   ships with the weights, or is exported once into the user cache for other weights, see
   :mod:`active_vision.onnx_export`; ``--precision auto``, the default, runs the shipped
   int8 model where it agrees with fp32 on this CPU's committed reference frames and is
   faster, else the fp32 export, measured once per machine and said in one log line;
   ``int8`` is refused where the int8 model disagrees; ``fp32`` is never checked; see
   :mod:`active_vision.precision`);
   with several slots this runs in ``--workers`` threads (default: one per CPU core, at
   most one per slot), each with its own network session, worker ``k`` serving the slots
   ``i`` with ``i % workers == k``: an env's frame is computed while another env renders,
   not after that env's frame (``--workers 1``, one loop over every slot, makes the envs
   wait for each other's frames and keeps them in step: RESULTS.md, "RoverEnvFused and
   fused training speed");
3. publishes each fused frame into its slot's segment with ``source_seq`` = the camera
   frame's ``seq`` (the env waits on that with ``FrameReader.wait_for``);
4. refreshes the fused segments' heartbeat while idle, and logs per-stage timings (input,
   network, publish) every ``--log-every`` frames.

``--heatmap detect`` (default, seed 000) publishes channel 1 as this frame's detection;
``--heatmap predict`` (seed 001) replaces it with the predicted occupancy over the next
1.5 s computed from the slot's history (:mod:`active_vision.predict`): every slot then keeps
its own history of its last ``K`` (5) fused detection frames
(:class:`~active_vision.history.SlotHistory`), cleared when a camera frame carries the
episode-start flag (``Frame.episode_start``, set by the env on each episode's first frame).
A daemon started
mid-episode has an empty history and fills it from the frames it sees; nothing of a slot's
history ever reaches another slot or survives an episode start.

With ``--source video:PATH`` (or ``device:N``) no camera segment is made: the video plays at
its frame rate into every slot's fused segment (``source_seq`` counts frames), for trying
the pipeline without the simulator. ``--source bag:PATH[#TOPIC]`` plays a ROS 2 bag's image
topic (a robot's recorded camera; MCAP or rosbag2, ``pip install 'roverav[ros]'``) the same
way, at the bag's timestamps (:mod:`active_vision.bag_source`). ``--preview PATH`` writes
slot 0's camera frame and its three fused channels side by side (PNG, refreshed twice a
second, or an MP4 of every frame); in ``predict`` mode the detection heatmap is shown next
to the prediction.

Start and stop: a live daemon already serving the name (its lock is held, or a fused
segment's writer is alive with a fresh heartbeat) makes this one refuse with exit status 1.
Segments left by a dead daemon are taken over in place (same inode, so attached envs keep
going). SIGINT/SIGTERM: set the shutting-down flag on every segment, unlink every segment
this daemon holds, exit 0. Exit status 1 for any start-up failure (weights, segments,
source), 2 for bad usage.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

import numpy as np

from active_vision.launcher import READY_MARKER
from fused_image import CHANNEL_HEATMAP, FUSED_SIZE
from roverav_cli import Connection, add_group, integer_at_least, positive_int
from shm_protocol import (
    DEFAULT_NAME,
    SPIN_S,
    FrameReader,
    FrameWriter,
    LayoutError,
    SegmentNotFoundError,
    ShmError,
    available_cores,
    camera_name,
    machine_spin,
    slot_name,
    validate_name,
)

if TYPE_CHECKING:
    from active_vision.history import SlotHistory
    from active_vision.perception import Perception
    from active_vision.predict import Predictor
    from active_vision.sources import FrameSource

logger = logging.getLogger("active_vision.daemon")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
IDLE_POLL_S = 0.2
"""Longest wait for a frame before the loop looks at its signals and heartbeat again."""
PNG_PREVIEW_EVERY_S = 0.5
SPIN_RECHECK_S = 5.0
"""How often a worker looks again whether its camera waits may spin (other daemons on this
machine may have started or stopped)."""


@dataclass
class DaemonConfig:
    """The daemon's options (CLI flags of the same names)."""

    name: str = DEFAULT_NAME
    """Base segment name; slot i uses ``slot_name(name, i)``."""
    slots: int = 1
    """Number of slots (one per env of a vector env)."""
    size: int = FUSED_SIZE[0]
    """Side of the square camera and fused frames (a multiple of 16; the seed's 96)."""
    depth: str = "model"
    """``model``: depth channel from the network; ``render``: from the camera frame's 4th
    channel (the env sends RGB + depth)."""
    threads: int = 1
    """Threads of the perception network (torch threads / ONNX Runtime intra-op threads)."""
    workers: int = 0
    """Serving loops (threads), each with its own network session, worker ``k`` serving the
    slots ``i`` with ``i % workers == k``; 0: one per CPU this process may run on, at most
    one per slot (:func:`worker_count`). 1: one loop runs the new frames of every slot as one
    batch (where batching pays, as on a GPU). A video or device source has one loop."""
    backend: str = "auto"
    """``auto`` (ONNX Runtime when installed, else torch), ``onnx`` or ``torch``."""
    precision: str = "auto"
    """``auto`` (the int8 model in ONNX Runtime where it agrees with fp32 here and is faster,
    else fp32, one log line saying why), ``int8`` (refused where it disagrees) or ``fp32``;
    ``active_vision.backends.DEFAULT_PRECISION``."""
    source: str = "camera"
    """``camera`` (segments written by envs), ``video:PATH``, ``device:N`` or
    ``bag:PATH[#TOPIC]`` (a ROS 2 bag's image topic)."""
    preview: Path | None = None
    """PNG or MP4 preview of slot 0 (camera frame and the fused channels)."""
    log_every: int = 1000
    """Log per-stage timings every this many frames (0: never)."""
    stale_after: float = 2.0
    """Heartbeat age (s) after which an existing fused segment's writer counts as dead (so
    its segments may be taken over); the heartbeat is refreshed 4x as often."""
    weights: Path | None = None
    """Network weights; default: the shipped ``active_vision/weights/avnet.pt``."""
    log_level: str = "INFO"
    heatmap: str = "detect"
    """Channel 1: ``detect`` (this frame's pedestrians) or ``predict`` (occupancy over the
    next 1.5 s from the slot's last K frames)."""
    predict_weights: Path | None = None
    """Predictor weights; default: the shipped ``active_vision/weights/predict.pt``."""
    spin_wait: str = "auto"
    """``auto``: a worker serving one slot watches for its camera frames in a busy loop for
    up to ``shm_protocol.SPIN_S`` before it sleeps where there are two cores for each env
    slot of every daemon on this machine (``shm_protocol.machine_spin``, looked at again
    every ``SPIN_RECHECK_S``); ``on``: wherever a worker serves one slot; ``off``: never."""


def worker_count(config: DaemonConfig) -> int:
    """Serving loops for ``config``: ``workers`` (0: the CPUs this process may run on), at
    most one per slot; 1 for a video or device source (it feeds every slot at once)."""
    if config.source != "camera":
        return 1
    return max(1, min(config.workers or available_cores(), config.slots))


def camera_spin(config: DaemonConfig) -> float:
    """Seconds a worker watches for its camera frames before sleeping: only a worker with
    one slot (a source over several slots sleeps on all of them at once), per
    ``config.spin_wait``."""
    if config.spin_wait == "off" or worker_count(config) < config.slots:
        return 0.0
    return SPIN_S if config.spin_wait == "on" else machine_spin(config.slots)


@dataclass
class _Worker:
    """One serving loop: some of the slots, their camera source, its own network session."""

    index: int
    slots: list[int]
    source: FrameSource
    perception: Perception
    predictor: Predictor | None


class DaemonError(RuntimeError):
    """The daemon cannot start (the message says why and what to do)."""


class _Stop:
    def __init__(self) -> None:
        self.signal: int | None = None

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.signal = signum


def _lock(name: str) -> socket.socket:
    """Hold an abstract Unix socket named after ``name``: the kernel releases it when this
    process dies however it dies, and nothing is left in any file system."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        sock.bind(f"\0roverav-av-daemon:{name}")
    except OSError:
        sock.close()
        raise
    return sock


def _live_writer(name: str, stale_after: float) -> int | None:
    """Pid of a live writer of fused segment ``name`` (alive and heartbeat fresh), or None."""
    try:
        reader = FrameReader(name, attach_timeout=0.0, stale_after=stale_after)
    except (SegmentNotFoundError, LayoutError):
        return None
    try:
        return reader.writer_pid if reader.is_writer_alive() else None
    finally:
        reader.close()


class Daemon:
    """One running daemon: segments, perception, the serve loop. See the module docstring."""

    def __init__(self, config: DaemonConfig) -> None:
        self.config = config
        self.fused: list[FrameWriter] = []
        self.sources: list[FrameSource] = []
        self.workers: list[_Worker] = []
        self._halt = threading.Event()  # a worker failed, or the first one returned
        self.stop = _Stop()
        self._lock: socket.socket | None = None
        self.preview = None
        self.history: SlotHistory | None = None  # --heatmap predict only

    # --- start-up -----------------------------------------------------------------------

    def _check_not_served(self) -> None:
        cfg = self.config
        try:
            self._lock = _lock(cfg.name)
        except OSError as exc:
            raise DaemonError(
                f"a live av-daemon already serves '{cfg.name}' (it holds the daemon lock for "
                "that name). Stop it first (SIGTERM), or start this one with another --name."
            ) from exc
        for i in range(cfg.slots):
            seg = slot_name(cfg.name, i)
            pid = _live_writer(seg, cfg.stale_after)
            if pid is not None and pid != os.getpid():
                raise DaemonError(
                    f"segment '{seg}' is served by a live writer (pid {pid}, heartbeat fresher "
                    f"than {cfg.stale_after:g} s): another av-daemon serves '{cfg.name}'. "
                    f"Stop it first (kill {pid}), or start this one with another --name."
                )

    def start(self) -> None:
        """Check, load the network, create/take over the segments. Raises DaemonError."""
        cfg = self.config
        self._check_not_served()
        # Perception first: a bad weights file fails before any segment exists.
        from active_vision.backends import BackendError
        from active_vision.models import WeightsError
        from active_vision.onnx_export import OnnxExportError
        from active_vision.perception import Perception, PerceptionConfig

        n_workers = worker_count(cfg)
        groups = [list(range(k, cfg.slots, n_workers)) for k in range(n_workers)]
        try:
            first = Perception(PerceptionConfig(
                size=cfg.size, depth=cfg.depth, threads=cfg.threads, weights=cfg.weights,
                max_batch=len(groups[0]), backend=cfg.backend,
                precision=cfg.precision))  # type: ignore[arg-type]
            perceptions = [first] + [first.clone() for _ in groups[1:]]
            predictors: list = [None] * len(groups)
            if cfg.heatmap == "predict":
                from active_vision.predict import Predictor

                predictors = [Predictor(weights=cfg.predict_weights) for _ in groups]
        except (WeightsError, BackendError, OnnxExportError) as exc:
            raise DaemonError(str(exc)) from exc
        if cfg.heatmap == "predict":
            from active_vision.history import SlotHistory
            from active_vision.predict import K

            self.history = SlotHistory(cfg.slots, K, (cfg.size, cfg.size, 3))
        from active_vision.sources import (
            BAG_KIND,
            CameraSegmentSource,
            OpenCVSource,
            SourceError,
            source_kind,
        )

        try:
            for i in range(cfg.slots):
                w = FrameWriter(slot_name(cfg.name, i), shape=(cfg.size, cfg.size, 3),
                                dtype=np.float32, create=True, replace=True)
                self.fused.append(w)
                if not w.created:
                    logger.info("took over segment %s left by a dead daemon", w.name)
            if cfg.source == "camera":
                channels = 4 if cfg.depth == "render" else 3
                spin = camera_spin(cfg)
                if spin:
                    logger.info("each worker watches for its camera frames for up to %.0f ms "
                                "before sleeping (--spin-wait %s)", spin * 1e3, cfg.spin_wait)
                for group in groups:
                    self.sources.append(CameraSegmentSource(cfg.name, cfg.slots, cfg.size,
                                                            channels, slot_ids=group,
                                                            spin=spin))
            else:
                if cfg.depth == "render":
                    raise DaemonError(f"--depth render needs --source camera (frames with a "
                                      f"depth channel); {cfg.source} has RGB only")
                if source_kind(cfg.source) == BAG_KIND:
                    from active_vision.bag_source import BagSource

                    self.sources.append(BagSource(cfg.source, cfg.slots, cfg.size))
                else:
                    self.sources.append(OpenCVSource(cfg.source, cfg.slots, cfg.size))
        except (ShmError, SourceError, OSError) as exc:
            self.shutdown()
            raise DaemonError(str(exc)) from exc
        except BaseException:
            self.shutdown()
            raise
        self.workers = [_Worker(k, group, src, perc, pred) for k, (group, src, perc, pred)
                        in enumerate(zip(groups, self.sources, perceptions, predictors,
                                         strict=True))]
        if len(self.workers) > 1:
            logger.info("%d workers (threads), each with its own network session, serve "
                        "%d slots", len(self.workers), cfg.slots)
        if cfg.preview is not None:
            from active_vision.preview import PreviewWriter

            self.preview = PreviewWriter(cfg.preview)

    @property
    def perception(self) -> Perception:
        """The first worker's network (every worker runs the same one)."""
        return self.workers[0].perception

    def segment_names(self) -> list[str]:
        names = [w.name for w in self.fused]
        for source in self.sources:
            names += list(getattr(source, "names", []))
        return names

    # --- serving ------------------------------------------------------------------------

    def serve(self) -> None:
        """Serve until SIGINT/SIGTERM (or the end of a non-looping source). With several
        workers, worker 0 runs in this thread and the others in their own; the first to
        fail stops them all, and its exception is raised here."""
        workers = self.workers
        if len(workers) == 1:
            self._serve(workers[0])
            return
        errors: list[BaseException] = []

        def run(worker: _Worker) -> None:
            try:
                self._serve(worker)
            except BaseException as exc:  # handed to the main thread, which re-raises it
                errors.append(exc)
                self._halt.set()

        threads = [threading.Thread(target=run, args=(w,), name=f"av-worker-{w.index}",
                                    daemon=True) for w in workers[1:]]
        for t in threads:
            t.start()
        try:
            self._serve(workers[0])
        finally:
            self._halt.set()
            for t in threads:
                t.join()
        if errors:
            raise errors[0]

    def _serve(self, worker: _Worker) -> None:
        """One worker's loop over its slots."""
        cfg = self.config
        source, perception, predictor = worker.source, worker.perception, worker.predictor
        fused = self.fused
        own = [fused[i] for i in worker.slots]
        hb_every = cfg.stale_after / 4.0
        last_hb = time.monotonic()
        publish_s = 0.0
        frames_since_log = 0
        t_log = time.perf_counter()
        next_png = 0.0
        channels = 4 if cfg.depth == "render" else 3
        width = len(worker.slots)
        batch = np.empty((width, cfg.size, cfg.size, channels), dtype=np.uint8)
        seqs = [0] * width
        slots = [0] * width
        # Batch views made once per size: the loop allocates no arrays per frame.
        gathered = [batch[:n] for n in range(width + 1)]
        buffer = getattr(source, "frames_buffer", None)
        history = self.history
        windows = None if history is None else np.empty(
            (width, history.k, cfg.size, cfg.size, 3), np.float32)
        detect_heat = np.empty((cfg.size, cfg.size), np.float32)
        prefix = f"worker {worker.index}: " if len(self.workers) > 1 else ""
        halt = self._halt
        readers = getattr(source, "readers", [])
        next_spin_check = time.monotonic() + SPIN_RECHECK_S
        while self.stop.signal is None and not halt.is_set():
            new = source.poll(IDLE_POLL_S)
            now = time.monotonic()
            if readers and now >= next_spin_check:
                spin = camera_spin(cfg)
                for r in readers:
                    r.spin = spin
                next_spin_check = now + SPIN_RECHECK_S
            if not new:
                if now - last_hb >= hb_every:
                    for w in own:
                        w.heartbeat()
                    last_hb = now
                if getattr(source, "finished", False):
                    logger.info("source finished; shutting down")
                    return
                continue
            n = len(new)
            first = new[0].row
            if buffer is not None and new[n - 1].row - first == n - 1:
                frames = buffer[first:first + n]  # consecutive rows: already in the buffer
                for j in range(n):
                    seqs[j] = new[j].seq
                    slots[j] = new[j].slot
            else:
                for j in range(n):
                    f = new[j]
                    batch[j] = f.data
                    seqs[j] = f.seq
                    slots[j] = f.slot
                frames = gathered[n]
            out = perception(frames)
            if predictor is not None:
                assert history is not None and windows is not None
                for j, f in enumerate(new):
                    if f.episode_start:
                        logger.debug("slot %d: episode start at camera frame %d", f.slot,
                                     f.seq)
                    history.push(f.slot, out[j], episode_start=f.episode_start)
                if self.preview is not None and slots[0] == 0:
                    detect_heat[:] = out[0, :, :, CHANNEL_HEATMAP]
                for j in range(n):
                    history.window(slots[j], out=windows[j])
                out[:, :, :, CHANNEL_HEATMAP] = predictor(windows[:n])
            t0 = time.perf_counter()
            for j in range(n):
                fused[slots[j]].publish(out[j], source_seq=seqs[j])
            publish_s += time.perf_counter() - t0
            last_hb = now
            if self.preview is not None and slots[0] == 0:
                if self.preview.video or now >= next_png:
                    self.preview.write(frames[0], out[0],
                                       detect_heat if predictor is not None else None)
                    next_png = now + PNG_PREVIEW_EVERY_S
            frames_since_log += n
            if cfg.log_every and frames_since_log >= cfg.log_every:
                tm = perception.timings
                ms = tm.per_frame_ms()
                pub = 1e3 * publish_s / max(tm.frames, 1)
                wall = time.perf_counter() - t_log
                logger.info(
                    "%s%d frames in %d batches (%.2f/batch): input %.3f ms/frame, network "
                    "%.3f, publish %.3f, total %.3f; %.1f frames/s", prefix,
                    tm.frames, tm.batches, tm.frames / max(tm.batches, 1), ms["input"],
                    ms["network"], pub, ms["input"] + ms["network"] + pub,
                    tm.frames / wall if wall > 0 else 0.0,
                )
                tm.reset()
                publish_s = 0.0
                frames_since_log = 0
                t_log = time.perf_counter()

    # --- shutdown -----------------------------------------------------------------------

    def shutdown(self) -> None:
        """Flag shutting-down and unlink every segment this daemon holds. Idempotent."""
        if self.preview is not None:
            self.preview.close()
        sources, self.sources = self.sources, []
        self.workers = []
        for source in sources:
            close = source.close  # type: ignore[attr-defined]
            if hasattr(source, "names"):
                close(unlink=True)  # camera segments: this daemon made them
            else:
                close()
        for w in self.fused:
            try:
                w.close(unlink=True)
            except ShmError as exc:
                logger.warning("closing %s: %s", w.name, exc)
        self.fused = []
        if self._lock is not None:
            self._lock.close()
            self._lock = None


def _count(text: str) -> int:
    return integer_at_least(text, 0, " (0: one per CPU core)")


def _size(text: str) -> int:
    v = positive_int(text)
    if v % 16:
        raise argparse.ArgumentTypeError(f"must be a multiple of 16 (the network halves the "
                                         f"frame four times), got {v}")
    return v


def _source(text: str) -> str:
    from active_vision.sources import SourceError, source_kind

    try:
        source_kind(text)
    except SourceError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def build_parser() -> argparse.ArgumentParser:
    """av-daemon's command line (no torch: it loads when serving starts)."""
    from active_vision.choices import BACKENDS, PRECISION_CHOICES

    d = DaemonConfig()
    p = argparse.ArgumentParser(
        prog="av-daemon",
        description="Active Vision daemon: camera frames in, fused observations out (shared "
                    "memory). Prints a line with 'ready' when a peer can attach.")
    add_group(p, Connection)
    p.add_argument("--size", type=_size, default=d.size, help="frame side in pixels")
    p.add_argument("--depth", choices=("model", "render"), default=d.depth,
                   help="depth channel from the network, or from the camera frame's 4th "
                        "channel (renderer's depth)")
    p.add_argument("--backend", choices=BACKENDS, default=d.backend,
                   help="inference backend of the perception network: auto (default: ONNX "
                        "Runtime when onnxruntime is installed, else torch, with one log "
                        "line), onnx (ONNX Runtime; the .onnx file ships with the weights or "
                        "is exported once into ~/.cache/roverav) or torch (eager)")
    p.add_argument("--precision", choices=PRECISION_CHOICES, default=d.precision,
                   help="auto (default): the shipped int8 model in ONNX Runtime where it "
                        "agrees with fp32 on this CPU and is faster, else fp32 (measured "
                        "once, cached in ~/.cache/roverav, one log line says why); int8: the "
                        "int8 model, refused where it disagrees with fp32 here; fp32: the "
                        "fp32 export, unchecked (torch: always fp32)")
    p.add_argument("--threads", type=positive_int, default=d.threads,
                   help="threads of the perception network (torch / ONNX Runtime intra-op)")
    p.add_argument("--workers", type=_count, default=d.workers,
                   help="serving loops (threads), each with its own network session; 0 "
                        "(default): one per CPU core, at most one per slot, so each env's "
                        "frame runs while the others render; 1: one loop batching every "
                        "slot's new frame (where batching pays, as on a GPU)")
    p.add_argument("--spin-wait", choices=("auto", "on", "off"), default=d.spin_wait,
                   help="a worker serving one slot watches for its camera frames for up to "
                        "3 ms before sleeping, taking the wake-up off the env's step: auto "
                        "(default) where the machine has two cores for each env slot of its "
                        "daemons (one for the env, one for its worker), on, or off (a "
                        "machine shared with other work)")
    p.add_argument("--source", type=_source, default=d.source,
                   help="camera (segments written by envs), video:PATH, device:N or "
                        "bag:PATH[#TOPIC] (a ROS 2 bag's image topic: an .mcap or .db3 file "
                        "or a rosbag2 directory, played at its timestamps; the topic "
                        "defaults to /camera/image_raw, else its image topic; needs "
                        "pip install 'roverav[ros]')")
    p.add_argument("--preview", type=Path, default=None,
                   help="write a PNG (or .mp4) of slot 0: camera + fused channels")
    p.add_argument("--log-every", type=int, default=d.log_every,
                   help="log per-stage timings every N frames (0: never)")
    p.add_argument("--stale-after", type=float, default=d.stale_after,
                   help="heartbeat age (s) after which an existing daemon counts as dead")
    p.add_argument("--weights", type=Path, default=None, help="network weights file")
    p.add_argument("--heatmap", choices=("detect", "predict"), default=d.heatmap,
                   help="channel 1: this frame's detection (default), or the predicted "
                        "occupancy over the next 1.5 s from the slot's last 5 frames")
    p.add_argument("--predict-weights", type=Path, default=None,
                   help="predictor weights file (--heatmap predict)")
    return p


def parse_args(argv: Sequence[str] | None = None) -> DaemonConfig:
    p = build_parser()
    a = p.parse_args(argv)
    try:
        validate_name(a.name)
        camera_name(slot_name(a.name, a.slots - 1))
    except ValueError as exc:
        p.error(f"--name: {exc}")
    if not a.stale_after > 0:
        p.error("--stale-after must be > 0")
    return DaemonConfig(name=a.name, slots=a.slots, size=a.size, depth=a.depth,
                        threads=a.threads, workers=a.workers, backend=a.backend,
                        precision=a.precision,
                        source=a.source, preview=a.preview,
                        log_every=max(0, a.log_every), stale_after=a.stale_after,
                        weights=a.weights, log_level=a.log_level,
                        heatmap=a.heatmap, predict_weights=a.predict_weights,
                        spin_wait=a.spin_wait)


def main(argv: Sequence[str] | None = None) -> int:
    cfg = parse_args(argv)
    logging.basicConfig(level=cfg.log_level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    daemon = Daemon(cfg)
    stop = daemon.stop
    old = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            daemon.start()
        except DaemonError as exc:
            print(f"av-daemon: {exc}", file=sys.stderr, flush=True)
            return EXIT_FAILURE
        if stop.signal is None:
            names = daemon.segment_names()
            print(f"{READY_MARKER}: name={cfg.name} slots={cfg.slots} size={cfg.size} "
                  f"depth={cfg.depth} workers={len(daemon.workers)} "
                  f"backend={daemon.perception.backend} "
                  f"precision={daemon.perception.precision} "
                  f"heatmap={cfg.heatmap} source={cfg.source} pid={os.getpid()} "
                  f"segments={','.join(names)}", flush=True)
            daemon.serve()
        if stop.signal is not None:
            logger.info("signal %d: shutting down", stop.signal)
        return EXIT_OK
    finally:
        daemon.shutdown()
        for s, h in old.items():
            signal.signal(s, h)


if __name__ == "__main__":
    raise SystemExit(main())
