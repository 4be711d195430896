"""The camera scan: a rover-frame memory of what the forward camera has seen, over 360°.

A fused image shows 90° of the world and forgets what the camera stops looking at. A
navigation stack's answer is a local costmap that the depth camera fills and the robot's
own motion carries (Nav2's obstacle layer). :class:`CameraScan` is the smallest such map that
a policy can read like the LIDAR: per bearing sector around the rover (the LIDAR's layout,
32 sectors over [-pi, pi) counter-clockwise from straight behind), three numbers:

- ``obstacle``: the nearest scenery the camera has seen in that sector (m from the rover's
  centre, on the ground plane; ``max_range`` when none is known);
- ``person``: the nearest pedestrian it has seen there (m; ``max_range`` when none);
- ``age``: seconds since the camera last looked that way (``memory_s`` when never, or
  longer ago than that).

What it reads is what the env already has, never the simulator's truth: the fused image's
depth channel (``fused_image.CHANNEL_DEPTH``, metres along the optical axis) and heatmap
(``CHANNEL_HEATMAP``), the camera's fixed geometry (``rover.CAMERA_X`` ahead of the rover's
centre, ``CAMERA_HEIGHT`` above flat ground, ``CAMERA_PITCH`` down, ``CAMERA_FOVY``; the pan
on the gaze envs) and the env's own pose and yaw.

Each update projects every image column to the ground plane. The column's pixels that
stand more than ``obstacle_height`` above the ground (and are not hot) are its scenery; the
``obstacle_quantile`` of their ground ranges is its obstacle (the nearest pixel alone reads
the depth network's noise). Its hot pixels (heatmap above ``person_threshold``) at their
median depth are its person.

Scenery goes into a world-frame grid of ``cell_m`` cells (an occupancy layer, as a costmap
keeps one): each column marks the cell of its obstacle and frees the remembered cells it
sees through, nearer than its obstacle (less ``clear_margin_m``) or, when it shows none,
within ``max_range``. A wall seen ahead is still there beside the rover as it passes, and
behind it after a turn, for ``memory_s``. People walk, so each sector keeps one person
point, the nearest, re-read from the rover's new pose every update; sectors in view are
replaced by what the camera shows (a sector seen empty is emptied) and points older than
``person_memory_s`` are dropped. The rover's own motion moves both memories, nothing else
does.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from fused_image import DEPTH_MAX_M
from rover_env import camera_scan_kernel as kernel
from rover_env import constants as c
from rover_env import rover

log = logging.getLogger(__name__)

CAMERA_HEIGHT = rover.REST_HEIGHT + rover.CAMERA_Z  # m above flat ground
SCAN_KEY = "camera_scan"
"""The observation key the fused envs give the scan under (their ``camera_scan=`` keyword)."""
SCAN_ROWS = ("obstacle", "person", "age")
"""The rows of the ``camera_scan`` observation, in order."""


@dataclass(frozen=True)
class CameraScanConfig:
    """How the camera scan reads the fused image and how long it remembers."""

    sectors: int = c.LIDAR_POINTS
    """Bearing sectors over 360° (the LIDAR's 32 by default, in its layout)."""
    max_range: float = DEPTH_MAX_M
    """Metres: the depth channel's far limit; unknown and empty sectors read this."""
    obstacle_height: float = 0.12
    """Metres above the ground plane from which a pixel counts as scenery (the wheels are
    0.13 m: lower steps are driven over)."""
    person_threshold: float = 0.5
    """Heatmap value from which a pixel counts as a person."""
    memory_s: float = 20.0
    """Seconds a scenery reading is kept once the camera looks away (the scenery does not
    move, and the pose is the env's own); also the age of a never-seen sector."""
    person_memory_s: float = 2.0
    """Seconds a person reading is kept once the camera looks away (people walk about
    1.3 m/s: older readings mislead more than they tell)."""
    cell_m: float = 0.1
    """Metres: the side of a cell of the scenery grid."""
    obstacle_quantile: float = 0.2
    """Which of a column's scenery pixels is its obstacle, as a quantile of their ground
    ranges: 0 is the nearest pixel, which reads the depth network's noise (on the maze,
    expert-driven, the scan read the walls 1-2.5 m away in view 0.25-0.30 m short by the
    median, 0.14 m at 0.2). A median filter down the column instead did less (0.15 m at 5
    pixels): the network's errors are correlated."""
    clear_margin_m: float = 0.1
    """Metres short of a column's obstacle up to which its remembered cells are freed (the
    cells between a wall's noisy readings and the camera: 0.2 m kept the walls read in view
    0.14 m short, 0.1 m 0.06-0.07 m, with no more walls lost)."""

    def __post_init__(self) -> None:
        if self.sectors < 4:
            raise ValueError(f"sectors must be >= 4, got {self.sectors}")
        if self.clear_margin_m < 0:
            raise ValueError(f"clear_margin_m must be >= 0, got {self.clear_margin_m}")
        for name in ("max_range", "memory_s", "person_memory_s", "cell_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.obstacle_quantile < 1.0:
            raise ValueError(f"obstacle_quantile must be in [0, 1), got {self.obstacle_quantile}")
        if not 0.0 < self.person_threshold < 1.0:
            raise ValueError(f"person_threshold must be in (0, 1), got {self.person_threshold}")


def sector_of(bearing: np.ndarray, sectors: int) -> np.ndarray:
    """The sector index of rover-frame bearings (rad): the LIDAR's layout, sector ``i``
    covering ``[-pi + i * w, -pi + (i + 1) * w)`` with ``w = 2 pi / sectors``."""
    width = 2.0 * math.pi / sectors
    return (np.floor((np.asarray(bearing) + math.pi) / width).astype(np.int64)) % sectors


def sector_centres(sectors: int) -> np.ndarray:
    """The rover-frame bearing (rad) of each sector's centre."""
    return -math.pi + (np.arange(sectors) + 0.5) * (2.0 * math.pi / sectors)


class CameraScan:
    """The camera scan of one env (see the module docstring).

    :meth:`reset` at each episode's start, then :meth:`update` with every new fused image;
    :attr:`observation` is the ``(3, sectors)`` float32 array (rows :data:`SCAN_ROWS`).

    :param size: (H, W) of the fused images.
    :param control_dt: seconds between updates (ages are counted in steps times this).
    """

    def __init__(self, size: tuple[int, int], control_dt: float,
                 config: CameraScanConfig | None = None) -> None:  # fmt: skip
        self.config = cfg = config or CameraScanConfig()
        self.control_dt = float(control_dt)
        height, width = int(size[0]), int(size[1])
        focal = 0.5 * height / math.tan(math.radians(rover.CAMERA_FOVY) / 2)
        self.half_fov = math.atan(0.5 * width / focal)
        pitch = math.radians(rover.CAMERA_PITCH)
        # A pixel at depth d (along the optical axis) lies d * (fwd, left, up) from the camera
        # in its level frame: forward = d (cos p - y sin p), up = -d (sin p + y cos p),
        # left = -d x, with x, y the pixel's offsets from the centre over the focal length.
        xs = (np.arange(width) + 0.5 - 0.5 * width) / focal
        ys = (np.arange(height) + 0.5 - 0.5 * height) / focal
        self._fwd = math.cos(pitch) - ys * math.sin(pitch)
        self._up = -(math.sin(pitch) + ys * math.cos(pitch))
        self._left = -xs
        self._shape = (height, width, 3)
        self._params = np.array([
            DEPTH_MAX_M, cfg.max_range, cfg.person_threshold,
            cfg.obstacle_height - CAMERA_HEIGHT,  # a pixel this far above the camera or more
            self.half_fov, cfg.memory_s, cfg.person_memory_s, rover.CAMERA_X, 0.0,
            cfg.cell_m, 0.0, cfg.obstacle_quantile, cfg.clear_margin_m])  # fmt: skip
        # the scenery grid is toroidal: slot (ix mod g, iy mod g) holds world cell (ix, iy).
        # Its read-out keeps cells within max_range + 1 m, so two live cells never share a
        # slot when g cells span twice that.
        g = math.ceil(2.0 * (cfg.max_range + 1.0) / cfg.cell_m) + 2
        self._params[10] = g
        self._grid_t = np.full(g * g, -np.inf)  # when each slot was last seen occupied (s)
        self._grid_i = np.zeros((g * g, 2), dtype=np.int64)  # the world cell a slot holds
        self._occ = np.zeros(g * g, dtype=np.int64)  # the listed (possibly occupied) slots
        self._occ_n = np.zeros(1, dtype=np.int64)
        self._pose = np.zeros(4)
        n = cfg.sectors
        self._person = np.full((n, 2), np.nan)  # world x, y of each sector's person reading
        self._person_t = np.full(n, -np.inf)  # when each reading was taken (s)
        self._seen_t = np.full(n, -np.inf)  # when each world-bearing sector was last in view
        self._t = 0.0
        self._warned = False
        self.observation = np.zeros((3, n), dtype=np.float32)
        self.columns = np.full((3, width), np.inf)
        """Per image column of the last update: its obstacle pixel's depth (m) and
        row (inf / -1 where none), then the median depth of its person pixels (inf where
        none)."""
        self.reset()

    @property
    def space(self) -> spaces.Box:
        """The ``camera_scan`` observation's Box: ranges in [0, max_range] m, ages in
        [0, memory_s] s."""
        cfg = self.config
        high = np.empty((3, cfg.sectors), dtype=np.float32)
        high[:2] = cfg.max_range
        high[2] = cfg.memory_s
        return spaces.Box(np.zeros_like(high), high, dtype=np.float32)

    def reset(self) -> None:
        """Forget everything (a new episode)."""
        self._grid_t[:] = -np.inf
        self._occ_n[0] = 0
        self._person[:] = np.nan
        self._person_t[:] = -np.inf
        self._seen_t[:] = -np.inf
        self._t = 0.0
        self.observation[:2] = self.config.max_range
        self.observation[2] = self.config.memory_s
        self.columns[:] = np.inf

    def update(self, fused: np.ndarray, x: float, y: float, yaw: float, pan: float = 0.0) -> None:
        """Take one fused image (H, W, 3) seen from pose (x, y, yaw) with the camera panned
        ``pan`` rad left of the heading. Non-finite depth or pose leaves the scan's readings
        as they were for this step (with one warning per scan); the gray channel is not read."""
        cfg = self.config
        self._t += self.control_dt
        if fused.shape != self._shape:
            raise ValueError(f"fused image of shape {fused.shape}; this scan reads "
                             f"{self._shape} images (its size)")  # fmt: skip
        image = fused if fused.dtype == np.float32 else fused.astype(np.float32)
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(yaw) and math.isfinite(pan):
            self._params[8] = self._t
            self._pose[:] = (x, y, yaw, pan)
            if kernel.scan_update(image, self._fwd, self._up, self._left, self._params,
                                  self._pose, self._grid_t, self._grid_i, self._occ, self._occ_n,
                                  self._person, self._person_t, self._seen_t, self.observation,
                                  self.columns):  # fmt: skip
                return
        if not self._warned:
            log.warning("camera scan: a non-finite pose or fused image; the scan keeps its "
                        "readings for this step (warned once)")  # fmt: skip
            self._warned = True
        kernel.scan_ages(self._seen_t, yaw if math.isfinite(yaw) else float(self._pose[2]),
                         self._t, cfg.memory_s, self.observation)  # fmt: skip

    def points(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """The remembered ``"obstacle"`` readings (the centres of the occupied scenery
        cells) or ``"person"`` readings as world points (K, 2), and their ages (K,) in
        seconds (for checking the scan against the simulator)."""
        if which not in SCAN_ROWS[:2]:
            raise ValueError(f"which must be 'obstacle' or 'person', got {which!r}")
        if which == "obstacle":
            slots = self._occ[: self._occ_n[0]]
            slots = slots[self._grid_t[slots] > self._t - self.config.memory_s]
            cells = self._grid_i[slots]
            return (cells + 0.5) * self.config.cell_m, self._t - self._grid_t[slots]
        known = np.isfinite(self._person[:, 0])
        return self._person[known].copy(), self._t - self._person_t[known]


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
