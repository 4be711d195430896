"""Training and held-out frames for the perception network, rendered from our own worlds.

``python -m active_vision.training.dataset --out DIR --frames N --seed S`` renders N camera frames
through :class:`rover_env.simulation.RoverSim` and writes
``DIR/av_<worlds>_s<S>_n<N>_<size>px_d<drive %>_v<version>.npz``
(compressed) with:

====================  ===================  =============================================
key                   shape / dtype        meaning
====================  ===================  =============================================
``rgb``               (N, S, S, 3) uint8   the rover's camera frame
``depth``             (N, S, S) float16    metric depth in metres (far clip: nothing)
``mask``              (N, S, S) bool       pedestrian pixels (segmentation rendering)
``world``             (N,) int8            index into ``worlds``
``worlds``            (W,) str             world names
``kind``              (N,) int8            0 empty, 1 walking, 2 placed, 3 driving
``episode``           (N,) int32           driving episode (-1: posed frame)
``step``              (N,) int16           control step within the episode (-1: posed)
``seed``              () int64             the seed the file was made from
====================  ===================  =============================================

A file is a pure function of ``(seed, frames, worlds, size, drive_fraction, appearance,
pedestrian_mode, n_pedestrians)``.
The first ``round(frames * drive_fraction)`` frames (70 % by default) are **driving**
frames: short episodes recorded while the rover drives (:mod:`active_vision.training.driving`:
random smooth driving, approaching a pedestrian, driving into walls and rocks, watching a
distant pedestrian; every 3rd control step kept), episode e in world ``e % W`` from
``np.random.default_rng([seed, 1, e])``. These are the frames the agent sees. The rest are
**posed** frames (frame j in world ``j % W`` from ``np.random.default_rng([seed, j])``),
which vary per frame:

- the rover pose: a free point (0.4 m clearance) near the pedestrian area or anywhere in
  bounds, random heading - so walls, rocks, panels and open ground all appear;
- the pedestrians (see :class:`FrameRenderer`): walking figures seen from 0.8-9 m
  (uniform in log distance), standing figures pinned in view (1-3, some straddling the frame
  edge, random headings), and ``p_empty`` of the frames with none in view.

Both kinds randomise the lighting (every light's diffuse/ambient/specular and the headlight
scaled by random factors, dim dusk to bright noon, with a random colour cast:
:func:`active_vision.training.lighting.random_lighting`) and, with ``appearance="random"``
(the default), the pedestrians' clothing colours, height, girth and gait phase
(``RoverSim(pedestrian_appearance=...)``).

The held-out split (``evaluate.heldout``) is ``drive_fraction=1``: driving frames only,
from ``HELDOUT_SEED`` (seeds, appearances and lighting never used in training), reported by
world (``--worlds`` renders a subset so a network can be trained without one world and
evaluated on it). Everything is read through public :class:`RoverSim` calls.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from active_vision.training.driving import DriveRecorder
from active_vision.training.lighting import random_lighting
from fused_image import FUSED_SIZE
from rover_env.crowd import MAX_PEDESTRIANS
from rover_env.pedestrians import PEDESTRIAN_MODES
from rover_env.worlds import WORLD_NAMES

logger = logging.getLogger(__name__)

WORLDS: tuple[str, ...] = WORLD_NAMES
"""The worlds, in the order a dataset's world index counts them."""
TRAIN_SEED = 0
HELDOUT_SEED = 1_000_003
VALIDATION_SEED = 2_000_003
"""Seed of the validation splits (neither training nor held-out): for choosing between
trained networks (options, epochs, seeds) without looking at the figures reported."""
SPLIT_SEEDS = {"heldout": HELDOUT_SEED, "validation": VALIDATION_SEED}
"""The evaluation splits by name: the figures reported, and the one to choose on."""
DATASET_VERSION = 6
"""Part of the cache file name: bump it when rendering changes, so stale files are not reused
(5: the moon's ground texture; 6: the moon's gentler metre-scale roughness)."""
KIND_EMPTY, KIND_WALKING, KIND_PLACED, KIND_DRIVING = 0, 1, 2, 3
_GROUND_CHECK_M = 3.0
_GROUND_MIN_M = 0.12
_SETTLE_S = 0.3
_MAX_TILT_RAD = 0.5
_POSE_TRIES = 8
DEFAULT_DATA_DIR = (
    Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "roverav" / "active_vision"
)
"""Where rendered datasets are cached (``$XDG_CACHE_HOME/roverav/active_vision``)."""


