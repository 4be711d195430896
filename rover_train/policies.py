"""Feature extractor for the roverav Dict observations.

SB3 treats only uint8 images as images: a float32 ``fused_image`` would be flattened into an
MLP. ``RoverExtractor`` routes every (H, W, C) Box through a small CNN and every vector Box
through a scaling to [-1, 1] (from the space's own bounds) and an MLP, then concatenates.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


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
        self.mlp = nn.Sequential(
            nn.Linear(low.size, mlp_dim), nn.ReLU(), nn.Linear(mlp_dim, mlp_dim), nn.ReLU()
        )

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        parts = [self.cnns[k](observations[k].permute(0, 3, 1, 2)) for k in self.image_keys]
        vec = torch.cat([observations[k].flatten(1) for k in self.vector_keys], dim=1)
        parts.append(self.mlp((vec - self._centre) / self._half))
        return torch.cat(parts, dim=1)
