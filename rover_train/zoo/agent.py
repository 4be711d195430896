"""The zoo's students: observation features, the network, and the agent that carries both.

A student maps one roverav observation to ``[speed, relative heading]``. Everything it
needs lives in the agent: the feature scaling (the world's centre and scale), the network
and its weights. Its features:

- the rover's position and the goal's position (the goal is recovered from ``pose``,
  ``imu`` yaw and ``target``), both centred on the world's goal square, plus sine/cosine
  features of them at a few spatial frequencies (so a small MLP can learn a fixed map's
  routing);
- yaw (cos, sin), pitch, roll, the target's distance and bearing (cos, sin), odometry;
- ``lidar`` (LIDAR students): ranges clipped to ``LIDAR_CLIP`` m, scaled to [0, 1];
- ``unmapped_scan`` (lidar-maze's students): the same ranges kept only where a return
  falls short of the world's map (:func:`unmapped_scan`), so that a pedestrian standing
  still does not look like the scenery;
- with ``FeatureSpec.history`` (the current entries), what one observation cannot show,
  kept by the agent between steps (:class:`ObsHistory`, cleared by ``reset()``): whether
  ``HISTORY_STEPS`` (2 s) of the episode have been seen, how much nearer the goal is than
  then and how far the rover moved since (the expert plans a detour when it has made no
  progress for 2 s beside a pedestrian; a memoryless student stood in such deadlocks), and
  for LIDAR students the change of every range over the last ``LIDAR_LAG`` steps (how the
  pedestrians move);
- ``depth_scan`` (the fused students): a forward range scan read off the fused
  image's depth channel, the LIDAR the fused env does not have: each pixel is lifted to 3D
  with the camera's pose on the rover, the ground and anything above ``SCAN_TOP`` dropped,
  and the nearest horizontal range kept per column band (:func:`depth_scan`); with history,
  its change over ``LIDAR_LAG`` steps too. Stage 1 of a fused entry (RoverEnv, no daemon)
  reads the same scan off the same fused image computed in-process
  (:class:`rover_train.imitation.dagger.FusedView`), so the state network learns walls and
  pedestrians ahead from its 190,000 samples instead of the image branch learning them
  from 48,000;
- ``fused_image`` (fused students): the three channels average-pooled to 48x48 through a
  small CNN whose features are added into the MLP's first hidden layer through a
  projection that starts at zero, so a fused student can start as a state-only one;
- ``gaze`` (gaze students, ``FeatureSpec.gaze``): where the camera looks, so the depth scan
  (read off the turned camera's image) and the image are placed round the rover.

The output head: a softmax over joint (speed level, heading bin) classes, ``SPEED_LEVELS`` x
``HEADING_BINS``, trained with cross-entropy on the expert's action's nearest class. The
expert's labels are multimodal (turn left or right round a panel, wait or back off for a
pedestrian); a regression averages the modes into an action that does neither, and leaves a
student stuck against obstacles (docs/decisions.md, "Imitation and the zoo"). Decoding takes
the most likely class and refines it with the probabilities of its neighbours (a circular mean
over the adjacent heading bins, a mean over the adjacent speed levels). A gaze student has a
second head, a softmax over ``PAN_BINS`` pan targets across the gaze env's +-60 degrees,
decoded the same way; its action is ``[speed, relative heading, pan target]``.
"""

from __future__ import annotations

import functools
import math
import pickle
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Protocol, cast, runtime_checkable

import numpy as np
import torch
from torch import nn

from fused_image import CHANNEL_DEPTH, DEPTH_MAX_M
from rover_env import FORWARD_CAMERA, LIDAR_SCAN_LAG, lidar_ray_angles, obstacle_map
from rover_env.constants import CONTROL_DT, PAN_LIMIT, PAN_RATE
from rover_env.discrete_env import N_SEED_ACTIONS
from rover_env.gaze_discrete_env import N_PAN_MOVES

