"""What rover-train may put between a fused env and the policy, and how an agent trained so
drives the plain env.

- :class:`RelativeTable` (``rover-train --relative-table``): ``Discrete(60)`` over a
  continuous env's ``[speed, relative heading]`` action, the seed's 5 speeds x 12 headings
  relative to the yaw, exactly ``RoverEnvDiscrete``'s table. PPO from scratch learns the
  nav task on that table where Gaussian noise on the box, filtered out by the rover's
  inertia, did not (the LIDAR RL entries); the fused discrete env's table steers to
  absolute compass headings, which a policy must then learn at every yaw.
- :class:`DropImage` (``rover-train --drop-image``): the observation without
  ``fused_image``, so the policy reads the camera scan and the state (an MLP) and not the
  pixels (a CNN): the daemon still perceives every frame, and the scan is made from it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rover_env.discrete_env import N_DIRECTIONS, N_SEED_ACTIONS, SPEED_LEVELS, decode_action

IMAGE_KEY = "fused_image"
RELATIVE_ANGLES = np.linspace(-np.pi, np.pi, N_DIRECTIONS, endpoint=False)
"""Heading k of the relative table: ``-pi + k * pi / 6`` rad from the yaw (k = 6 straight on)."""


def relative_action(action: Any) -> np.ndarray:
    """The ``[speed, relative heading]`` float32 command of a table action in ``0..59``."""
    speed_idx, direction_idx = decode_action(action)
    return np.array([SPEED_LEVELS[speed_idx], RELATIVE_ANGLES[direction_idx]], dtype=np.float32)


class RelativeTable(gym.ActionWrapper):
    """``Discrete(60)`` over an env whose actions are ``[speed, relative heading, ...]`` (see
    the module docstring); a gaze env's pan target stays straight ahead."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        box = env.action_space
        if not isinstance(box, spaces.Box) or box.shape[0] < 2:
            raise ValueError(
                f"the relative table drives a continuous [speed, relative heading] action; "
                f"this env's action space is {box} (use --env fused or fused-gaze)"
            )
        self._rest = np.zeros(box.shape[0] - 2, dtype=np.float32)
        self.action_space = spaces.Discrete(N_SEED_ACTIONS)

    def action(self, action: Any) -> np.ndarray:
        command = relative_action(action)
        return np.concatenate([command, self._rest]) if len(self._rest) else command


class DropImage(gym.ObservationWrapper):
    """The observation without ``fused_image`` (see the module docstring)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, spaces.Dict) or IMAGE_KEY not in space.spaces:
            raise ValueError(f"--drop-image takes {IMAGE_KEY!r} out of a fused env's "
                             f"observation; this env's has none ({space})")  # fmt: skip
        self.observation_space = spaces.Dict(
            {k: s for k, s in space.spaces.items() if k != IMAGE_KEY}
        )

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        return drop_image(observation)


def drop_image(observation: dict[str, Any]) -> dict[str, Any]:
    """``observation`` without ``fused_image`` (a new dict)."""
    return {k: v for k, v in observation.items() if k != IMAGE_KEY}


def agent_io(recipe: dict[str, Any]) -> tuple[Callable[[Any], Any] | None,
                                              Callable[[Any], Any] | None]:  # fmt: skip
    """What an agent trained with ``recipe`` (a rover-train model's stored arguments) does
    to the plain env's observations, and to its own actions, to drive that env as it was
    trained: (observe, act), each None when nothing is to be done."""
    steps: list[Callable[[Any], Any]] = []
    if recipe.get("waypoint"):
        from rover_train.waypoint import observer

        steps.append(observer(recipe["world"]))
    if recipe.get("drop_image"):
        steps.append(drop_image)

    def observe(obs: Any) -> Any:
        for step in steps:
            obs = step(obs)
        return obs

    return (observe if steps else None,
            relative_action if recipe.get("relative_table") else None)  # fmt: skip
