"""The collision shield on the camera scan (rover_train.shield) and ModelAgent's shielded choice."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from rover_env.camera_scan import CameraScanConfig, sector_of
from rover_env.gaze_discrete_env import PAN_WINDOWS
from rover_train import zoo
from rover_train.algos import ModelAgent
from rover_train.shield import (
    HALF_LENGTH,
    HALF_WIDTH,
    CollisionShield,
    ShieldConfig,
    ShieldedAgent,
    outline_distance,
    shield_for,
    table_trajectories,
)
from rover_train.wrappers import (
    RelativeTable,
    agent_io,
    relative_action,
    relative_head_action,
    relative_looking_action,
)

FAR = CameraScanConfig().max_range


def _scan(*readings: tuple[float, float], row: int = 0) -> np.ndarray:
    """A camera-scan observation with nothing known but ``(bearing rad, range m)`` readings."""
    scan = np.full((3, 32), FAR, dtype=np.float32)
    scan[2] = 0.0
    for bearing, rng in readings:
        scan[row, sector_of(np.array([bearing]), 32)[0]] = rng
    return scan


def _action(speed: float, heading: float) -> int:
    return next(a for a in range(60) if np.allclose(relative_action(a), [speed, heading]))


def test_the_outline_distance_is_signed_from_the_rovers_box() -> None:
    pts = np.array([[HALF_LENGTH + 0.1, 0.0], [0.0, -(HALF_WIDTH + 0.2)], [0.0, 0.0],
                    [HALF_LENGTH + 0.3, HALF_WIDTH + 0.4]])  # fmt: skip
    assert outline_distance(pts) == pytest.approx([0.1, 0.2, -HALF_WIDTH, 0.5])


def test_each_action_is_rolled_forward_on_the_rovers_kinematics() -> None:
    poses = table_trajectories(0.5)
    assert poses.shape == (60, 10, 3)
    ahead = poses[_action(1.0, 0.0)]
    assert ahead[-1] == pytest.approx([0.5, 0.0, 0.0])  # 1 m/s for 0.5 s, no turn
    assert np.all(poses[_action(0.0, 0.0)] == 0)  # standing still goes nowhere
    left = poses[_action(0.6, np.pi / 2)][-1]
    assert left[2] == pytest.approx(np.pi / 2 * 2.0 * 0.5)  # the PID's kp times the heading
    assert left[1] > 0  # and it curves left
    assert poses[_action(-0.2, 0.0)][-1, 0] == pytest.approx(-0.1)


def test_nothing_known_nearby_allows_every_action() -> None:
    assert CollisionShield().allowed(_scan()).all()
    shield = CollisionShield()
    assert shield.reach == pytest.approx(0.5 + np.hypot(HALF_LENGTH, HALF_WIDTH) + 0.3)
    assert shield.allowed(_scan((0.0, shield.reach + 0.01), row=1)).all()  # out of reach
    # just inside it, a person ahead is the first thing the fastest drive would near
    assert not shield.allowed(_scan((0.0, HALF_LENGTH + 0.5 + 0.29), row=1))[_action(1.0, 0.0)]


def test_a_wall_ahead_forbids_driving_into_it_and_allows_backing_off() -> None:
    allowed = CollisionShield().allowed(_scan((0.01, 0.45)))
    assert not allowed[_action(1.0, 0.0)] and not allowed[_action(0.6, 0.0)]
    assert allowed[_action(0.0, 0.0)] and allowed[_action(-0.2, 0.0)]
    assert allowed[_action(0.3, -np.pi)]  # turning away from it
    # a reading close behind the rover forbids the reverse instead
    behind = CollisionShield().allowed(_scan((np.pi - 0.01, 0.32)))  # 9.5 cm off its back
    assert not behind[_action(-0.2, 0.0)] and behind[_action(1.0, 0.0)]


def test_already_too_close_the_rover_may_keep_or_open_its_clearance() -> None:
    shield = CollisionShield(ShieldConfig(margin_m=0.1))
    allowed = shield.allowed(_scan((np.pi / 2, HALF_WIDTH + 0.05)))  # 5 cm off its left side
    assert allowed[_action(0.0, 0.0)]  # standing still keeps 5 cm
    assert not allowed[_action(0.3, np.pi / 2)]  # turning in toward it does not


def test_people_are_checked_unless_told_not_to() -> None:
    person_ahead = _scan((0.01, 0.45), row=1)
    assert not CollisionShield().allowed(person_ahead)[_action(1.0, 0.0)]
    assert CollisionShield(ShieldConfig(people=False)).allowed(person_ahead).all()


def test_people_get_a_wider_berth_than_the_scenery() -> None:
    at = (0.01, HALF_LENGTH + 0.25)  # 25 cm ahead of the bumper
    wall, person = _scan(at), _scan(at, row=1)
    assert CollisionShield().allowed(wall)[_action(0.3, 0.0)]  # 15 cm on: 10 cm left
    assert not CollisionShield().allowed(person)[_action(0.3, 0.0)]  # within 0.3 m of a person
    assert CollisionShield().allowed(person)[_action(0.0, 0.0)]  # no closer: allowed
    assert CollisionShield().allowed(person)[_action(-0.2, 0.0)]


def _lidar(*readings: tuple[float, float]) -> dict[str, np.ndarray]:
    """A RoverEnvDiscrete observation's LIDAR, clear to 12 m but for ``(bearing, range)``."""
    ranges = np.full(32, 12.0, dtype=np.float32)
    for bearing, rng in readings:
        ranges[sector_of(np.array([bearing]), 32)[0]] = rng
    return {"lidar": ranges, "pose": np.zeros(3, np.float32)}