LIDAR_CLIP = 4.0  # m
FREQUENCIES = (0.5, 1.0, 2.0)  # cycles per world half-size, for position features
POOL = 2  # fused image average-pool factor (96 -> 48)
IMAGE_FEATURES = 32
HEADING_BINS = 32  # heading classes of the ``bins`` head (11.25 degrees each)
SPEED_LEVELS = (-0.6, -0.36, 0.0, 0.175, 0.35, 0.525, 0.7, 0.85, 1.0)
"""Speeds of the ``bins`` head's classes as fractions of ``max_speed`` (the expert's local
planner uses 0, 0.35, 0.7, 1 and reverses at -0.36; its pursuit speed is continuous)."""
PAN_BINS = 13
"""Pan classes of a gaze student's second head: targets -60, -50, ..., +60 degrees."""
HISTORY_STEPS = 40  # 2 s at the 0.05 s control period
LIDAR_LAG = 5  # 0.25 s
SCAN_BOTTOM = 0.12  # m above the ground: lower points are ground (or depth error on it)
SCAN_TOP = 1.2  # m above the ground: higher points cannot touch the rover
UNMAPPED_MARGIN = 0.15  # m: a return this much nearer than the map's is not the scenery
UNMAPPED_YAW_SPREAD = 0.03  # rad: the map is cast this far either side of the heading too
_PAN_STEP = PAN_RATE * CONTROL_DT  # rad: the most the camera turns in a control step


@dataclass(frozen=True)
class FeatureSpec:
    """How observations become the network's input (saved with each zoo entry)."""

    centre: tuple[float, float]
    """Centre of the world's goal square (m)."""
    scale: float
    """Half size of the goal square (m)."""
    lidar_points: int = 0
    """LIDAR points in the input (0: no LIDAR)."""
    image: bool = False
    """Whether the fused image goes through the CNN."""
    max_speed: float = 1.0
    min_speed: float = -0.6
    history: bool = False
    """Add the :class:`ObsHistory` features (files written before it existed: off)."""
    depth_scan: int = 0
    """Bands of the forward range scan read off the depth channel (0: none; see
    :func:`depth_scan`)."""
    unmapped_scan: bool = False
    """With ``lidar_points``: a second scan of the LIDAR returns that ``world``'s map does
    not explain, the pedestrians (see :func:`unmapped_scan`)."""
    world: str = ""
    """The world the student was made for (needed by ``unmapped_scan``)."""
    gaze: bool = False
    """A gaze student: sees where the camera looks (the ``gaze`` key) and chooses the pan
    target (a second head of ``PAN_BINS`` classes): it drives RoverEnvFusedGaze."""
    table: bool = False
    """A discrete student: its action is the seed's table's integer. Its driving head is
    over the table's 60 cells (5 speeds x 12 compass headings: ``Discrete(60)``,
    RoverEnvFusedDiscrete); with ``gaze`` a pan head over the 3 pan moves makes the
    ``Discrete(180)`` action ``cell * 3 + move`` (RoverEnvFusedGazeDiscrete), and with
    ``history`` it also sees how fast the camera turns, which tells whether a move is under
    way."""

    def __post_init__(self) -> None:
        if self.unmapped_scan and not (self.lidar_points and self.world):
            raise ValueError("unmapped_scan needs the LIDAR (lidar_points > 0) and the world")

    @property
    def scan_points(self) -> int:
        """Range features derived from the observation: the fused image's scans and the
        LIDAR's unmapped returns."""
        unmapped = self.lidar_points if self.unmapped_scan else 0
        return self.depth_scan + unmapped

    @property
    def range_points(self) -> int:
        """Range features in all: the LIDAR's, then the scans'."""
        return self.lidar_points + self.scan_points

    @property
    def n_drive(self) -> int:
        """Classes of the driving head: speed level x heading bin, or a discrete student's
        table cells (60)."""
        if self.table:
            return N_SEED_ACTIONS
        return len(SPEED_LEVELS) * HEADING_BINS

    @property
    def n_pan(self) -> int:
        """Classes of a gaze student's pan head: ``PAN_BINS`` pan targets, a discrete one's
        ``N_PAN_MOVES`` moves (0 without ``gaze``)."""
        if not self.gaze:
            return 0
        return N_PAN_MOVES if self.table else PAN_BINS

    @property
    def n_outputs(self) -> int:
        return self.n_drive + self.n_pan

    @property
    def action_size(self) -> int:
        """Values of an action: ``[speed, heading]``, with ``gaze`` the pan target too; a
        discrete student's one integer."""
        return 1 if self.table else 3 if self.gaze else 2

    @property
    def history_dim(self) -> int:
        """Features of :class:`ObsHistory` (0 without ``history``)."""
        if not self.history:
            return 0
        return 3 + self.range_points + (self.gaze and self.table)

    @property
    def state_dim(self) -> int:
        base = 4 + 4 * 2 * len(FREQUENCIES) + 2 + 2 + 3 + 2 + self.range_points + self.gaze
        return base + self.history_dim


