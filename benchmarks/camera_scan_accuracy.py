"""How well the camera scan knows the world, and what it costs a fused step.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.camera_scan_accuracy --episodes 4 --steps 300

For each world and crowd size, the planner expert drives a ``RoverEnvFused(camera_scan=True)``
on a real av-daemon (the shipped network, the daemon's default precision) over seeded
episodes, and every step the scan is checked against the simulator's truth:

- scenery range error: in sectors the camera sees now (``now``) and in those it remembers
  (``kept``, seen within the scan's memory), the scan's nearest scenery against the LIDAR's
  scan of the scenery alone (``sim.lidar(pedestrians=False)``, 0.30 m above the ground),
  where both read under 10 m: median and 90th percentile of the absolute error; ``missed``:
  sectors where the LIDAR has scenery within 5 m and the scan none; ``phantom``: the scan
  has scenery within 5 m and the LIDAR none within 10 m;
- scenery beside and behind: of the sectors out of view now whose LIDAR scenery lies within
  ``BESIDE_M`` and that the camera has looked towards within the scan's memory, the share
  where the scan reads that range within 0.5 m (``known``): what the memory keeps of the
  walls the rover passes;
- scenery at arm's length: of all the sectors whose LIDAR scenery lies within ``CLOSE_M``
  (where the rover's corners touch things), seen or not, the share where the scan reads
  that range within ``CLOSE_TOLERANCE_M`` (``close known``);
- people found: of the pedestrians inside the camera's view within 6 m (a geometric test:
  one behind a wall counts too), the share with a scan person reading within 0.5 m of them;
- false people: the share of the scan's person readings (taken this step) with no
  pedestrian within 0.5 m.

Cost: the same episodes are stepped with and without the scan, alternating, and the
table prints the scan's own update time (``CameraScan.update`` timed in the process, the last
episode's images and poses replayed five times from a reset scan).
"""

from __future__ import annotations

import argparse
import json
import math
import time
import uuid
from dataclasses import dataclass, field

import numpy as np

from active_vision import spawn_daemon
from benchmarks.machine import cpu_name
from rover_env import RoverEnvFused
from rover_env.camera_scan import sector_centres
from rover_train.imitation.expert import PlannerExpert

WORLDS = ("inspect", "moon", "maze")
NEAR_M = 0.5  # a person reading counts as finding a pedestrian within this
VIEW_M = 6.0  # pedestrians in view this near must be found
SCENERY_NEAR_M = 5.0
BESIDE_M = 2.0  # scenery this near, out of view, should still be known
CLOSE_M = 1.0  # scenery this near is where the rover's corners touch things
CLOSE_TOLERANCE_M = 0.25  # a close sector is known when the scan reads it this well


@dataclass
class Tally:
    err_now: list[float] = field(default_factory=list)
    err_kept: list[float] = field(default_factory=list)
    missed: int = 0
    phantom: int = 0
    sectors_now: int = 0
    beside: int = 0
    beside_known: int = 0
    close: int = 0
    close_known: int = 0
    people_in_view: int = 0
    people_found: int = 0
    readings: int = 0
    false_readings: int = 0
    update_s: list[float] = field(default_factory=list)

    def row(self) -> dict[str, float]:
        def q(v: list[float], p: float) -> float:
            return float(np.percentile(v, p)) if v else math.nan

        return {
            "range_err_now_median_m": q(self.err_now, 50),
            "range_err_now_p90_m": q(self.err_now, 90),
            "range_err_kept_median_m": q(self.err_kept, 50),
            "range_err_kept_p90_m": q(self.err_kept, 90),
            "missed_share": self.missed / max(self.sectors_now, 1),
            "beside_known_share": self.beside_known / max(self.beside, 1),
            "beside_sectors": self.beside,
            "close_known_share": self.close_known / max(self.close, 1),
            "close_sectors": self.close,
            "phantom_share": self.phantom / max(self.sectors_now, 1),
            "people_found": self.people_found / max(self.people_in_view, 1),
            "people_in_view": self.people_in_view,
            "false_people": self.false_readings / max(self.readings, 1),
            "person_readings": self.readings,
            "update_ms_median": (1e3 * float(np.median(self.update_s)) if self.update_s
                                 else math.nan),
        }