@dataclass
class DatasetConfig:
    """What :func:`render_dataset` renders."""

    frames: int = 8000
    """Number of frames."""
    seed: int = TRAIN_SEED
    """Base seed; frame i uses ``np.random.default_rng([seed, i])``."""
    worlds: tuple[str, ...] = WORLDS
    """Worlds to render from."""
    size: int = FUSED_SIZE[0]
    """Camera resolution (square) - the fused resolution."""
    p_empty: float = 0.3
    """Probability of a frame with no pedestrian placed in view."""
    max_visible: int = 3
    """Most pedestrians placed in view in one frame."""
    min_distance: float = 0.8
    """Nearest pedestrian distance from the camera (m)."""
    max_distance: float = 9.0
    """Farthest pedestrian distance from the camera (m)."""
    drive_fraction: float = 0.7
    """Share of the frames recorded while driving (:mod:`active_vision.training.driving`); the rest
    are posed views."""
    appearance: str = "random"
    """Pedestrian appearance (``RoverSim(pedestrian_appearance=...)``)."""
    pedestrian_mode: str = "pacing"
    """How the pedestrians walk (``RoverSim(pedestrian_mode=...)``). ``pacing`` (the
    out-and-back pacers) here, whatever the envs' default, so that the held-out and validation
    splits stay the same frames; ``train --crowds`` renders its training scenes among other
    modes through its own configs."""
    n_pedestrians: int | None = None
    """Pedestrians in each world (``RoverSim(n_pedestrians=...)``; None: the world's own, 3).
    With ``pedestrian_mode``, what ``evaluate --pedestrian-mode crowd --pedestrians 10``
    renders its split with (the targets are held at 3 and at 10 people)."""


@dataclass
class Dataset:
    """Frames and ground truth loaded from (or about to be written to) an ``.npz`` file."""

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    world: np.ndarray
    worlds: tuple[str, ...]
    kind: np.ndarray
    seed: int
    episode: np.ndarray | None = None
    """(N,) driving episode of each frame (-1: a posed frame); None in old files."""
    step: np.ndarray | None = None
    """(N,) control step of each driving frame within its episode (-1: posed)."""

    def __post_init__(self) -> None:
        n = int(self.rgb.shape[0])
        if self.episode is None:
            self.episode = np.full(n, -1, np.int64)
        if self.step is None:
            self.step = np.full(n, -1, np.int64)

    def __len__(self) -> int:
        return int(self.rgb.shape[0])

    def save(self, path: Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(
            tmp,
            rgb=self.rgb,
            depth=self.depth.astype(np.float16),
            mask=self.mask,
            world=self.world.astype(np.int8),
            worlds=np.array(self.worlds),
            kind=self.kind.astype(np.int8),
            seed=np.int64(self.seed),
            episode=np.asarray(self.episode, np.int32),
            step=np.asarray(self.step, np.int16),
        )
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: Path | str) -> Dataset:
        with np.load(Path(path)) as z:
            return cls(
                rgb=z["rgb"],
                depth=z["depth"].astype(np.float32),
                mask=z["mask"].astype(bool),
                world=z["world"].astype(np.int64),
                worlds=tuple(str(w) for w in z["worlds"]),
                kind=z["kind"].astype(np.int64),
                seed=int(z["seed"]),
                episode=z["episode"].astype(np.int64) if "episode" in z else None,
                step=z["step"].astype(np.int64) if "step" in z else None,
            )

    @classmethod
    def concatenate(cls, parts: Sequence[Dataset]) -> Dataset:
        """One dataset of ``parts`` in order (same worlds); episodes are renumbered so that
        each part's driving episodes stay apart. Its seed is the first part's."""
        worlds = parts[0].worlds
        if any(p.worlds != worlds for p in parts):
            raise ValueError(f"datasets of different worlds: {[p.worlds for p in parts]}")
        episodes, offset = [], 0
        for p in parts:
            e = np.asarray(p.episode)
            episodes.append(np.where(e >= 0, e + offset, -1))
            offset += int(e.max(initial=-1)) + 1
        return cls(*(np.concatenate([getattr(p, k) for p in parts])
                     for k in ("rgb", "depth", "mask", "world")),
                   worlds, np.concatenate([p.kind for p in parts]), parts[0].seed,
                   np.concatenate(episodes), np.concatenate([np.asarray(p.step) for p in parts]))

    def subset(self, index: np.ndarray) -> Dataset:
        return Dataset(self.rgb[index], self.depth[index], self.mask[index], self.world[index],
                       self.worlds, self.kind[index], self.seed,
                       np.asarray(self.episode)[index], np.asarray(self.step)[index])