@functools.cache
def _scan_geometry(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of a (height, width) frame of the forward camera: the horizontal range and
    the height above the camera of a point at unit z-depth (MuJoCo's depth is along the
    optical axis), with the forward camera pitched down on a level rover
    (``rover_env.FORWARD_CAMERA``)."""
    f = (height / 2) / math.tan(math.radians(FORWARD_CAMERA.fovy_deg) / 2)
    xn = (np.arange(width) + 0.5 - width / 2) / f  # right
    yn = (np.arange(height) + 0.5 - height / 2) / f  # down
    p = math.radians(FORWARD_CAMERA.pitch_deg)
    forward = math.cos(p) - yn * math.sin(p)
    horizontal = np.sqrt(forward[:, None] ** 2 + xn[None, :] ** 2)
    up = -(yn * math.cos(p) + math.sin(p))
    return (
        horizontal.astype(np.float32),
        np.broadcast_to(up[:, None], (height, width)).astype(np.float32),
    )


def depth_scan(depth_channel: np.ndarray, bands: int) -> np.ndarray:
    """A forward range scan from the fused image's depth channel: ``(bands,)`` in [0, 1].

    Each pixel's depth (``(1 - v) * DEPTH_MAX_M``; 0 is "far") is lifted to a point in the
    rover's frame; points lower than ``SCAN_BOTTOM`` (the ground) or higher than
    ``SCAN_TOP`` above flat ground, and far ones, are dropped; each of ``bands`` equal
    column bands (left to right across the 90-degree view) keeps its nearest horizontal
    range, clipped to ``LIDAR_CLIP`` and scaled to [0, 1] (1: nothing within reach), like
    the LIDAR students' ranges. Assumes level ground (the zoo's worlds).
    """
    v = np.asarray(depth_channel, dtype=np.float32)
    height, width = v.shape
    if width % bands:
        raise ValueError(f"{bands} scan bands do not divide a {width}-pixel-wide frame")
    horizontal, up = _scan_geometry(height, width)
    z = (1.0 - v) * DEPTH_MAX_M
    elevation = FORWARD_CAMERA.height_m + z * up
    keep = (v > 0.0) & (elevation > SCAN_BOTTOM) & (elevation < SCAN_TOP)
    ranges = np.where(keep, z * horizontal, LIDAR_CLIP)
    nearest = ranges.reshape(height, bands, width // bands).min(axis=(0, 2))
    return np.clip(nearest, 0.0, LIDAR_CLIP) / LIDAR_CLIP


def unmapped_scan(obs: dict[str, np.ndarray], world: str) -> np.ndarray:
    """The LIDAR returns of ``obs`` that ``world``'s map does not explain: ``(lidar_points,)``
    in [0, 1], a point's range where it is at least ``UNMAPPED_MARGIN`` nearer than the map's
    (a pedestrian, or anything else not in the map), else 1 (scaled like the ranges).

    The map's scan is cast against the world's obstacle footprints
    (:func:`rover_env.obstacle_map`) with the env's ray layout. The env's scan is cast from
    the pose MuJoCo's kinematics computed at the start of the last physics step,
    ``rover_env.LIDAR_SCAN_LAG`` before ``obs["pose"]`` (up to 0.1 rad behind when turning fast), so
    the map is cast from there, dead-reckoned back with the odometry, and at
    ``UNMAPPED_YAW_SPREAD`` either side (the nearest kept): that marks few of the scenery's
    returns and nearly all the pedestrians' (the figures: docs/decisions.md, "The unmapped
    scan").
    Assumes a level rover (the flat worlds).
    """
    lidar = np.asarray(obs["lidar"], dtype=np.float32)
    angles, per_point = lidar_ray_angles(len(lidar))
    speed, turn = float(obs["velocities"][0]), float(obs["velocities"][1])
    yaw = float(obs["imu"][2])
    x = float(obs["pose"][0]) - speed * math.cos(yaw) * LIDAR_SCAN_LAG
    y = float(obs["pose"][1]) - speed * math.sin(yaw) * LIDAR_SCAN_LAG
    yaw -= turn * LIDAR_SCAN_LAG
    world_map = obstacle_map(world)
    reach = LIDAR_CLIP + UNMAPPED_MARGIN
    casts = [
        world_map.ray_distances(x, y, yaw + d + angles, reach)
        for d in (-UNMAPPED_YAW_SPREAD, 0.0, UNMAPPED_YAW_SPREAD)
    ]
    mapped = np.minimum.reduce(casts).reshape(len(lidar), per_point).min(axis=1)
    ranges = np.where(lidar < mapped - UNMAPPED_MARGIN, lidar, LIDAR_CLIP)
    return (np.clip(ranges, 0.0, LIDAR_CLIP) / LIDAR_CLIP).astype(np.float32)


def range_features(obs: dict[str, np.ndarray], spec: FeatureSpec) -> np.ndarray:
    """The range features of ``obs``: scaled LIDAR ranges, its unmapped returns, then the
    depth scans."""
    parts = []
    if spec.lidar_points:
        lidar = np.asarray(obs["lidar"], dtype=np.float32)
        parts.append(np.clip(lidar, 0.0, LIDAR_CLIP) / LIDAR_CLIP)
        if spec.unmapped_scan:
            parts.append(unmapped_scan(obs, spec.world))
    if spec.depth_scan:
        image = obs["fused_image"]
        parts.append(depth_scan(image[:, :, CHANNEL_DEPTH], spec.depth_scan))
    return np.concatenate(parts) if parts else np.zeros(0, np.float32)


def goal_position(obs: dict[str, np.ndarray]) -> tuple[float, float]:
    """The goal's world position, recovered from ``pose``, ``imu`` yaw and ``target``."""
    x, y, yaw = float(obs["pose"][0]), float(obs["pose"][1]), float(obs["imu"][2])
    dist, bearing = float(obs["target"][0]), float(obs["target"][1])
    return x + dist * math.cos(yaw + bearing), y + dist * math.sin(yaw + bearing)


