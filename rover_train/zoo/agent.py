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
- ``fused_image`` (fused students): the three channels average-pooled to 48x48 through a
  small CNN whose features are added into the MLP's first hidden layer through a
  projection that starts at zero, so a fused student can start as a state-only one.

The network predicts ``(speed / max speed, cos heading, sin heading)``; the heading is
decoded with ``atan2`` so "turn around" has no discontinuity at +-pi.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

LIDAR_CLIP = 4.0  # m
FREQUENCIES = (0.5, 1.0, 2.0)  # cycles per world half-size, for position features
POOL = 2  # fused image average-pool factor (96 -> 48)
IMAGE_FEATURES = 32


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

    @property
    def state_dim(self) -> int:
        return 4 + 4 * 2 * len(FREQUENCIES) + 2 + 2 + 3 + 2 + self.lidar_points


def state_features(obs: dict[str, np.ndarray], spec: FeatureSpec) -> np.ndarray:
    """The state feature vector of one observation (float32, ``spec.state_dim``)."""
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
    if spec.lidar_points:
        lidar = np.asarray(obs["lidar"], dtype=np.float64)
        parts.append(np.clip(lidar, 0.0, LIDAR_CLIP) / LIDAR_CLIP)
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
    """``[speed, heading]`` -> the network's target ``(speed / max, cos, sin)``."""
    speed, heading = float(action[0]), float(action[1])
    return np.array([speed / spec.max_speed, math.cos(heading), math.sin(heading)], np.float32)


def decode_action(out: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    speed = float(np.clip(out[0] * spec.max_speed, spec.min_speed, spec.max_speed))
    return np.array([speed, math.atan2(float(out[2]), float(out[1]))], dtype=np.float32)


class StudentNet(nn.Module):
    """MLP on state features, plus (fused) a CNN on the pooled image added into layer 1."""

    def __init__(self, spec: FeatureSpec, hidden: int = 256) -> None:
        super().__init__()
        self.spec = spec
        self.inp = nn.Linear(spec.state_dim, hidden)
        self.body = nn.Sequential(
            nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.out = nn.Linear(hidden, 3)
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


class StudentAgent:
    """A zoo agent: ``reset()`` at each episode start, ``act(obs)`` -> action (deterministic).

    It holds everything it needs (feature spec, network); it keeps no state between
    steps, so ``reset()`` only exists for callers that treat every agent alike.
    """

    def __init__(self, net: StudentNet, meta: dict[str, Any] | None = None) -> None:
        self.net = net.eval()
        self.spec = net.spec
        self.meta = dict(meta or {})

    def reset(self) -> None:
        return None

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = torch.from_numpy(state_features(obs, self.spec))[None]
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
        return {"weights": weights, "spec": spec, "meta": self.meta}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> StudentAgent:
        spec_d = dict(blob["spec"])
        spec_d["centre"] = tuple(spec_d["centre"])
        spec = FeatureSpec(**spec_d)
        net = StudentNet(spec)
        net.load_state_dict({k: v.float() for k, v in blob["weights"].items()})
        return cls(net, blob.get("meta"))

    def save(self, path: Any) -> None:
        torch.save(self.state_dict(), path)

    @classmethod
    def load(cls, path: Any) -> StudentAgent:
        return cls.from_state_dict(torch.load(path, map_location="cpu", weights_only=True))
