"""How well the unmapped scan (``rover_train.zoo.agent.unmapped_scan``) separates the scenery
from the pedestrians: drive random smooth actions (seeded) and count, among the LIDAR
returns within ``LIDAR_CLIP``, the scenery's that it marks (false) and the pedestrians'
that it marks (found). A return is the pedestrians' when it is nearer than the same scan
cast against the scenery only (MuJoCo, geom group 0).

    MUJOCO_GL=egl python benchmarks/unmapped_scan_check.py --episodes 4 --steps 300

Three ways of casting the map's scan, in one run: from ``obs["pose"]`` as it is; from the
pose one physics step back by the odometry (the env's scan lags by one); and that, with the
nearest of three casts at +-``UNMAPPED_YAW_SPREAD`` (what ``unmapped_scan`` does).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rover_env import LIDAR_SCAN_LAG, lidar_ray_angles, obstacle_map
from rover_train.envs import make_env
from rover_train.zoo.agent import (
    LIDAR_CLIP,
    UNMAPPED_MARGIN,
    UNMAPPED_YAW_SPREAD,
    unmapped_scan,
)

WAYS = ("from obs pose", "one step back", "one step back, +-spread (shipped)")


def mapped(world, obs: dict, back: bool, spread: float) -> np.ndarray:
    lidar = obs["lidar"]
    angles, per_point = lidar_ray_angles(len(lidar))
    x, y, yaw = float(obs["pose"][0]), float(obs["pose"][1]), float(obs["imu"][2])
    if back:
        v, w = float(obs["velocities"][0]), float(obs["velocities"][1])
        x, y = x - v * math.cos(yaw) * LIDAR_SCAN_LAG, y - v * math.sin(yaw) * LIDAR_SCAN_LAG
        yaw -= w * LIDAR_SCAN_LAG
    reach = LIDAR_CLIP + UNMAPPED_MARGIN
    offsets = (-spread, 0.0, spread) if spread else (0.0,)
    casts = [world.ray_distances(x, y, yaw + d + angles, reach) for d in offsets]
    return np.minimum.reduce(casts).reshape(len(lidar), per_point).min(axis=1)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--worlds", nargs="+", default=["maze", "inspect"])
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--seed", type=int, default=900)
    a = p.parse_args()
    print("| world | map cast | scenery returns marked | pedestrian returns marked |")
    print("|---|---|---|---|")
    for name in a.worlds:
        env = make_env("lidar", world=name)
        world = obstacle_map(name)
        counts = {w: [0, 0, 0, 0] for w in WAYS}
        rng = np.random.default_rng(a.seed)
        for ep in range(a.episodes):
            obs, _ = env.reset(seed=a.seed + ep)
            sim = env.unwrapped.sim
            for t in range(a.steps):
                if t % 10 == 0:
                    low, high = env.action_space.low, env.action_space.high
                    action = rng.uniform(low, high).astype(np.float32)
                obs, _, terminated, truncated, _ = env.step(action)
                lidar = obs["lidar"]
                near = lidar < LIDAR_CLIP
                person = lidar < sim.lidar(len(lidar), LIDAR_CLIP + 1.0, pedestrians=False) - 0.05
                shipped = unmapped_scan(obs, name) < 1.0
                for way, back, spread in zip(WAYS, (False, True, True),
                                             (0.0, 0.0, UNMAPPED_YAW_SPREAD), strict=True):
                    marked = lidar < mapped(world, obs, back, spread) - UNMAPPED_MARGIN
                    if spread:
                        assert np.array_equal(marked & near, shipped & near)
                    c = counts[way]
                    c[0] += int(np.count_nonzero(marked & near & ~person))
                    c[1] += int(np.count_nonzero(near & ~person))
                    c[2] += int(np.count_nonzero(marked & near & person))
                    c[3] += int(np.count_nonzero(near & person))
                if terminated or truncated:
                    break
        env.close()
        for way, (fs, s, fp, pn) in counts.items():
            print(f"| {name} | {way} | {fs / s:.2%} of {s} | {fp / max(pn, 1):.1%} of {pn} |")


if __name__ == "__main__":
    main()
