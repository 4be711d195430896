"""The shipped perception on real pedestrian footage: people found, box cover and false heat.

    .venv/bin/python -m benchmarks.real_footage [--precision fp32,int8]
        [--weights FILE] [--stride 8] [--video PATH] [--picture docs/real_footage.png]
        [--write-test-data tests/data/real_footage]

The network (AVNet) was trained on MuJoCo renders only. This runs it, through the daemon's own
:class:`~active_vision.perception.Perception` (ONNX Runtime, one thread, once per precision),
on frames of ``vtest.avi`` and measures at the detection threshold
(``active_vision.training.evaluate.THRESHOLD``, 0.5 on the heatmap channel):

- **people found**: a reference person is found when a detection blob (an 8-connected
  component of ``heatmap >= THRESHOLD`` with at least ``MIN_BLOB_PX`` pixels, evaluate's
  definition) overlaps the person's box by at least one pixel;
- **mean box cover**: the fraction of the person's box area with ``heatmap >= THRESHOLD``,
  averaged over the reference people;
- **false heat**: the share of people-free area with ``heatmap >= THRESHOLD``: its median over
  people-free crops (or frames), and the share of crops (frames) with more than 2 % and more
  than 10 % of it hot;
- **against the silhouette** (person crops, second table): each person's MOG2 moving
  foreground inside their box (below), kept when it fills at least ``MIN_SILHOUETTE`` of the
  box (a walking person): the silhouette's own box cover (what a heatmap exactly on the
  person scores as box cover), the heatmap's box cover on the same people, the share of the
  silhouette's pixels that are hot, and the IoU of hot pixels and silhouette in the box;
- **depth**: the network's depth in metres (``channel_to_depth``), median and 5-95th
  percentiles over every pixel of the view. The footage has no depth ground truth: a sanity
  figure (the street's far side is farther than the channel's 10 m limit).

Two views, both at the fused size (96x96, what the network runs at):

- ``crop``: 192x192 crops of the 768x576 frame, resized to 96x96 (INTER_AREA). A person crop
  is centred on a reference person (shifted to stay inside the frame); a people-free crop is
  a cell of a 192x192 grid at a 96-pixel step that keeps ``FootageConfig.free_margin`` pixels
  clear of every HOG detection and of every moving-foreground blob (below);
- ``frame``: the whole 768x576 frame resized to 96x96, what ``av-daemon --source
  video:vtest.avi`` feeds the network (:class:`active_vision.sources.OpenCVSource`). Its false
  heat is measured over the frame's people-free area (pixels clear of every HOG detection and
  foreground blob by the same margin), one figure per frame.

Reference people: OpenCV 4.x's HOG people detector (``HOGDescriptor`` with
``getDefaultPeopleDetector``, ``detectMultiScale(winStride=(8, 8), padding=(8, 8),
scale=1.05)``). A reference person's box is a detection shrunk by 15 % of its width on each
side and 5 % of its height at top and bottom (how OpenCV's ``samples/python/peopledetect.py``
draws it: HOG's window holds a margin around the person); the detections kept have an SVM
weight of at least ``FootageConfig.hog_min_weight`` and a box that fits the 192-pixel crop
(the taller ones here are groups of people or the lamp post). People-free crops keep clear of
every detection, of any weight or size. HOG misses people (those under 128 pixels tall
among them), so the people-free crops also avoid moving foreground: MOG2 background
subtraction (project OpenCV, ``history=200, varThreshold=25``, shadows excluded, 3x3
opening, blobs of at least ``fg_min_area`` pixels) over every frame of the video. A person
who stands still long enough to fade from MOG2's foreground and whom HOG misses can still
sit in a people-free crop.

Where HOG comes from: the project's OpenCV is 5.0, which dropped ``cv2.HOGDescriptor``. The
detector runs in its own process: the project's Python with ``opencv-python-headless`` 4.x
(PyPI wheel) installed with ``pip install --no-deps --target runs/footage/opencv4`` and put
first on that process's ``PYTHONPATH`` (numpy is the project's). ``--hog-python PATH`` runs
another interpreter instead, e.g. ``/usr/bin/python3`` after ``apt-get install
python3-opencv`` (Debian bookworm: OpenCV 4.6). Its boxes are cached in
``runs/footage/hog_boxes.json`` (keyed by the video's sha256, the frame stride and the HOG
settings), so a rerun skips HOG (about 0.7 s a frame on one thread).

The footage: ``vtest.avi`` (795 frames, 768x576, 10 fps, a street seen from above) from
OpenCV's sample data (``samples/data/vtest.avi``), looked for in ``--video``, the known places
(``KNOWN_PLACES``) and ``runs/footage/``; else ``apt-get download opencv-doc`` (Debian's
OpenCV 4.6 documentation package, ``apt-get update`` first if that fails) into
``runs/footage/`` and only the video and the copyright file unpacked from it (``dpkg-deb
--fsys-tarfile``). Licence: OpenCV keeps no separate licence for ``samples/data``, so the file
falls under OpenCV's own; Debian's ``/usr/share/doc/opencv-doc/copyright`` lists it under
``Files: *``: Apache-2.0 AND BSD-3-Clause, copyright Intel Corporation, Willow Garage, NVIDIA,
AMD, the OpenCV Foundation, Itseez, Xperience AI, and the OpenCV contributors. OpenCV's
repository does not record where the clip was filmed or by whom.

The rules and the targets are :mod:`active_vision.training.real_footage`'s. Targets,
at the threshold: people found >= 95 % with mean box cover >= 0.4;
people-free crops: median hot area <= 0.5 %, at most 10 % of crops with more than 2 % hot.

``--picture PATH`` writes a PNG: real crops (RGB with the reference box, heatmap, depth as the
fused image encodes it, near is bright) side by side. ``--write-test-data DIR`` writes the
crops ``tests/test_real_footage.py`` checks (``TEST_PEOPLE`` person crops and ``TEST_FREE``
people-free crops, evenly spaced over the benchmark's lists, with their boxes in
``index.json``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from active_vision.backends import PRECISIONS
from active_vision.perception import Perception, PerceptionConfig
from active_vision.training.evaluate import MIN_BLOB_PX, THRESHOLD
from active_vision.training.real_footage import (
    MIN_SILHOUETTE,
    TARGETS,
    TEST_FREE,
    TEST_PEOPLE,
    Figures,
    figures,
)
from benchmarks.machine import cpu_name
from fused_image import (
    CHANNEL_DEPTH,
    CHANNEL_HEATMAP,
    DEPTH_MAX_M,
    FUSED_SIZE,
    channel_to_depth,
)

ROOT = Path(__file__).resolve().parents[1]

logger = logging.getLogger("real_footage")

CACHE_DIR = ROOT / "runs" / "footage"
VIDEO_NAME = "vtest.avi"
DEB_PACKAGE = "opencv-doc"
DEB_VIDEO = "usr/share/doc/opencv-doc/examples/data/vtest.avi"
DEB_COPYRIGHT = "usr/share/doc/opencv-doc/copyright"
KNOWN_PLACES: tuple[Path, ...] = (
    Path("/") / DEB_VIDEO,
    Path("/usr/share/opencv4/samples/data/vtest.avi"),
    Path("/usr/local/share/opencv4/samples/data/vtest.avi"),
    CACHE_DIR / DEB_VIDEO,
)
"""Where ``vtest.avi`` is looked for: Debian's opencv-doc, OpenCV installs, the cache."""
OPENCV4_REQUIREMENT = "opencv-python-headless>=4.6,<5"
"""The reference detector's OpenCV (HOG is gone from 5.0)."""
PICTURE_SCALE = 2