class ObsHistory:
    """The few facts about the recent past a student sees (see the module docstring).

    Call :meth:`reset` at each episode start and :meth:`features` once per step, in order.
    A new goal (the env draws one after each success) restarts the record. Until
    ``HISTORY_STEPS`` steps are recorded the features are zeros with the "seen" flag off,
    which is also what states drawn without driving get (:meth:`absent`).
    """

    def __init__(self, spec: FeatureSpec) -> None:
        self.spec = spec
        self.reset()

    def reset(self) -> None:
        self._goal: tuple[float, float] | None = None
        self._track: deque[tuple[float, float, float]] = deque(maxlen=HISTORY_STEPS + 1)
        self._past_ranges: deque[np.ndarray] = deque(maxlen=LIDAR_LAG + 1)
        self._last_pan: float | None = None

    def absent(self) -> np.ndarray:
        """The features of a state without a past."""
        return np.zeros(self.spec.history_dim, np.float32)

    def features(self, obs: dict[str, np.ndarray],
                 ranges: np.ndarray | None = None) -> np.ndarray:
        """This step's features; ``ranges`` is ``range_features(obs, spec)`` if the caller
        has it already (it is computed otherwise)."""
        goal = goal_position(obs)
        if self._goal is None or math.hypot(goal[0] - self._goal[0],
                                            goal[1] - self._goal[1]) > 0.25:
            self.reset()
            self._goal = goal
        x, y = float(obs["pose"][0]), float(obs["pose"][1])
        self._track.append((x, y, float(obs["target"][0])))
        out = self.absent()
        if len(self._track) > HISTORY_STEPS:
            x0, y0, d0 = self._track[0]
            out[0] = 1.0
            out[1] = np.clip((d0 - self._track[-1][2]) / 2.0, -1.0, 1.0)
            out[2] = min(math.hypot(x - x0, y - y0) / 2.0, 1.0)
        if self.spec.range_points:
            if ranges is None:
                ranges = range_features(obs, self.spec)
            self._past_ranges.append(ranges)
            if len(self._past_ranges) > LIDAR_LAG:
                out[3 : 3 + len(ranges)] = (ranges - self._past_ranges[0]) * 4.0
        if self.spec.gaze and self.spec.table:  # the camera's turn in the last step
            pan = float(obs["gaze"][0])
            if self._last_pan is not None:
                out[-1] = np.clip((pan - self._last_pan) / _PAN_STEP, -1.0, 1.0)
            self._last_pan = pan
        return out