def test_the_lidar_shield_keeps_the_person_margin_off_every_return_all_round() -> None:
    shield = CollisionShield(source="lidar")
    assert shield(_lidar()).all()
    at = (0.01, HALF_LENGTH + 0.25)  # 25 cm ahead: a person or a wall, the LIDAR cannot say
    allowed = shield(_lidar(at))
    assert not allowed[_action(0.3, 0.0)] and allowed[_action(0.0, 0.0)]
    assert CollisionShield(ShieldConfig(person_margin_m=0.05), source="lidar")(
        _lidar(at))[_action(0.3, 0.0)]  # with the scenery's margin it may go 15 cm on
    behind = shield(_lidar((np.pi - 0.01, HALF_LENGTH + 0.35)))  # where no camera looks
    assert not behind[_action(-0.2, 0.0)] and behind[_action(1.0, 0.0)]
    batch = {k: v[None] for k, v in _lidar(at).items()}  # as a vector env gives it
    assert np.array_equal(shield(batch), allowed)
    with pytest.raises(ValueError, match="'lidar'"):
        shield({"camera_scan": _scan()})
    with pytest.raises(ValueError, match="source"):
        CollisionShield(source="sonar")


def test_any_command_is_checked_as_the_tables_are() -> None:
    shield = CollisionShield()
    table = np.stack([relative_action(a) for a in range(60)])
    for scan in (_scan((0.01, 0.45)), _scan((np.pi / 2, HALF_WIDTH + 0.2), row=1), _scan()):
        assert np.array_equal(shield.allowed_commands(scan, table), shield.allowed(scan))
    wall = _scan((0.01, 0.45))
    assert not shield.allowed_commands(wall, np.array([[0.8, 0.1]]))[0]  # not a table drive
    assert shield.allowed_commands(wall, np.array([[-0.5, 0.0]]))[0]  # backing off


class _Steady:
    """An agent that always sends one action, as a Box student would."""

    def __init__(self, action: list[float]) -> None:
        self.action, self.resets = np.array(action, np.float32), 0

    def reset(self) -> None:
        self.resets += 1

    def act(self, obs: object) -> np.ndarray:
        return self.action.copy()


def test_a_shielded_student_keeps_its_command_where_safe_and_the_nearest_safe_drive_else() -> None:
    ahead = ShieldedAgent(_Steady([1.0, 0.2, 0.5]), CollisionShield())  # gaze: pan kept
    clear = ahead.act({"camera_scan": _scan()})
    assert np.array_equal(clear, np.float32([1.0, 0.2, 0.5])) and ahead.overridden == 0
    wall = {"camera_scan": _scan((0.01, 0.45))}
    guarded = ahead.act(wall)
    assert ahead.overridden == 1 and guarded[2] == np.float32(0.5)
    shield = CollisionShield()
    assert shield.allowed_commands(wall["camera_scan"], guarded[None, :2].astype(float))[0]
    # the nearest allowed table drive: no other allowed one is nearer to the asked command
    table = np.stack([relative_action(a) for a in range(60)])
    turn = np.abs(np.angle(np.exp(1j * (table[:, 1] - 0.2))))
    cost = np.where(shield.allowed(wall["camera_scan"]),
                    np.abs(table[:, 0] - 1.0) / 1.6 + turn / np.pi, np.inf)  # fmt: skip
    assert np.allclose(guarded[:2], table[np.argmin(cost)])
    assert guarded[0] < 1.0  # slowed, not driven on into the wall
    ahead.reset()
    assert ahead.resets == 1  # read through to the student
    with pytest.raises(ValueError, match="camera_scan=True"):
        ahead.act({"fused_image": np.zeros((96, 96, 3))})