@dataclass
class FootageConfig:
    """Which frames, which reference people, which crops."""

    stride: int = 8
    """Every ``stride``-th frame from frame 0 (8: 100 of 795 frames)."""
    crop: int = 192
    """Side of a crop in the frame's pixels (resized to the fused size)."""
    free_step: int = 96
    """Step of the grid of candidate people-free crops."""
    free_margin: int = 16
    """Pixels a people-free crop (or frame area) keeps clear of boxes and foreground blobs."""
    hog_min_weight: float = 0.5
    """Smallest HOG SVM weight kept as a reference person."""
    hog_win_stride: int = 8
    hog_padding: int = 8
    hog_scale: float = 1.05
    fg_min_area: int = 30
    """Smallest moving-foreground blob (pixels of the 768x576 frame) that counts."""


@dataclass
class Footage:
    """The reference set: person crops with their boxes, people-free crops, whole frames."""

    person_rgb: np.ndarray
    """uint8 ``(P, 96, 96, 3)``."""
    person_box: np.ndarray
    """int ``(P, 4)``: x, y, w, h in the 96x96 crop."""
    person_meta: list[dict[str, object]]
    person_silhouette: np.ndarray
    """bool ``(P, 96, 96)``: the MOG2 moving foreground inside each person's box (the person's
    silhouette while they walk; little or nothing once they stand still long enough to fade)."""
    free_rgb: np.ndarray
    """uint8 ``(F, 96, 96, 3)``."""
    free_meta: list[dict[str, object]]
    frame_rgb: np.ndarray
    """uint8 ``(N, 576, 768, 3)`` the sampled frames."""
    frame_boxes: list[np.ndarray]
    """Per sampled frame, int ``(k, 4)`` boxes in the 96x96 resized frame."""
    frame_free: np.ndarray
    """bool ``(N, 96, 96)``: the people-free area of each resized frame."""
    frame_index: list[int]
    hog_opencv: str
    frames_total: int


