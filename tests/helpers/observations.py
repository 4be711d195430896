"""Hand-made observations for the students' feature tests."""

from __future__ import annotations

import numpy as np


def gaze_obs(pan: float) -> dict[str, np.ndarray]:
    """A gaze env's state keys at one pose, the camera turned to ``pan`` (rad)."""
    return {
        "pose": np.array([1.0, 2.0, 0.1], np.float32),
        "imu": np.array([0.0, 0.0, 0.3], np.float32),
        "target": np.array([4.0, 0.5], np.float32),
        "velocities": np.array([0.5, 0.1], np.float32),
        "gaze": np.array([pan], np.float32),
    }