def state_features(obs: dict[str, np.ndarray], spec: FeatureSpec,
                   history: ObsHistory | np.ndarray | None = None) -> np.ndarray:
    """The state feature vector of one observation (float32, ``spec.state_dim``).

    :param history: for a spec with ``history``: the episode's :class:`ObsHistory` (updated
        with ``obs``), or its features already computed.
    """
    pose, imu, target, vel = obs["pose"], obs["imu"], obs["target"], obs["velocities"]
    x, y = float(pose[0]), float(pose[1])
    pitch, roll, yaw = float(imu[0]), float(imu[1]), float(imu[2])
    dist, bearing = float(target[0]), float(target[1])
    gx = x + dist * math.cos(yaw + bearing)
    gy = y + dist * math.sin(yaw + bearing)
    cx, cy = spec.centre
    s = spec.scale
    coords = np.array([(x - cx) / s, (y - cy) / s, (gx - cx) / s, (gy - cy) / s])
    freq = np.array(FREQUENCIES) * math.pi
    phases = (coords[:, None] * freq[None, :]).ravel()
    parts = [
        coords,
        np.sin(phases),
        np.cos(phases),
        [math.cos(yaw), math.sin(yaw)],
        [pitch, roll],
        [min(dist, 2 * s) / s, math.cos(bearing), math.sin(bearing)],
        [float(vel[0]), float(vel[1]) / 2.0],
    ]
    ranges = range_features(obs, spec)
    parts.append(ranges)
    if spec.gaze:
        parts.append([float(obs["gaze"][0]) / PAN_LIMIT])
    if spec.history:
        if history is None:
            raise ValueError("this student sees its recent past: pass history=")
        if isinstance(history, ObsHistory):
            history = history.features(obs, ranges)
        parts.append(history)
    return np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts]).astype(
        np.float32
    )