def tight_box(x: int, y: int, w: int, h: int) -> tuple[int, int, int, int]:
    """A HOG detection shrunk to the person (peopledetect.py: 15 % of the width off each
    side, 5 % of the height off top and bottom)."""
    pw, ph = int(0.15 * w), int(0.05 * h)
    return x + pw, y + ph, w - 2 * pw, h - 2 * ph


# --- the footage -------------------------------------------------------------------------


def _run(cmd: Sequence[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    logger.info("running: %s", " ".join(cmd))
    return subprocess.run(list(cmd), cwd=cwd, capture_output=True, text=True, check=False)


def find_video(given: Path | None = None, cache: Path = CACHE_DIR) -> Path:
    """``vtest.avi``: ``given``, a known place, or downloaded with apt into ``cache``.

    :raises RuntimeError: not found and apt could not fetch it (the message says why).
    """
    if given is not None:
        if not given.is_file():
            raise RuntimeError(f"--video {given}: no such file")
        return given
    for place in (*KNOWN_PLACES[:-1], cache / DEB_VIDEO):
        if place.is_file():
            return place
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        got = _run(["apt-get", "download", DEB_PACKAGE], cwd=Path(tmp))
        if got.returncode != 0:
            logger.info(
                "apt-get download failed (%s): apt-get update, then again",
                got.stderr.strip()[-300:],
            )
            upd = _run(["apt-get", "update", "-qq"])
            if upd.returncode != 0:
                raise RuntimeError(f"apt-get update failed: {upd.stderr.strip()[-500:]}")
            got = _run(["apt-get", "download", DEB_PACKAGE], cwd=Path(tmp))
        debs = sorted(Path(tmp).glob(f"{DEB_PACKAGE}_*.deb"))
        if got.returncode != 0 or not debs:
            raise RuntimeError(
                f"cannot download {DEB_PACKAGE} ({got.stderr.strip()[-500:]}); pass the "
                f"video with --video PATH (OpenCV's samples/data/{VIDEO_NAME})"
            )
        # only the video and the copyright file out of the 95 MB package
        tar = subprocess.run(
            ["dpkg-deb", "--fsys-tarfile", str(debs[0])], check=True, capture_output=True
        ).stdout
        subprocess.run(
            ["tar", "-x", "-C", str(cache), f"./{DEB_VIDEO}", f"./{DEB_COPYRIGHT}"],
            input=tar,
            check=True,
            capture_output=True,
        )
    logger.info("unpacked %s from %s into %s", VIDEO_NAME, debs[0].name, cache)
    return cache / DEB_VIDEO


def read_video(path: Path) -> list[np.ndarray]:
    """Every frame of ``path`` as BGR uint8 (the project's OpenCV)."""
    cap = cv2.VideoCapture(str(path))
    frames: list[np.ndarray] = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    cap.release()
    if not frames:
        raise RuntimeError(f"{path}: no frame could be read")
    return frames


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


HOG_SCRIPT = r"""
import json, sys
import cv2
import numpy as np
cv2.setNumThreads(1)
video, stride, win, pad, scale = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), \
    int(sys.argv[4]), float(sys.argv[5])
hog = cv2.HOGDescriptor()
hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
cap = cv2.VideoCapture(video)
out, i = {}, 0
while True:
    ok, frame = cap.read()
    if not ok:
        break
    if i % stride == 0:
        rects, weights = hog.detectMultiScale(frame, winStride=(win, win), padding=(pad, pad),
                                              scale=scale)
        out[str(i)] = [[int(v) for v in r] + [round(float(w), 4)]
                       for r, w in zip(rects, np.ravel(weights))]
    i += 1
print(json.dumps({"opencv": cv2.__version__, "frames_total": i, "boxes": out}))
"""


def hog_interpreter(given: str | None, cache: Path = CACHE_DIR) -> tuple[list[str], dict[str, str]]:
    """The command and environment that run OpenCV 4.x's HOG: ``given`` as it is, else the
    project's Python with ``opencv-python-headless`` 4.x from ``cache/opencv4`` (installed
    there with pip on first use)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    if given:
        return [given, "-s"], env
    target = cache / "opencv4"
    env["PYTHONPATH"] = str(target)
    cmd = [sys.executable, "-s"]
    probe = "import cv2, sys; sys.exit(0 if cv2.__version__.startswith('4.') else 1)"
    if subprocess.run([*cmd, "-c", probe], env=env, capture_output=True).returncode != 0:
        shutil.rmtree(target, ignore_errors=True)
        got = _run(
            [
                sys.executable,
                "-m",
                "pip",
                "install",
                "-q",
                "--no-deps",
                "--target",
                str(target),
                OPENCV4_REQUIREMENT,
            ]
        )
        if got.returncode != 0:
            raise RuntimeError(
                f"pip could not install {OPENCV4_REQUIREMENT} into {target} "
                f"({got.stderr.strip()[-500:]}); run HOG with another interpreter: "
                "apt-get install python3-opencv, then --hog-python /usr/bin/python3"
            )
    return cmd, env


def hog_boxes(
    video: Path, cfg: FootageConfig, hog_python: str | None = None, cache: Path = CACHE_DIR
) -> dict[str, object]:
    """HOG's detections ``{"opencv", "frames_total", "boxes": {frame: [[x, y, w, h,
    weight], ...]}}`` at every ``cfg.stride``-th frame, from the cache when its key holds."""
    key = {
        "video_sha256": sha256_of(video),
        "stride": cfg.stride,
        "win_stride": cfg.hog_win_stride,
        "padding": cfg.hog_padding,
        "scale": cfg.hog_scale,
    }
    path = cache / "hog_boxes.json"
    if path.is_file():
        try:
            cached = json.loads(path.read_text())
            if cached.get("key") == key:
                return dict(cached)
        except (OSError, ValueError):
            pass
    cmd, env = hog_interpreter(hog_python, cache)
    logger.info("HOG over every %d-th frame of %s (about 0.7 s a frame)", cfg.stride, video)
    got = subprocess.run(
        [
            *cmd,
            "-c",
            HOG_SCRIPT,
            str(video),
            str(cfg.stride),
            str(cfg.hog_win_stride),
            str(cfg.hog_padding),
            str(cfg.hog_scale),
        ],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if got.returncode != 0:
        raise RuntimeError(f"the HOG process failed: {got.stderr.strip()[-1000:]}")
    result = json.loads(got.stdout.strip().splitlines()[-1])
    if not str(result["opencv"]).startswith("4."):
        raise RuntimeError(f"HOG ran on OpenCV {result['opencv']}, not 4.x")
    result["key"] = key
    cache.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result))
    return dict(result)


def foreground(frames: Sequence[np.ndarray], min_area: int) -> list[np.ndarray]:
    """Moving-foreground masks (bool) of every frame: MOG2, shadows excluded, 3x3 opening,
    blobs of at least ``min_area`` pixels."""
    mog = cv2.createBackgroundSubtractorMOG2(history=200, varThreshold=25, detectShadows=True)
    kernel = np.ones((3, 3), np.uint8)
    out = []
    for f in frames:
        m = (mog.apply(f) == 255).astype(np.uint8)
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, kernel)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        keep = np.zeros(n, bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
        out.append(keep[labels])
    return out


def build_footage(
    video: Path, cfg: FootageConfig, hog_python: str | None = None, cache: Path = CACHE_DIR
) -> Footage:
    """Person crops, people-free crops and whole frames of ``video`` (see the docstring)."""
    hog = hog_boxes(video, cfg, hog_python, cache)
    frames = read_video(video)
    fg = foreground(frames, cfg.fg_min_area)
    s, c = FUSED_SIZE[0], cfg.crop
    k = s / c
    height, width = frames[0].shape[:2]
    sx, sy = s / width, s / height
    pad = np.ones((2 * cfg.free_margin + 1,) * 2, np.uint8)
    person_rgb, person_box, person_meta, person_sil = [], [], [], []
    free_rgb, free_meta = [], []
    frame_rgb, frame_boxes, frame_free, frame_index = [], [], [], []
    boxes_by_frame: dict[str, list[list[float]]] = hog["boxes"]  # type: ignore[assignment]
    for key in sorted(boxes_by_frame, key=int):
        t = int(key)
        rgb = cv2.cvtColor(frames[t], cv2.COLOR_BGR2RGB)
        people = []
        occupied = fg[t].astype(np.uint8)
        for x, y, w, h, weight in boxes_by_frame[key]:
            x, y, w, h = int(x), int(y), int(w), int(h)
            occupied[max(0, y) : y + h, max(0, x) : x + w] = 1  # every detection, any weight
            bx, by, bw, bh = tight_box(x, y, w, h)
            x0, y1 = max(0, bx), max(0, by)
            bw, bh = min(width, bx + bw) - x0, min(height, by + bh) - y1
            if weight >= cfg.hog_min_weight and 0 < bh <= c and bw > 0:
                people.append((x0, y1, bw, bh, float(weight)))
        occupied = np.asarray(cv2.dilate(occupied, pad), np.uint8)
        for bx, by, bw, bh, weight in people:
            cx0 = int(np.clip(bx + bw // 2 - c // 2, 0, width - c))
            cy0 = int(np.clip(by + bh // 2 - c // 2, 0, height - c))
            crop = cv2.resize(
                rgb[cy0 : cy0 + c, cx0 : cx0 + c], (s, s), interpolation=cv2.INTER_AREA
            )
            box = [
                int(round((bx - cx0) * k)),
                int(round((by - cy0) * k)),
                max(1, int(round(bw * k))),
                max(1, int(round(bh * k))),
            ]
            inside = np.zeros((height, width), np.uint8)  # the foreground inside the box
            inside[by : by + bh, bx : bx + bw] = fg[t][by : by + bh, bx : bx + bw]
            sil = cv2.resize(
                inside[cy0 : cy0 + c, cx0 : cx0 + c].astype(np.float32), (s, s),
                interpolation=cv2.INTER_AREA,
            )  # fmt: skip
            person_sil.append(sil >= 0.5)
            person_rgb.append(crop)
            person_box.append(box)
            person_meta.append(
                {
                    "frame": t,
                    "crop_origin": [cx0, cy0],
                    "crop_size": c,
                    "box_in_frame": [bx, by, bw, bh],
                    "hog_weight": weight,
                }
            )
        for cy0 in range(0, height - c + 1, cfg.free_step):
            for cx0 in range(0, width - c + 1, cfg.free_step):
                if occupied[cy0 : cy0 + c, cx0 : cx0 + c].any():
                    continue
                free_rgb.append(
                    cv2.resize(
                        rgb[cy0 : cy0 + c, cx0 : cx0 + c], (s, s), interpolation=cv2.INTER_AREA
                    )
                )
                free_meta.append({"frame": t, "crop_origin": [cx0, cy0], "crop_size": c})
        frame_rgb.append(rgb)
        frame_index.append(t)
        frame_boxes.append(
            np.asarray(
                [
                    [int(bx * sx), int(by * sy), max(1, round(bw * sx)), max(1, round(bh * sy))]
                    for bx, by, bw, bh, _ in people
                ],
                dtype=int,
            ).reshape(-1, 4)
        )
        frame_free.append(cv2.resize(occupied, (s, s), interpolation=cv2.INTER_AREA) == 0)
    logger.info(
        "%d sampled frames: %d reference people, %d people-free crops",
        len(frame_index),
        len(person_rgb),
        len(free_rgb),
    )
    return Footage(
        person_rgb=np.asarray(person_rgb, np.uint8).reshape(-1, s, s, 3),
        person_box=np.asarray(person_box, int).reshape(-1, 4),
        person_meta=person_meta,
        person_silhouette=np.asarray(person_sil, bool).reshape(-1, s, s),
        free_rgb=np.asarray(free_rgb, np.uint8).reshape(-1, s, s, 3),
        free_meta=free_meta,
        frame_rgb=np.asarray(frame_rgb, np.uint8),
        frame_boxes=frame_boxes,
        frame_free=np.asarray(frame_free, bool),
        frame_index=frame_index,
        hog_opencv=str(hog["opencv"]),
        frames_total=len(frames),
    )


# --- running the network -----------------------------------------------------------------


def perception(precision: str, batch: int = 32, weights: Path | None = None) -> Perception:
    """The daemon's perception on ``weights`` (None: the shipped ones): ONNX Runtime, one
    thread."""
    return Perception(
        PerceptionConfig(threads=1, max_batch=batch, backend="onnx", precision=precision,
                         weights=weights)
    )


def fused(p: Perception, rgb: np.ndarray, batch: int = 32) -> np.ndarray:
    """Fused frames ``(N, 96, 96, 3)`` of uint8 RGB frames ``(N, H, W, 3)``, in batches."""
    out = [p(rgb[i : i + batch]).copy() for i in range(0, len(rgb), batch)]
    s = p.size
    return np.concatenate(out) if out else np.zeros((0, s, s, 3), np.float32)


def network_name(p: Perception) -> str:
    path = getattr(p.net, "path", None)
    return path.name if isinstance(path, Path) else f"{p.backend} network"


def measure(p: Perception, fp: Footage) -> dict[str, Figures]:
    """``{"crop": Figures, "frame": Figures}`` of one perception on the footage."""
    out_p, out_f, out_w = (fused(p, x) for x in (fp.person_rgb, fp.free_rgb, fp.frame_rgb))
    heat_p, heat_f, heat_w = (o[..., CHANNEL_HEATMAP] for o in (out_p, out_f, out_w))
    crop = figures(list(heat_p), [[b] for b in fp.person_box], list(heat_f),
                   silhouettes=list(fp.person_silhouette))  # fmt: skip
    frame = figures(
        list(heat_w), [list(b) for b in fp.frame_boxes], list(heat_w), list(fp.frame_free)
    )
    for fig, outs in ((crop, (out_p, out_f)), (frame, (out_w,))):
        depth = channel_to_depth(np.concatenate([o[..., CHANNEL_DEPTH].ravel() for o in outs]))
        lo, mid, hi = np.percentile(depth, (5, 50, 95))
        fig.depth_m = (float(lo), float(mid), float(hi))
    return {"crop": crop, "frame": frame}


# --- output ------------------------------------------------------------------------------


def _pct(x: float, digits: int = 0) -> str:
    return f"{100 * x:.{digits}f} %"


def table(rows: dict[str, dict[str, Figures]]) -> str:
    """The markdown table: one row per precision and view, the targets first."""
    lines = [
        "| precision | view | people found | mean box cover | people-free | median hot "
        "| > 2 % hot | > 10 % hot | depth m, median (5-95 %) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        f"| target | | ≥ {_pct(TARGETS['found'])} | ≥ {TARGETS['cover']:.2f} | "
        f"| ≤ {_pct(TARGETS['free_median'], 1)} | ≤ {_pct(TARGETS['free_gt2'])} | — | — |",
    ]
    for prec, views in rows.items():
        for view, f in views.items():
            what = "crops" if view == "crop" else "frames"
            lines.append(
                f"| {prec} | {view} | {f.found}/{f.people} ({_pct(f.found_share, 1)}) | "
                f"{f.cover:.3f} | {f.free} {what} | {_pct(f.free_median, 1)} | "
                f"{_pct(f.free_gt2)} | {_pct(f.free_gt10)} | "
                f"{f.depth_m[1]:.1f} ({f.depth_m[0]:.1f}-{f.depth_m[2]:.1f}) |"
            )
    return "\n".join(lines)


def silhouette_table(rows: dict[str, dict[str, Figures]]) -> str:
    """The person crops against the people's MOG2 silhouettes (walking people only)."""
    lines = [
        "| precision | people with a silhouette | silhouette's own box cover | heatmap's box "
        "cover | silhouette pixels hot | IoU in the box |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for prec, views in rows.items():
        f = views["crop"]
        lines.append(
            f"| {prec} | {f.silhouettes} | {f.silhouette_share:.3f} | {f.silhouette_cover:.3f} "
            f"| {_pct(f.silhouette_recall, 1)} | {f.silhouette_iou:.3f} |"
        )
    return "\n".join(lines)


def to_u8(channel: np.ndarray) -> np.ndarray:
    """A [0, 1] channel as uint8 gray."""
    return np.asarray(np.clip(channel, 0.0, 1.0) * 255.0 + 0.5, np.uint8)


def _tile(img: np.ndarray, scale: int = PICTURE_SCALE) -> np.ndarray:
    return cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)


