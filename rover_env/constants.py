"""Constants taken from the seeds (RoboTerrain's RoverEnv / RoverEnvFused), named once.

Where we renamed a seed field, the seed's name is given beside ours. Values not stated by
a seed (rover geometry, physics step, pedestrian speeds) live in the module that uses them.
"""

from __future__ import annotations

import math

from shm_protocol.names import DEFAULT_NAME

# --- episode and timing ----------------------------------------------------------------
LENGTH = 2000  # seed: RoverEnv(length=2000), maximum steps per episode
FUSED_LENGTH = 6000  # seed: RoverEnvFused(length=6000)
SIZE = (64, 64)  # seed: RoverEnv(size=(64, 64)), reserved image buffer (unused by RoverEnv)
CONNECTION_CHECK_TIMEOUT = 30  # seed: connection_check_timeout (no effect without ROS)
CONTROL_DT = 0.05  # s of simulated time per env step (the seed ran at wall clock)

# --- sensors ---------------------------------------------------------------------------
LIDAR_POINTS = 32  # seed: lidar_points
MAX_LIDAR_RANGE = 12.0  # seed: max_lidar_range (m)

# --- ROS topic arguments (accepted, no effect) ----------------------------------------
SCAN_TOPIC = "/scan"
IMU_TOPIC = "/imu/data"
CMD_VEL_TOPIC = "/cmd_vel"
CAMERA_TOPIC = "/camera/image_raw"
RL_OBS_NAME = DEFAULT_NAME  # seed: rl_obs_name (fused envs' segment); home: shm_protocol.names

# --- spaces ----------------------------------------------------------------------------
ACTION_LOW = (-1.0, -math.pi)  # RoverEnv: speed m/s, relative heading rad
ACTION_HIGH = (1.0, math.pi)
FUSED_ACTION_LOW = (-0.6, -math.pi)  # RoverEnvFused: reverse limited to -0.6 m/s
FUSED_ACTION_HIGH = (1.0, math.pi)
POSE_LOW = (-30.0, -30.0, -10.0)
POSE_HIGH = (30.0, 30.0, 10.0)
IMU_LOW = (-math.pi, -math.pi, -math.pi)  # pitch, roll, yaw
IMU_HIGH = (math.pi, math.pi, math.pi)
TARGET_LOW = (0.0, -math.pi)  # distance m, relative angle rad
TARGET_HIGH = (100.0, math.pi)
VELOCITIES_LOW = (-10.0, -10.0)  # linear m/s, angular rad/s
VELOCITIES_HIGH = (10.0, 10.0)

# --- discrete action table (seed 002) ----------------------------------------------------
DISCRETE_SPEED_LEVELS = (-0.2, 0.0, 0.3, 0.6, 1.0)  # seed: speed_levels (m/s)
DISCRETE_N_DIRECTIONS = 12  # seed: n_directions; np.linspace(-pi, pi, 12, endpoint=False)

# --- PID heading controller ----------------------------------------------------------------
PID_KP = 2.0  # seed: Kp
PID_KI = 0.0  # seed: Ki
PID_KD = 0.1  # seed: Kd
MAX_ANGULAR_VELOCITY = 7.0  # seed: max_angular_velocity (rad/s clamp)

# --- safety ------------------------------------------------------------------------------
FLIP_THRESHOLD = 1.48  # seed: FLIP_THRESHOLD / flip_threshold (rad, about 85 deg)
STUCK_WINDOW = 600  # seed: stuck_window (steps); also the stuck-in-collision limit
STUCK_THRESHOLD = 0.001  # seed: stuck_threshold (m)
FUSED_STUCK_WINDOW = 5000  # seed 000/002: stuck_window of the fused envs
FUSED_STUCK_THRESHOLD = 0.0001  # seed 000/002: stuck_threshold of the fused envs