def test_the_lidar_shield_can_tell_people_from_walls_by_the_map() -> None:
    from rover_env.lidar_discrete_env import RoverEnvDiscrete

    shield = CollisionShield(ShieldConfig(lidar_map=True), source="lidar", world="maze")
    env = RoverEnvDiscrete(world_n="maze", n_pedestrians=0)
    try:
        obs, _ = env.reset(seed=3)
        for _ in range(10):
            walls, people = shield.scan_of(obs)
            assert np.sum(people < shield.reach) <= 1  # the map explains the walls
            assert np.array_equal(walls[walls < shield.reach], obs["lidar"][walls < shield.reach])
            obs, *_ = env.step(54)  # 1 m/s straight on
        k = int(np.argmax(obs["lidar"]))  # the farthest return: open space
        person = {**obs, "lidar": obs["lidar"].copy()}
        person["lidar"][k] = 0.5  # something the map does not have, 0.5 m off
        walls, people = shield.scan_of(person)
        assert people[k] == pytest.approx(0.5) and walls[k] > shield.reach
    finally:
        env.close()
    with pytest.raises(ValueError, match="give world"):
        CollisionShield(ShieldConfig(lidar_map=True), source="lidar")


def test_a_person_may_close_in_over_the_horizon() -> None:
    still = CollisionShield()
    closing = CollisionShield(ShieldConfig(person_speed_mps=1.0))
    at = _scan((0.01, HALF_LENGTH + 0.65), row=1)  # a person 0.65 m ahead of the bumper
    assert still.allowed(at)[_action(0.6, 0.0)]  # 0.3 m on, 0.35 left: clear of 0.3
    assert not closing.allowed(at)[_action(0.6, 0.0)]  # 0.3 + 0.5 m of closing: not
    for shield in (still, closing):  # standing still stays allowed however close
        assert shield.allowed(_scan((0.01, HALF_LENGTH + 0.1), row=1))[_action(0.0, 0.0)]
    wall = _scan((0.01, HALF_LENGTH + 0.65))  # walls do not walk
    assert np.array_equal(closing.allowed(wall), still.allowed(wall))
    assert closing.reach == pytest.approx(still.reach + 0.5)
    with pytest.raises(ValueError, match="person_speed_mps"):
        ShieldConfig(person_speed_mps=-1.0)


def test_bad_settings_and_observations_are_refused() -> None:
    with pytest.raises(ValueError, match="horizon_s"):
        ShieldConfig(horizon_s=0.0)
    with pytest.raises(ValueError, match="margin_m"):
        ShieldConfig(margin_m=-0.1)
    with pytest.raises(ValueError, match="person_margin_m"):
        ShieldConfig(person_margin_m=-0.1)
    with pytest.raises(ValueError, match="--camera-scan --relative-table"):
        shield_for({"relative_table": True, "camera_scan": False}, "runs/x/model.zip")
    with pytest.raises(ValueError, match="camera_scan=True"):
        CollisionShield()({"lidar": np.zeros(32)})


def _fused_obs(model: object, seed: int) -> dict[str, np.ndarray]:
    space = model.observation_space  # type: ignore[attr-defined]
    space.seed(seed)
    return space.sample()


