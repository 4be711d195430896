"""Which precision the ONNX backend runs here: int8 where it is faster, with its quality
checked on this CPU.

The int8 model (:mod:`active_vision.training.quantize`) is not equally good everywhere: on
x86 CPUs without an int8 dot-product instruction (VNNI) ONNX Runtime's u8s8 kernels add
pairs of uint8 x int8 products in 16 bits, which saturates with full 8-bit weights and
wrecks the heatmap and the depth; and where it is right it may still be no faster than
fp32. So the daemon measures rather than reads instruction flags (``--precision``,
:func:`choose_precision`):

- **the agreement check**: the int8 model and the fp32 export run on the committed
  reference frames (:data:`REFERENCE_FRAMES`, rendered from the worlds with pedestrians by
  ``python -m active_vision.training.reference_frames``; :class:`ReferenceRecipe`), and
  :func:`agreement` compares them: the detections' IoU (pixels with heatmap >= 0.5, summed
  over the frames) and the depth AbsRel of int8 against fp32 (pixels fp32 puts at
  0.3-10 m). :class:`AgreementLimits` says what passes, and why;
- **the timing**: both models at batch 1 on the daemon's thread count, interleaved rounds,
  the fastest round of each (:func:`time_networks`);
- ``auto`` (the default) runs int8 only if it agrees and is at least ``MIN_SPEEDUP`` times
  as fast, else fp32, and logs in one line what it chose and why with the figures;
  ``int8`` runs int8 if it agrees and otherwise is refused (:class:`BackendError`, naming
  the figure and ``--precision fp32``); ``fp32`` runs fp32 without any check.

The measurement is cached once per CPU (model name and flags), ONNX Runtime version, the
two model files' and the reference frames' sha256, and thread count
(:func:`cache_key`) in ``$XDG_CACHE_HOME/roverav/active_vision/precision/``
(:data:`PRECISION_CACHE_DIR`), so later starts only hash the files. Delete the file (its
path is in the log line) or run ``python -m active_vision.precision --remeasure`` to
measure again.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import platform
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from active_vision.backends import BackendError, OnnxNetwork, Precision
from active_vision.models import MIN_DEPTH_M
from fused_image import CHANNEL_DEPTH, CHANNEL_HEATMAP, DEPTH_MAX_M, FUSED_SIZE, channel_to_depth

logger = logging.getLogger(__name__)

REFERENCE_FRAMES = Path(__file__).resolve().parent / "weights" / "reference_frames.npz"
"""The committed reference frames: ``rgb`` uint8 ``(N, 96, 96, 3)`` and ``recipe`` (the
:class:`ReferenceRecipe` they were rendered with, JSON)."""
PRECISION_CACHE_DIR = (
    Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    / "roverav" / "active_vision" / "precision"
)
"""Where measurements are cached, one JSON file per :func:`cache_key`."""
CHECK_VERSION = 1
"""Part of the cache key: bump it when what is measured changes, so old files are not read."""
DETECTION_THRESHOLD = 0.5
"""A heatmap pixel is a detection at this value or above (the evaluator's ``THRESHOLD``,
which the runtime may not import; tests/test_av_precision.py holds them equal)."""
NEAR_DEPTH_M = 0.3
"""Depth pixels compared: fp32's depth in ``[NEAR_DEPTH_M, DEPTH_MAX_M)`` (the evaluator's
range for AbsRel, its ``NEAR_DEPTH_M``); int8's depth is clipped to at least
``models.MIN_DEPTH_M``, as the evaluator does."""
MIN_SPEEDUP = 1.05
"""``auto`` runs int8 only when fp32 takes at least this many times as long a frame: below
it the difference is within what timing a few frames can tell, and fp32 is the exact one."""
TIMING_ROUNDS = 8
TIMING_WARMUP = 3
TIMING_ITERS = 10
"""Timing: ``TIMING_ROUNDS`` interleaved rounds (the models' order swapped each round),
each model run ``TIMING_WARMUP`` times and then timed over ``TIMING_ITERS`` runs at batch 1;
a model's time is its fastest round (another process taking the CPU only slows rounds)."""
_INT8_FLAGS = ("avx512_vnni", "avx_vnni", "amx_int8", "asimddp", "i8mm")
"""CPU flags of int8 dot-product instructions, named in the log line (not decisive)."""


@dataclass(frozen=True)
class AgreementLimits:
    """What the int8 model must reach against the fp32 export on the reference frames.

    The held-out targets (:data:`active_vision.training.evaluate.TARGETS`) are IoU >= 0.6,
    recall >= 0.95, false-positive frames <= 2 %, AbsRel <= 0.15 and delta1 >= 0.85; fp32's
    worst worlds, among the pacers and crowds of 3 and 10, read IoU 0.832, AbsRel 0.097 and
    delta1 0.898 (benchmarks/RESULTS.md), margins of 0.23, 0.053 and 0.048.
    """

    detection_iou: float = 0.95
    """Least IoU of int8's detections with fp32's. One minus the IoU is a distance between
    masks (the Jaccard distance), so a held-out IoU against the truth moves by at most 0.05
    where the masks agree this well, a fifth of the IoU target's margin. On the reference
    frames the shipped model (7-bit weights) reads 0.991 on an AVX2 CPU without VNNI, where
    the 8-bit-weight model, whose kernels saturate there, read 0.417. Recall and false
    positives count whole blobs, which a 5 % edge disagreement does not remove or make: the
    held-out evaluation (``evaluate --precision int8``) is what shows their targets hold."""
    depth_abs_rel: float = 0.03
    """Most AbsRel of int8's depth against fp32's. The held-out AbsRel moves by at most about
    this much (``|p8 - d| <= |p32 - d| + |p8 - p32|``), under 0.053 of margin, and delta1
    counts the pixels whose ratio it pushes over 1.25. The shipped model reads 0.011 on the
    AVX2 CPU, the saturating one 0.350."""

    def problems(self, detection_iou: float, depth_abs_rel: float) -> list[str]:
        """The figures that miss a limit, each with the limit, worded for a message."""
        out = []
        if not detection_iou >= self.detection_iou:
            out.append(f"detection IoU {detection_iou:.3f} < {self.detection_iou}")
        if not depth_abs_rel <= self.depth_abs_rel:
            out.append(f"depth AbsRel {depth_abs_rel:.3f} > {self.depth_abs_rel}")
        return out


@dataclass(frozen=True)
class ReferenceRecipe:
    """How the reference frames are rendered (stored in their file; ``python -m
    active_vision.training.reference_frames`` remakes them from these defaults)."""

    scenes: tuple[str, ...] = ("pacing", "crowd:10")
    """Pedestrian scenes (``dataset.crowd_config``: the world's 3 pacers, a crowd of 10)."""
    frames_per_scene: int = 16
    """Posed frames per scene, over the worlds in turn (walking, placed and empty views)."""
    seed: int = 3_000_003
    """Neither the training seeds, the held-out (1,000,003) nor the validation (2,000,003)."""


@dataclass(frozen=True)
class CpuIdentity:
    """The CPU as the cache key and the log line name it."""

    model: str
    flags: tuple[str, ...]

    def int8_summary(self) -> str:
        """E.g. ``avx2, no int8 dot-product instruction`` or ``avx512_vnni, amx_int8``."""
        found = [f for f in _INT8_FLAGS if f in self.flags]
        if found:
            return ", ".join(found)
        simd = "avx512f" if "avx512f" in self.flags else "avx2" if "avx2" in self.flags else ""
        return f"{simd + ', ' if simd else ''}no int8 dot-product instruction"


def cpu_identity(cpuinfo: Path = Path("/proc/cpuinfo")) -> CpuIdentity:
    """The first processor's model name and flags in ``cpuinfo`` (``flags`` on x86,
    ``Features`` on Arm); ``platform`` names it where the file is not there."""
    model = ""
    flags: tuple[str, ...] = ()
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        text = ""
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("model name", "Hardware") and not model:
            model = value.strip()
        elif key in ("flags", "Features") and not flags:
            flags = tuple(sorted(value.split()))
        if model and flags:
            break
    return CpuIdentity(model or platform.processor() or platform.machine(), flags)


@dataclass
class Measurement:
    """The int8 model against the fp32 export on this machine (what is cached)."""

    detection_iou: float
    """IoU of int8's detections with fp32's over the reference frames."""
    depth_abs_rel: float
    """AbsRel of int8's depth against fp32's (pixels fp32 puts at 0.3-10 m)."""
    fp32_ms: float
    int8_ms: float
    """Milliseconds a frame, batch 1, on ``threads`` threads (the fastest round)."""
    frames: int
    threads: int
    cpu: str
    """Model name and int8 instructions (:meth:`CpuIdentity.int8_summary`)."""
    measured_at: str
    """UTC, ISO 8601."""

    @property
    def speedup(self) -> float:
        return self.fp32_ms / self.int8_ms if self.int8_ms > 0 else 0.0

    def figures(self, limits: AgreementLimits | None = None) -> str:
        """The figures, with the limits, for a log line or message."""
        lim = limits or AgreementLimits()
        return (f"on {self.frames} reference frames detection IoU {self.detection_iou:.3f} "
                f"(>= {lim.detection_iou}), depth AbsRel {self.depth_abs_rel:.3f} "
                f"(<= {lim.depth_abs_rel}); int8 {self.int8_ms:.2f} ms a frame against fp32 "
                f"{self.fp32_ms:.2f} ms ({self.speedup:.2f}x, {self.threads} thread"
                f"{'s' if self.threads != 1 else ''}) on {self.cpu}")


@dataclass(frozen=True)
class Choice:
    """What :func:`decide` picked from a :class:`Measurement`."""

    precision: Precision
    agrees: bool
    problems: tuple[str, ...] = field(default=())
    """The agreement figures that miss a limit (empty when it agrees)."""
    reason: str = ""
    """Why, in a few words, for the log line."""


class ReferenceFramesError(BackendError):
    """The reference frames cannot be read (the message says what to do)."""


def load_reference_frames(path: Path | None = None) -> np.ndarray:
    """The reference frames ``(N, 96, 96, 3)`` uint8 RGB of ``path`` (default
    :data:`REFERENCE_FRAMES`).

    :raises ReferenceFramesError: the file is missing or holds no ``rgb`` frames.
    """
    path = Path(path) if path is not None else REFERENCE_FRAMES
    try:
        with np.load(path) as z:
            rgb = np.asarray(z["rgb"])
    except (OSError, KeyError, ValueError) as exc:
        raise ReferenceFramesError(
            f"cannot read the reference frames {path} ({exc}); reinstall roverav, remake "
            "them with `python -m active_vision.training.reference_frames`, or run "
            "--precision fp32") from exc
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise ReferenceFramesError(f"{path}: expected uint8 frames (N, S, S, 3), found {rgb.dtype} "
                           f"{rgb.shape}; remake it with `python -m "
                           "active_vision.training.reference_frames`")
    return rgb


def reference_recipe(path: Path | None = None) -> ReferenceRecipe:
    """The recipe stored in the reference frames file ``path``."""
    with np.load(Path(path) if path is not None else REFERENCE_FRAMES) as z:
        stored = json.loads(str(z["recipe"]))
    stored["scenes"] = tuple(stored["scenes"])
    return ReferenceRecipe(**stored)


def agreement(fp32: np.ndarray, int8: np.ndarray) -> tuple[float, float]:
    """Detection IoU and depth AbsRel of the fused frames ``int8`` against ``fp32`` (both
    ``(N, S, S, 3)``, see :class:`AgreementLimits`). With no detection in either, the IoU
    is 1; with no depth pixel in range, the AbsRel is 0."""
    a = fp32[..., CHANNEL_HEATMAP] >= DETECTION_THRESHOLD
    b = int8[..., CHANNEL_HEATMAP] >= DETECTION_THRESHOLD
    union = int(np.count_nonzero(a | b))
    iou = np.count_nonzero(a & b) / union if union else 1.0
    d32 = channel_to_depth(fp32[..., CHANNEL_DEPTH])
    d8 = np.maximum(channel_to_depth(int8[..., CHANNEL_DEPTH]), np.float32(MIN_DEPTH_M))
    valid = (d32 >= NEAR_DEPTH_M) & (d32 < DEPTH_MAX_M)
    ref = d32[valid].astype(np.float64)
    abs_rel = float(np.mean(np.abs(d8[valid] - ref) / ref)) if ref.size else 0.0
    return float(iou), abs_rel


def at_side(frames: np.ndarray, size: int) -> np.ndarray:
    """uint8 ``frames`` ``(N, H, W, 3)`` at side ``size`` (resized with ``INTER_AREA``, as
    :class:`~active_vision.perception.Perception` does, where they are another size)."""
    if frames.shape[1:3] == (size, size):
        return frames
    import cv2

    return np.stack([cv2.resize(f, (size, size), interpolation=cv2.INTER_AREA) for f in frames])


def fused_of(net: OnnxNetwork, frames: np.ndarray) -> np.ndarray:
    """A copy of ``net``'s fused frames of uint8 ``frames`` ``(N, S, S, 3)``."""
    n = len(frames)
    net.input(n)[...] = frames
    return net.run(n).copy()


def time_networks(nets: dict[str, OnnxNetwork], frame: np.ndarray,
                  rounds: int = TIMING_ROUNDS, iters: int = TIMING_ITERS) -> dict[str, float]:
    """Milliseconds a frame of each network at batch 1 on ``frame`` (uint8 ``(S, S, 3)`` at
    the networks' side): interleaved rounds, the fastest round of each."""
    for net in nets.values():
        net.input(1)[...] = frame
    best = {k: float("inf") for k in nets}
    order = list(nets.items())
    for r in range(rounds):
        for k, net in (order if r % 2 == 0 else order[::-1]):
            for _ in range(TIMING_WARMUP):
                net.run(1)
            t0 = time.perf_counter()
            for _ in range(iters):
                net.run(1)
            best[k] = min(best[k], 1e3 * (time.perf_counter() - t0) / iters)
    return best


class Int8LoadError(BackendError):
    """ONNX Runtime cannot load the int8 model (a build without its quantized kernels)."""


def measure(fp32: Path, int8: Path, size: int = FUSED_SIZE[0], threads: int = 1,
            frames: np.ndarray | None = None) -> Measurement:
    """Run the agreement check and the timing of the int8 model ``int8`` against the fp32
    export ``fp32`` on ``frames`` (default: the reference frames) on ``threads`` threads.

    :raises Int8LoadError: the int8 model does not load.
    :raises ReferenceFramesError: the reference frames cannot be read.
    :raises BackendError: the fp32 export does not load.
    """
    frames = at_side(load_reference_frames() if frames is None else frames, size)
    n = len(frames)
    ref = OnnxNetwork(fp32, size, threads=threads, capacity=n)
    try:
        low = OnnxNetwork(int8, size, threads=threads, capacity=n, precision="int8")
    except BackendError as exc:
        raise Int8LoadError(str(exc)) from exc
    iou, abs_rel = agreement(fused_of(ref, frames), fused_of(low, frames))
    ms = time_networks({"fp32": ref, "int8": low}, frames[0])
    cpu = cpu_identity()
    return Measurement(detection_iou=iou, depth_abs_rel=abs_rel, fp32_ms=ms["fp32"],
                       int8_ms=ms["int8"], frames=n, threads=threads,
                       cpu=f"{cpu.model}: {cpu.int8_summary()}",
                       measured_at=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))