def image_features(obs: dict[str, np.ndarray]) -> np.ndarray:
    """The fused image average-pooled by ``POOL``, channels first, as uint8 (storage)."""
    img = np.asarray(obs["fused_image"], dtype=np.float32)
    h, w, c = img.shape
    pooled = img.reshape(h // POOL, POOL, w // POOL, POOL, c).mean(axis=(1, 3))
    return np.rint(np.clip(pooled, 0.0, 1.0) * 255.0).astype(np.uint8).transpose(2, 0, 1)


def encode_action(action: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """``[speed, heading]`` -> the stored target ``(speed / max, cos, sin)`` (its class:
    :func:`action_classes`); a gaze student's ``[speed, heading, pan]`` -> ``(..., pan)``
    (its pan class: :func:`pan_classes`)."""
    if spec.table:  # the table's action itself: its class
        index = np.asarray(action).reshape(-1)
        if index.size != 1 or not np.issubdtype(index.dtype, np.integer):
            raise ValueError(f"a discrete student learns the table's action, an integer; got "
                             f"{action!r}: label it with PlannerExpert.act_env on a discrete env")
        return np.array([float(index[0])], np.float32)
    speed, heading = float(action[0]), float(action[1])
    target = [speed / spec.max_speed, math.cos(heading), math.sin(heading)]
    if spec.gaze:
        if len(action) != 3:
            raise ValueError(f"a gaze student learns [speed, heading, pan target]; the label "
                             f"{np.asarray(action).tolist()} has no pan target: label it with "
                             "the gaze env's action (PlannerExpert.act_env on a gaze env)")
        target.append(float(action[2]))
    return np.array(target, np.float32)


_LEVELS = np.asarray(SPEED_LEVELS)
_BIN_ANGLES = -math.pi + (np.arange(HEADING_BINS) + 0.5) * (2 * math.pi / HEADING_BINS)
PAN_ANGLES = np.linspace(-PAN_LIMIT, PAN_LIMIT, PAN_BINS)
"""The pan target of each class of a gaze student's pan head (rad)."""


def action_classes(targets: torch.Tensor, spec: FeatureSpec | None = None) -> torch.Tensor:
    """The driving head's class of encoded targets: (speed level * HEADING_BINS + heading bin)
    of ``(N, 3)`` = (speed / max, cos, sin), or a discrete student's (``spec.table``) table
    cell of its table actions ``(N, 1)``."""
    if spec is not None and spec.table:
        action = targets[:, 0].round().long()
        return action // N_PAN_MOVES if spec.gaze else action
    levels = torch.as_tensor(_LEVELS, dtype=targets.dtype)
    level = (targets[:, :1] - levels[None]).abs().argmin(dim=1)
    heading = torch.atan2(targets[:, 2], targets[:, 1])
    hbin = torch.floor((heading + math.pi) / (2 * math.pi) * HEADING_BINS).long()
    return level * HEADING_BINS + hbin.clamp(0, HEADING_BINS - 1)


def pan_classes(targets: torch.Tensor, spec: FeatureSpec | None = None) -> torch.Tensor:
    """A gaze student's pan class (the nearest of :data:`PAN_ANGLES`) of encoded targets
    ``(N, 4)`` (the pan target last); a discrete gaze student's pan move of its table actions
    ``(N, 1)``."""
    if spec is not None and spec.table:
        return targets[:, 0].round().long() % N_PAN_MOVES
    angles = torch.as_tensor(PAN_ANGLES, dtype=targets.dtype)
    return (targets[:, 3:4] - angles[None]).abs().argmin(dim=1)


def head_log_probs(out: torch.Tensor, spec: FeatureSpec) -> torch.Tensor:
    """The network's logits ``(N, n_outputs)`` as log-probabilities, each head normalised on
    its own (the driving head, and a gaze student's pan head)."""
    drive = out[:, : spec.n_drive].log_softmax(dim=-1)
    if not spec.n_pan:
        return drive
    return torch.cat([drive, out[:, spec.n_drive :].log_softmax(dim=-1)], dim=-1)


def decode_action(out: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """The network's output (one row of class logits) -> ``[speed, relative heading]``, for a
    gaze student ``[speed, relative heading, pan target]`` (the pan head's most likely class
    refined by its neighbours' probabilities); for a discrete student the most likely table
    action (a 0-d integer array)."""
    out = np.asarray(out, dtype=np.float64)
    if spec.table:  # the likeliest cell, with a pan head the likeliest move
        action = int(np.argmax(out[: spec.n_drive]))
        if spec.gaze:
            action = action * N_PAN_MOVES + int(np.argmax(out[spec.n_drive :]))
        return np.asarray(action, dtype=np.int64)
    drive = _decode_drive(out[: spec.n_drive], spec)
    if not spec.gaze:
        return drive
    q = out[spec.n_drive :]
    q = np.exp(q - q.max())
    k = int(np.argmax(q))
    near = [j for j in (k - 1, k, k + 1) if 0 <= j < PAN_BINS]
    pan = float(q[near] @ PAN_ANGLES[near] / q[near].sum())
    return np.array([drive[0], drive[1], pan], dtype=np.float32)


def _decode_drive(out: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    logits = np.asarray(out, dtype=np.float64).reshape(len(SPEED_LEVELS), HEADING_BINS)
    p = np.exp(logits - logits.max())
    s, h = np.unravel_index(int(np.argmax(p)), p.shape)
    hs = [(h + k) % HEADING_BINS for k in (-1, 0, 1)]
    w = p[s, hs]
    heading = math.atan2(float(w @ np.sin(_BIN_ANGLES[hs])),
                         float(w @ np.cos(_BIN_ANGLES[hs])))  # fmt: skip
    ss = [k for k in (s - 1, s, s + 1) if 0 <= k < len(SPEED_LEVELS)]
    frac = float(p[ss, h] @ _LEVELS[ss] / p[ss, h].sum())
    speed = float(np.clip(frac * spec.max_speed, spec.min_speed, spec.max_speed))
    return np.array([speed, heading], dtype=np.float32)


def class_action(k: int, spec: FeatureSpec) -> np.ndarray:
    """Class ``k`` of the head (speed level * HEADING_BINS + heading bin) as the action
    ``[speed, relative heading]``: its speed level and its bin's centre."""
    level, hbin = divmod(int(k), HEADING_BINS)
    if not 0 <= level < len(SPEED_LEVELS):
        raise ValueError(f"class {k} is outside the head's {spec.n_outputs} classes")
    speed = float(np.clip(SPEED_LEVELS[level] * spec.max_speed, spec.min_speed, spec.max_speed))
    return np.array([speed, _BIN_ANGLES[hbin]], dtype=np.float32)


class StudentNet(nn.Module):
    """MLP on state features, plus (fused) a CNN on the pooled image added into layer 1."""

    def __init__(self, spec: FeatureSpec, hidden: int = 256) -> None:
        super().__init__()
        self.spec = spec
        self.inp = nn.Linear(spec.state_dim, hidden)
        self.body = nn.Sequential(
            nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.out = nn.Linear(hidden, spec.n_outputs)
        if spec.image:
            self.cnn = nn.Sequential(
                nn.Conv2d(3, 16, 5, stride=2, padding=2),
                nn.ReLU(),
                nn.Conv2d(16, 32, 3, stride=2, padding=1),
                nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=2, padding=1),
                nn.ReLU(),
                nn.AdaptiveAvgPool2d((3, 3)),
                nn.Flatten(),
                nn.Linear(32 * 9, IMAGE_FEATURES),
                nn.ReLU(),
            )
            self.img_proj = nn.Linear(IMAGE_FEATURES, hidden, bias=False)
            nn.init.zeros_(self.img_proj.weight)

    def forward(self, state: torch.Tensor, image: torch.Tensor | None = None) -> torch.Tensor:
        h = self.inp(state)
        if self.spec.image:
            if image is None:
                raise ValueError("this student sees the fused image: pass image=")
            h = h + self.img_proj(self.cnn(image.float() / 255.0))
        return self.out(self.body(h))


class EnsembleNet(nn.Module):
    """Several students of one feature spec, each trained by its own DAgger run (another
    seed: its own initialisation, episodes and sample order), acting as one.

    Output: the mean of the members' log-probabilities (the decoding's softmax of it is
    their normalised geometric mean, so a class wins only where the members agree on it).
    One run of the recipe is one
    draw of a noisy process (two runs of one recipe can differ by several points of success
    on the same episodes); averaging draws cuts the variance that one draw carries.
    """

    def __init__(self, members: list[StudentNet]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
        spec = members[0].spec
        for i, m in enumerate(members[1:], start=1):
            if m.spec != spec:
                raise ValueError(
                    f"ensemble member {i} has another feature spec than member 0 "
                    f"({m.spec} against {spec}): combine students made for one entry"
                )
        self.spec = spec
        self.members = nn.ModuleList(members)

    def forward(self, state: torch.Tensor, image: torch.Tensor | None = None) -> torch.Tensor:
        outs = torch.stack([head_log_probs(m(state, image), self.spec) for m in self.members])
        return outs.mean(dim=0)


@runtime_checkable
class Agent(Protocol):
    """What drives an env episode: ``reset()`` at each episode start, then ``act(obs)`` ->
    the env's action for each observation. :class:`StudentAgent` (what ``zoo.load``
    returns) is one; so are ``rover_train.agents.RandomAgent``, the lab's planner expert,
    and anything ``rover_train.evaluate.evaluate_agent`` (rover-eval) runs.
    ``isinstance(x, Agent)`` checks that the two methods exist, not their signatures (mypy
    checks those)."""

    def reset(self) -> None: ...

    def act(self, obs: Any) -> np.ndarray: ...


class StudentAgent:
    """A zoo agent: ``reset()`` at each episode start, ``act(obs)`` -> action (deterministic).

    It holds everything it needs (feature spec, network, and with ``spec.history`` the
    episode's :class:`ObsHistory`, which ``reset()`` clears).
    """

    def __init__(self, net: StudentNet | EnsembleNet, meta: dict[str, Any] | None = None
                 ) -> None:
        self.net = net.eval()
        self.spec = net.spec
        self.meta = dict(meta or {})
        self.history = ObsHistory(self.spec)

    def reset(self) -> None:
        self.history.reset()

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = torch.from_numpy(state_features(obs, self.spec, self.history))[None]
        image = torch.from_numpy(image_features(obs))[None] if self.spec.image else None
        out = self.net(state, image)[0].numpy()
        return decode_action(out, self.spec)

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self.act(obs)

    # --- files ---------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to rebuild the agent (tensors in fp16, plain metadata)."""
        weights = {k: v.detach().half() for k, v in self.net.state_dict().items()}
        spec = asdict(self.spec)
        spec["centre"] = list(spec["centre"])
        members = len(self.net.members) if isinstance(self.net, EnsembleNet) else 1
        return {"weights": weights, "spec": spec, "meta": self.meta, "members": members}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> StudentAgent:
        spec_d = dict(blob["spec"])
        spec_d["centre"] = tuple(spec_d["centre"])
        # keys of options that are gone: refused unless they hold what is now the only way
        for key, only in (("head", "bins"), ("pedestrian_scan", False)):
            if spec_d.pop(key, only) != only:
                raise ValueError(f"this student was made with {key}={blob['spec'][key]!r}, "
                                 f"which roverav no longer runs (only {only!r}); remake it "
                                 "with its entry's command (rover_train.zoo.command)")
        spec = FeatureSpec(**spec_d)
        members = int(blob.get("members", 1))  # files before ensembles: one student
        net: StudentNet | EnsembleNet = (
            EnsembleNet([StudentNet(spec) for _ in range(members)]) if members > 1
            else StudentNet(spec)
        )
        net.load_state_dict({k: v.float() for k, v in blob["weights"].items()})
        return cls(net, _current_meta(blob.get("meta")))

    @classmethod
    def ensemble(cls, agents: list[StudentAgent], meta: dict[str, Any] | None = None
                 ) -> StudentAgent:
        """One agent acting as the :class:`EnsembleNet` of ``agents``' networks (members
        that are ensembles themselves are flattened into it)."""
        nets: list[StudentNet] = []
        for a in agents:
            members = a.net.members if isinstance(a.net, EnsembleNet) else [a.net]
            nets.extend(cast(list[StudentNet], members))  # an EnsembleNet holds StudentNets
        return cls(EnsembleNet(nets), meta if meta is not None else agents[0].meta)

    def save(self, path: Any) -> None:
        torch.save(self.state_dict(), path)

    @classmethod
    def load(cls, path: Any) -> StudentAgent:
        """The student saved at ``path``; :class:`StudentFileError` when the file does not
        read as one (cut short, say)."""
        return cls.from_state_dict(read_student_file(path))

    @staticmethod
    def read_meta(path: Any) -> dict[str, Any]:
        """The ``meta`` of the student file ``path`` (its name, kind, world and recipe),
        read without building the network."""
        return dict(_current_meta(read_student_file(path).get("meta")) or {})


def _current_meta(meta: dict[str, Any] | None) -> dict[str, Any] | None:
    """A student file's ``meta`` with its env kind under today's name (``discrete`` was the
    fused discrete env: ``rover_train.zoo.registry.RENAMED_KINDS``)."""
    from rover_train.zoo.registry import stored_kind

    if meta and isinstance(meta.get("kind"), str):
        return {**meta, "kind": stored_kind(meta["kind"])}
    return meta


class StudentFileError(ValueError):
    """A student file that does not read as one: cut short (an interrupted copy or
    download), or not a student file at all. The message names the file."""


def read_student_file(path: Any) -> dict[str, Any]:
    """The dict :meth:`StudentAgent.save` wrote to ``path``. Raises FileNotFoundError for a
    missing file and :class:`StudentFileError`, naming the file, for one torch cannot read
    (torch's own errors say neither which file nor why: "failed finding central directory",
    ``OSError: [Errno 22]``, an empty ``EOFError``)."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except (OSError, RuntimeError, EOFError, pickle.UnpicklingError) as exc:
        raise StudentFileError(
            f"{path} is not a readable student file ({type(exc).__name__}: "
            f"{str(exc).split('. ')[0] or 'the file ends early'}); it may be cut short, by "
            "an interrupted copy or download"
        ) from exc
    if not isinstance(blob, dict) or "weights" not in blob or "spec" not in blob:
        raise StudentFileError(f"{path} is not a student file: it holds no weights and spec")
    return blob