def test_a_shielded_agent_chooses_among_the_allowed_actions_only() -> None:
    model = zoo.load("rl-fused-inspect").model
    only = np.zeros(60, dtype=bool)
    only[[_action(0.0, 0.0), _action(-0.2, 0.0)]] = True
    changed = 0
    for seed in range(20):
        obs = _fused_obs(model, seed)
        free = int(ModelAgent(model, deterministic=False, seed=seed).act(obs))
        guarded = int(ModelAgent(model, deterministic=False, seed=seed,
                                 shield=lambda o: only).act(obs))  # fmt: skip
        assert only[guarded]
        changed += free != guarded
        everything = int(ModelAgent(model, deterministic=False, seed=seed,
                                    shield=lambda o: np.ones(60, dtype=bool)).act(obs))  # fmt: skip
        assert everything == free  # where the policy's own draw is allowed, it stands
        best = int(ModelAgent(model, shield=lambda o: only).act(obs))
        assert only[best]
    assert changed > 0  # the mask did change draws


def test_the_shield_goes_with_the_rl_entries_and_the_box_students() -> None:
    maze = zoo.load("rl-lidar-maze").shield  # they ship behind the LIDAR's
    assert maze.source == "lidar" and maze.config.person_margin_m == 0.15
    assert not maze.config.lidar_map  # one margin for every return
    inspect = zoo.load("rl-lidar-inspect").shield  # walls and people apart, by the map
    assert inspect.config == ShieldConfig(margin_m=0.15, person_margin_m=0.45, lidar_map=True)
    assert inspect.world == "inspect"
    # rover-eval --person-margin sets the berth from people over the entry's other settings
    import argparse

    from rover_train.evaluate import _shield_config

    given = _shield_config(argparse.Namespace(person_margin=0.5), "rl-lidar-inspect")
    assert given == ShieldConfig(margin_m=0.15, person_margin_m=0.5, lidar_map=True)
    with pytest.raises(ValueError, match="lidar student"):
        zoo.load("lidar-inspect", shield=True)
    with pytest.raises(ValueError, match="steer by"):
        zoo.load("discrete-inspect", shield=True)  # the seed's compass table
    student = zoo.load("fused-inspect", shield=True)  # a Box student, behind it when asked
    assert isinstance(student, ShieldedAgent) and student.meta == student.agent.meta
    for name in ("rl-fused-inspect", "rl-fused-maze", "rl-fused-gaze-inspect",
                 "rl-fused-inspect-twin"):  # they ship behind it
        assert isinstance(zoo.load(name).shield, CollisionShield)
    assert zoo.load("rl-fused-inspect", shield=False).shield is None
    assert zoo.load("rl-lidar-inspect", shield=False).shield is None
    assert zoo.load("rl-fused-gaze-inspect").shield.pan_head  # the drive head's mask
    # the shield's settings at drive time: the entry's own berth from people, unless given
    for name in ("rl-fused-inspect", "rl-fused-gaze-inspect", "rl-fused-inspect-twin"):
        config = zoo.load(name).shield.config
        assert config.person_margin_m == zoo.ENTRIES[name].shield_settings["person_margin_m"]
        assert config.person_margin_m == 0.6
        assert config.margin_m == ShieldConfig().margin_m  # only the berth from people
    assert zoo.load("rl-fused-maze").shield.config == ShieldConfig()  # its training berth
    given = zoo.load("rl-fused-inspect", shield_config=ShieldConfig(person_margin_m=0.45))
    assert given.shield.config.person_margin_m == 0.45
    # the recipe in the file keeps training behind the default, so zoo.command remakes it
    assert "person" not in zoo.command("rl-fused-inspect")
    with pytest.raises(ValueError, match="without the collision shield"):
        zoo.load("rl-fused-inspect", shield=False, shield_config=ShieldConfig())


class _Box3Env(gym.Env):
    """A stand-in with the gaze env's action box, recording what it is sent."""

    action_space = spaces.Box(-np.ones(3, np.float32), np.ones(3, np.float32))
    observation_space = spaces.Box(0.0, 1.0, shape=(1,))

    def step(self, action: np.ndarray) -> tuple:
        self.sent = np.asarray(action)
        return np.zeros(1, np.float32), 0.0, False, False, {}