def file_digest(path: Path) -> str:
    """sha256 of the file at ``path`` (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cache_key(fp32: Path, int8: Path, size: int, threads: int,
              frames: Path | None = None) -> dict[str, object]:
    """What a measurement depends on: the CPU (model name, sha256 of its flags), ONNX
    Runtime's version, the sha256 of the two models and of the reference frames, the frame
    side, the threads and :data:`CHECK_VERSION`."""
    import onnxruntime

    frames = frames or REFERENCE_FRAMES
    try:
        frames_digest = file_digest(frames)
    except OSError as exc:
        raise ReferenceFramesError(
            f"cannot read the reference frames {frames} ({exc.strerror}); reinstall roverav, "
            "or remake them with `python -m active_vision.training.reference_frames`") from exc
    cpu = cpu_identity()
    return {"check": CHECK_VERSION, "cpu": cpu.model,
            "flags": hashlib.sha256(" ".join(cpu.flags).encode()).hexdigest()[:16],
            "onnxruntime": onnxruntime.__version__, "fp32": file_digest(fp32)[:16],
            "int8": file_digest(int8)[:16], "frames": frames_digest[:16], "size": size,
            "threads": threads}


def cache_file(key: dict[str, object], cache_dir: Path | None = None) -> Path:
    """The JSON file of ``key`` in ``cache_dir`` (default :data:`PRECISION_CACHE_DIR`)."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return Path(cache_dir if cache_dir is not None else PRECISION_CACHE_DIR) / f"{digest}.json"


