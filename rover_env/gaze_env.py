"""RoverEnvFusedGaze: RoverEnvFused whose agent also chooses where the camera looks."""

from __future__ import annotations

import logging
import math
from typing import Any, cast

import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env.core import float_box
from rover_env.fused_env import RoverEnvFused

log = logging.getLogger(__name__)

_F32 = np.float32


class RoverEnvFusedGaze(RoverEnvFused):
    """RoverEnvFused plus gaze control: each action also sets the camera's pan.

    ## Description

    The "active" in Active Vision (seed 001: the gaze-control head of the original joint
    policy). The forward camera sits on a pan head that turns about the vertical through
    the camera (a frame of the MuJoCo rover model, ``rover.CAMERA_HEAD_NAME``; the chase
    view shows the head turning). With a 90 deg camera, a pedestrian approaching from the
    side stays out of view until it is close, unless the agent looks. The daemon is
    unchanged: it processes whatever the camera sees.

    ## Action space

    ``Box([-0.6, -pi, -pi/3], [1.0, pi, pi/3], (3,), float32)``:

    | Index | Meaning | Range |
    |---|---|---|
    | 0 | forward speed (m/s), as RoverEnvFused | [-0.6, 1.0] |
    | 1 | desired heading relative to the current yaw (rad), as RoverEnvFused | [-pi, pi] |
    | 2 | pan target relative to the rover's heading (rad, positive = left) | [-pi/3, pi/3] |

    The head turns towards the target at ``pan_rate`` (default 180 deg/s = pi rad/s, a
    loaded hobby pan servo: 9 deg per 0.05 s step, a full -60 to +60 deg sweep in 0.67 s)
    and is where the camera looks when the step's frame is rendered; ``pan_rate=None``
    makes it jump to the target at once. Out-of-range actions are clipped; anything but
    3 finite numbers raises ``ValueError``.

    ## Observation space

    RoverEnvFused's keys plus:

    | Key | Shape | Range | Meaning |
    |-----|-------|-------|---------|
    | ``gaze`` | (1,) | [-pi/3, pi/3] | the camera's pan when ``fused_image`` was taken (rad) |

    ## Rewards

    RoverEnvFused's (progress, goal, heatmap centre penalty, terminal penalties), plus
    ``reward_pan`` in ``info``: always 0 here (panning is free in the continuous env);
    :class:`DiscreteRoverEnvFusedGaze` charges ``RewardConfig.pan_penalty`` per pan move.
    Note that the heatmap penalty looks at the image's centre columns wherever the camera
    points, as in the seed: looking away from a pedestrian in the rover's way lowers it.
    ``RewardConfig.fused(pedestrian_penalty_frame="heading")`` charges the pedestrians in
    the rover's heading instead, wherever the camera looks.

    ## Episode end

    As RoverEnvFused. The camera faces straight ahead again at every ``reset()``.

    ## Info

    RoverEnvFused's keys (``pedestrian_in_view``, ``nearest_pedestrian_in_view`` and the
    rest) plus ``pan`` (rad, where the camera looks relative to the heading),
    ``pan_target`` (rad) and ``pan_moves`` (steps in this episode in which the camera
    turned).

    ## Arguments

    RoverEnvFused's, plus ``pan_rate`` (rad/s, default ``math.radians(180)``; ``None``:
    the pan jumps to the target). ``render_mode="rgb_array"`` frames show where the camera
    looks: its centre line and field-of-view edges on the ground.

    ## Version history

    - v0: first release.
    """

    _counts_turns = 1  # pan_moves counts steps in which the camera turned (discrete: 0)

    def __init__(self, *args: Any, pan_rate: float | None = c.PAN_RATE, **kwargs: Any) -> None:
        if pan_rate is not None and not (math.isfinite(pan_rate) and pan_rate > 0):
            raise ValueError(
                f"pan_rate must be a positive number of rad/s (e.g. math.radians(180)) or "
                f"None for an instant pan, got {pan_rate!r}"
            )
        super().__init__(*args, **kwargs)
        self.pan_rate = None if pan_rate is None else float(pan_rate)
        self.pan_limit = c.PAN_LIMIT
        self.observation_space = spaces.Dict(
            {
                **cast(spaces.Dict, self.observation_space).spaces,
                "gaze": spaces.Box(-self.pan_limit, self.pan_limit, shape=(1,), dtype=_F32),
            }
        )
        self.action_space = float_box(c.GAZE_ACTION_LOW, c.GAZE_ACTION_HIGH)
        self.pan_target = 0.0
        self.pan_moves = 0
        self._pan_cost_units = 0  # pan moves charged this step

    # --- hooks ----------------------------------------------------------------------------------
    def _decode_action(self, action: Any) -> tuple[float, float]:
        try:
            a = np.asarray(action, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise ValueError(self._bad_action(action, f"not numbers ({exc})")) from None
        if a.shape != (3,):
            raise ValueError(self._bad_action(action, f"shape {np.shape(action)}"))
        if not np.all(np.isfinite(a)):
            raise ValueError(self._bad_action(action, "non-finite values"))
        box = cast(spaces.Box, self.action_space)  # the discrete gaze env overrides this method
        low, high = box.low, box.high
        speed, heading, pan = (float(min(max(a[i], low[i]), high[i])) for i in range(3))
        self.pan_target = pan
        self._pan_cost_units = 0
        return speed, float(self.orientation[2]) + heading

    @staticmethod
    def _bad_action(action: Any, found: str) -> str:
        return (
            f"{type_name(action)} action {action!r}: expected 3 finite numbers [speed m/s, "
            f"relative heading rad, pan target rad] (Box([-0.6, -pi, -pi/3], [1, pi, pi/3])), "
            f"found {found}. Pass e.g. np.array([0.5, 0.0, 0.3], np.float32) or "
            "env.action_space.sample()."
        )

    def _on_reset(self) -> None:
        super()._on_reset()
        self.pan_target = 0.0
        self.pan_moves = 0
        self._pan_cost_units = 0
        self.sim.set_camera_pan(0.0)

    def _observe(self) -> dict[str, np.ndarray]:
        self._turn_camera()
        obs = super()._observe()
        pan = min(max(self.sim.camera_pan, -self.pan_limit), self.pan_limit)
        obs["gaze"] = np.array([pan], dtype=_F32)
        return obs

    def _turn_camera(self) -> None:
        """Move the pan head towards ``pan_target`` by at most one step's servo travel."""
        pan, target = self.sim.camera_pan, self.pan_target
        if pan == target:
            return
        self.sim.set_camera_pan(servo_step(pan, target, self.pan_rate, self.control_dt))
        self.pan_moves += self._counts_turns

    def _task_reward(self, obs: dict[str, np.ndarray]) -> float:
        reward = super()._task_reward(obs)
        if self.goal_reached:  # the goal step's only term is the goal, as in RoverEnvFused
            self._add_reward_term("pan", 0.0)
            return reward
        cost = (
            -self.reward_config.pan_penalty * self._pan_cost_units if self._pan_cost_units else 0.0
        )
        return reward + self._add_reward_term("pan", cost)

    def _info(self, reward: float, reason: str) -> dict[str, Any]:
        info = super()._info(reward, reason)
        info["pan"] = self.sim.camera_pan
        info["pan_target"] = self.pan_target
        info["pan_moves"] = self.pan_moves
        return info

    def render(self) -> np.ndarray | None:
        """``rgb_array``: a chase-camera frame with the camera's view cone on the ground."""
        if self.render_mode != "rgb_array" or self.closed:
            return super().render()  # warns, or raises EnvClosedError
        return self.sim.render_chase(*self.render_size, view_cone=True)


def servo_step(pan: float, target: float, rate: float | None, dt: float) -> float:
    """Where a pan head at ``pan`` (rad) turning towards ``target`` at ``rate`` rad/s is
    after ``dt`` s (``rate=None``: at the target at once). The gaze envs' servo, and that of
    anything that turns a sim's camera the way they do."""
    if rate is None:
        return target
    travel = rate * dt
    return pan + min(max(target - pan, -travel), travel)


def type_name(value: Any) -> str:
    """``type(value).__name__`` with an article, for error messages."""
    name = type(value).__name__
    return f"an {name}" if name[:1].lower() in "aeiou" else f"a {name}"