def test_on_a_gaze_env_the_relative_table_also_chooses_the_pan_window() -> None:
    env = RelativeTable(_Box3Env())
    assert env.action_space == spaces.Discrete(300)
    a = 5 * _action(0.6, 0.0) + 0  # 0.6 m/s straight on, the camera 60 deg right
    env.step(a)
    assert env.unwrapped.sent == pytest.approx([0.6, 0.0, PAN_WINDOWS[0]])
    assert PAN_WINDOWS[0] == pytest.approx(-np.pi / 3)
    for k in range(300):
        assert relative_looking_action(k) == pytest.approx(
            [*relative_action(k // 5), PAN_WINDOWS[k % 5]])
    assert agent_io({"relative_table": True, "env": "fused-gaze"})[1] is relative_looking_action
    assert agent_io({"relative_table": True, "env": "fused"})[1] is relative_action
    with pytest.raises(ValueError, match="0..299"):
        relative_looking_action(300)


def test_the_shield_of_a_looking_policy_judges_the_drive_whatever_the_pan() -> None:
    shield = shield_for({"relative_table": True, "camera_scan": True, "env": "fused-gaze"}, "x")
    scan = _scan((0.01, 0.45))
    mask = shield({"camera_scan": scan})
    assert mask.shape == (300,)
    drives = CollisionShield().allowed(scan)
    assert np.array_equal(mask, np.repeat(drives, 5))  # action // 5 is the drive
    assert not mask[5 * _action(1.0, 0.0) + 4]


def test_the_pan_head_splits_the_looking_table_into_a_drive_and_a_window() -> None:
    env = RelativeTable(_Box3Env(), pan_head=True)
    assert env.action_space == spaces.MultiDiscrete([60, 5])
    for drive in range(60):
        for window in range(5):
            env.step(np.array([drive, window]))
            assert env.unwrapped.sent == pytest.approx(relative_looking_action(5 * drive + window))
    recipe = {"relative_table": True, "env": "fused-gaze", "pan_head": True}
    assert agent_io(recipe)[1] is relative_head_action
    with pytest.raises(ValueError, match="pan window 0..4"):
        relative_head_action([0, 5])
    with pytest.raises(ValueError, match="--env fused-gaze"):
        RelativeTable(_Box2Env(), pan_head=True)


class _Box2Env(_Box3Env):
    action_space = spaces.Box(-np.ones(2, np.float32), np.ones(2, np.float32))


def test_the_shield_of_the_pan_head_masks_the_drive_head_and_frees_the_window() -> None:
    recipe = {"relative_table": True, "camera_scan": True, "env": "fused-gaze", "pan_head": True}
    shield = shield_for(recipe, "x")
    scan = _scan((0.01, 0.45))
    mask = shield({"camera_scan": scan})
    assert mask.shape == (65,)  # sb3-contrib's MultiDiscrete mask: 60 drives, then 5 windows
    assert np.array_equal(mask[:60], CollisionShield().allowed(scan)) and mask[60:].all()
    assert not mask[_action(1.0, 0.0)]
    with pytest.raises(ValueError, match="give one of them"):
        CollisionShield(pan_windows=5, pan_head=True)


class _ScanEnv(gym.Env):
    """The camera scan in, the pan head's two heads out (for an untrained policy)."""

    observation_space = spaces.Dict({"camera_scan": spaces.Box(0.0, FAR, shape=(3, 32))})
    action_space = spaces.MultiDiscrete([60, 5])

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple:
        return self.observation_space.sample(), {}

    def step(self, action: np.ndarray) -> tuple:
        return self.observation_space.sample(), 0.0, False, False, {}


def test_a_shielded_two_head_agent_drives_allowed_and_looks_where_it_draws() -> None:
    from sb3_contrib import MaskablePPO

    model = MaskablePPO("MultiInputPolicy", _ScanEnv(), seed=0, device="cpu")
    only = np.zeros(65, dtype=bool)
    only[[_action(0.0, 0.0), _action(-0.2, 0.0)]] = True
    only[60:] = True  # every window
    windows = set()
    changed = 0
    for seed in range(30):
        obs = {"camera_scan": _scan((0.5 * seed, 1.0))}
        free = ModelAgent(model, deterministic=False, seed=seed,
                          shield=lambda o: np.ones(65, dtype=bool)).act(obs)  # fmt: skip
        guarded = ModelAgent(model, deterministic=False, seed=seed, shield=lambda o: only).act(obs)
        assert free.shape == guarded.shape == (2,)
        assert only[guarded[0]]
        changed += int(free[0] != guarded[0])
        windows.add(int(guarded[1]))
        best = ModelAgent(model, shield=lambda o: only).act(obs)
        assert only[best[0]] and 0 <= best[1] < 5
    assert changed > 0 and len(windows) > 1  # the mask changed drives; the window stays drawn