# --- rewards -------------------------------------------------------------------------------
SUCCESS_DISTANCE = 0.5  # seed: success_distance (m)
GOAL_REWARD = 100.0  # seed: goal reward; a new goal is sampled, the episode continues
COLLISION_DISTANCE = 0.3  # seed: collision when LIDAR min < 0.3 m
COLLISION_PENALTY = -0.5  # seed: per-step collision penalty
STUCK_PENALTY = -25.0  # seed: stuck_penilty
GENERAL_PENALTY = -20.0  # seed: general_penility (flip, stuck-in-collision)
TOO_FAR_AWAY_PENALTY = -10.0  # seed: too_far_away_penilty (out of bounds)
DISTANCE_DELTA_SCALE = 0.3 * 1.5  # seed: distance_delta * 0.3 * 1.5
FUSED_DISTANCE_DELTA_SCALE = 0.9  # seed 000: distance_delta_scale of RoverEnvFused
LINEAR_VELOCITY_SCALE = 0.0025  # seed: linear_vel * 0.0025
TURN_PENALTY_SCALE = 0.0015  # seed: -0.0015 * |angular_vel|
HEATMAP_CENTER_SCALE = 0.1  # seed 000: heatmap_center_scale (fused envs)
HEATMAP_CENTER_COLUMNS = 4  # seed 000: sum over the centre 4 columns of the heatmap
PAN_PENALTY = 0.02  # original joint gaze policy: -0.02 reward per camera pan move

# --- gaze (seed 001: pan_offsets = [-60, -30, 0, +30, +60] degrees) -------------------------
PAN_WINDOWS_DEG = (-60.0, -30.0, 0.0, 30.0, 60.0)  # camera pan relative to the heading
PAN_LIMIT = math.radians(60.0)  # rad, either side; the continuous gaze env's action bound
PAN_RATE = math.radians(180.0)  # rad/s, the camera head's servo rate (hobby pan servos:
# 0.1-0.2 s per 60 deg unloaded; 180 deg/s is a loaded, conservative figure)
GAZE_ACTION_LOW = (-0.6, -math.pi, -math.pi / 3)  # speed m/s, heading rad, pan target rad
GAZE_ACTION_HIGH = (1.0, math.pi, math.pi / 3)

# --- worlds (seed: "World-Specific Configuration"), to the metre ---------------------------
# rand_x_range / rand_y_range: rover spawn; rand_goal_*: goal;
# too_far_away_{low,high}_{x,y}: out-of-bounds rectangle.
WORLD_RECTANGLES: dict[str, dict[str, tuple[float, float]]] = {
    "inspect": {
        "rand_x_range": (-27.0, -19.0),
        "rand_y_range": (-27.0, -19.0),
        "rand_goal_x_range": (-27.0, -19.0),
        "rand_goal_y_range": (-27.0, -19.0),
        "too_far_away_x": (-29.0, -13.0),
        "too_far_away_y": (-29.0, -17.0),
    },
    "moon": {
        "rand_x_range": (-4.0, 4.0),
        "rand_y_range": (-4.0, 4.0),
        "rand_goal_x_range": (-4.0, 4.0),
        "rand_goal_y_range": (-4.0, 4.0),
        "too_far_away_x": (-20.0, 10.0),
        "too_far_away_y": (-20.0, 20.0),
    },
    "maze": {
        "rand_x_range": (-4.0, 4.0),
        "rand_y_range": (-4.0, 4.0),
        "rand_goal_x_range": (-4.0, 4.0),
        "rand_goal_y_range": (-4.0, 4.0),
        "too_far_away_x": (-30.0, 30.0),
        "too_far_away_y": (-30.0, 30.0),
    },
}
WORLD_ALIASES = {"island": "moon"}  # seed: if world_n == 'island': world_name = 'moon'
DEFAULT_WORLD = "inspect"  # seed: world_n='inspect'; every CLI's default too

# --- proxemics (not in the seeds; the metrics every env and report use) -------------------
PERSONAL_SPACE_M = 1.2  # a pedestrian closer than this is a personal-space intrusion
INTIMATE_SPACE_M = 0.45  # ... and closer than this an intimate-space intrusion
ROVER_STOPPED_SPEED = 0.05  # m/s: slower, a pedestrian contact is the pedestrian's doing
