"""Does looking help? Fixed-camera vs gaze agents in the crossing scenario.

    .venv/bin/python -m benchmarks.gaze_crossing --fixed runs/fixed/model.zip \\
        --gaze runs/gaze/model.zip --episodes 30 --gif docs/gaze_crossing.gif

Both agents meet the same episodes: episode i is reset with seed ``--seed + i`` in
``--world`` with ``pedestrian_mode="crossing"`` (pedestrians walk across the line from the
rover's start to its goal, from the side). An episode ends at the first goal (success), a
termination (flip, stuck, out of bounds) or after ``--max-steps``. Each agent gets its own
daemon slot of one daemon started here. Per agent it prints, over all episodes:

- success rate; pedestrian collision rate (episodes with a rover-pedestrian contact);
- personal-space (< 1.2 m) and intimate-space (< 0.45 m) intrusion rates (fractions of steps);
- nearest pedestrian in view: fraction of steps in which the nearest pedestrian stands inside
  the camera's horizontal field of view (within 10 m), and the fraction of steps in which it
  is in view only thanks to the pan (outside the +-45 deg a fixed camera covers);
- mean |pan| (deg) and pan-turning steps.

``--gif`` writes a short clip of the gaze agent: the episode with the most steps in which the
nearest pedestrian was seen only thanks to the pan, re-run with rendering (chase view with the
view cone, grayscale, heatmap), cut to the frames around the first such moment.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fused_image import DEPTH_MAX_M as VIEW_RANGE_M  # in view: within depth range
from rover_env.constants import INTIMATE_SPACE_M, PERSONAL_SPACE_M
from rover_train.imitation.gaze_value import video_frame, write_gif

FIXED_HALF_FOV = math.radians(45.0)  # the forward camera's half field of view, unpanned


@dataclass
class Tally:
    episodes: int = 0
    successes: int = 0
    pedestrian_collision_episodes: int = 0
    steps: int = 0
    personal_steps: int = 0
    intimate_steps: int = 0
    nearest_in_view_steps: int = 0
    seen_only_by_pan_steps: int = 0
    abs_pan_sum_deg: float = 0.0
    turning_steps: int = 0
    per_episode_pan_only: list[int] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        n, s = max(self.episodes, 1), max(self.steps, 1)
        return {
            "episodes": self.episodes,
            "success_rate": self.successes / n,
            "pedestrian_collision_rate": self.pedestrian_collision_episodes / n,
            "personal_space_intrusion_rate": self.personal_steps / s,
            "intimate_space_intrusion_rate": self.intimate_steps / s,
            "nearest_pedestrian_in_view": self.nearest_in_view_steps / s,
            "nearest_seen_only_thanks_to_pan": self.seen_only_by_pan_steps / s,
            "mean_abs_pan_deg": self.abs_pan_sum_deg / s,
            "turning_steps": self.turning_steps / s,
            "steps": self.steps,
        }


def nearest_outside_fixed_view(env: Any) -> bool:
    """Whether the nearest pedestrian is outside the view of an unpanned camera."""
    base = env.unwrapped
    i = base.nearest_pedestrian_index()
    if i < 0:
        return True
    px, py = base.sim.pedestrians.positions[i]
    x, y, yaw = base.position[0], base.position[1], base.orientation[2]
    bearing = math.atan2(py - y, px - x) - yaw
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
    return abs(bearing) > FIXED_HALF_FOV or math.hypot(px - x, py - y) > VIEW_RANGE_M


def run_episode(
    env: Any, act: Callable[[Any], Any], seed: int, max_steps: int, tally: Tally,
    frames: list[np.ndarray] | None = None,
) -> list[bool]:  # fmt: skip
    """One episode into ``tally``; returns per step whether the pan alone showed the nearest."""
    obs, info = env.reset(seed=seed)
    tally.episodes += 1
    collided = False
    pan_only: list[bool] = []
    last_pan = 0.0
    for _ in range(max_steps):
        obs, _, terminated, truncated, info = env.step(act(obs))
        tally.steps += 1
        d = float(info["min_pedestrian_distance"])
        tally.personal_steps += d < PERSONAL_SPACE_M
        tally.intimate_steps += d < INTIMATE_SPACE_M
        collided |= bool(info.get("pedestrian_collision", False))
        seen = bool(info["nearest_pedestrian_in_view"])
        tally.nearest_in_view_steps += seen
        only = seen and nearest_outside_fixed_view(env)
        pan_only.append(only)
        tally.seen_only_by_pan_steps += only
        pan = float(info.get("pan", 0.0))
        tally.abs_pan_sum_deg += abs(math.degrees(pan))
        tally.turning_steps += pan != last_pan
        last_pan = pan
        if frames is not None:
            frames.append(video_frame(env, obs))
        if info["goals_reached"] > 0:
            tally.successes += 1
            break
        if terminated or truncated:
            break
    tally.pedestrian_collision_episodes += collided
    tally.per_episode_pan_only.append(sum(pan_only))
    return pan_only


def load_agent(path: Path) -> Callable[[Any], Any]:
    from stable_baselines3 import PPO

    model = PPO.load(path, device="cpu")
    return lambda obs: model.predict(obs, deterministic=True)[0]


def scripted_visibility(world: str, episodes: int, seed: int, max_steps: int) -> dict[str, float]:
    """What looking could give, without learning: a scripted driver (0.6 m/s straight at the
    goal, LIDAR env, no daemon) with the camera fixed ahead vs. turned towards the nearest
    pedestrian (clamped to +-60 deg). Returns the fraction of steps with the nearest
    pedestrian in view for each."""
    import rover_env

    out = {}
    for look in (False, True):
        env = rover_env.RoverEnv(world_n=world, pedestrian_mode="crossing")
        seen = steps = 0
        try:
            for i in range(episodes):
                obs, info = env.reset(seed=seed + i)
                for _ in range(max_steps):
                    if look:
                        j = env.nearest_pedestrian_index()
                        px, py = env.sim.pedestrians.positions[j]
                        x, y, yaw = env.position[0], env.position[1], env.orientation[2]
                        bearing = math.atan2(py - y, px - x) - yaw
                        bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
                        env.sim.set_camera_pan(max(-math.pi / 3, min(math.pi / 3, bearing)))
                    j = env.nearest_pedestrian_index()
                    seen += bool(env.sim.pedestrians_in_view()[j])
                    steps += 1
                    action = np.array([0.6, obs["target"][1]], np.float32)
                    obs, _, terminated, truncated, info = env.step(action)
                    if info["goals_reached"] or terminated or truncated:
                        break
        finally:
            env.close()
        out["scripted, camera turned to the nearest" if look else "scripted, camera fixed"] = (
            seen / max(steps, 1)
        )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fixed", type=Path, required=True, help="PPO model.zip for --env fused")
    p.add_argument("--gaze", type=Path, required=True, help="PPO model.zip for fused-gaze")
    p.add_argument("--world", default="moon")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--seed", type=int, default=5000, help="episode i uses seed + i")
    p.add_argument("--max-steps", type=int, default=400)
    p.add_argument("--gif", type=Path, help="write a clip of the gaze agent looking")
    p.add_argument("--gif-frames", type=int, default=90)
    p.add_argument("--json", type=Path, help="write the summaries here")
    args = p.parse_args(argv)

    for label, frac in scripted_visibility(
        args.world, args.episodes, args.seed, args.max_steps
    ).items():
        print(f"{label}: nearest pedestrian in view in {frac:.1%} of steps")

    from active_vision import spawn_daemon
    from rover_train.envs import make_env

    name = f"gazebench_{uuid.uuid4().hex[:6]}"
    agents = {
        "fixed camera (fused)": ("fused", args.fixed),
        "gaze (fused-gaze)": ("fused-gaze", args.gaze),
    }
    results: dict[str, dict[str, float]] = {}
    with spawn_daemon(name, slots=2, extra_args=["--threads", "1"]):
        best: tuple[int, int] = (-1, 0)
        for slot, (label, (kind, model)) in enumerate(agents.items()):
            act = load_agent(model)
            tally = Tally()
            env = make_env(kind, world=args.world, slot=slot, name=name,
                           pedestrian_mode="crossing", length=args.max_steps)  # fmt: skip
            try:
                for i in range(args.episodes):
                    run_episode(env, act, args.seed + i, args.max_steps, tally)
            finally:
                env.close()
            results[label] = tally.summary()
            if kind == "fused-gaze":
                counts = tally.per_episode_pan_only
                k = int(np.argmax(counts))
                best = (k, counts[k])
        print_table(results, args)
        if args.json:
            args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()},
                                             "results": results}, indent=2))  # fmt: skip
        if args.gif is not None:
            k, count = best
            act = load_agent(args.gaze)
            env = make_env("fused-gaze", world=args.world, slot=1, name=name,
                           pedestrian_mode="crossing", length=args.max_steps,
                           render_mode="rgb_array")  # fmt: skip
            frames: list[np.ndarray] = []
            try:
                pan_only = run_episode(env, act, args.seed + k, args.max_steps, Tally(), frames)
                fps = 1.0 / env.unwrapped.control_dt
            finally:
                env.close()
            first = pan_only.index(True) if any(pan_only) else 0
            lo = max(0, first - args.gif_frames * 2 // 3)
            clip = frames[lo : lo + args.gif_frames : 2]  # every other step: 10 fps, real time
            write_gif(clip, args.gif, fps / 2)
            print(
                f"wrote {args.gif}: episode seed {args.seed + k}, steps {lo}..{lo + len(clip) * 2}"
                f" ({count} steps with the nearest pedestrian seen only thanks to the pan)"
            )
    return 0


def print_table(results: dict[str, dict[str, float]], args: argparse.Namespace) -> None:
    rows = [
        ("success rate", "success_rate", ".0%"),
        ("pedestrian collision rate (episodes)", "pedestrian_collision_rate", ".0%"),
        ("personal-space intrusion rate (steps)", "personal_space_intrusion_rate", ".1%"),
        ("intimate-space intrusion rate (steps)", "intimate_space_intrusion_rate", ".1%"),
        ("nearest pedestrian in view (steps)", "nearest_pedestrian_in_view", ".1%"),
        ("  of which only thanks to the pan", "nearest_seen_only_thanks_to_pan", ".1%"),
        ("mean absolute pan (deg)", "mean_abs_pan_deg", ".1f"),
        ("steps with the camera turning", "turning_steps", ".1%"),
        ("steps", "steps", "d"),
    ]
    labels = list(results)
    last = args.seed + args.episodes - 1
    print(f"crossing scenario, world {args.world}, seeds {args.seed}..{last}, "
          f"max {args.max_steps} steps")  # fmt: skip
    print("| metric | " + " | ".join(labels) + " |")
    print("|---|" + "---|" * len(labels))
    for title, key, spec in rows:
        print(f"| {title} | " + " | ".join(format(results[a][key], spec) for a in labels) + " |")


if __name__ == "__main__":
    sys.exit(main())
