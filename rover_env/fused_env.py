"""RoverEnvFused: the rover sees a fused 96x96x3 image computed by the Active Vision daemon."""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from gymnasium import spaces

from fused_image import CHANNEL_HEATMAP, FUSED_SIZE, depth_to_channel
from rover_env import constants as c
from rover_env import reward as rw
from rover_env.camera_scan import SCAN_KEY, CameraScan, CameraScanConfig
from rover_env.core import RoverEnvBase, float_box, state_spaces
from rover_env.reward import RewardConfig
from shm_protocol import (
    SPIN_S,
    FrameReader,
    FrameWriter,
    LayoutError,
    SegmentBusyError,
    SegmentNotFoundError,
    camera_name,
    machine_spin,
    segment_path,
    slot_name,
    writer_alive,
)

log = logging.getLogger(__name__)

FRAME_TIMEOUT = 2.0  # s without a fused frame before FrameTimeoutError
AUTO_SLOT = "auto"  # slot= value: the first daemon slot no other env holds
_POLL_S = 0.05  # s between looks for a daemon that is coming up
_LOCK_GRACE_S = 5.0  # s beyond connection_check_timeout to wait for another env's choice
# The seed's descriptive message when the segment is missing (it then called exit(1)).
SEED_MISSING_MESSAGE = (
    "Shared memory segment '{name}' not found. The Active Vision inference pipeline must be "
    "running and writing frames before RoverEnvFused is created."
)


def served_slots(name: str, timeout: float = 0.0) -> int:
    """How many env slots the live av-daemon serving base name ``name`` has (its
    ``--slots N``), or 0 when none serves it after waiting up to ``timeout`` s for one.

    The one probe of a daemon's slots (the envs' ``slot="auto"`` and slot checks, and
    rover-train's start-up check use it). The daemon creates every slot's fused segment
    before the first camera segment, so once slot 0's camera segment exists the run of
    fused segments ``name``, ``name_1``, ... is complete.
    """
    deadline = time.monotonic() + timeout
    while True:
        if os.path.exists(segment_path(camera_name(name))) and writer_alive(name):
            served = 1
            while os.path.exists(segment_path(slot_name(name, served))):
                served += 1
            return served
        if time.monotonic() >= deadline:
            return 0
        time.sleep(_POLL_S)


