"""The shipped perception on real pedestrian footage: committed crops of OpenCV's
``vtest.avi`` (``tests/data/real_footage/``, made by ``python -m benchmarks.real_footage
--write-test-data``; no download, no HOG here) through the daemon's ``Perception``, measured
with the benchmark's rules (``active_vision.training.real_footage``): people found and box
cover on the person crops, false heat on the people-free crops, against the bounds below."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from active_vision.models import WeightsError  # noqa: E402
from active_vision.perception import Perception, PerceptionConfig  # noqa: E402
from active_vision.training.real_footage import (  # noqa: E402
    MIN_SILHOUETTE,
    TEST_FREE,
    TEST_PEOPLE,
    figures,
    silhouette_figures,
)
from fused_image import CHANNEL_HEATMAP, FUSED_SIZE  # noqa: E402

DATA = Path(__file__).resolve().parent / "data" / "real_footage"

FOUND_MIN = 0.9
"""Share of the person crops' people found: the benchmark's target (95 %) with one crop of slack
(15 of 16 passes). The shipped network finds 16/16 here (282/283 in the benchmark)."""
COVER_MIN = 0.2
"""Mean box cover, a regression bound: 0.232 (fp32) / 0.229 (int8) on these crops. The target
(0.4) is above what a heatmap exactly on the person scores (0.27 in the benchmark)."""
FREE_MEDIAN_MAX = 0.005
FREE_GT2_MAX = 0.1
"""False heat on the people-free crops, the benchmark's targets: median hot area <= 0.5 % and at
most 10 % of crops (1 of 16) over 2 % hot. The shipped network: 0 % median, none over 2 %
(the network it was fine-tuned from: 3.15 % median, 14 of 16 over 2 %)."""


@dataclass
class Crops:
    person: np.ndarray
    """uint8 (P, 96, 96, 3) RGB."""
    boxes: list[list[int]]
    """x, y, w, h of each person crop's reference person."""
    free: np.ndarray
    """uint8 (F, 96, 96, 3) RGB."""


def _rgb(name: str) -> np.ndarray:
    bgr = cv2.imread(str(DATA / name), cv2.IMREAD_COLOR)
    assert bgr is not None, f"cannot read {DATA / name}"
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


@pytest.fixture(scope="module")
def crops() -> Crops:
    index = json.loads((DATA / "index.json").read_text())
    return Crops(
        person=np.stack([_rgb(e["file"]) for e in index["person"]]),
        boxes=[list(e["box"]) for e in index["person"]],
        free=np.stack([_rgb(e["file"]) for e in index["free"]]),
    )


def problems(person_heat: np.ndarray, boxes: list[list[int]], free_heat: np.ndarray) -> list[str]:
    """What misses a bound, given the heatmaps of the person and people-free crops."""
    f = figures(list(person_heat), [[b] for b in boxes], list(free_heat))
    out = []
    if f.found_share < FOUND_MIN:
        out.append(f"people found {f.found}/{f.people} < {FOUND_MIN:.0%}")
    if f.cover < COVER_MIN:
        out.append(f"mean box cover {f.cover:.3f} < {COVER_MIN}")
    if f.free_median > FREE_MEDIAN_MAX:
        out.append(f"false heat: median hot area {f.free_median:.1%} > {FREE_MEDIAN_MAX:.1%}")
    if f.free_gt2 > FREE_GT2_MAX:
        out.append(f"false heat: {f.free_gt2:.0%} of crops over 2 % hot > {FREE_GT2_MAX:.0%}")
    return out


def test_the_committed_crops_are_what_the_readme_says(crops: Crops) -> None:
    s = FUSED_SIZE[0]
    assert crops.person.shape == (TEST_PEOPLE, s, s, 3)
    assert crops.free.shape == (TEST_FREE, s, s, 3)
    for x, y, w, h in crops.boxes:
        assert 0 <= x and 0 <= y and w > 0 and h > 0 and x + w <= s and y + h <= s
    assert sum(p.stat().st_size for p in DATA.iterdir()) < 1_000_000


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_shipped_perception_on_real_crops(crops: Crops, precision: str) -> None:
    p = Perception(
        PerceptionConfig(threads=1, max_batch=TEST_PEOPLE, backend="onnx", precision=precision)
    )
    assert p.precision == precision
    person = p(crops.person)[..., CHANNEL_HEATMAP].copy()
    free = p(crops.free)[..., CHANNEL_HEATMAP].copy()
    assert problems(person, crops.boxes, free) == []


def test_the_bounds_fail_an_all_hot_and_an_all_cold_heatmap(crops: Crops) -> None:
    shape = crops.person.shape[:3]
    hot, cold = np.ones(shape, np.float32), np.zeros(shape, np.float32)
    assert any("false heat" in m for m in problems(hot, crops.boxes, hot))
    cold_says = problems(cold, crops.boxes, cold)
    assert any("people found" in m for m in cold_says)
    assert any("box cover" in m for m in cold_says)
    # heat exactly on the reference boxes and nowhere else meets every bound
    exact = cold.copy()
    for i, (x, y, w, h) in enumerate(crops.boxes):
        exact[i, y : y + h, x : x + w] = 1.0
    assert problems(exact, crops.boxes, cold) == []


def test_a_missing_weights_file_is_named() -> None:
    """The benchmark's ``--weights`` runs this perception: a missing file is named."""
    with pytest.raises(WeightsError, match="/nonexistent/avnet.pt"):
        Perception(PerceptionConfig(threads=1, backend="onnx",
                                    weights=Path("/nonexistent/avnet.pt")))  # fmt: skip


def test_silhouette_figures_score_a_heatmap_against_the_person_inside_the_box() -> None:
    box = (10, 20, 10, 20)  # x, y, w, h: 200 pixels
    silhouette = np.zeros((96, 96), bool)
    silhouette[25:35, 12:17] = True  # 50 pixels: a quarter of the box
    silhouette[0:5, 0:5] = True  # outside the box: not the person's
    heat = np.zeros((96, 96), np.float32)
    heat[25:35, 12:15] = 1.0  # 30 of the silhouette's pixels
    heat[20:22, 10:20] = 1.0  # 20 pixels of the box off the silhouette
    share, cover, recall, iou = silhouette_figures(heat, box, silhouette)
    assert (share, cover, recall) == pytest.approx((0.25, 0.25, 0.6))
    assert iou == pytest.approx(30 / 70)
    # exactly on the silhouette: its box cover is the silhouette's own share, IoU 1
    assert silhouette_figures(silhouette.astype(np.float32), box, silhouette) == pytest.approx(
        (0.25, 0.25, 1.0, 1.0))
    faint = np.zeros((96, 96), bool)
    faint[25, 12 : 12 + int(MIN_SILHOUETTE * 200) - 1] = True  # a person standing still
    assert silhouette_figures(heat, box, faint) is None
    f = figures([heat, heat], [[box], [box]], [heat], silhouettes=[silhouette, faint])
    assert f.silhouettes == 1 and f.silhouette_share == pytest.approx(0.25)
