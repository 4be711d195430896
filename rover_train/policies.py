"""Feature extractor for the roverav Dict observations.

SB3 treats only uint8 images as images: a float32 ``fused_image`` would be flattened into an
MLP. ``RoverExtractor`` routes every (H, W, C) Box through a small CNN and every vector Box
through a scaling to [-1, 1] (from the space's own bounds) and an MLP, then concatenates.

Scaled by its bounds alone, a LIDAR range of 0.3 m (a collision) and one of 0.5 m lie 0.03
apart over the 12 m reach, and a goal 1 m away and one 10 m away 0.18 apart over the
target's 100 m: too close for a policy to tell a panel from open ground (docs/decisions.md,
"RL"). So the MLP also sees each LIDAR range as ``exp(-range / PROXIMITY_M)``
and the target as (distance within ``GOAL_NEAR_M``, cos and sin of its bearing), and the
map planner's waypoint, where the observation has one (``rover-train --waypoint``), also as
the cos and sin of its bearing. The camera scan (``rover-train --camera-scan``) is a vector
key too, its ranges also seen as proximities, as the LIDAR's are.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from rover_env.camera_scan import SCAN_KEY  # (obstacle, person, age) x sectors
from rover_train.waypoint import WAYPOINT_KEY

PROXIMITY_M = 0.5
"""Metres: the LIDAR's proximity features are exp(-range / PROXIMITY_M) (0.55 at 0.3 m, 0.37 at
0.5 m, 0.14 at 1 m)."""
GOAL_NEAR_M = 12.0
"""Metres: the target distance feature is min(distance, GOAL_NEAR_M) scaled to [-1, 1]."""
LIDAR_KEY = "lidar"
SCAN_PROXIMITY_M = 1.0
"""Metres: the camera scan's ranges are also seen as exp(-range / SCAN_PROXIMITY_M) (a person
at 0.6 m 0.55, at 1.2 m 0.30, at 3 m 0.05): its 10 m reach flattens a near person as the
LIDAR's 12 m does."""
TARGET_KEY = "target"  # (distance m, bearing rad)


def _is_image(space: gym.Space) -> bool:
    return isinstance(space, gym.spaces.Box) and len(space.shape) == 3


class RoverExtractor(BaseFeaturesExtractor):
    """CNN for channels-last float images in [0, 1], MLP for bounded vectors.

    :param observation_space: the env's Dict observation space
    :param cnn_dim: features produced by the CNN per image key
    :param mlp_dim: features produced by the MLP over all vector keys together
    """

    def __init__(self, observation_space: gym.spaces.Dict, cnn_dim: int = 128, mlp_dim: int = 64):
        image_keys = [k for k, s in observation_space.spaces.items() if _is_image(s)]
        vector_keys = [k for k in observation_space.spaces if k not in image_keys]
        super().__init__(observation_space, features_dim=cnn_dim * len(image_keys) + mlp_dim)
        self.image_keys = image_keys
        self.vector_keys = vector_keys
        self.cnns = nn.ModuleDict()
        for key in image_keys:
            h, w, c = observation_space[key].shape
            cnn = nn.Sequential(
                nn.Conv2d(c, 16, 8, stride=4),
                nn.ReLU(),
                nn.Conv2d(16, 32, 4, stride=2),
                nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=1),
                nn.ReLU(),
                nn.Flatten(),
            )
            with torch.no_grad():
                n_flat = cnn(torch.zeros(1, c, h, w)).shape[1]
            self.cnns[key] = nn.Sequential(cnn, nn.Linear(n_flat, cnn_dim), nn.ReLU())
        lows, highs = [], []
        for key in vector_keys:
            space = observation_space[key]
            lows.append(np.broadcast_to(space.low, space.shape).ravel())
            highs.append(np.broadcast_to(space.high, space.shape).ravel())
        low = np.concatenate(lows).astype(np.float32)
        high = np.concatenate(highs).astype(np.float32)
        self.register_buffer("_centre", torch.as_tensor((high + low) / 2))
        self.register_buffer("_half", torch.as_tensor(np.maximum((high - low) / 2, 1e-6)))
        with torch.no_grad():  # the inputs vector_inputs builds, counted as the CNN's are
            sample = {k: torch.as_tensor(np.asarray(observation_space[k].sample())[None])
                      for k in vector_keys}  # fmt: skip
            n_inputs = self.vector_inputs(sample).shape[1]
        self.mlp = nn.Sequential(
            nn.Linear(n_inputs, mlp_dim), nn.ReLU(), nn.Linear(mlp_dim, mlp_dim),
            nn.ReLU()
        )

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        parts = [self.cnns[k](observations[k].permute(0, 3, 1, 2)) for k in self.image_keys]
        parts.append(self.mlp(self.vector_inputs(observations)))
        return torch.cat(parts, dim=1)

    def vector_inputs(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """What the MLP sees: every vector key scaled to [-1, 1] by its bounds, then the LIDAR
        proximities and the target's near distance, cos and sin of bearing (when present)."""
        vec = torch.cat([observations[k].flatten(1) for k in self.vector_keys], dim=1)
        inputs = [(vec - self._centre) / self._half]
        if LIDAR_KEY in self.vector_keys:
            inputs.append(torch.exp(-observations[LIDAR_KEY].flatten(1) / PROXIMITY_M))
        if SCAN_KEY in self.vector_keys:
            ranges = observations[SCAN_KEY][:, :2].flatten(1)
            inputs.append(torch.exp(-ranges / SCAN_PROXIMITY_M))
        if TARGET_KEY in self.vector_keys:
            dist, bearing = observations[TARGET_KEY][:, 0], observations[TARGET_KEY][:, 1]
            near = torch.clamp(dist, max=GOAL_NEAR_M) * (2.0 / GOAL_NEAR_M) - 1.0
            inputs.append(torch.stack([near, torch.cos(bearing), torch.sin(bearing)], dim=1))
        if WAYPOINT_KEY in self.vector_keys:
            bearing = observations[WAYPOINT_KEY][:, 1]
            inputs.append(torch.stack([torch.cos(bearing), torch.sin(bearing)], dim=1))
        return torch.cat(inputs, dim=1)