def read_cached(path: Path, key: dict[str, object]) -> Measurement | None:
    """The measurement cached in ``path`` for ``key``, or None (absent, another key, or
    unreadable: measured again and rewritten)."""
    try:
        stored = json.loads(path.read_text())
        if stored.get("key") != key:
            return None
        return Measurement(**stored["measurement"])
    except FileNotFoundError:
        return None
    except (OSError, ValueError, TypeError, KeyError) as exc:
        logger.debug("ignoring the unreadable precision cache %s (%s)", path, exc)
        return None


def write_cached(path: Path, key: dict[str, object], m: Measurement) -> bool:
    """Store ``m`` for ``key`` in ``path`` (atomically); False when it cannot be written."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps({"key": key, "measurement": asdict(m)}, indent=1))
        tmp.replace(path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        logger.debug("cannot cache the precision measurement in %s (%s)", path, exc)
        return False
    return True


def measured(fp32: Path, int8: Path, size: int = FUSED_SIZE[0], threads: int = 1,
             cache_dir: Path | None = None, remeasure: bool = False
             ) -> tuple[Measurement, Path, bool]:
    """The measurement of ``int8`` against ``fp32`` here: cached, or made now and cached.
    Returns it, its cache file, and whether it came from the cache."""
    key = cache_key(fp32, int8, size, threads)
    path = cache_file(key, cache_dir)
    if not remeasure:
        cached = read_cached(path, key)
        if cached is not None:
            return cached, path, True
    m = measure(fp32, int8, size, threads)
    write_cached(path, key, m)
    return m, path, False


def decide(m: Measurement, limits: AgreementLimits | None = None) -> Choice:
    """``auto``'s pick from ``m``: int8 if it agrees within ``limits`` and is at least
    ``MIN_SPEEDUP`` times as fast as fp32, else fp32."""
    problems = tuple((limits or AgreementLimits()).problems(m.detection_iou, m.depth_abs_rel))
    if problems:
        return Choice("fp32", False, problems,
                      f"the int8 model disagrees with fp32 here ({', '.join(problems)})")
    if m.speedup < MIN_SPEEDUP:
        return Choice("fp32", True, (), f"int8 agrees with fp32 but is only {m.speedup:.2f}x "
                                        f"as fast here (< {MIN_SPEEDUP}x)")
    return Choice("int8", True, (), f"it agrees with fp32 and is {m.speedup:.2f}x as fast "
                                    "here")


def choose_precision(requested: str, fp32: Path, int8: Path, size: int = FUSED_SIZE[0],
                     threads: int = 1, *, limits: AgreementLimits | None = None,
                     cache_dir: Path | None = None) -> Precision:
    """The precision the ONNX backend runs for ``requested`` (``auto`` or ``int8``), with
    the int8 model ``int8`` and the fp32 export ``fp32`` both there (see the module
    docstring). Logs one line; an int8 model that does not load gives fp32 with one warning,
    and so do reference frames that cannot be read under ``auto``.

    :raises BackendError: ``int8`` is asked for and the int8 model disagrees with fp32 here,
        or cannot be checked (:class:`ReferenceFramesError`).
    """
    if requested not in ("auto", "int8"):
        raise ValueError(f"requested must be auto or int8, got {requested!r}")
    try:
        m, path, cached = measured(fp32, int8, size, threads, cache_dir)
    except Int8LoadError as exc:
        logger.warning("the int8 model does not load here, perception runs the fp32 export: "
                       "%s", exc)
        return "fp32"
    except ReferenceFramesError as exc:
        if requested == "int8":
            raise
        logger.warning("precision auto: fp32, since the int8 model cannot be checked here: "
                       "%s", exc)
        return "fp32"
    choice = decide(m, limits)
    when = (f"cached in {path} ({m.measured_at})" if cached
            else f"measured now, cached in {path}")
    if requested == "int8":
        if not choice.agrees:
            raise BackendError(
                f"--precision int8: the int8 model {int8.name} disagrees with the fp32 export "
                f"on this CPU ({m.cpu}): {', '.join(choice.problems)} on {m.frames} reference "
                "frames. Run --precision fp32 (or auto, which picks fp32 here). Without VNNI, "
                "ONNX Runtime's int8 kernels saturate on 8-bit weights: `python -m "
                "active_vision.training.quantize --reduce-range` makes a model with 7-bit "
                f"ones ({when}).")
        logger.info("precision int8 (asked for): it agrees with fp32 %s; %s",
                    m.figures(limits), when)
        return "int8"
    logger.info("precision auto: %s, since %s: %s; %s", choice.precision, choice.reason,
                m.figures(limits), when)
    return choice.precision


def main(argv: Sequence[str] | None = None) -> int:
    from active_vision.onnx_export import int8_file_for, onnx_file_for

    p = argparse.ArgumentParser(
        prog="python -m active_vision.precision",
        description="Measure the int8 model against the fp32 export here (agreement on the "
                    "reference frames, time a frame) and say what --precision auto runs.")
    p.add_argument("--weights", type=Path, default=None, help="default: the shipped weights")
    p.add_argument("--size", type=int, default=FUSED_SIZE[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--remeasure", action="store_true",
                   help="measure again even if a measurement is cached (and cache it)")
    p.add_argument("--json", action="store_true", help="end with one JSON line")
    p.add_argument("--log-level", default="INFO")
    a = p.parse_args(argv)
    logging.basicConfig(level=a.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    try:
        fp32 = onnx_file_for(a.weights, a.size)
    except Exception as exc:  # OnnxExportError, WeightsError
        print(f"precision: {exc}", file=sys.stderr)
        return 1
    int8 = int8_file_for(a.weights, a.size)
    if int8 is None:
        print(f"precision: no int8 model of {a.weights or 'the shipped weights'}; make it with "
              "`python -m active_vision.training.quantize`", file=sys.stderr)
        return 1
    try:
        m, path, cached = measured(fp32, int8, a.size, a.threads, remeasure=a.remeasure)
    except BackendError as exc:
        print(f"precision: {exc}", file=sys.stderr)
        return 1
    choice = decide(m)
    print(f"auto runs {choice.precision}, since {choice.reason}")
    print(f"  {m.figures()}")
    print(f"  {'cached' if cached else 'measured now, cached'} in {path} ({m.measured_at})")
    if a.json:
        print(json.dumps({**asdict(m), "speedup": m.speedup, "auto": choice.precision,
                          "agrees": choice.agrees, "limits": asdict(AgreementLimits()),
                          "min_speedup": MIN_SPEEDUP, "cache": str(path)}))
    return 0


__all__ = [
    "CHECK_VERSION",
    "MIN_SPEEDUP",
    "PRECISION_CACHE_DIR",
    "REFERENCE_FRAMES",
    "AgreementLimits",
    "Choice",
    "CpuIdentity",
    "Measurement",
    "Int8LoadError",
    "ReferenceFramesError",
    "ReferenceRecipe",
    "agreement",
    "at_side",
    "cache_key",
    "choose_precision",
    "cpu_identity",
    "decide",
    "load_reference_frames",
    "measure",
    "measured",
    "reference_recipe",
    "time_networks",
]


if __name__ == "__main__":
    raise SystemExit(main())