def parse_crowds(text: str) -> tuple[str, ...]:
    """Pedestrian scenes from ``"pacing,crowd:3,crowd:10"`` (an argparse ``type``): a
    ``RoverSim`` pedestrian mode, optionally ``:N`` pedestrians per world."""
    crowds = tuple(c.strip() for c in text.split(",") if c.strip())
    if not crowds:
        raise argparse.ArgumentTypeError(f"{text!r}: give pedestrian scenes, e.g. "
                                         "pacing,crowd:3,crowd:10")
    for c in crowds:
        try:
            crowd_config(c)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return crowds


def crowd_config(spec: str) -> tuple[str, int | None]:
    """``(pedestrian_mode, n_pedestrians)`` of one ``--crowds`` entry (``"crowd:10"``)."""
    mode, _, count = spec.partition(":")
    if mode not in PEDESTRIAN_MODES:
        raise ValueError(f"{spec!r}: unknown pedestrian mode {mode!r}; give one of "
                         f"{', '.join(PEDESTRIAN_MODES)}, optionally with :N pedestrians")
    if not count:
        return mode, None
    if not count.isdigit() or not 0 < int(count) <= MAX_PEDESTRIANS:
        raise ValueError(f"{spec!r}: give the pedestrians as an integer in 1..{MAX_PEDESTRIANS}, "
                         "e.g. crowd:10")
    return mode, int(count)


