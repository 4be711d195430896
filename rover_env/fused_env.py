"""RoverEnvFused: the rover sees a fused 96x96x3 image computed by the Active Vision daemon."""

from __future__ import annotations

import logging
import os
import time
from typing import Any

import numpy as np
from gymnasium import spaces

from rover_env import constants as c
from rover_env import reward as rw
from rover_env.core import RENDER_SIZE, RoverEnvBase, float_box, state_spaces
from rover_env.reward import RewardConfig
from rover_env.simulation import PHYSICS_DT
from shm_protocol import (
    CHANNEL_HEATMAP,
    FrameReader,
    FrameWriter,
    SegmentNotFoundError,
    camera_name,
    depth_to_channel,
    slot_name,
)

log = logging.getLogger(__name__)

FRAME_TIMEOUT = 2.0  # s without a fused frame before FrameTimeoutError
INTIMATE_ZONE_M = 0.45  # proxemics: intimate distance
PERSONAL_ZONE_M = 1.2  # proxemics: personal distance
# The seed's descriptive message when the segment is missing (it then called exit(1)).
SEED_MISSING_MESSAGE = (
    "Shared memory segment '{name}' not found. The Active Vision inference pipeline must be "
    "running and writing frames before RoverEnvFused is created."
)


class RoverEnvFused(RoverEnvBase):
    """Drive to random goals seeing a fused image: grayscale, pedestrian heatmap, depth.

    ## Description

    RoboTerrain's ``RoverEnvFused`` on MuJoCo. The env owns the world (rover physics,
    pedestrians, camera rendering); a separate process, the Active Vision daemon
    (``av-daemon``), turns each camera frame into the fused image. Per step the env
    renders its forward camera, publishes it to the daemon's camera segment
    ``<rl_obs_name>[_<slot>]_camera`` and waits for the fused frame computed from exactly
    that camera frame (``source_seq``), so observations are in lock-step with the physics
    and reproducible for a fixed seed. The first camera frame of every episode carries the
    episode-start flag, on which the daemon clears the slot's frame history (what
    ``av-daemon --heatmap predict`` predicts from), so ``reset(seed=s)`` reproduces whole
    episodes in either heatmap mode.

    Start the daemon first (``av-daemon --name rl_observation``), or run both under the
    supervisor (``rover-pair -- <your trainer>``).

    ## Action space

    ``Box([-0.6, -pi], [1.0, pi], (2,), float32)``: forward speed (m/s, reverse limited
    to -0.6) and desired heading relative to the current yaw (rad), tracked by the seed's
    PID (Kp 2.0, Ki 0.0, Kd 0.1, +-7 rad/s, simulated dt). Out-of-range actions are
    clipped; non-finite actions raise ``ValueError``.

    ## Observation space

    | Key | Shape | Range | Meaning |
    |-----|-------|-------|---------|
    | ``fused_image`` | (H, W, 3) | [0, 1] | 0 grayscale, 1 pedestrian heatmap, 2 depth (near = 1) |
    | ``pose`` | (3,) | x, y in [-30, 30], z in [-10, 10] | rover position (m) |
    | ``imu`` | (3,) | [-pi, pi] | pitch, roll, yaw (rad) |
    | ``target`` | (2,) | [0, 100], [-pi, pi] | goal distance (m), bearing from heading (rad) |
    | ``velocities`` | (2,) | [-10, 10] | wheel-odometry linear (m/s), angular (rad/s) |

    Depth: ``1 - d / 10 m`` clipped to [0, 1] (``shm_protocol.depth_to_channel``).

    ## Rewards

    | Term (``info`` key) | Value |
    |------|-------|
    | goal (``reward_goal``) | +100 when closer than 0.5 m (the step's only term); new goal |
    | progress (``reward_progress``) | (metres closer to the goal) x 0.9 |
    | heatmap (``reward_heatmap``) | -0.1 x sum of the heatmap's 4 centre columns (of 96) |

    The centre columns scale with the width: ``round(4 * W / 96)`` columns.

    A step that ends the episode returns only its penalty: flip -20, stuck-in-collision
    -20, stuck -25 (no 0.0001 m of motion over 5000 steps), out of bounds -10.
    Collisions are MuJoCo contacts between the rover and obstacles or pedestrians (the
    fused env has no LIDAR); they count towards stuck-in-collision. Every constant is a
    field of :class:`~rover_env.reward.RewardConfig` (``RewardConfig.fused()`` defaults).

    ## Episode end

    ``terminated`` on flip (|roll| or |pitch| > 1.48 rad), stuck, stuck-in-collision
    (more than 5000 collision steps) and out of bounds; ``truncated`` after ``length``
    steps. A daemon that dies mid-episode raises ``shm_protocol.WriterGoneError``
    promptly; one that stalls raises ``FrameTimeoutError`` after ``frame_timeout``. Once
    the daemon is back on the same name, ``reset()`` works again on the same env.

    ## Info

    RoverEnv's keys (``steps``, ``total_steps``, ``reward``, ``goals_reached``,
    ``is_success``, ``collision``, ``termination_reason``, ``distance_to_goal``,
    ``min_pedestrian_distance``, the reward terms) plus ``frame_latency_ms`` (camera
    publish to fused frame received), ``pedestrian_collision``,
    ``personal_space_intrusion`` (a pedestrian within 1.2 m), ``intimate_space_intrusion``
    (within 0.45 m) and ``heatmap_center`` (the centre-column heatmap sum).

    ## Arguments

    ``size`` (H, W) of the fused image (must match the daemon's ``--size``); ``length``
    steps per episode (6000); ``world_n`` ``inspect`` | ``moon`` (``island``) | ``maze``;
    ``connection_check_timeout`` seconds to wait for the daemon's segments at
    construction; ``rl_obs_name`` the daemon's segment base name; ``slot`` which daemon
    slot (``--slots N``) this env uses; ``frame_timeout`` seconds per fused frame;
    ``control_dt``; ``reward_config``; ``render_mode`` (``"rgb_array"``: chase camera);
    ``pedestrian_appearance`` ``"fixed"`` (default, the seed's figures) or ``"random"``
    (clothing colours, height, girth and gait phase drawn per episode from the reset seed);
    ``report_latency`` (default True) puts the measured ``frame_latency_ms`` in ``info``.
    It is the one wall-clock value in ``info``, so two runs with the same seed and actions
    differ in it and nothing else; pass ``report_latency=False`` where infos are compared
    for determinism (Gymnasium's ``check_env`` does).
    ``scan_topic``, ``imu_topic``, ``cmd_vel_topic``, ``lidar_points`` and
    ``max_lidar_range`` are accepted for compatibility with the seed and have no effect.

    ## Version history

    - v0: first release.
    """

    def __init__(
        self,
        size: tuple[int, int] = c.FUSED_SIZE,
        length: int = c.FUSED_LENGTH,
        scan_topic: str = "/scan",
        imu_topic: str = "/imu/data",
        cmd_vel_topic: str = "/cmd_vel",
        world_n: str = c.DEFAULT_WORLD,
        connection_check_timeout: float = 30,
        lidar_points: int = c.LIDAR_POINTS,
        max_lidar_range: float = c.MAX_LIDAR_RANGE,
        rl_obs_name: str = "rl_observation",
        *,
        slot: int = 0,
        frame_timeout: float = FRAME_TIMEOUT,
        control_dt: float = c.CONTROL_DT,
        physics_dt: float = PHYSICS_DT,
        reward_config: RewardConfig | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = RENDER_SIZE,
        pedestrian_appearance: str = "fixed",
        report_latency: bool = True,
    ) -> None:
        del scan_topic, imu_topic, cmd_vel_topic  # ROS topics: accepted, no effect
        height, width = int(size[0]), int(size[1])
        if slot < 0:
            raise ValueError(f"slot must be >= 0, got {slot}")
        if not frame_timeout > 0:
            raise ValueError(f"frame_timeout must be > 0 s, got {frame_timeout}")
        self.rl_obs_name = slot_name(rl_obs_name, slot)
        self.slot = slot
        self.frame_timeout = float(frame_timeout)
        self.report_latency = bool(report_latency)
        self.connection_check_timeout = float(connection_check_timeout)
        self._fused: FrameReader | None = None
        self._camera: FrameWriter | None = None
        # Attach before building the world: a missing daemon fails fast and cheaply.
        self._connect(self.connection_check_timeout)
        try:
            super().__init__(
                world_n=world_n,
                length=length,
                lidar_points=lidar_points,
                max_lidar_range=max_lidar_range,
                camera_size=(height, width),
                control_dt=control_dt,
                physics_dt=physics_dt,
                reward_config=reward_config if reward_config is not None else RewardConfig.fused(),
                render_mode=render_mode,
                render_size=render_size,
                pedestrian_appearance=pedestrian_appearance,
            )
        except BaseException:
            self._disconnect()
            raise
        self.observation_space = spaces.Dict(
            {
                "fused_image": spaces.Box(0.0, 1.0, shape=(height, width, 3), dtype=np.float32),
                **state_spaces(),
            }
        )
        self.action_space = float_box(c.FUSED_ACTION_LOW, c.FUSED_ACTION_HIGH)
        self._frame_latency_ms = 0.0
        self._episode_start = False
        self._heatmap_center = 0.0
        self._pedestrian_collision = False

    # --- the daemon link ------------------------------------------------------------------------
    def _connect(self, timeout: float) -> None:
        """Attach to the fused segment (reader) and its camera segment (as writer)."""
        self._disconnect()
        name, cam = self.rl_obs_name, camera_name(self.rl_obs_name)
        how = f"av-daemon --name {self._base_name()} --slots {self.slot + 1}"
        if not os.path.exists(f"/dev/shm/{name}"):
            log.warning(
                "waiting up to %.0f s for the Active Vision daemon's segment '%s'; "
                "start it with: %s (or run your trainer under rover-pair)",
                timeout, name, how,
            )  # fmt: skip
        deadline = time.monotonic() + timeout
        try:
            fused = FrameReader(name, dtype=np.float32, attach_timeout=timeout)
        except SegmentNotFoundError as exc:
            raise SegmentNotFoundError(
                SEED_MISSING_MESSAGE.format(name=name)
                + f" Waited {timeout:.0f} s (connection_check_timeout). Start the daemon with:"
                f"\n    {how}\nor run the trainer under the supervisor:\n"
                f"    rover-pair --name {self._base_name()} --slots {self.slot + 1} -- "
                f"<trainer command>\n{exc}",
                name,
                exc.available,
            ) from None
        try:
            camera = FrameWriter(
                cam, create=False, attach_timeout=max(deadline - time.monotonic(), 1.0)
            )
        except BaseException:
            fused.close()
            raise
        self._fused, self._camera = fused, camera
        # Fused frames already in the segment answer camera frames of an earlier link (a
        # daemon restarted with a new camera segment restarts its frame numbers while the
        # fused segment keeps its source_seq): never take one of those as ours.
        newest = fused.latest()
        self._stale_seq = newest.seq if newest is not None else 0
        self._camera_ino = os.stat(camera.path).st_ino
        h, w, ch = camera.shape
        self._render_depth = ch == 4
        self._camera_buf = np.zeros((h, w, ch), dtype=np.uint8)

    def _base_name(self) -> str:
        suffix = f"_{self.slot}"
        if self.slot and self.rl_obs_name.endswith(suffix):
            return self.rl_obs_name[: -len(suffix)]
        return self.rl_obs_name

    def _disconnect(self) -> None:
        if self._camera is not None:
            self._camera.close(unlink=False)
            self._camera = None
        if self._fused is not None:
            self._fused.close()
            self._fused = None

    def _link_is_current(self) -> bool:
        """False when the daemon replaced its segments (a new daemon after an orderly stop)."""
        try:
            return os.stat(f"/dev/shm/{camera_name(self.rl_obs_name)}").st_ino == self._camera_ino
        except FileNotFoundError:
            return False

    # --- hooks ----------------------------------------------------------------------------------
    def _on_reset(self) -> None:
        if self._camera is None or not self._link_is_current():
            log.info("re-attaching to the daemon's segments for '%s'", self.rl_obs_name)
            self._connect(self.connection_check_timeout)
        self._episode_start = True  # the next camera frame opens the episode

    def _observe(self) -> dict[str, np.ndarray]:
        assert self._camera is not None and self._fused is not None
        frame = self.sim.render_camera(depth=self._render_depth)
        buf = self._camera_buf
        buf[:, :, :3] = frame.rgb
        if self._render_depth:
            np.rint(depth_to_channel(frame.depth) * 255.0, out=buf[:, :, 3], casting="unsafe")
        t0 = time.perf_counter()
        seq = self._camera.publish(buf, episode_start=self._episode_start)
        self._episode_start = False
        fused = self._fused.wait_for(source_seq=seq, timeout=self.frame_timeout)
        while fused.seq <= self._stale_seq:
            fused = self._fused.wait_next(timeout=self.frame_timeout)
        self._frame_latency_ms = (time.perf_counter() - t0) * 1e3
        obs = self._state_observation()
        obs["fused_image"] = fused.data  # a fresh copy owned by this observation
        return obs

    def _collision(self) -> bool:
        contacts = self.sim.rover_contacts()
        self._pedestrian_collision = contacts.pedestrian
        return contacts.obstacle or contacts.pedestrian

    def _task_reward(self, obs: dict[str, np.ndarray]) -> float:
        cfg = self.reward_config
        heatmap = obs["fused_image"][:, :, CHANNEL_HEATMAP]
        self._heatmap_center = heatmap_center_sum(heatmap, cfg.heatmap_center_columns)
        if self.goal_reached:
            return self._add_reward_term("goal", rw.goal_reward(True, cfg))
        self._add_reward_term("goal", 0.0)
        progress = self._add_reward_term("progress", rw.progress_reward(self.distance_delta, cfg))
        heat = self._add_reward_term("heatmap", -cfg.heatmap_center_scale * self._heatmap_center)
        return progress + heat

    def _info(self, reward: float, reason: str) -> dict[str, Any]:
        info = super()._info(reward, reason)
        d_ped = info["min_pedestrian_distance"]
        if self.report_latency:
            info["frame_latency_ms"] = self._frame_latency_ms
        info["pedestrian_collision"] = self._pedestrian_collision and self.collided
        info["personal_space_intrusion"] = bool(d_ped < PERSONAL_ZONE_M)
        info["intimate_space_intrusion"] = bool(d_ped < INTIMATE_ZONE_M)
        info["heatmap_center"] = self._heatmap_center
        return info

    def close(self) -> None:
        """Detach from the daemon (never unlinks its segments) and free the renderer."""
        self._disconnect()
        super().close()


def heatmap_center_sum(heatmap: np.ndarray, columns: int = c.HEATMAP_CENTER_COLUMNS) -> float:
    """Sum of the centre columns of an (H, W) heatmap: ``columns`` of 96, scaled to W."""
    width = heatmap.shape[1]
    n = max(1, round(columns * width / c.FUSED_SIZE[1]))
    lo = (width - n) // 2
    return float(heatmap[:, lo : lo + n].sum())
