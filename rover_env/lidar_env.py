"""RoverEnv: LIDAR-first rover navigation (the seed's baseline env) on MuJoCo."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env.core import RoverEnvBase, float_box, state_spaces


class RoverEnv(RoverEnvBase):
    """Drive a Leo-like rover to random goals using a 2D LIDAR, pose, IMU and odometry.

    ## Description

    RoboTerrain's ``RoverEnv`` rebuilt on MuJoCo, without ROS. A 6.5 kg four-wheel
    skid-steer rover (0.45 x 0.43 m, 0.13 m wheels) drives in one of three worlds:
    ``inspect`` (solar-panel rows and service structures), ``moon`` (rough height-field
    terrain with rocks and hills where it can flip; ``island`` is an alias) or ``maze``
    (walls). Each world has at least two pedestrians walking back and forth at 1.0-1.5 m/s;
    they collide with the rover and the LIDAR sees them. The agent reaches a goal
    (+100), gets a new one, and carries on until it fails or runs out of steps (with
    ``goal_ends_episode=True`` the first goal ends the episode: the RL task
    ``rover-train --task nav`` trains on).

    One step is ``control_dt`` seconds of simulated time (0.05 s by default): the action
    is applied, the physics advanced, and the observation read. Nothing waits for the
    wall clock.

    ## Action space

    ``Box([-1, -pi], [1, pi], (2,), float32)``

    | Num | Action | Min | Max | Unit |
    |-----|--------|-----|-----|------|
    | 0 | forward speed command | -1.0 | 1.0 | m/s |
    | 1 | desired heading, relative to the current yaw | -pi | pi | rad |

    The heading goes through the seed's PID (Kp 2.0, Ki 0.0, Kd 0.1, output clamped to
    +-7 rad/s; dt = ``control_dt`` of simulated time, not wall-clock time) which
    produces the yaw-rate command. Out-of-range actions are clipped to the box;
    non-finite actions (NaN, inf) raise ``ValueError``.

    ## Observation space

    ``Dict`` of float32 Boxes, exactly the seed's:

    | Key | Shape | Range | Meaning |
    |-----|-------|-------|---------|
    | ``lidar`` | (lidar_points,) | [0, max_lidar_range] | planar scan, min per segment (m) |
    | ``pose`` | (3,) | x, y in [-30, 30], z in [-10, 10] | rover position (m) |
    | ``imu`` | (3,) | [-pi, pi] | pitch, roll, yaw (rad) |
    | ``target`` | (2,) | [0, 100], [-pi, pi] | goal distance (m), bearing from heading (rad) |
    | ``velocities`` | (2,) | [-10, 10] | wheel-odometry linear (m/s), angular (rad/s) |

    The LIDAR sits 0.30 m above the ground at the rover's centre and turns with it.
    It casts ``lidar_points * k`` rays (k so that there are at least 360) over
    [-pi, pi) counter-clockwise, starting straight behind; each point is the minimum of its
    k rays, so the middle points look forward. Misses and returns beyond
    ``max_lidar_range`` read ``max_lidar_range``. It sees walls, panels, rocks and
    pedestrians, not the ground itself nor the rover.

    ## Rewards

    Each step that does not end the episode:

    | Term (``info`` key) | Value |
    |------|-------|
    | goal (``reward_goal``) | +100 when the goal is closer than 0.5 m; a new goal is drawn |
    | | (with ``goal_ends_episode=True``: the episode ends instead) |
    | progress (``reward_progress``) | (metres closer to the goal) x 0.3 x 1.5 |
    | velocity bonus (``reward_velocity``) | odometry linear velocity x 0.0025 |
    | turn penalty (``reward_turn``) | -0.0015 x abs(odometry angular velocity) |
    | collision (``reward_collision``) | -0.5 when the LIDAR minimum is below 0.3 m |
    | clearance (``reward_clearance``) | not in the seed (0): ``clearance_penalty`` x metres |
    | | the LIDAR minimum lies inside ``clearance_distance`` |
    | personal space (``reward_personal_space``) | not in the seed (0): |
    | | ``personal_space_penalty`` x metres the nearest person stands inside |
    | | ``personal_space_distance`` |

    A step that ends the episode returns only its penalty (as in the seed):
    flip -20, stuck-in-collision -20, stuck -25, out of bounds -10
    (``reward_termination``). Every constant is a field of
    :class:`~rover_env.reward.RewardConfig`; pass ``reward_config=`` to change them.

    ## Starting state

    ``reset(seed=...)`` draws, from ``self.np_random``: the rover position uniformly
    from the world's spawn rectangle (resampled until 0.4 m clear of obstacles), its yaw
    uniformly in [-pi, pi), the goal uniformly from the goal rectangle (resampled inside
    obstacles and within 1 m of the rover), and every pedestrian's path, speed, phase
    and clothing. The rover starts at rest on the ground. Rectangles (seed, metres):

    | world | spawn = goal rectangle | out-of-bounds rectangle |
    |-------|-------------------|-------------------------|
    | inspect | x, y in [-27, -19] | x in [-29, -13], y in [-29, -17] |
    | moon / island | x, y in [-4, 4] | x in [-20, 10], y in [-20, 20] |
    | maze | x, y in [-4, 4] | x, y in [-30, 30] |

    ``options={"rover_pose": (x, y, yaw), "goal": (x, y)}`` overrides either draw.
    The same seed and the same actions give the same observations.

    ## Episode end

    ``terminated`` (``info["termination_reason"]``):

    - ``flipped``: abs(roll) or abs(pitch) > 1.48 rad (``info["flip_direction"]`` says
      roll_left / roll_right / pitch_forward / pitch_backward);
    - ``stuck_in_collision``: more than 600 collision steps in the episode;
    - ``stuck``: moved less than 0.001 m over the last 600 steps;
    - ``out_of_bounds``: left the world's out-of-bounds rectangle.

    With ``goal_ends_episode=True`` also ``goal``: the step that reaches the goal ends the
    episode with its full reward (goal reward included) and ``info["is_success"]`` True.

    ``truncated`` (``time_limit``) after ``length`` steps. The checks run after the
    physics step, so the failing step reports the failure. Gymnasium semantics: the
    seed used ``done`` for both, which corrupts value bootstrapping.

    ## Info

    ``steps``, ``total_steps`` (over all episodes since the last seeded reset),
    ``reward``, ``episode_reward``,
    ``goals_reached``, ``is_success`` (at least one goal), ``collision`` (the seed's:
    the LIDAR closer than ``RewardConfig.collision_distance``), ``collision_count``,
    ``scenery_contact`` (the rover's body touched the scenery this step), ``contact``
    (it touched anything, scenery or a person: what the evaluators count as a collision
    episode beside ``collision``; ``RewardConfig(contact_is_collision=True)`` makes it a
    collision step), ``termination_reason`` ("" while running), ``distance_to_goal``,
    ``x_position``, ``y_position``, ``goal``, each ``reward_*`` term, and the social
    metrics (the same in every roverav env): ``min_pedestrian_distance`` (m, inf with no
    pedestrians), ``personal_space_intrusion`` (a pedestrian within 1.2 m),
    ``intimate_space_intrusion`` (within 0.45 m), ``pedestrian_collision`` (the rover
    touched a pedestrian this step), split as HuNavSim does into ``rover_hit_pedestrian``
    (the rover was moving, odometry >= 0.05 m/s) and ``pedestrian_hit_rover`` (a person
    walked into the stopped rover).

    ## Arguments

    | Argument | Default | Effect |
    |----------|---------|--------|
    | ``size`` | (64, 64) | the seed's unused image buffer; here the (H, W) of |
    | | | ``env.sim.render_camera()`` frames |
    | ``length`` | 2000 | steps before ``truncated`` |
    | ``scan_topic`` | ``/scan`` | ROS topic: accepted for drop-in use, no effect |
    | ``imu_topic`` | ``/imu/data`` | ROS topic: no effect |
    | ``cmd_vel_topic`` | ``/cmd_vel`` | ROS topic: no effect |
    | ``camera_topic`` | ``/camera/image_raw`` | ROS topic: no effect |
    | ``world_n`` | ``"inspect"`` | ``inspect``, ``moon``, ``island`` (= moon), ``maze``; |
    | | | anything else raises ``ValueError`` |
    | ``connection_check_timeout`` | 30 | no effect (the simulation is in-process) |
    | ``lidar_points`` | 32 | LIDAR points in the observation |
    | ``max_lidar_range`` | 12.0 | LIDAR range (m) |

    Keyword-only, common to every roverav env (:class:`~rover_env.core.EnvOptions`):
    ``control_dt`` (0.05 s simulated per step), ``physics_dt`` (0.025 s, largest physics
    step), ``reward_config`` (``RewardConfig()``), ``render_mode`` (None or ``"rgb_array"``:
    chase camera), ``render_size`` ((480, 360), width x height), ``n_pedestrians`` (0-20;
    default the world's 3), ``pedestrian_mode`` (``"crowd"``, the default: a social-force
    crowd walking to goals around the scenery, making room for the rover; ``"pacing"``:
    out-and-back walkers who wait for the rover; ``"oblivious"``: the same crowd, blind to the
    rover; ``"crossing"``: the crowd walking across the line from the start to the first goal,
    from the side; ``"blind-crossing"``: those crossings by walkers blind to the rover (they
    come from outside a forward camera's view and do not give way); ``"groups"``: the crowd
    in groups of 2-3; ``"walk"`` is the deprecated name
    of ``"pacing"``), ``pedestrian_appearance`` (``"fixed"``, or ``"random"``: clothing
    colours, height, girth and gait phase drawn per episode from the reset seed),
    ``goal_ends_episode`` (False, the seed's: a new goal after each; True: the first goal ends
    the episode, ``terminated`` with ``termination_reason`` ``"goal"``).

    ## Version history

    - v0: first MuJoCo release.
    """

    def __init__(
        self,
        size: tuple[int, int] = c.SIZE,
        length: int = c.LENGTH,
        scan_topic: str = c.SCAN_TOPIC,
        imu_topic: str = c.IMU_TOPIC,
        cmd_vel_topic: str = c.CMD_VEL_TOPIC,
        camera_topic: str = c.CAMERA_TOPIC,
        world_n: str = c.DEFAULT_WORLD,
        connection_check_timeout: float = c.CONNECTION_CHECK_TIMEOUT,
        lidar_points: int = c.LIDAR_POINTS,
        max_lidar_range: float = c.MAX_LIDAR_RANGE,
        **options: Any,
    ) -> None:
        super().__init__(
            world_n=world_n,
            length=length,
            lidar_points=lidar_points,
            max_lidar_range=max_lidar_range,
            camera_size=size,
            **options,
        )
        # Kept for compatibility and introspection only (no ROS here).
        self.size = tuple(size)
        self.scan_topic, self.imu_topic = scan_topic, imu_topic
        self.cmd_vel_topic, self.camera_topic = cmd_vel_topic, camera_topic
        self.connection_check_timeout = connection_check_timeout
        self.observation_space = spaces.Dict(
            {
                "lidar": spaces.Box(
                    low=0.0,
                    high=self.max_lidar_range,
                    shape=(self.lidar_points,),
                    dtype=np.float32,
                ),
                **state_spaces(),
            }
        )
        self.action_space = float_box(c.ACTION_LOW, c.ACTION_HIGH)
        self.nearest_range = float(self.max_lidar_range)

    def _observe(self) -> dict[str, np.ndarray]:
        scan = self.sim.lidar(self.lidar_points, self.max_lidar_range)
        self.nearest_range = float(scan.min())
        return {"lidar": scan, **self._state_observation()}

    def _collision(self) -> bool:
        # The scan of this step's observation: the seed's "LIDAR min < 0.3 m".
        return self.nearest_range < self.reward_config.collision_distance
