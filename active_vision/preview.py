"""What the agent sees: camera frame and the three fused channels side by side.

:class:`PreviewWriter` writes a PNG (overwritten with the latest frame) or, when the path
ends in ``.mp4``, appends one video frame per call. Tiles, left to right: the camera frame,
grayscale, pedestrian heatmap (inferno colour map), depth channel (near is bright), each
upscaled ``scale`` times with nearest-neighbour so single pixels stay visible. With
``av-daemon --heatmap predict`` a fifth tile follows the heatmap: the heatmap tile is then
the predicted occupancy (``predict``) and the detection of this frame is shown beside it
(``detect``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from fused_image import CHANNEL_DEPTH, CHANNEL_GRAY, CHANNEL_HEATMAP

logger = logging.getLogger(__name__)

_LABELS = ("camera", "gray", "heatmap", "depth")


def compose(camera: np.ndarray, fused: np.ndarray, scale: int = 3,
            detect: np.ndarray | None = None) -> np.ndarray:
    """BGR uint8 image ``(S*scale + 14, T*S*scale, 3)`` of the tiles with labels (T = 4, or
    5 when ``detect``, the detection heatmap ``(S, S)``, is given beside a predicted one)."""
    s = fused.shape[0]
    rgb = np.asarray(camera)[..., :3]
    if rgb.shape[:2] != (s, s):
        rgb = cv2.resize(rgb, (s, s), interpolation=cv2.INTER_AREA)
    cam_bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)

    def u8(a: np.ndarray) -> np.ndarray:
        return np.clip(a * 255.0 + 0.5, 0, 255).astype(np.uint8)

    tiles = [
        cam_bgr,
        cv2.cvtColor(u8(fused[..., CHANNEL_GRAY]), cv2.COLOR_GRAY2BGR),
        cv2.applyColorMap(u8(fused[..., CHANNEL_HEATMAP]), cv2.COLORMAP_INFERNO),
        cv2.cvtColor(u8(fused[..., CHANNEL_DEPTH]), cv2.COLOR_GRAY2BGR),
    ]
    labels = list(_LABELS)
    if detect is not None:
        tiles.insert(3, cv2.applyColorMap(u8(detect), cv2.COLORMAP_INFERNO))
        labels[2:3] = ["predict", "detect"]
    side = s * scale
    big = [cv2.resize(t, (side, side), interpolation=cv2.INTER_NEAREST) for t in tiles]
    strip = np.hstack(big)
    label_bar = np.zeros((14, strip.shape[1], 3), np.uint8)
    for i, text in enumerate(labels):
        cv2.putText(label_bar, text, (i * side + 3, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([label_bar, strip])


class PreviewWriter:
    """Writes previews to ``path`` (``.png``: latest frame; ``.mp4``: a video)."""

    def __init__(self, path: Path | str, scale: int = 3, fps: float = 20.0) -> None:
        self.path = Path(path)
        self.scale = scale
        self.fps = fps
        self.video = self.path.suffix.lower() == ".mp4"
        self._writer: cv2.VideoWriter | None = None
        self.frames = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, camera: np.ndarray, fused: np.ndarray,
              detect: np.ndarray | None = None) -> None:
        """Add one preview: ``detect`` is the detection heatmap shown beside a predicted
        channel 1 (``--heatmap predict``), None in ``detect`` mode."""
        img = compose(camera, fused, self.scale, detect)
        if self.video:
            if self._writer is None:
                h, w = img.shape[:2]
                self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter.fourcc(*"mp4v"),
                                               self.fps, (w, h))
                if not self._writer.isOpened():
                    raise OSError(f"OpenCV cannot write an MP4 video to {self.path}")
            self._writer.write(img)
        else:
            tmp = self.path.with_name(self.path.stem + ".tmp" + self.path.suffix)
            if not cv2.imwrite(str(tmp), img):
                raise OSError(f"OpenCV cannot write an image to {self.path}")
            tmp.replace(self.path)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None


__all__ = ["PreviewWriter", "compose"]