def check_step(env: RoverEnvFused, obs: dict, tally: Tally) -> None:
    scan = env.camera_scan
    assert scan is not None
    sim = env.sim
    lidar = sim.lidar(scan.config.sectors, 12.0, pedestrians=False)
    s = obs["camera_scan"]
    dt = env.control_dt
    now = s[2] < 0.5 * dt + 1e-6
    kept = s[2] < scan.config.memory_s
    both = (s[0] < scan.config.max_range) & (lidar < scan.config.max_range)
    tally.err_now += np.abs(s[0] - lidar)[now & both].tolist()
    tally.err_kept += np.abs(s[0] - lidar)[kept & both & ~now].tolist()
    tally.sectors_now += int(now.sum())
    beside = ~now & kept & (lidar < BESIDE_M)
    tally.beside += int(beside.sum())
    tally.beside_known += int((beside & (np.abs(s[0] - lidar) < 0.5)).sum())
    close = lidar < CLOSE_M
    tally.close += int(close.sum())
    tally.close_known += int((close & (np.abs(s[0] - lidar) < CLOSE_TOLERANCE_M)).sum())
    tally.missed += int((now & (lidar < SCENERY_NEAR_M) & (s[0] >= scan.config.max_range)).sum())
    tally.phantom += int((now & (s[0] < SCENERY_NEAR_M) & (lidar >= scan.config.max_range)).sum())
    peds = sim.pedestrian_positions
    if len(peds):
        x, y = float(env.position[0]), float(env.position[1])
        near = np.hypot(peds[:, 0] - x, peds[:, 1] - y) < VIEW_M
        in_view = sim.pedestrians_in_view() & near
        points, ages = scan.points("person")
        for px, py in peds[in_view]:
            tally.people_in_view += 1
            if len(points) and np.hypot(points[:, 0] - px, points[:, 1] - py).min() < NEAR_M:
                tally.people_found += 1
        fresh = points[ages < 0.5 * dt + 1e-6]
        for qx, qy in fresh:
            tally.readings += 1
            tally.false_readings += int(np.hypot(peds[:, 0] - qx, peds[:, 1] - qy).min() >= NEAR_M)


def run_world(world: str, people: int, daemon: str, episodes: int, steps: int,
              seed: int) -> tuple[Tally, float, float]:  # fmt: skip
    """The tally, and steps/s without and with the scan (alternating episodes)."""
    tally = Tally()
    rates: dict[bool, list[float]] = {False: [], True: []}
    for scan_on in (True, False):
        env = RoverEnvFused(world_n=world, rl_obs_name=daemon, slot=0, camera_scan=scan_on,
                            n_pedestrians=people, goal_ends_episode=True)  # fmt: skip
        expert = PlannerExpert(world)
        try:
            for ep in range(episodes):
                obs, _ = env.reset(seed=seed + ep)
                expert.reset()
                frames: list[tuple[np.ndarray, float, float, float]] = []
                t0, n = time.perf_counter(), 0
                for _ in range(steps):
                    obs, _, terminated, truncated, _ = env.step(expert.act_env(env))
                    n += 1
                    if scan_on:
                        t1 = time.perf_counter()
                        check_step(env, obs, tally)
                        frames.append((obs["fused_image"].copy(), float(env.position[0]),
                                       float(env.position[1]), float(env.orientation[2])))
                        t0 += time.perf_counter() - t1  # the check is not the env's time
                    if terminated or truncated:
                        break
                rates[scan_on].append(n / (time.perf_counter() - t0))
            if scan_on:
                scan = env.camera_scan
                assert scan is not None
                tally.update_s = time_updates(scan, frames)
        finally:
            env.close()
    return tally, float(np.median(rates[False])), float(np.median(rates[True]))


def time_updates(scan, frames: list[tuple[np.ndarray, float, float, float]],
                 repeats: int = 5) -> list[float]:  # fmt: skip
    """The scan's update alone: the last episode's fused images and poses replayed
    ``repeats`` times from a reset scan, so the memory holds what an episode gives it."""
    out = []
    for _ in range(repeats):
        scan.reset()
        for fused, x, y, yaw in frames:
            t0 = time.perf_counter()
            scan.update(fused, x, y, yaw)
            out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--people", default="3,10")
    p.add_argument("--worlds", default=",".join(WORLDS))
    p.add_argument("--seed", type=int, default=500_000)
    p.add_argument("--json", help="write the rows to this file")
    args = p.parse_args()
    name = f"scanbench_{uuid.uuid4().hex[:6]}"
    rows = []
    assert sector_centres(32).shape == (32,)
    with spawn_daemon(name, slots=1):
        for world in args.worlds.split(","):
            for people in (int(v) for v in args.people.split(",")):
                tally, off, on = run_world(world, people, name, args.episodes, args.steps,
                                           args.seed)  # fmt: skip
                row = {"world": world, "people": people, **tally.row(),
                       "steps_per_s_without": off, "steps_per_s_with": on}
                rows.append(row)
                print(json.dumps(row), flush=True)
    print(f"\nCPU: {cpu_name()}; {args.episodes} episodes x {args.steps} steps, seeds "
          f"{args.seed}..; planner expert driving\n")
    print("| world | people | range err. now, median / p90 (m) | kept, median / p90 (m) | "
          "missed / phantom (sectors in view) | scenery beside known | scenery within 1 m "
          "known | people found ≤ 0.5 m | false people | scan update (ms) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['world']} | {r['people']} | {r['range_err_now_median_m']:.2f} / "
              f"{r['range_err_now_p90_m']:.2f} | {r['range_err_kept_median_m']:.2f} / "
              f"{r['range_err_kept_p90_m']:.2f} | {100 * r['missed_share']:.1f} / "
              f"{100 * r['phantom_share']:.1f} % | {100 * r['beside_known_share']:.0f} % "
              f"(of {r['beside_sectors']}) | {100 * r['close_known_share']:.0f} % "
              f"(of {r['close_sectors']}) | {100 * r['people_found']:.0f} % "
              f"(of {r['people_in_view']}) | {100 * r['false_people']:.1f} % "
              f"(of {r['person_readings']}) | {r['update_ms_median']:.3f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