@contextmanager
def _slot_choice_lock(name: str, timeout: float) -> Iterator[None]:
    """Hold, across processes, the right to choose a free slot of ``name`` (so that envs
    made at once, e.g. by an async vector env, do not pick the same one). An abstract Unix
    socket: the kernel releases it however its holder dies, and it leaves no file."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    deadline = time.monotonic() + timeout
    try:
        while True:
            try:
                sock.bind(f"\0roverav-slot-choice:{name}")
                break
            except OSError:
                if time.monotonic() >= deadline:
                    raise SegmentBusyError(
                        f"could not choose a slot of '{name}' within {timeout:.0f} s: another "
                        "env kept choosing one (slot=\"auto\"). Try again, or give each env "
                        "its own slot= (0..N-1).",
                        name,
                    ) from None
                time.sleep(_POLL_S / 5)
        yield
    finally:
        sock.close()


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

    Depth: ``1 - d / 10 m`` clipped to [0, 1] (``fused_image.depth_to_channel``).

    ``camera_scan=True`` (every fused env, the gaze envs included; off by default, so the
    seed's spaces stay) adds ``camera_scan``, (3, 32) float32: a rover-frame memory of what
    the camera has seen over 360°. Per bearing sector (the LIDAR's 32, over [-pi, pi)
    counter-clockwise from straight behind), row 0 is the nearest scenery seen there (m from
    the rover's centre; 10 when none is known), row 1 the nearest person seen (m; 10 when
    none), row 2 the seconds since the camera last looked that way (20 when never). The
    readings move with the rover's own motion; a person's are dropped 2 s after the camera
    looks away, the scenery's after 20 s. Computed in this process from the fused image's
    depth and heatmap, the camera's geometry and pan, and the env's pose: no simulator truth
    (:mod:`rover_env.camera_scan`; a ``CameraScanConfig`` instead of True changes its
    constants).

    ## Rewards

    | Term (``info`` key) | Value |
    |------|-------|
    | goal (``reward_goal``) | +100 when closer than 0.5 m (the step's only term); new goal |
    | progress (``reward_progress``) | (metres closer to the goal) x 0.9 |
    | heatmap (``reward_heatmap``) | -0.1 x sum of the heatmap's 4 centre columns (of 96) |
    | personal space (``reward_personal_space``) | not in the seed (0): as in ``RoverEnv`` |
    | clearance (``reward_clearance``) | not in the seed (0): as in ``RoverEnv``, from a |
    | | LIDAR scan the simulator casts for the reward alone (``lidar_points``, |
    | | ``max_lidar_range``); the agent never sees it |

    The centre columns scale with the width: ``round(4 * W / 96)`` columns. With
    ``RewardConfig(pedestrian_penalty_frame="heading")`` the heatmap term charges the sum
    those columns would hold for a camera facing along the rover's heading, from the
    pedestrians' true positions (``reward.heading_center_sum``), instead of the image's.

    A step that ends the episode returns only its penalty: flip -20, stuck-in-collision
    -20, stuck -25 (no 0.0001 m of motion over 5000 steps), out of bounds -10.
    Collisions are MuJoCo contacts between the rover and obstacles or pedestrians (the
    fused env has no LIDAR); they count towards stuck-in-collision. Every constant is a
    field of :class:`~rover_env.reward.RewardConfig` (``RewardConfig.fused()`` defaults).

    ## Episode end

    ``terminated`` on flip (|roll| or |pitch| > 1.48 rad), stuck, stuck-in-collision
    (more than 5000 collision steps) and out of bounds, and with ``goal_ends_episode=True``
    on the goal (``termination_reason`` ``"goal"``, the goal reward, ``is_success``);
    ``truncated`` after ``length`` steps. A daemon that dies mid-episode raises
    ``shm_protocol.WriterGoneError`` promptly; one that stalls raises ``FrameTimeoutError``
    after ``frame_timeout``. Once the daemon is back on the same name, ``reset()`` works
    again on the same env.

    ## Info

    RoverEnv's keys (``steps``, ``total_steps``, ``reward``, ``goals_reached``,
    ``is_success``, ``collision``, ``scenery_contact``, ``contact``, ``termination_reason``,
    ``distance_to_goal``, ``min_pedestrian_distance``, ``personal_space_intrusion``,
    ``intimate_space_intrusion``, ``pedestrian_collision``, ``rover_hit_pedestrian``,
    ``pedestrian_hit_rover``, the reward terms) plus ``heatmap_center`` (the centre-column
    heatmap sum), ``pedestrian_in_view`` (some pedestrian stands inside the camera's
    horizontal field of view, within the depth range of 10 m; geometric, occlusion not
    tested) and ``nearest_pedestrian_in_view`` (the nearest one does). With
    ``report_latency=True`` also ``frame_latency_ms`` (camera publish to fused frame
    received, wall clock).

    ## Arguments

    ``size`` (H, W) of the fused image (must match the daemon's ``--size``); ``length``
    steps per episode (6000); ``world_n`` ``inspect`` | ``moon`` (``island``) | ``maze``;
    ``connection_check_timeout`` seconds to wait for the daemon's segments at
    construction; ``rl_obs_name`` the daemon's segment base name; ``slot`` which daemon
    slot (``--slots N``) this env uses: an int in 0..N-1 (default 0), or ``"auto"``, the
    first slot no other open env holds (what ``gym.make_vec`` needs: every copy gets the
    same keywords; a daemon with every slot taken raises ``SegmentBusyError`` saying to
    serve more slots or close an env). The slot taken is ``env.slot``.
    ``frame_timeout`` seconds per fused frame; ``report_latency`` (default False) puts the
    measured ``frame_latency_ms`` in ``info``: a wall-clock value, so two runs with the
    same seed and actions then differ in it (Gymnasium's ``check_env`` compares infos, so
    leave it off there). ``spin_wait``: after publishing its camera frame the env watches
    for the fused frame in a busy loop for up to 3 ms (``shm_protocol.SPIN_S``) before it
    sleeps, at the price of a busy core while the daemon perceives; with the daemon doing
    the same for camera frames (``av-daemon --spin-wait``), the step saves two futex
    wake-ups. None (default) spins when this process may use at least two cores per env
    slot of every av-daemon on this machine, one for each env and one for its daemon worker
    (``shm_protocol.machine_spin``, looked at again on every reset); True always; False
    never (e.g. on a machine shared with other work). A reader whose spins stop paying
    sleeps at once for a while (``shm_protocol.FrameReader``).
    The keyword-only options common to every roverav env
    (:class:`~rover_env.core.EnvOptions`): ``control_dt``, ``physics_dt``,
    ``reward_config`` (default ``RewardConfig.fused()``), ``render_mode``
    (``"rgb_array"``: chase camera), ``render_size``, ``n_pedestrians`` (0-20, default
    the world's 3), ``pedestrian_mode`` ``"crowd"`` (default), ``"pacing"``,
    ``"oblivious"``, ``"crossing"``, ``"groups"`` or ``"blind-crossing"`` (see ``RoverEnv``),
    ``pedestrian_appearance``
    ``"fixed"`` (default, the seed's figures) or ``"random"`` (clothing colours, height,
    girth and gait phase drawn per episode from the reset seed), ``goal_ends_episode``
    (False, the seed's: a new goal after each; True: the first goal ends the episode).
    ``scan_topic``, ``imu_topic`` and ``cmd_vel_topic`` are accepted for compatibility with
    the seed and have no effect; ``lidar_points`` and ``max_lidar_range`` shape only the
    LIDAR scan of the clearance term, when ``reward_config`` turns it on.

    ## Version history

    - v0: first release.
    """

    def __init__(
        self,
        size: tuple[int, int] = FUSED_SIZE,
        length: int = c.FUSED_LENGTH,
        scan_topic: str = "/scan",
        imu_topic: str = "/imu/data",
        cmd_vel_topic: str = "/cmd_vel",
        world_n: str = c.DEFAULT_WORLD,
        connection_check_timeout: float = 30,
        lidar_points: int = c.LIDAR_POINTS,
        max_lidar_range: float = c.MAX_LIDAR_RANGE,
        rl_obs_name: str = c.RL_OBS_NAME,
        *,
        slot: int | str = 0,
        frame_timeout: float = FRAME_TIMEOUT,
        report_latency: bool = False,
        spin_wait: bool | None = None,
        camera_scan: bool | CameraScanConfig = False,
        **options: Any,
    ) -> None:
        del scan_topic, imu_topic, cmd_vel_topic  # ROS topics: accepted, no effect
        height, width = int(size[0]), int(size[1])
        auto = slot == AUTO_SLOT
        if not auto and (
            isinstance(slot, bool) or not isinstance(slot, (int, np.integer)) or slot < 0
        ):
            raise ValueError(
                f"slot must be an int >= 0 (the daemon slot this env uses: 0..N-1 with "
                f"av-daemon --slots N) or {AUTO_SLOT!r} (the first free one), got {slot!r}"
            )
        if not frame_timeout > 0:
            raise ValueError(f"frame_timeout must be > 0 s, got {frame_timeout}")
        if spin_wait is not None and not isinstance(spin_wait, bool):
            raise ValueError(
                f"spin_wait must be True, False or None (spin when the machine has a core for "
                f"each env and daemon worker), got {spin_wait!r}"
            )
        if not isinstance(camera_scan, bool | CameraScanConfig):
            raise ValueError(
                f"camera_scan must be True, False or a rover_env.camera_scan.CameraScanConfig, "
                f"got {camera_scan!r}"
            )
        self.spin_wait = spin_wait
        self._base = rl_obs_name
        self._set_slot(0 if auto else int(slot))
        self.frame_timeout = float(frame_timeout)
        self.report_latency = bool(report_latency)
        self.connection_check_timeout = float(connection_check_timeout)
        self._size = (height, width)
        self._fused: FrameReader | None = None
        self._camera: FrameWriter | None = None
        # Attach before building the world: a missing daemon fails fast and cheaply.
        if auto:
            self._connect_first_free(self.connection_check_timeout)
        else:
            self._connect(self.connection_check_timeout)
        try:
            super().__init__(
                world_n=world_n,
                length=length,
                lidar_points=lidar_points,
                max_lidar_range=max_lidar_range,
                camera_size=(height, width),
                **options,
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
        self.camera_scan: CameraScan | None = None
        if camera_scan is not False:
            self.camera_scan = CameraScan(
                (height, width), self.control_dt,
                None if camera_scan is True else camera_scan)  # fmt: skip
            self.observation_space = spaces.Dict(
                {**self.observation_space.spaces, SCAN_KEY: self.camera_scan.space}
            )
        self.action_space = float_box(c.FUSED_ACTION_LOW, c.FUSED_ACTION_HIGH)
        self._frame_latency_ms = 0.0
        self._episode_start = False
        self._heatmap_center = 0.0
        self._in_view = np.zeros(0, dtype=bool)  # pedestrians in view, set with each frame
        self._nearest = -1

    @classmethod
    def _default_reward_config(cls) -> RewardConfig:
        return RewardConfig.fused()

    # --- the daemon link ------------------------------------------------------------------------
    def _set_slot(self, slot: int) -> None:
        self.slot = slot
        self.rl_obs_name = slot_name(self._base, slot)

    def _connect_first_free(self, timeout: float) -> None:
        """``slot="auto"``: attach to the first slot of the daemon that no open env holds."""
        base = self._base
        deadline = time.monotonic() + timeout
        holders: list[str] = []
        # Envs made at the same time (an async vector env's workers) choose one at a time.
        with _slot_choice_lock(base, timeout + _LOCK_GRACE_S):
            slot, served = 0, 1
            while slot < served:
                self._set_slot(slot)
                try:
                    # slot 0 waits for a daemon that is not up yet (and, with none, says how
                    # to start one); the others exist once slot 0 is served
                    self._connect(max(deadline - time.monotonic(), 0.0 if slot == 0 else 1.0))
                except SegmentBusyError as exc:
                    holders.append(f"slot {slot}: pid {exc.pid}")
                else:
                    log.info("slot='auto': took slot %d of '%s'", slot, base)
                    return
                slot, served = slot + 1, served_slots(base)
        self._set_slot(0)
        raise SegmentBusyError(
            f"slot='auto' found no free slot: every one of the {served} slot(s) of the "
            f"av-daemon serving '{base}' is held by an open env ({'; '.join(holders)}). "
            f"Serve more slots (av-daemon --name {base} --slots {served + 1}, or rover-pair "
            f"--name {base} --slots {served + 1}), or close an env first.",
            base,
        )

    def _connect(self, timeout: float) -> None:
        """Attach to the fused segment (reader) and its camera segment (as writer)."""
        self._disconnect()
        name, cam = self.rl_obs_name, camera_name(self.rl_obs_name)
        how = f"av-daemon --name {self._base} --slots {self.slot + 1}"
        if not os.path.exists(segment_path(name)):
            self._check_slot_served()
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
                f"    rover-pair --name {self._base} --slots {self.slot + 1} -- "
                f"<trainer command>\n{exc}",
                name,
                exc.available,
            ) from None
        try:
            self._check_size(fused.shape, "fused")
            daemon_pid = fused.writer_pid
            camera = FrameWriter(
                cam,
                create=False,
                attach_timeout=max(deadline - time.monotonic(), 1.0),
                exclusive=True,
                ignore_pids=() if daemon_pid is None else (daemon_pid,),
            )
        except SegmentBusyError as exc:
            fused.close()
            raise SegmentBusyError(
                self._slot_busy_message(exc.pid, exc.command), cam, exc.pid, exc.command
            ) from None
        except BaseException:
            fused.close()
            raise
        try:
            self._check_size(camera.shape, "camera")
        except BaseException:
            camera.close()
            fused.close()
            raise
        fused.spin = self._spin()
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

    def _spin(self) -> float:
        """Seconds to watch for the fused frame before sleeping (``spin_wait``; None:
        ``shm_protocol.machine_spin``, two cores for each env slot on this machine)."""
        if self.spin_wait is None:
            return machine_spin(served_slots(self._base))
        return SPIN_S if self.spin_wait else 0.0

    def _check_slot_served(self) -> None:
        """Fail fast when a running daemon serves the base name with fewer slots than
        ``slot + 1`` (instead of waiting ``connection_check_timeout`` for a segment that
        will never come)."""
        if self.slot == 0:
            return
        base = self._base
        served = served_slots(base)
        if not served or self.slot < served:
            return
        raise SegmentNotFoundError(
            f"slot={self.slot} is beyond the slots of the av-daemon serving '{base}': it "
            f"serves {served} slot(s), 0..{served - 1}. Use slot= in "
            f"0..{served - 1}, or restart the daemon with more slots: av-daemon --name {base} "
            f"--slots {self.slot + 1} (or rover-pair --name {base} --slots {self.slot + 1} "
            "-- <trainer command>).",
            self.rl_obs_name,
            [slot_name(base, i) for i in range(served)],
        )

    def _check_size(self, shape: tuple[int, int, int], which: str) -> None:
        """LayoutError naming both sizes when the daemon's frames differ from ``size``."""
        if tuple(shape[:2]) == self._size:
            return
        h, w = self._size
        side = f"--size {h}" if h == w else f"a square --size (this env's size is {h}x{w})"
        raise LayoutError(
            f"size mismatch: this env was made with size=({h}, {w}) but the av-daemon serving "
            f"'{self.rl_obs_name}' makes {shape[0]}x{shape[1]} frames (its {which} segment "
            f"holds {shape[0]}x{shape[1]}x{shape[2]}; av-daemon --size {shape[0]}). Make the "
            f"env with size=({shape[0]}, {shape[1]}), or restart the daemon with {side}."
        )

    def _slot_busy_message(self, pid: int, command: str) -> str:
        who = (
            "this process (another RoverEnvFused here that is not closed)"
            if pid == os.getpid()
            else f"another process ({command or 'command line unknown'})"
        )
        base = self._base
        return (
            f"daemon slot {self.slot} of '{base}' is already in use: pid {pid}, {who}, holds "
            f"its camera segment '{camera_name(self.rl_obs_name)}'. Each env needs its own "
            f"slot: give each env a different slot= (0..N-1) and serve N slots with "
            f"av-daemon --name {base} --slots N (or rover-pair --slots N), or close the "
            "other env first. (A holder that crashed or closed does not block.)"
        )

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
            return os.stat(segment_path(camera_name(self.rl_obs_name))).st_ino == self._camera_ino
        except FileNotFoundError:
            return False

    # --- hooks ----------------------------------------------------------------------------------
    def _on_reset(self) -> None:
        if self._camera is None or not self._link_is_current():
            log.info("re-attaching to the daemon's segments for '%s'", self.rl_obs_name)
            self._connect(self.connection_check_timeout)
        elif self._fused is not None:
            self._fused.spin = self._spin()  # envs may have come or gone on this machine
        # reset()'s info describes the new episode, not the last step of the previous one
        self._heatmap_center = 0.0
        self._episode_start = True  # the next camera frame opens the episode
        if self.camera_scan is not None:
            self.camera_scan.reset()

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
        # What does not need the fused frame is computed while the daemon perceives
        obs = self._state_observation()
        self._in_view = self.sim.pedestrians_in_view()
        self._nearest = self.nearest_pedestrian_index()
        fused = self._fused.wait_for(source_seq=seq, timeout=self.frame_timeout)
        while fused.seq <= self._stale_seq:
            fused = self._fused.wait_next(timeout=self.frame_timeout)
        self._frame_latency_ms = (time.perf_counter() - t0) * 1e3
        obs["fused_image"] = fused.data  # a fresh copy owned by this observation
        scan = self.camera_scan
        if scan is not None:
            scan.update(fused.data, float(self.position[0]), float(self.position[1]),
                        float(self.orientation[2]), self.sim.camera_pan)  # fmt: skip
            obs[SCAN_KEY] = scan.observation.copy()
        return obs

    def _collision(self) -> bool:
        contacts = self.sim.rover_contacts()
        return contacts.obstacle or contacts.pedestrian

    def _task_reward(self, obs: dict[str, np.ndarray]) -> float:
        cfg = self.reward_config
        heatmap = obs["fused_image"][:, :, CHANNEL_HEATMAP]
        self._heatmap_center = rw.heatmap_center_sum(heatmap, cfg.heatmap_center_columns)
        if self.goal_reached:
            return self._add_reward_term("goal", rw.goal_reward(True, cfg))
        self._add_reward_term("goal", 0.0)
        progress = self._add_reward_term("progress", rw.progress_reward(self.distance_delta, cfg))
        if cfg.pedestrian_penalty_frame == rw.HEADING_FRAME:
            x, y = float(self.position[0]), float(self.position[1])
            charged = rw.heading_center_sum(x, y, float(self.orientation[2]),
                                            self.sim.pedestrian_positions, self._size,
                                            cfg.heatmap_center_columns)  # fmt: skip
        else:
            charged = self._heatmap_center
        heat = self._add_reward_term("heatmap", rw.heatmap_center_penalty(charged, cfg))
        near = self._add_reward_term(
            "personal_space", rw.personal_space_penalty(self.nearest_pedestrian, cfg))
        clear = 0.0
        if cfg.clearance_penalty:  # the simulator's LIDAR: the trainer's signal, not an input
            nearest = float(self.sim.lidar(self.lidar_points, self.max_lidar_range).min())
            clear = rw.clearance_penalty(self.clearance_range(nearest), cfg)
        return progress + heat + near + self._add_reward_term("clearance", clear)

    def _info(self, reward: float, reason: str) -> dict[str, Any]:
        info = super()._info(reward, reason)
        if self.report_latency:
            info["frame_latency_ms"] = self._frame_latency_ms
        info["heatmap_center"] = self._heatmap_center
        in_view = self._in_view
        info["pedestrian_in_view"] = bool(in_view.any())
        info["nearest_pedestrian_in_view"] = bool(len(in_view) and in_view[self._nearest])
        return info

    def close(self) -> None:
        """Detach from the daemon (never unlinks its segments) and free the renderer."""
        self._disconnect()
        super().close()