def crowd_shares(total: int, crowds: Sequence[str]) -> list[tuple[int, str, int | None, int]]:
    """``(seed, pedestrian_mode, n_pedestrians, share)`` of each ``--crowds`` scene: ``total``
    (frames or episodes) split evenly, scene k from seed ``TRAIN_SEED + k``."""
    n = len(crowds)
    return [(TRAIN_SEED + k, *crowd_config(spec), total // n + (1 if k < total % n else 0))
            for k, spec in enumerate(crowds)]


def crowd_tag(pedestrian_mode: str, n_pedestrians: int | None) -> str:
    """The part of a cache file's name that names its pedestrians (none for the pacers' 3,
    so their files keep the names they always had)."""
    if pedestrian_mode == "pacing" and n_pedestrians is None:
        return ""
    return f"_p{pedestrian_mode}" + ("" if n_pedestrians is None else str(n_pedestrians))


def dataset_path(out_dir: Path, config: DatasetConfig) -> Path:
    """The file :func:`build` writes for ``config`` in ``out_dir``."""
    tag = "-".join(config.worlds)
    drive = f"_d{round(100 * config.drive_fraction)}" + (
        "" if config.appearance == "random" else f"_{config.appearance}")
    drive += crowd_tag(config.pedestrian_mode, config.n_pedestrians)
    return Path(out_dir) / (f"av_{tag}_s{config.seed}_n{config.frames}_{config.size}px"
                            f"{drive}_v{DATASET_VERSION}.npz")


class FrameRenderer:
    """Renders dataset frames for one world (one :class:`RoverSim`, reused).

    Three kinds of frame (chosen per frame from its generator):

    - ``walking`` (40 %): the pedestrians walk their episode paths (legs swinging); the rover
      is put at a random distance and bearing from one of them, facing it within the field
      of view (others may be in view too);
    - ``placed`` (30 %): the rover at a random free pose, 1-3 pedestrians pinned standing in
      view at random distances, the rest behind the rover;
    - ``empty`` (the remaining 30 %, ``p_empty``): the rover at a random free pose and every
      pedestrian behind it, out of view.
    """

    def __init__(self, world: str, config: DatasetConfig) -> None:
        from rover_env import rover
        from rover_env.simulation import RoverSim  # rendering only; not needed to train
        from rover_env.worlds.spec import Rect

        self.config = config
        self.sim = RoverSim(world=world, camera_size=(config.size, config.size),
                            pedestrian_mode=config.pedestrian_mode,
                            n_pedestrians=config.n_pedestrians,
                            pedestrian_appearance=config.appearance)
        self.world = self.sim.world
        self.fov = self.sim.camera_fov
        self.clearance = float(rover.SPAWN_CLEARANCE)
        self.n_peds = int(self.sim.pedestrian_positions.shape[0])
        ped, bounds = self.world.pedestrian_area.expanded(3.0), self.world.bounds
        near = Rect((max(ped.x[0], bounds.x[0]), min(ped.x[1], bounds.x[1])),
                    (max(ped.y[0], bounds.y[0]), min(ped.y[1], bounds.y[1])))
        self._areas = (near, bounds.expanded(-1.0))

    def close(self) -> None:
        self.sim.close()

    def _set_pose(self, x: float, y: float, yaw: float) -> None:
        """Put the rover at (x, y, yaw) resting on the terrain as rendered.

        On a height field the rest height comes from rays cast onto the rendered terrain
        under the wheels rather than from ``WorldSpec.ground_height``, which reads the
        terrain lower than MuJoCo draws it (by 0.1-0.5 m on moon), so the camera would sit
        inside a slope; then ``_SETTLE_S`` of physics lets the rover tilt with the slope.
        """
        if self.world.heightfield is None:
            self.sim.set_rover_pose(x, y, yaw)
            return
        from rover_env import rover

        c, s = math.cos(yaw), math.sin(yaw)
        ground = max(self.sim.terrain_height(x + c * wx - s * wy, y + s * wx + c * wy)
                     for wx in (-rover.WHEEL_X, 0.0, rover.WHEEL_X)
                     for wy in (-rover.WHEEL_Y, 0.0, rover.WHEEL_Y))
        self.sim.set_rover_pose(x, y, yaw, z=ground + rover.REST_HEIGHT + 0.02)
        # let it settle onto the slope (tilted with the terrain, as it drives there)
        self.sim.advance(_SETTLE_S)

    def _random_pose(self, rng: np.random.Generator) -> None:
        area = self._areas[0] if rng.random() < 0.6 else self._areas[1]
        x, y = self.world.sample_free(rng, area, self.clearance)
        self._set_pose(x, y, float(rng.uniform(-math.pi, math.pi)))

    def _bearing_in_view(self, rng: np.random.Generator) -> float:
        # a little beyond the half field of view, so some figures straddle the frame edge
        return float(rng.uniform(-0.55, 0.55) * self.fov)

    def _distance(self, rng: np.random.Generator) -> float:
        cfg = self.config
        # uniform in log distance: as many near figures as far ones
        return float(np.exp(rng.uniform(np.log(cfg.min_distance), np.log(cfg.max_distance))))

    def _pin_behind(self, rng: np.random.Generator, indices: Sequence[int]) -> None:
        sim = self.sim
        x, y, _ = sim.position
        yaw = sim.yaw
        for i in indices:
            dist = float(rng.uniform(2.5, 8.0))
            bearing = math.pi + float(rng.uniform(-0.6, 0.6))
            sim.place_pedestrian(i, x + dist * math.cos(yaw + bearing),
                                 y + dist * math.sin(yaw + bearing),
                                 float(rng.uniform(-math.pi, math.pi)))

    def _walking(self, rng: np.random.Generator) -> bool:
        sim, world = self.sim, self.world
        sim.advance(float(rng.uniform(0.05, 0.6)))  # somewhere along the path, mid-stride
        target = sim.pedestrian_positions[int(rng.integers(self.n_peds))]
        for _ in range(20):
            dist = self._distance(rng)
            phi = float(rng.uniform(-math.pi, math.pi))  # direction rover -> pedestrian
            x = float(target[0]) - dist * math.cos(phi)
            y = float(target[1]) - dist * math.sin(phi)
            if world.in_bounds(x, y) and world.is_free(x, y, self.clearance):
                self._set_pose(x, y, phi - self._bearing_in_view(rng))
                return True
        return False

    def _placed(self, rng: np.random.Generator) -> None:
        sim, world, cfg = self.sim, self.world, self.config
        self._random_pose(rng)
        x, y, _ = sim.position
        yaw = sim.yaw
        k = int(rng.integers(1, min(cfg.max_visible, self.n_peds) + 1))
        for i in range(k):
            for _ in range(10):  # prefer a free spot (not inside a wall or a rock)
                dist = self._distance(rng)
                ang = yaw + self._bearing_in_view(rng)
                px, py = x + dist * math.cos(ang), y + dist * math.sin(ang)
                if world.is_free(px, py, 0.2):
                    break
            sim.place_pedestrian(i, px, py, float(rng.uniform(-math.pi, math.pi)))
        self._pin_behind(rng, range(k, self.n_peds))

    def _compose(self, rng: np.random.Generator) -> int:
        sim = self.sim
        sim.reset(rng)
        u = rng.random()
        if self.n_peds and u < 0.4 and self._walking(rng):
            return KIND_WALKING
        if self.n_peds and u < 1.0 - self.config.p_empty:
            self._placed(rng)
            return KIND_PLACED
        self._random_pose(rng)
        self._pin_behind(rng, range(self.n_peds))
        return KIND_EMPTY

    def render(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """One frame: (rgb, metric depth, pedestrian mask, kind of frame).

        A pose whose camera does not see the ground just below it as from a rover standing on
        it (the median of the depth image's bottom rows outside ``_GROUND_MIN_M`` to
        ``_GROUND_CHECK_M``: the camera is inside or against the terrain, or over a drop), or
        where the rover settled tilted more than ``_MAX_TILT_RAD`` (tipping over: an episode
        would end there) is drawn again, up to ``_POSE_TRIES`` times.
        """
        for _ in range(_POSE_TRIES):
            kind = self._compose(rng)
            self.sim.set_lighting(random_lighting(self.sim, rng))
            try:
                frame = self.sim.render_camera(depth=True, segmentation=True)
            finally:
                self.sim.set_lighting(self.sim.default_lighting)
            s = self.config.size
            bottom = frame.depth[-max(1, s // 16):, s // 3: 2 * s // 3]
            pitch, roll, _ = self.sim.orientation
            upright = max(abs(pitch), abs(roll)) < _MAX_TILT_RAD
            if upright and _GROUND_MIN_M < float(np.median(bottom)) < _GROUND_CHECK_M:
                break
            logger.debug("%s: rover tipped over or camera not above the ground; new pose",
                         self.world.name)
        return frame.rgb, frame.depth, frame.pedestrian_mask, kind


def render_dataset(config: DatasetConfig, progress_every: int = 500) -> Dataset:
    """Render ``config.frames`` frames (see the module docstring): first
    ``round(frames * drive_fraction)`` driving frames (episode e in world ``e % W``, from
    ``np.random.default_rng([seed, 1, e])``), then posed frames (frame i in world ``i % W``,
    from ``np.random.default_rng([seed, i])``)."""
    n, s = config.frames, config.size
    if not 0.0 <= config.drive_fraction <= 1.0:
        raise ValueError(f"drive_fraction must be in [0, 1], got {config.drive_fraction}")
    n_drive = int(round(n * config.drive_fraction))
    rgb = np.zeros((n, s, s, 3), np.uint8)
    depth = np.zeros((n, s, s), np.float32)
    mask = np.zeros((n, s, s), bool)
    world = np.zeros(n, np.int64)
    kind = np.zeros(n, np.int64)
    episode = np.full(n, -1, np.int64)
    step = np.full(n, -1, np.int64)
    renderers: dict[str, FrameRenderer] = {}
    recorders: dict[str, DriveRecorder] = {}

    def renderer(name: str) -> FrameRenderer:
        if name not in renderers:
            renderers[name] = FrameRenderer(name, config)
        return renderers[name]

    t0 = time.perf_counter()
    try:
        i, e = 0, 0
        while i < n_drive:
            w = e % len(config.worlds)
            name = config.worlds[w]
            if name not in recorders:
                recorders[name] = DriveRecorder(renderer(name))
            got = recorders[name].record(np.random.default_rng([config.seed, 1, e]))
            k = min(len(got.rgb), n_drive - i)
            rgb[i:i + k], depth[i:i + k], mask[i:i + k] = got.rgb[:k], got.depth[:k], got.mask[:k]
            world[i:i + k], kind[i:i + k] = w, KIND_DRIVING
            episode[i:i + k], step[i:i + k] = e, got.step[:k]
            if progress_every and (i + k) // progress_every > i // progress_every:
                logger.info("driving: %d/%d frames, %d episodes (%.1f s)", i + k, n_drive,
                            e + 1, time.perf_counter() - t0)
            i, e = i + k, e + 1
        for j in range(n - n_drive):
            w = j % len(config.worlds)
            rng = np.random.default_rng([config.seed, j])
            i = n_drive + j
            rgb[i], depth[i], mask[i], kind[i] = renderer(config.worlds[w]).render(rng)
            world[i] = w
            if progress_every and (j + 1) % progress_every == 0:
                logger.info("posed: %d/%d frames (%.1f s)", j + 1, n - n_drive,
                            time.perf_counter() - t0)
    finally:
        for r in renderers.values():
            r.close()
    return Dataset(rgb, depth, mask, world, tuple(config.worlds), kind, config.seed,
                   episode, step)


def build(out_dir: Path, config: DatasetConfig, *, reuse: bool = True) -> Path:
    """Render ``config`` into ``out_dir`` (or reuse the file already there); its path."""
    path = dataset_path(out_dir, config)
    if reuse and path.is_file():
        logger.info("reusing %s", path)
        return path
    data = render_dataset(config)
    data.save(path)
    logger.info("wrote %s (%d frames, %.1f MB)", path, len(data), path.stat().st_size / 1e6)
    return path


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m active_vision.training.dataset", description=__doc__
                                .split("\n")[0])
    p.add_argument("--out", type=Path, default=DEFAULT_DATA_DIR, help="output directory")
    p.add_argument("--frames", type=int, default=DatasetConfig.frames)
    p.add_argument("--seed", type=int, default=TRAIN_SEED,
                   help=f"base seed (training {TRAIN_SEED}, held-out {HELDOUT_SEED})")
    p.add_argument("--worlds", default=",".join(WORLDS),
                   help="comma-separated worlds (default: all three)")
    p.add_argument("--size", type=int, default=FUSED_SIZE[0])
    p.add_argument("--drive-fraction", type=float, default=DatasetConfig.drive_fraction,
                   help="share of frames recorded while driving (held-out split: 1)")
    p.add_argument("--force", action="store_true", help="re-render even if the file exists")
    p.add_argument("--log-level", default="INFO")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    worlds = tuple(w.strip() for w in args.worlds.split(",") if w.strip())
    config = DatasetConfig(frames=args.frames, seed=args.seed, worlds=worlds, size=args.size,
                           drive_fraction=args.drive_fraction)
    path = build(args.out, config, reuse=not args.force)
    data = Dataset.load(path)
    empty = float(np.mean(~data.mask.reshape(len(data), -1).any(axis=1)))
    print(f"{path}: {len(data)} frames, worlds {','.join(data.worlds)}, "
          f"{100 * empty:.0f}% without a visible pedestrian")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
