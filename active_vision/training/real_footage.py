"""How a heatmap is scored on real footage: people found, box cover, false heat and the
person's silhouette, at the detection threshold (:data:`~active_vision.training.evaluate.
THRESHOLD`, blobs of at least ``MIN_BLOB_PX`` pixels, evaluate's definitions), with its
targets. ``benchmarks/real_footage.py`` runs the daemon's perception on ``vtest.avi`` and
scores it with these rules (its docstring says how the reference people and the people-free
crops are made); ``tests/test_real_footage.py`` holds the committed crops to them. Results:
benchmarks/RESULTS.md, "Perception on real footage".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from active_vision.training.evaluate import MIN_BLOB_PX, THRESHOLD

TARGETS = {"found": 0.95, "cover": 0.4, "free_median": 0.005, "free_gt2": 0.10}
"""The targets on real footage: found share and mean box cover (at least), people-free median
hot area and share of crops with more than 2 % hot (at most)."""
MIN_SILHOUETTE = 0.1
"""A person's MOG2 silhouette counts when it fills at least this share of their box."""
TEST_PEOPLE = 16
TEST_FREE = 16
"""Crops ``--write-test-data`` writes: person crops, people-free crops."""


@dataclass
class Figures:
    """One row of the table."""

    people: int = 0
    found: int = 0
    cover: float = 0.0
    """Mean box cover."""
    free: int = 0
    free_median: float = 0.0
    """Median hot fraction of the people-free area."""
    free_gt2: float = 0.0
    free_gt10: float = 0.0
    depth_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Predicted depth in metres over every pixel of the view's maps: 5th percentile, median,
    95th percentile (no ground truth: the footage has none)."""
    hot_free: list[float] = field(default_factory=list, repr=False)
    silhouettes: int = 0
    """People with a MOG2 silhouette of at least ``MIN_SILHOUETTE`` of their box."""
    silhouette_share: float = 0.0
    """Mean fraction of those people's boxes that their silhouette fills: the box cover a
    heatmap exactly on the silhouette would score."""
    silhouette_cover: float = 0.0
    """Mean box cover of the heatmap on the same people."""
    silhouette_recall: float = 0.0
    """Mean fraction of their silhouette pixels that are hot."""
    silhouette_iou: float = 0.0
    """Mean IoU, inside the box, of the hot pixels and the silhouette."""

    @property
    def found_share(self) -> float:
        return self.found / self.people if self.people else 0.0


def hot(heat: np.ndarray) -> np.ndarray:
    """Detection pixels: ``heat >= THRESHOLD``."""
    return np.asarray(heat) >= THRESHOLD


def person_found(heat: np.ndarray, box: Sequence[int]) -> bool:
    """Whether a detection blob (8-connected, at least ``MIN_BLOB_PX`` pixels) overlaps the
    box ``(x, y, w, h)`` by at least one pixel."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(
        hot(heat).astype(np.uint8), connectivity=8
    )
    x, y, w, h = (int(v) for v in box)
    inside = np.unique(labels[max(0, y) : y + h, max(0, x) : x + w])
    return any(lab != 0 and stats[lab, cv2.CC_STAT_AREA] >= MIN_BLOB_PX for lab in inside)


def box_cover(heat: np.ndarray, box: Sequence[int]) -> float:
    """Fraction of the box ``(x, y, w, h)`` with ``heat >= THRESHOLD``."""
    x, y, w, h = (int(v) for v in box)
    sub = hot(heat)[max(0, y) : y + h, max(0, x) : x + w]
    return float(sub.mean()) if sub.size else 0.0


def hot_fraction(heat: np.ndarray, area: np.ndarray | None = None) -> float:
    """Fraction of ``area`` (bool mask; the whole map when None) with heat at threshold."""
    h = hot(heat)
    if area is None:
        return float(h.mean())
    n = int(area.sum())
    return float((h & area).sum() / n) if n else 0.0


def silhouette_figures(
    heat: np.ndarray, box: Sequence[int], silhouette: np.ndarray
) -> tuple[float, float, float, float] | None:
    """(silhouette share of the box, heat's box cover, silhouette recall, IoU in the box) of
    one person, or None when the silhouette fills under ``MIN_SILHOUETTE`` of the box."""
    x, y, w, h = (int(v) for v in box)
    ys, xs = slice(max(0, y), y + h), slice(max(0, x), x + w)
    sil, hh = np.asarray(silhouette, bool)[ys, xs], hot(heat)[ys, xs]
    if not sil.size or sil.mean() < MIN_SILHOUETTE:
        return None
    union = int((sil | hh).sum())
    return (float(sil.mean()), float(hh.mean()), float((sil & hh).sum() / sil.sum()),
            float((sil & hh).sum() / union) if union else 0.0)  # fmt: skip


def figures(
    person_heat: Sequence[np.ndarray],
    boxes: Sequence[Sequence[Sequence[int]]],
    free_heat: Sequence[np.ndarray],
    free_area: Sequence[np.ndarray | None] | None = None,
    silhouettes: Sequence[np.ndarray] | None = None,
) -> Figures:
    """The figures of one view: ``person_heat[i]`` holds the people ``boxes[i]`` (one or
    more boxes each); ``free_heat`` are people-free maps, measured over ``free_area``
    (whole maps when None); ``silhouettes[i]``, with one box a map, is person i's MOG2
    silhouette (the silhouette columns)."""
    found: list[bool] = []
    cover: list[float] = []
    for heat, bs in zip(person_heat, boxes, strict=True):
        for b in bs:
            found.append(person_found(heat, b))
            cover.append(box_cover(heat, b))
    areas = free_area if free_area is not None else [None] * len(free_heat)
    fr = np.asarray([hot_fraction(h, a) for h, a in zip(free_heat, areas, strict=True)])
    sil: list[tuple[float, float, float, float]] = []
    for heat, bs, mask in zip(person_heat, boxes, silhouettes or [], strict=False):
        one = silhouette_figures(heat, bs[0], mask)
        if one is not None:
            sil.append(one)
    share, sil_cover, recall, iou = np.mean(sil, axis=0) if sil else (0.0, 0.0, 0.0, 0.0)
    return Figures(
        people=len(found),
        found=int(sum(found)),
        cover=float(np.mean(cover)) if cover else 0.0,
        free=len(fr),
        free_median=float(np.median(fr)) if len(fr) else 0.0,
        free_gt2=float(np.mean(fr > 0.02)) if len(fr) else 0.0,
        free_gt10=float(np.mean(fr > 0.10)) if len(fr) else 0.0,
        hot_free=fr.tolist(),
        silhouettes=len(sil),
        silhouette_share=float(share),
        silhouette_cover=float(sil_cover),
        silhouette_recall=float(recall),
        silhouette_iou=float(iou),
    )
