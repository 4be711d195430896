"""HeadingPID: the seed's heading controller, on simulated time.

The seed's ``heading_controller`` measured ``dt`` with ``time.time()``, which makes the
derivative term (and so the rover's behaviour) depend on how fast the host runs. Here
``dt`` is the simulated control period: the same actions give the same motion anywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rover_env.constants import CONTROL_DT, MAX_ANGULAR_VELOCITY, PID_KD, PID_KI, PID_KP


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to [-pi, pi] the seed's way: atan2(sin, cos)."""
    return math.atan2(math.sin(angle), math.cos(angle))


@dataclass
class HeadingPID:
    """PID from heading error to a yaw-rate command, clamped to ``+-max_output``.

    :param kp: proportional gain (seed Kp = 2.0).
    :param ki: integral gain (seed Ki = 0.0).
    :param kd: derivative gain (seed Kd = 0.1).
    :param max_output: clamp in rad/s (seed max_angular_velocity = 7.0).
    :param dt: simulated seconds between updates (the env's control period).
    """

    kp: float = PID_KP
    ki: float = PID_KI
    kd: float = PID_KD
    max_output: float = MAX_ANGULAR_VELOCITY
    dt: float = CONTROL_DT
    integral_error: float = field(default=0.0, init=False)
    last_error: float = field(default=0.0, init=False)

    def __post_init__(self) -> None:
        if not self.dt > 0:
            raise ValueError(f"HeadingPID dt must be > 0 s, got {self.dt}")
        if not self.max_output > 0:
            raise ValueError(f"HeadingPID max_output must be > 0, got {self.max_output}")

    def reset(self) -> None:
        """Forget the integral and the last error (start of an episode)."""
        self.integral_error = 0.0
        self.last_error = 0.0

    def update(self, desired_heading: float, current_heading: float) -> float:
        """Yaw-rate command (rad/s) steering ``current_heading`` towards ``desired_heading``.

        The error is wrapped to [-pi, pi], so the rover turns the short way round.
        """
        error = wrap_angle(desired_heading - current_heading)
        self.integral_error += error * self.dt
        derivative = (error - self.last_error) / self.dt
        self.last_error = error
        control = self.kp * error + self.ki * self.integral_error + self.kd * derivative
        return min(max(control, -self.max_output), self.max_output)
