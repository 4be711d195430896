"""The fused channels of your own recorded camera, written beside it into a new MCAP file.

    python -m active_vision.bag_fuse IN OUT.mcap [--topic /camera/image_raw]
        [--backend auto|onnx|torch] [--precision int8|fp32] [--threads 1] [--weights FILE]
        [--batch 16] [--log-level INFO]

Reads every image of one image topic of the bag ``IN`` (a ``.mcap`` file, a ``.db3`` file or
a rosbag2 directory; the topic as ``av-daemon --source bag:IN#TOPIC`` chooses it), turns each
into the daemon's camera frame (96 x 96 RGB, ``INTER_AREA``) and runs the daemon's
perception on it (:class:`~active_vision.perception.Perception`, in this process, no
daemon, in batches of ``--batch``). ``OUT`` gets the original image messages, as they were,
on their topic, and for each the fused channels on ``/active_vision/gray``,
``/active_vision/heatmap`` and ``/active_vision/depth`` (``32FC1`` images; depth in metres)
with the original's log time and header stamp and frame: open ``OUT`` in Foxglove and the
camera and the heatmap play side by side.

Exit status 0; 1 when the bag cannot be read as asked (the message says why: no bag there,
truncated or corrupt, no such topic, no image topic, an encoding not read here) or the
network does not load; 2 for bad usage. ``OUT`` is written under ``OUT.part`` and appears
only when complete. Needs ``pip install 'roverav[ros]'``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from active_vision.bag_source import camera_frame
from active_vision.ros_formats import (
    COMPRESSIONS,
    BagImage,
    BagImageReader,
    McapWriter,
    RosFormatError,
    fused_messages,
)
from fused_image import FUSED_SIZE

logger = logging.getLogger("active_vision.bag_fuse")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


@dataclass(frozen=True)
class FuseConfig:
    """How :func:`fuse_bag` runs (the command's flags of the same names)."""

    topic: str | None = None
    """The image topic; None: ``/camera/image_raw``, else the bag's image topic."""
    backend: str = "auto"
    precision: str = "int8"
    threads: int = 1
    weights: Path | None = None
    batch: int = 16
    """Frames per perception call."""
    size: int = FUSED_SIZE[0]
    compression: str = "zstd"


@dataclass(frozen=True)
class FuseReport:
    """What :func:`fuse_bag` wrote."""

    path: Path
    topic: str
    frames: int
    backend: str
    precision: str


def fuse_bag(src: Path | str, dst: Path | str, config: FuseConfig | None = None) -> FuseReport:
    """Write ``dst``: the image topic of bag ``src`` and its fused channels (module
    docstring). Raises :class:`~active_vision.ros_formats.RosFormatError` for a bag it
    cannot read as asked, and the perception's errors for weights that do not load."""
    from active_vision.perception import Perception, PerceptionConfig

    cfg = config or FuseConfig()
    if cfg.batch < 1:
        raise ValueError(f"batch must be >= 1, got {cfg.batch}")
    with BagImageReader(src, cfg.topic) as reader:
        perception = Perception(PerceptionConfig(
            size=cfg.size, threads=cfg.threads, weights=cfg.weights, max_batch=cfg.batch,
            backend=cfg.backend, precision=cfg.precision))
        frames = 0
        with McapWriter(dst, compression=cfg.compression) as writer:
            pending: list[BagImage] = []

            def flush() -> None:
                batch = np.stack([camera_frame(img.rgb, cfg.size) for img in pending])
                fused = perception(batch)
                for img, out in zip(pending, fused, strict=True):
                    writer.write_raw(reader.topic, reader.msgtype, img.raw, img.log_ns,
                                     msgdef=reader.msgdef)
                    for topic, msg in fused_messages(out, img.stamp_ns, img.frame_id):
                        writer.write(topic, msg, img.log_ns)
                pending.clear()

            for image in reader.frames():
                pending.append(image)
                frames += 1
                if len(pending) == cfg.batch:
                    flush()
            if pending:
                flush()
        logger.info("%d images of %s fused into %s", frames, reader.topic, dst)
        return FuseReport(Path(dst), reader.topic, frames, perception.backend,
                          perception.precision)


def parse_args(argv: Sequence[str] | None = None) -> tuple[Path, Path, FuseConfig, str]:
    from active_vision.choices import BACKENDS, PRECISIONS

    d = FuseConfig()
    p = argparse.ArgumentParser(
        prog="python -m active_vision.bag_fuse",
        description="The daemon's fused channels (gray, heatmap, depth) of a ROS 2 bag's "
                    "camera, written beside its images into a new MCAP file.")
    p.add_argument("src", type=Path, metavar="IN",
                   help="the bag: a .mcap file, a .db3 file or a rosbag2 directory")
    p.add_argument("dst", type=Path, metavar="OUT", help="the MCAP file to write")
    p.add_argument("--topic", default=None,
                   help="the image topic (default: /camera/image_raw when the bag has it, "
                        "else its image topic with the most messages)")
    p.add_argument("--backend", choices=BACKENDS, default=d.backend,
                   help="inference backend, as av-daemon --backend")
    p.add_argument("--precision", choices=PRECISIONS, default=d.precision,
                   help="as av-daemon --precision")
    p.add_argument("--threads", type=int, default=d.threads, help="network threads")
    p.add_argument("--weights", type=Path, default=None, help="network weights file")
    p.add_argument("--batch", type=int, default=d.batch, help="frames per network call")
    p.add_argument("--compression", choices=COMPRESSIONS, default=d.compression,
                   help="MCAP chunk compression of OUT")
    p.add_argument("--log-level", type=str.upper, default="INFO",
                   choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    a = p.parse_args(argv)
    if a.threads < 1 or a.batch < 1:
        p.error(f"--threads and --batch must be >= 1, got {a.threads} and {a.batch}")
    if a.dst.resolve() == a.src.resolve():
        p.error("OUT must be another file than IN")
    cfg = FuseConfig(topic=a.topic, backend=a.backend, precision=a.precision,
                     threads=a.threads, weights=a.weights, batch=a.batch,
                     compression=a.compression)
    return a.src, a.dst, cfg, a.log_level


def main(argv: Sequence[str] | None = None) -> int:
    from active_vision.backends import BackendError
    from active_vision.models import WeightsError
    from active_vision.onnx_export import OnnxExportError

    src, dst, cfg, level = parse_args(argv)
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        report = fuse_bag(src, dst, cfg)
    except (RosFormatError, WeightsError, BackendError, OnnxExportError) as exc:
        print(f"bag_fuse: {exc}", file=sys.stderr, flush=True)
        return EXIT_FAILURE
    print(f"wrote {report.path}: {report.frames} images of {report.topic} with "
          f"/active_vision/gray, /heatmap, /depth ({report.backend}, {report.precision})",
          flush=True)
    return EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