def picture(p: Perception, fp: Footage, path: Path, people: int = 3, free: int = 1) -> None:
    """A PNG of ``people`` person crops and ``free`` people-free crops (evenly spaced over
    the lists), one a row: RGB with the reference box, heatmap, depth (near is bright)."""
    pi = np.linspace(0, len(fp.person_rgb) - 1, people + 2).round().astype(int)[1:-1]
    fi = np.linspace(0, len(fp.free_rgb) - 1, free + 2).round().astype(int)[1:-1]
    rgb = np.concatenate([fp.person_rgb[pi], fp.free_rgb[fi]])
    boxes: list[np.ndarray | None] = [fp.person_box[i] for i in pi] + [None] * len(fi)
    out = fused(p, rgb)
    green = (0, 255, 0)
    rows = []
    for im, f, b in zip(rgb, out, boxes, strict=True):
        cam = _tile(im)
        heat = cv2.cvtColor(_tile(to_u8(f[..., CHANNEL_HEATMAP])), cv2.COLOR_GRAY2RGB)
        depth = cv2.cvtColor(_tile(to_u8(f[..., CHANNEL_DEPTH])), cv2.COLOR_GRAY2RGB)
        if b is not None:
            x, y, w, h = (int(v) * PICTURE_SCALE for v in b)
            for t in (cam, heat):
                cv2.rectangle(t, (x, y), (x + w - 1, y + h - 1), green, 1)
        gap = np.full((cam.shape[0], 4, 3), 255, np.uint8)
        rows.append(np.concatenate([cam, gap, heat, gap, depth], axis=1))
    sep = np.full((4, rows[0].shape[1], 3), 255, np.uint8)
    body = np.concatenate([r for row in rows for r in (row, sep)][:-1], axis=0)
    head = np.full((22, body.shape[1], 3), 255, np.uint8)
    col = body.shape[1] // 3
    for i, text in enumerate(("vtest.avi crop", "heatmap", "depth (near bright)")):
        cv2.putText(
            head, text, (i * col + 6, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA
        )
    img = np.concatenate([head, body], axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    logger.info("wrote %s (%d bytes)", path, path.stat().st_size)


def write_test_data(fp: Footage, out: Path, cfg: FootageConfig, video_sha: str) -> None:
    """``TEST_PEOPLE`` person crops and ``TEST_FREE`` people-free crops, evenly spaced over
    the benchmark's lists (not chosen by the network's output), as PNGs with ``index.json``."""
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.png"):
        old.unlink()
    pi = np.linspace(0, len(fp.person_rgb) - 1, TEST_PEOPLE).round().astype(int)
    fi = np.linspace(0, len(fp.free_rgb) - 1, TEST_FREE).round().astype(int)
    index: dict[str, object] = {
        "source": f"{VIDEO_NAME} (OpenCV samples/data, Debian {DEB_PACKAGE}), sha256 {video_sha}",
        "recipe": ".venv/bin/python -m benchmarks.real_footage "
        f"--write-test-data {out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}",
        "config": asdict(cfg),
        "hog_opencv": fp.hog_opencv,
        "box": "x, y, w, h in the 96x96 crop",
        "person": [],
        "free": [],
    }
    for kind, idx, rgb in (("person", pi, fp.person_rgb), ("free", fi, fp.free_rgb)):
        entries: list[dict[str, object]] = []
        for n, i in enumerate(idx):
            name = f"{kind}_{n:02d}.png"
            cv2.imwrite(
                str(out / name),
                cv2.cvtColor(rgb[i], cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_PNG_COMPRESSION, 9],
            )
            meta = fp.person_meta[i] if kind == "person" else fp.free_meta[i]
            entry: dict[str, object] = {"file": name, **meta}
            if kind == "person":
                entry["box"] = [int(v) for v in fp.person_box[i]]
            entries.append(entry)
        index[kind] = entries
    (out / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    logger.info("wrote %d + %d crops to %s", len(pi), len(fi), out)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.real_footage",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--precision",
        default=",".join(PRECISIONS),
        help="comma-separated precisions, one row each (default: fp32,int8)",
    )
    p.add_argument(
        "--stride",
        type=int,
        default=FootageConfig.stride,
        help="every N-th frame of the video (default 8: 100 of 795)",
    )
    p.add_argument(
        "--video",
        type=Path,
        default=None,
        help="vtest.avi (default: look for "
        "it, else download Debian's opencv-doc into runs/footage/)",
    )
    p.add_argument(
        "--hog-python",
        default=None,
        metavar="PYTHON",
        help="interpreter whose cv2 is OpenCV 4.x (default: the project's Python "
        "with opencv-python-headless 4.x installed into runs/footage/opencv4)",
    )
    p.add_argument(
        "--weights",
        type=Path,
        default=None,
        help="AVNet weights with their ONNX exports beside them, as training writes them "
        "(default: the shipped active_vision/weights/avnet.pt)",
    )
    p.add_argument(
        "--picture",
        type=Path,
        default=None,
        metavar="PNG",
        help="also write a picture of crops, their heatmap and depth (fp32)",
    )
    p.add_argument(
        "--write-test-data",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write the crops tests/test_real_footage.py checks",
    )
    p.add_argument("--log-level", default="INFO")
    a = p.parse_args(argv)
    logging.basicConfig(level=a.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    precisions = [s.strip() for s in a.precision.split(",") if s.strip()]
    if not precisions or any(s not in PRECISIONS for s in precisions):
        p.error(f"--precision: give some of {', '.join(PRECISIONS)}, got {a.precision!r}")
    if a.stride < 1:
        p.error("--stride must be >= 1")
    if a.weights is not None and not a.weights.is_file():
        p.error(f"--weights {a.weights}: no such weights file")
    cfg = FootageConfig(stride=a.stride)
    try:
        video = find_video(a.video)
        fp = build_footage(video, cfg, a.hog_python)
    except RuntimeError as exc:
        logger.error("%s", exc)
        return 1
    if a.write_test_data is not None:
        write_test_data(fp, a.write_test_data.resolve(), cfg, sha256_of(video))
    rows: dict[str, dict[str, Figures]] = {}
    names = []
    for prec in precisions:
        net = perception(prec, weights=a.weights)
        label = prec if net.precision == prec else f"{prec} (ran {net.precision})"
        rows[label] = measure(net, fp)
        names.append(f"{label}: {network_name(net)}")
        if a.picture is not None and prec == precisions[0]:
            picture(net, fp, a.picture)
    print(f"CPU: {cpu_name()}; network: {'; '.join(names)}")
    print(
        f"footage: {video.name}, {len(fp.frame_index)} frames (every {cfg.stride}-th of "
        f"{fp.frames_total}), 768x576; reference people: HOG (OpenCV {fp.hog_opencv}, "
        f"weight >= {cfg.hog_min_weight}); people-free: clear of HOG boxes and MOG2 "
        f"foreground by {cfg.free_margin} px"
    )
    print(
        f"threshold {THRESHOLD} (heatmap); found: a blob of >= {MIN_BLOB_PX} px overlaps the "
        f"box; crop: {cfg.crop}x{cfg.crop} -> 96x96; frame: 768x576 -> 96x96 (false heat "
        "over its people-free area)"
    )
    print(
        f"depth: the network's, in metres (channel_to_depth), over every pixel of the view "
        f"(no ground truth; the far side of the street is beyond the channel's "
        f"{DEPTH_MAX_M:.0f} m limit, which reads {DEPTH_MAX_M:.0f})\n"
    )
    print(table(rows))
    print(
        f"\nPerson crops against the MOG2 moving foreground inside each box (people whose "
        f"silhouette fills >= {MIN_SILHOUETTE:.0%} of it). The silhouette's own box cover is "
        "what a heatmap exactly on the person would score as 'mean box cover':\n"
    )
    print(silhouette_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
