"""rover-eval: evaluate an agent on seeded episodes and report (a zoo entry, a rover-train
model, a student file, the planner expert or a random policy).

    rover-eval lidar-maze                                  # a zoo entry, 100 episodes
    rover-pair -- rover-eval fused-maze --suite            # its world's scenarios (the daemon)
    rover-eval lidar-maze --file runs/x/lidar-maze.pt      # a file made like the entry
    rover-eval runs/x/lidar-maze.pt                        # the same: the file names its entry
    rover-eval lidar-maze --expert                         # the planner expert that teaches it
    rover-eval lidar-maze --random                         # a seeded random policy on its env
    rover-eval runs/demo/model.zip --env fused --world maze --video runs/demo/eval.mp4
    rover-eval --random --env lidar --world maze --episodes 20

Episode i is reset with seed ``--seed + i`` (default the zoo's evaluation seeds, from
``zoo.EVAL_SEED_BASE`` = 100000, which no training episode uses), so every agent meets the
same start/goal pairs. It ends at the first goal reached (success), at a termination (flip,
stuck, out of bounds), at the env's length limit, or after ``--max-steps`` (default
``zoo.EVAL_MAX_STEPS`` = 600 steps, 30 s: a timeout). ``--episodes`` defaults to
``zoo.EVAL_EPISODES`` (100).

A zoo entry, a file made like it (``--file``), its teacher (``--expert``) and ``--random``
with it run on the env the entry was made for (:func:`entry_env`; ``--pedestrian-mode`` and
``--n-pedestrians`` override its crowd). A model runs on ``--env`` in ``--world`` with
``--task`` (default: the model's, from metrics.json beside it, else ``seed``), seen and
driven as it was trained (its recipe: ``--camera-scan``, ``--waypoint``, ``--drop-image``,
``--relative-table``). A bare ``--suite`` is the scenarios of the agent's world: a zoo
entry's, else ``--world``'s. :func:`evaluate_agent` is the library function behind it.

Metrics (the table, and ``--json``'s last line):
- success rate: episodes that reached the goal.
- collision rate: episodes in which the rover collided: a collision step in the seed's sense
  (``info["collision"]``: the LIDAR closer than 0.3 m on the LIDAR envs) or any touch of a
  person or the scenery (``info["contact"]``). The split follows it: seed collisions,
  pedestrian contact, scenery contact (shares of episodes).
- timeouts: episodes ended by the step limit without success or failure.
- path length: metres driven (mean over episodes).
- SPL: success weighted by path length, mean of S * d0 / max(p, d0) with d0 the straight
  start-goal distance (a lower bound of the shortest path) and p the path driven.
- time to goal: simulated seconds, mean over successful episodes.
- personal-space intrusion rate: fraction of steps with a pedestrian within 1.2 m.
- intimate-space intrusion: share of episodes with a pedestrian within 0.45 m at some step.
- min pedestrian distance: the smallest over all steps of all episodes (mean of the
  per-episode minima in brackets).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rover_env.constants import DEFAULT_WORLD, PERSONAL_SPACE_M
from rover_env.crowd import MAX_PEDESTRIANS
from rover_env.pedestrians import DEFAULT_MODE
from rover_env.reward import STUCK_IN_COLLISION
from rover_train import zoo
from rover_train.agents import (
    EXPERT_PLUGIN,
    AgentSource,
    PluginMissingError,
    RandomAgent,
    agent_plugin,
)
from rover_train.algos import ALGOS, RECURRENT, ModelAgent, algo_class
from rover_train.envs import DEFAULT_TASK, ENV_IDS, NAV_LENGTH, TASKS, make_env
from rover_train.progress import StatusLine
from rover_train.recipe import RecipeError, read_recipe
from rover_train.shield import ShieldConfig, shield_for
from rover_train.wrappers import agent_io
from rover_train.zoo.registry import (
    EVAL_MAX_STEPS,
    EVAL_SEED_BASE,
    STUDENT_FUSED_KINDS,
)
from roverav_cli import Connection, Episodes, add_group
from shm_protocol.names import default_name

if TYPE_CHECKING:
    from rover_env.scenarios import Scenario
    from rover_train.agents import Agent
    from rover_train.record import EpisodeRecorder

DEFAULT_ENV = "lidar"  # a model's (and --random's without an agent) env kind
SUITE_OWN_WORLD = "world"  # a bare --suite: the scenarios of the agent's world
STATUS_EVERY_S = 10.0  # seconds between the status lines of a running evaluation
VIDEO_PANEL = 256  # pixels per side of each video panel
VIDEO_PANEL_NAMES = ("chase", "gray", "heatmap", "depth")  # left to right
OUTCOME_HOLD_S = 1.0  # videos hold an episode's last frame, with its outcome, this long
_GOAL_RGB = (25, 230, 50)  # the sim's goal marker's green
_OUTCOME_RGB = {"success": (0, 140, 0), "timeout": (200, 110, 0)}  # else red: a failure
_FAILURE_RGB = (190, 0, 0)


@dataclass
class EpisodeResult:
    success: bool
    collided: bool
    timeout: bool
    termination: str
    path_length: float
    start_distance: float
    time_to_goal: float | None
    steps: int
    intrusion_steps: int
    min_ped_distance: float
    ret: float
    pedestrian_contact: bool = False  # the rover's body touched a pedestrian
    scenery_contact: bool = False  # ... or the scenery
    seed_collision: bool = False  # a step with info["collision"] (the seed's LIDAR test)
    intimate_intrusion: bool = False  # a pedestrian within 0.45 m at some step
    walked_into: bool = False  # a pedestrian touched the rover while it stood (HuNavSim's
    # pedestrian_hit_rover); a touch while it moved is rover_hit_pedestrian


class PolicyLoadError(ValueError):
    """A model file is missing, cannot be loaded, or was trained for another env (the message
    says which and what to do)."""


def load_policy(model: Path, env: Any, algo: str | None = None,
                deterministic: bool = True, seed: int = 0,
                temperature: float = 1.0, shield: bool | None = None,
                shield_config: ShieldConfig | None = None) -> ModelAgent:  # fmt: skip
    """The rover-train model at ``model`` as an agent for ``env``: a
    :class:`~rover_train.algos.ModelAgent` (``reset()`` per episode, ``act(obs)``, also
    callable), deterministic or sampling its policy (each draw seeded by ``seed`` and the
    observation), driving ``env`` as the model was trained (its recipe's waypoint, dropped
    image, relative table; a recurrent model keeps its LSTM state). ``algo``: default from
    ``metrics.json`` beside it; ``seed``: of the sampled actions; ``shield``: behind the
    collision shield on its camera scan (``rover_train.shield``); None: where it was trained
    behind it (``rover-train --shield``); ``shield_config``: the shield's settings at drive time
    (default ``ShieldConfig()``, what the shielded recipes train behind). Raises
    :class:`PolicyLoadError`.
    """
    if not model.is_file():
        raise PolicyLoadError(_no_model_file(model))
    if algo is None:
        algo = run_metrics(model).get("algo")
    # without metrics.json: recurrent first (its load refuses a non-recurrent policy)
    order = [algo] if algo else [*RECURRENT, *(a for a in ALGOS if a not in RECURRENT)]
    errors = []
    recipe = _recipe(model)
    masked = bool(recipe.get("shield"))
    for name in order:
        try:
            loaded = algo_class(name, masked=masked and name == "ppo").load(model, device="cpu")
        except Exception as exc:  # noqa: BLE001 - try the next algorithm
            errors.append(f"{name}: {exc}")
            continue
        check_spaces(model, loaded, _as_trained(recipe, env))
        observe, act = agent_io(recipe)
        try:
            guard = (shield_for(recipe, str(model), shield_config)
                     if (masked if shield is None else shield) else None)  # fmt: skip
            if guard is None and shield_config is not None:
                raise ValueError("shield settings were given, but it drives without the shield "
                                 "(add --shield, or drop the settings)")  # fmt: skip
            return ModelAgent(loaded, deterministic=deterministic, observe=observe, act=act,
                              seed=seed, temperature=temperature, shield=guard)
        except ValueError as exc:
            raise PolicyLoadError(f"{model}: {exc}") from None
    raise PolicyLoadError(f"could not load {model}: " + "; ".join(errors))


def _no_model_file(model: Path) -> str:
    return f"no model file at {model} (train one with rover-train)"


def _recipe(model: Path) -> dict[str, Any]:
    """The rover-train arguments stored in ``model`` ({} for a .zip rover-train did not write)."""
    try:
        return read_recipe(model)
    except RecipeError:
        return {}


def _as_trained(recipe: dict[str, Any], env: Any) -> Any:
    """``env`` as a model trained with ``recipe`` sees it (``rover_train.envs.policy_view``:
    the waypoint, the image dropped, the relative table), for the space check."""
    from rover_train.envs import policy_view

    flags = {k: bool(recipe.get(k))
             for k in ("waypoint", "drop_image", "relative_table", "pan_head")}  # fmt: skip
    if not any(flags.values()):
        return env
    return policy_view(env, env.unwrapped.world, **flags)


def trained_with_scan(model: Path | None) -> bool:
    """Whether ``model`` was trained with ``rover-train --camera-scan`` (its recipe says):
    rover-eval then makes the fused env with ``camera_scan=True`` itself."""
    if model is None or not model.is_file():
        return False
    try:
        return bool(read_recipe(model).get("camera_scan", False))
    except RecipeError:  # a model .zip rover-train did not write
        return False


def run_metrics(model: Path | None) -> dict[str, Any]:
    """The ``metrics.json`` rover-train wrote beside ``model`` ({} when there is none)."""
    meta = model.parent / "metrics.json" if model is not None else None
    if meta is None or not meta.is_file():
        return {}
    data = json.loads(meta.read_text())
    return data if isinstance(data, dict) else {}


def check_spaces(path: Path, model: Any, env: Any) -> None:
    """Raise :class:`PolicyLoadError` when ``model`` was made for other spaces than ``env``'s
    (say a LIDAR policy evaluated on the fused env), naming both and the fix."""
    for what in ("observation", "action"):
        want = getattr(model, f"{what}_space")
        have = getattr(env, f"{what}_space")
        if want != have and what == "observation" and "camera_scan" in getattr(
                want, "spaces", {}) and "camera_scan" not in getattr(have, "spaces", {}):
            raise PolicyLoadError(
                f"{path} was trained with the camera scan (rover-train --camera-scan): its "
                "observation has the camera_scan key, and this env has none. Make the env "
                "with camera_scan=True (a fused env: RoverEnvFused and its gaze and discrete "
                "kinds); rover-eval and zoo.load do so themselves from the model's recipe."
            )
        if want != have:
            raise PolicyLoadError(
                f"{path} was trained for another env: its {what} space is {_describe(want)}, "
                f"but this env's (--env, --world) is {_describe(have)}. Evaluate it with the "
                "--env it was trained on (see metrics.json beside the model), or train a "
                "model for this env with rover-train."
            )


def _describe(space: Any) -> str:
    from gymnasium import spaces

    if isinstance(space, spaces.Dict):
        return "Dict(" + ", ".join(f"{k}: {_describe(v)}" for k, v in space.spaces.items()) + ")"
    if isinstance(space, spaces.Box):
        return f"Box{tuple(space.shape)}"
    return str(space)


def _video_frame(env: Any, obs: Any) -> np.ndarray:
    import cv2

    chase = env.render()
    panels = [cv2.resize(chase, (VIDEO_PANEL, VIDEO_PANEL), interpolation=cv2.INTER_AREA)]
    if isinstance(obs, dict) and "fused_image" in obs:
        fused = obs["fused_image"]
        for c in range(fused.shape[2]):
            ch = (np.clip(fused[:, :, c], 0, 1) * 255).astype(np.uint8)
            ch = cv2.resize(ch, (VIDEO_PANEL, VIDEO_PANEL), interpolation=cv2.INTER_NEAREST)
            cmap = cv2.COLORMAP_INFERNO if c else None
            rgb = (
                cv2.applyColorMap(ch, cmap)[:, :, ::-1]
                if cmap is not None
                else np.repeat(ch[:, :, None], 3, 2)
            )
            panels.append(rgb)
    return np.concatenate(panels, axis=1)


def _labelled_frame(
    env: Any, obs: Any, info: dict[str, Any], step: int, goal: Any
) -> np.ndarray:
    """This step's video frame with its labels; on the step that reaches the goal the
    distance and arrow are the reached goal's (the env has already drawn the next one)."""
    distance, bearing = float(obs["target"][0]), float(obs["target"][1])
    if info.get("goals_reached", 0) > 0 and goal is not None:
        x, y, yaw = float(obs["pose"][0]), float(obs["pose"][1]), float(obs["imu"][2])
        distance = float(np.hypot(goal[0] - x, goal[1] - y))
        bearing = float(np.arctan2(goal[1] - y, goal[0] - x)) - yaw
    return label_frame(
        _video_frame(env, obs), step, distance, bearing,
        collision=bool(info.get("collision", False)),
    )  # fmt: skip


def _put_text(
    frame: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.45,
    rgb: tuple[int, int, int] = (255, 255, 255), box: tuple[int, int, int] | None = (0, 0, 0),
    thickness: int = 1,
) -> None:  # fmt: skip
    """``text`` with its baseline-left corner at ``org``, on a filled ``box`` (legible on
    any panel), or outlined in black when ``box`` is None."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    (w, h), base = cv2.getTextSize(text, font, scale, thickness)
    x, y = org
    if box is not None:
        cv2.rectangle(frame, (x - 3, y - h - 3), (x + w + 2, y + base), box, cv2.FILLED)
    else:
        cv2.putText(frame, text, org, font, scale, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.putText(frame, text, org, font, scale, rgb, thickness, cv2.LINE_AA)


def label_frame(
    frame: np.ndarray, step: int, distance: float, bearing: float, *, collision: bool = False
) -> np.ndarray:
    """Draw on a composed video frame (RGB, in place, and returned): each panel's name
    (``VIDEO_PANEL_NAMES``), the step and the distance to the goal (m) under the chase view,
    ``collision`` on steps with one, and an arrow towards the goal (up: the rover's heading;
    ``bearing`` in rad, positive to the left) in the chase view's top right corner, where
    the goal marker itself is often off screen or behind a wall.
    """
    import cv2

    for i, name in enumerate(VIDEO_PANEL_NAMES[: frame.shape[1] // VIDEO_PANEL]):
        _put_text(frame, name, (i * VIDEO_PANEL + 6, 17))
    bottom = VIDEO_PANEL - 7
    _put_text(frame, f"step {step}   goal {distance:.1f} m", (6, bottom))
    if collision:
        _put_text(frame, "collision", (6, bottom - 20), rgb=(255, 60, 60))
    r = 17
    cx, cy = VIDEO_PANEL - r - 6, r + 22
    _put_text(frame, "goal", (cx - 14, 16), rgb=_GOAL_RGB)
    cv2.circle(frame, (cx, cy), r, (0, 0, 0), cv2.FILLED, cv2.LINE_AA)
    cv2.circle(frame, (cx, cy), r, (255, 255, 255), 1, cv2.LINE_AA)
    tip = (round(cx - 0.85 * r * np.sin(bearing)), round(cy - 0.85 * r * np.cos(bearing)))
    tail = (round(cx + 0.5 * r * np.sin(bearing)), round(cy + 0.5 * r * np.cos(bearing)))
    cv2.arrowedLine(frame, tail, tip, _GOAL_RGB, 2, cv2.LINE_AA, tipLength=0.45)
    return frame


def episode_outcome(result: EpisodeResult) -> str:
    """How an episode ended, in a video's words: ``success``, ``timeout``, ``collision``
    (stuck in a collision) or the termination (``flipped``, ``stuck``, ``out of bounds``),
    with ``(collided)`` added when a collision step happened on the way."""
    if result.success:
        word = "success"
    elif result.timeout:
        word = "timeout"
    elif result.termination == STUCK_IN_COLLISION:
        word = "collision"
    else:
        word = result.termination.replace("_", " ")
    return f"{word} (collided)" if result.collided and word != "collision" else word


def draw_outcome(frame: np.ndarray, outcome: str) -> np.ndarray:
    """A copy of ``frame`` with ``outcome`` (:func:`episode_outcome`) in a banner across the
    chase view's middle: green for success, orange for a timeout, red otherwise."""
    import cv2

    out = frame.copy()
    head = outcome.split(" (")[0]
    rgb = _OUTCOME_RGB.get(head, _FAILURE_RGB)
    text = outcome.upper()
    scale = 0.8
    while scale > 0.4 and cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 2)[0][0] > (
        VIDEO_PANEL - 20
    ):
        scale -= 0.05
    (w, _h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 2)
    cv2.rectangle(out, (0, VIDEO_PANEL // 2 - 24), (VIDEO_PANEL - 1, VIDEO_PANEL // 2 + 12), rgb,
                  cv2.FILLED)  # fmt: skip
    _put_text(out, text, ((VIDEO_PANEL - w) // 2, VIDEO_PANEL // 2), scale, box=None, thickness=2)
    return out


def run_episode(
    env: Any, act: Any, seed: int, max_steps: int, frames: list | None,
    recorder: EpisodeRecorder | None = None,
) -> EpisodeResult:
    """One evaluation episode of ``act`` from ``reset(seed=seed)``. ``frames``, when given,
    gets a labelled video frame per step (:func:`label_frame`) and then the last one again
    with the outcome (:func:`draw_outcome`), held ``OUTCOME_HOLD_S``. ``recorder``, when
    given, gets the reset and every step (:class:`rover_train.record.EpisodeRecorder`; the
    caller closes it)."""
    obs, info = env.reset(seed=seed)
    if recorder is not None:
        recorder.reset(obs, info)
    reset = getattr(act, "reset", None)
    if callable(reset):  # a policy with a state (ModelAgent): a new episode
        reset()
    base = env.unwrapped
    pos = np.array(obs["pose"][:2], dtype=np.float64)
    start_distance = float(obs["target"][0])
    control_dt = float(getattr(base, "control_dt", 0.05))
    path = 0.0
    seed_collision = ped_contact = scenery_contact = intimate = walked_into = False
    intrusions = 0
    min_ped = float(info.get("min_pedestrian_distance", np.inf))
    ret = 0.0
    success = False
    termination = "timeout"
    steps = 0
    while steps < max_steps:
        steps += 1
        goal = info.get("goal")  # this step's goal (a reached one is replaced at once)
        obs, reward, terminated, truncated, info = env.step(act(obs))
        if recorder is not None:
            recorder.step(obs, info)
        if frames is not None:
            frames.append(_labelled_frame(env, obs, info, steps, goal))
        ret += float(reward)
        new = np.array(obs["pose"][:2], dtype=np.float64)
        path += float(np.linalg.norm(new - pos))
        pos = new
        seed_collision |= bool(info.get("collision", False))
        ped_contact |= bool(info.get("pedestrian_collision", False))
        scenery_contact |= bool(info.get("scenery_contact", False))
        intimate |= bool(info.get("intimate_space_intrusion", False))
        walked_into |= bool(info.get("pedestrian_hit_rover", False))
        d_ped = float(info.get("min_pedestrian_distance", np.inf))
        intrusions += int(d_ped < PERSONAL_SPACE_M)
        min_ped = min(min_ped, d_ped)
        if info.get("goals_reached", 0) > 0:
            success, termination = True, "goal"
            break
        if terminated:
            termination = str(info.get("termination_reason") or "terminated")
            break
        if truncated:
            termination = "length"
            break
    result = EpisodeResult(
        success=success,
        collided=seed_collision or ped_contact or scenery_contact,
        timeout=termination in ("timeout", "length"),
        termination=termination,
        path_length=path,
        start_distance=start_distance,
        time_to_goal=steps * control_dt if success else None,
        steps=steps,
        intrusion_steps=intrusions,
        min_ped_distance=min_ped,
        ret=ret,
        pedestrian_contact=ped_contact,
        scenery_contact=scenery_contact,
        seed_collision=seed_collision,
        intimate_intrusion=intimate,
        walked_into=walked_into,
    )
    if frames is not None and steps > 0:
        hold = max(1, round(OUTCOME_HOLD_S / control_dt))
        frames[-1] = draw_outcome(frames[-1], episode_outcome(result))
        frames.extend(frames[-1].copy() for _ in range(hold - 1))
    return result


def evaluate_agents(
    pairs: Sequence[tuple[Any, Agent]],
    episodes: int,
    seed: int = EVAL_SEED_BASE,
    max_steps: int = EVAL_MAX_STEPS,
    frames: list[np.ndarray] | None = None,
    video_episodes: int = 0,
    status: StatusLine | None = None,
    record_dir: Path | None = None,
) -> list[EpisodeResult]:
    """``episodes`` evaluation episodes spread over ``pairs`` of (env, agent): episode i is
    ``agent.reset()`` then :func:`run_episode` from ``reset(seed=seed + i)`` on pair
    ``i % len(pairs)``. ``frames`` gets the video frames of the first ``video_episodes``
    episodes of the first pair; ``status`` hears every step and episode; ``record_dir``
    gets every episode as a ROS 2 bag (:func:`rover_train.record.episode_path`; the envs
    render ``rgb_array``)."""
    results = []
    for i in range(episodes):
        k = i % len(pairs)
        env, agent = pairs[k]
        agent.reset()
        act: Callable[[Any], Any] = agent.act
        if status is not None:

            def act(obs: Any, _act: Callable[[Any], Any] = agent.act) -> Any:
                status.step()
                return _act(obs)

        keep = frames if (k == 0 and i < video_episodes * len(pairs)) else None
        if record_dir is None:
            result = run_episode(env, act, seed + i, max_steps, keep)
        else:
            from rover_train.record import EpisodeRecorder, episode_path

            with EpisodeRecorder(env, episode_path(record_dir, seed + i, i)) as rec:
                result = run_episode(env, act, seed + i, max_steps, keep, rec)
        if status is not None:
            status.episode(result.success)
        results.append(result)
    return results


def evaluate_agent(
    env: Any,
    agent: Agent,
    episodes: int,
    seed: int = EVAL_SEED_BASE,
    max_steps: int = EVAL_MAX_STEPS,
    frames: list[np.ndarray] | None = None,
    video_episodes: int = 0,
    status: StatusLine | None = None,
) -> list[EpisodeResult]:
    """Run ``episodes`` evaluation episodes of ``agent`` (``reset()``/``act(obs)``) on
    ``env``, seeds ``seed``, ``seed + 1``, ... (:func:`evaluate_agents` with one env)."""
    return evaluate_agents([(env, agent)], episodes, seed, max_steps, frames, video_episodes,
                           status)  # fmt: skip


def entry_env(entry: str, name: str | None = None, slot: int = 0, **overrides: Any) -> Any:
    """Zoo entry ``entry``'s env (``overrides``: env keywords, e.g. a scenario's); a fused
    one attaches to slot ``slot`` of daemon ``name`` (default: ``$ROVERAV_SHM_NAME``, which
    rover-pair sets)."""
    if zoo.ENTRIES[entry].kind not in STUDENT_FUSED_KINDS:
        return zoo.make_env(entry, **overrides)
    if slot:
        overrides["slot"] = slot
    return zoo.make_env(entry, rl_obs_name=name or default_name(), **overrides)


def summarise(results: list[EpisodeResult]) -> dict[str, Any]:
    n = len(results)
    spl = [
        (r.start_distance / max(r.path_length, r.start_distance)) if r.success else 0.0
        for r in results
    ]
    ttg = [r.time_to_goal for r in results if r.time_to_goal is not None]
    total_steps = sum(r.steps for r in results)
    finite_min = [r.min_ped_distance for r in results if np.isfinite(r.min_ped_distance)]
    return {
        "episodes": n,
        "success_rate": sum(r.success for r in results) / n,
        "collision_rate": sum(r.collided for r in results) / n,
        "seed_collision_rate": sum(r.seed_collision for r in results) / n,
        "pedestrian_contact_rate": sum(r.pedestrian_contact for r in results) / n,
        "scenery_contact_rate": sum(r.scenery_contact for r in results) / n,
        "intimate_intrusion_rate": sum(r.intimate_intrusion for r in results) / n,
        "walked_into_rate": sum(r.walked_into for r in results) / n,
        "timeouts": sum(r.timeout for r in results),
        "path_length_m": float(np.mean([r.path_length for r in results])),
        "spl": float(np.mean(spl)),
        "time_to_goal_s": float(np.mean(ttg)) if ttg else None,
        "personal_space_intrusion_rate": sum(r.intrusion_steps for r in results)
        / max(total_steps, 1),
        "min_pedestrian_distance_m": float(min(finite_min)) if finite_min else None,
        "mean_episode_min_pedestrian_distance_m": float(np.mean(finite_min))
        if finite_min
        else None,
        "mean_return": float(np.mean([r.ret for r in results])),
        "terminations": {
            t: sum(r.termination == t for r in results)
            for t in sorted({r.termination for r in results})
        },
    }


def summarise_scenario(results: list[EpisodeResult]) -> dict[str, Any]:
    """:func:`summarise` plus what the scenario suite's table adds: the 95 % Wilson
    intervals of the success and of the collision and pedestrian-contact shares."""
    from rover_train.suite import wilson_interval

    summary = summarise(results)
    n = len(results)
    summary["success_ci95"] = list(wilson_interval(sum(r.success for r in results), n))
    summary["collision_ci95"] = list(wilson_interval(sum(r.collided for r in results), n))
    summary["pedestrian_contact_ci95"] = list(
        wilson_interval(sum(r.pedestrian_contact for r in results), n))
    return summary


def _table_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """(metric, value) rows of a :func:`summarise` summary, in the tables' order."""

    def fmt(v: Any, spec: str) -> str:
        return "n/a" if v is None else format(v, spec)

    return [
        ("episodes", str(summary["episodes"])),
        ("success rate", fmt(summary["success_rate"], ".0%")),
        ("collision rate (contact counted)", fmt(summary["collision_rate"], ".0%")),
        ("  seed's collision / ped. contact / scenery contact",
         " / ".join(fmt(summary.get(k), ".0%") for k in (
             "seed_collision_rate", "pedestrian_contact_rate", "scenery_contact_rate"))),
        ("intimate-space intrusion (episodes)", fmt(summary.get("intimate_intrusion_rate"),
                                                    ".0%")),
        ("timeouts", str(summary["timeouts"])),
        ("path length (m)", fmt(summary["path_length_m"], ".2f")),
        ("SPL", fmt(summary["spl"], ".3f")),
        ("mean time to goal (s)", fmt(summary["time_to_goal_s"], ".1f")),
        ("personal-space intrusion rate", fmt(summary["personal_space_intrusion_rate"], ".1%")),
        (
            "min pedestrian distance (m)",
            f"{fmt(summary['min_pedestrian_distance_m'], '.2f')} (mean of episode minima "
            f"{fmt(summary['mean_episode_min_pedestrian_distance_m'], '.2f')})",
        ),
        ("mean return", fmt(summary["mean_return"], ".1f")),
        ("endings", ", ".join(f"{k} {v}" for k, v in summary["terminations"].items())),
    ]


def format_table(summary: dict[str, Any], title: str) -> str:
    rows = _table_rows(summary)
    width = max(len(k) for k, _ in rows)
    lines = [title, "-" * len(title)]
    lines += [f"| {k.ljust(width)} | {v} |" for k, v in rows]
    return "\n".join(lines)


def format_comparison(columns: Sequence[tuple[str, dict[str, Any]]], title: str) -> str:
    """One table of several policies' summaries side by side: a row per metric, a column
    per ``(heading, summary)``, in the order given (a Markdown table under ``title``)."""
    tables = [dict(_table_rows(summary)) for _, summary in columns]
    metrics = list(tables[0])
    cells = [["", *(heading for heading, _ in columns)]]
    cells += [[m, *(t[m] for t in tables)] for m in metrics]
    widths = [max(len(row[i]) for row in cells) for i in range(len(cells[0]))]

    def line(row: list[str]) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) + " |"

    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([title, "-" * len(title), line(cells[0]), rule, *map(line, cells[1:])])


def write_video(frames: list[np.ndarray], path: Path, fps: float) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV could not open {path} for writing (mp4v codec)")
    try:
        for f in frames:
            writer.write(np.ascontiguousarray(f[:, :, ::-1]))
    finally:
        writer.release()


def validate(args: argparse.Namespace) -> str | None:
    """What else is wrong with rover-eval's arguments, and how to fix it; None if nothing."""
    from shm_protocol import InvalidNameError, camera_name, slot_name

    if args.n_pedestrians is not None and not 0 <= args.n_pedestrians <= MAX_PEDESTRIANS:
        return f"--n-pedestrians must be from 0 to {MAX_PEDESTRIANS}, got {args.n_pedestrians}"
    try:
        camera_name(slot_name(args.name, args.slots - 1))
    except InvalidNameError as exc:
        return f"--name: {exc}"
    if args.manners is not None and not args.expert:
        return "--manners is the planner expert's: give it with --expert"
    if args.temperature is not None:
        if not args.temperature > 0:
            return f"--temperature must be > 0 (1: the policy as trained), got {args.temperature}"
        if args.agent not in zoo.ENTRIES and not args.sample:
            return ("--temperature scales a model's sampled actions: add --sample (a zoo entry "
                    "that samples takes it alone)")  # fmt: skip
    if args.shield is not None and (args.random or args.expert):
        return ("--shield guards an RL policy's own actions: give a zoo entry or a "
                "model .zip, not --random or --expert")  # fmt: skip
    if args.person_margin is not None:
        if not args.person_margin >= 0:
            return f"--person-margin must be 0 or more metres, got {args.person_margin}"
        if args.shield is False or args.random or args.expert:
            return ("--person-margin sets the collision shield's berth from people: give it "
                    "to a shielded RL entry or model, without --no-shield")  # fmt: skip
    if args.suite is not None:
        for flag, what in (("--video", args.video), ("--record", args.record),
                           ("--dump", args.dump)):  # fmt: skip
            if what is not None:
                return f"{flag} keeps one env's episodes: drop it with --suite"
    return None


class _EvalError(RuntimeError):
    """What stops an evaluation (no daemon, a model that does not load), as printed."""


@dataclass(frozen=True)
class _Plan:
    """What rover-eval's arguments ask for: who is evaluated (``source``), on which env
    (``entry``: a zoo entry's, else ``--env`` in ``--world``), and a bare ``--suite``'s
    world."""

    source: AgentSource
    entry: str | None
    world: str

    def place(self, env: str) -> str:
        """Where the episodes run, in a title."""
        return self.entry if self.entry is not None else f"{ENV_IDS[env]} ({self.world})"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rover-eval", description=" ".join(__doc__.split("\n\n")[0].split()),
        epilog="examples:\n" + "\n".join(_EXAMPLES),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,  # the removed --slot (a first slot) must not read as --slots
    )  # fmt: skip
    p.add_argument("agent", nargs="?", metavar="AGENT",
                   help="a zoo entry (rover_train.zoo.ENTRIES: "
                        f"{', '.join(sorted(zoo.ENTRIES))}), a model .zip written by "
                        "rover-train, or a student .pt (evaluated as the zoo entry it was "
                        "made like); none with --random")  # fmt: skip
    who = p.add_mutually_exclusive_group()
    who.add_argument("--file", type=Path,
                     help="with a zoo entry: a file made like it instead of the shipped one "
                          "(a student .pt; for an rl-* entry a rover-train model .zip)")
    who.add_argument("--expert", action="store_true",
                     help="with a zoo entry: the planner expert that teaches it, on the same "
                          "episodes (it sees all round)")
    who.add_argument("--random", action="store_true",
                     help="uniform random actions from a generator seeded with --seed: on a "
                          "zoo entry's env, or without AGENT on --env in --world")
    p.add_argument("--manners", metavar="MANNERS",
                   help="with --expert: its pedestrian terms, a name of the lab's "
                        "rover_train.imitation.expert.MANNERS (default: those of the entry's "
                        "teacher)")  # fmt: skip
    p.add_argument("--algo", choices=ALGOS,
                   help="a model's algorithm (default: from metrics.json beside it)")
    p.add_argument("--sample", action="store_true",
                   help="a model's actions sampled from its policy, as in training (each "
                        "draw seeded by --seed and the observation), not its most likely ones; "
                        "an RL zoo entry acts as it says (rl-fused entries sample)")  # fmt: skip
    p.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="with sampled actions (--sample, or an entry that samples): scale the "
                        "policy's spread by T before each draw (logits / T); 1 is the policy as "
                        "trained, below 1 nearer its most likely action (default: 1)")  # fmt: skip
    p.add_argument("--person-margin", type=float, default=None, metavar="M",
                   help="with the collision shield: metres its drives keep from a person "
                        "reading (default: a zoo entry's own, 0.6 for the shielded ones; "
                        "0.3 for a model file, what the shielded recipes train with)")  # fmt: skip
    p.add_argument("--shield", action=argparse.BooleanOptionalAction, default=None,
                   help="an RL entry behind the collision shield on its camera scan (or its "
                        "LIDAR: rl-lidar-*), or not (rover_train.shield; default: as the entry "
                        "ships)")  # fmt: skip
    p.add_argument("--task", choices=tuple(TASKS), default=None,
                   help="a model's episode, as rover-train --task: seed (the env's own "
                        f"length) or nav ({NAV_LENGTH} steps); default: the model's "
                        f"(metrics.json beside it), else {DEFAULT_TASK}")  # fmt: skip
    p.add_argument("--env", choices=sorted(ENV_IDS), default=None,
                   help=f"a model's env kind, and --random's without AGENT (default "
                        f"{DEFAULT_ENV}); a zoo entry runs on the env it was made for")
    add_group(p, Connection).description = (
        "--slots: envs to spread the episodes over, one per daemon slot (episode i on slot "
        "i mod N)")
    add_group(p, Episodes).description = (
        "A zoo entry runs in its own world among its own pedestrians (--pedestrian-mode and "
        "--n-pedestrians override them); a model or --random without AGENT in --world "
        f"(default {DEFAULT_WORLD}) among {DEFAULT_MODE} pedestrians unless given.")
    p.add_argument("--video", type=Path,
                   help="write an MP4: chase view beside the fused channels, labelled")
    p.add_argument("--video-episodes", type=int, default=1, help="episodes recorded in the video")
    p.add_argument("--record", type=Path, metavar="DIR",
                   help="write every episode as a ROS 2 bag, DIR/episode_<seed>.mcap (camera, "
                        "chase view, scan, IMU, odometry, tf, cmd_vel, goal, pedestrians, "
                        "fused channels on sim time; docs/foxglove_layout.json opens it in "
                        "Foxglove; needs pip install 'roverav[ros]')")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on the last line")
    p.add_argument("--dump", type=Path,
                   help="write every episode's result to this JSON file (to merge split runs)")
    p.add_argument(
        "--suite", nargs="?", const=SUITE_OWN_WORLD, default=None, metavar="SCENARIOS",
        help="evaluate over the scenario suite (rover_env.scenarios) and print one table: "
             "bare, the scenarios of the agent's world (a zoo entry's, else --world's); "
             "'all', a world, or names separated by commas; the scenarios set the world "
             "and the pedestrians",
    )  # fmt: skip
    return p


_EXAMPLES = tuple(f"  {cmd:<58} {what}" for cmd, what in (
    ("rover-eval lidar-maze", "a zoo entry, 100 episodes"),
    ("rover-pair -- rover-eval fused-maze --suite", "its world's scenarios (the daemon)"),
    ("rover-eval lidar-maze --file runs/x/lidar-maze.pt", "a file made like the entry"),
    ("rover-eval lidar-maze --expert", "the planner expert that teaches it"),
    ("rover-eval lidar-maze --random", "a seeded random policy on its env"),
    ("rover-eval runs/x/model.zip --env fused --world maze", "a rover-train model"),
    ("rover-eval --random --env lidar --world maze", "a seeded random policy"),
))  # fmt: skip


def _plan(args: argparse.Namespace, p: argparse.ArgumentParser) -> _Plan:
    """Who rover-eval's arguments evaluate, and where (``p.error`` for what does not fit).
    Sets ``args.model`` (a model .zip or None), ``args.env``, ``args.world`` and
    ``args.task``."""
    args.model = None
    entry: str | None = None
    student: Path | None = None
    random = AgentSource("random policy", lambda env: RandomAgent(env.action_space, args.seed))
    if args.agent is None:
        if not args.random:
            p.error("give an agent: a zoo entry, a model .zip or a student .pt (or --random)")
    elif args.agent in zoo.ENTRIES:
        entry = args.agent
    elif args.agent in zoo.RETIRED:
        p.error(zoo.RETIRED[args.agent].message(args.agent))
    else:
        path = Path(args.agent)
        if path.suffix not in (".zip", ".pt") and not path.exists():
            p.error(f"{args.agent!r} is neither a zoo entry ({', '.join(sorted(zoo.ENTRIES))}) "
                    "nor a file: give a model .zip or a student .pt")  # fmt: skip
        if args.file or args.expert or args.random:
            p.error("--file, --expert and --random go with a zoo entry (or --random alone), "
                    f"not with the file {path}")  # fmt: skip
        if path.suffix == ".pt":
            student, entry = path, _student_entry(path, p)
        else:
            args.model = path
    if entry is None:
        args.env = args.env or DEFAULT_ENV
        args.world = args.world or DEFAULT_WORLD
        if args.task is None:
            args.task = run_metrics(args.model).get("task", DEFAULT_TASK)
        model = args.model
        source = random if args.random else AgentSource(
            str(model), lambda env: _model_agent(model, env, args.algo, args.sample, args.seed,
                                      args.temperature, args.shield, _shield_config(args)))
        return _Plan(source, None, args.world)
    spec = zoo.ENTRIES[entry]
    given = [f for f, v in (("--env", args.env), ("--world", args.world), ("--task", args.task),
                            ("--algo", args.algo)) if v is not None]  # fmt: skip
    if given:
        p.error(f"{', '.join(given)}: a zoo entry runs on the env it was made for ({entry}: "
                f"{ENV_IDS[spec.kind]} in {spec.world}); those flags are a model's")
    if args.expert:
        if spec.trainer == zoo.RL:
            p.error(f"--expert: the planner expert drives RoverEnv, and {entry} its discrete "
                    f"twin; evaluate the expert on the same episodes with: rover-eval "
                    f"lidar-{spec.world} --expert")
        try:
            source = agent_plugin(EXPERT_PLUGIN)(entry, args.manners)
        except (PluginMissingError, ValueError) as exc:
            p.error(f"--expert: {exc}")
    elif args.random:
        source = random
    else:
        file = args.file if args.file is not None else student
        try:
            loaded = zoo.load(entry, file, temperature=args.temperature, shield=args.shield,
                              shield_config=_shield_config(args, entry))  # fmt: skip
        except (FileNotFoundError, RecipeError, zoo.StudentFileError, ValueError) as exc:
            p.error(f"--file: {exc}" if args.file is not None else str(exc))
        source = AgentSource(f"zoo {entry}" if file is None else str(file),
                             lambda env: loaded)  # fmt: skip
    return _Plan(source, entry, spec.world)


def _student_entry(path: Path, p: argparse.ArgumentParser) -> str:
    """The zoo entry the student file ``path`` was made like (its ``meta["name"]``)."""
    try:
        made_like = zoo.StudentAgent.read_meta(path).get("name")
    except FileNotFoundError:
        p.error(f"no student file at {path}")
    except zoo.StudentFileError as exc:
        p.error(str(exc))
    if made_like not in zoo.ENTRIES:
        p.error(f"{path} does not say which zoo entry it was made like (its name: "
                f"{made_like!r}); name the entry: rover-eval ENTRY --file {path}")
    return str(made_like)


def _shield_config(args: argparse.Namespace, entry: str | None = None) -> ShieldConfig | None:
    """The shield's drive-time settings rover-eval's arguments ask for (None: the entry's, or
    the defaults): ``--person-margin`` over zoo entry ``entry``'s own settings."""
    if args.person_margin is None:
        return None
    if entry is None:
        return ShieldConfig(person_margin_m=args.person_margin)
    return zoo.drive_shield(entry, person_margin_m=args.person_margin)


def _model_agent(model: Path, env: Any, algo: str | None, sample: bool, seed: int,
                 temperature: float | None = None, shield: bool | None = None,
                 shield_config: ShieldConfig | None = None) -> Agent:  # fmt: skip
    try:
        return load_policy(model, env, algo, deterministic=not sample, seed=seed,
                           temperature=1.0 if temperature is None else temperature,
                           shield=shield, shield_config=shield_config)
    except PolicyLoadError as exc:
        raise _EvalError(f"rover-eval: {exc}") from exc


def main(argv: Sequence[str] | None = None) -> int:
    p = _parser()
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(name)s %(levelname)s %(message)s")
    problem = validate(args)
    if problem:
        p.error(problem)
    plan = _plan(args, p)
    scenarios = None
    if args.suite is not None:
        from rover_env.scenarios import select_scenarios

        try:
            scenarios = select_scenarios(plan.world if args.suite == SUITE_OWN_WORLD
                                         else args.suite)  # fmt: skip
        except ValueError as exc:
            p.error(f"--suite: {exc}")
    if args.record is not None:
        from active_vision.ros_formats import RosExtraMissingError, typestore

        try:
            typestore()
        except RosExtraMissingError as exc:
            p.error(f"--record: {exc}")
    if args.model is not None and not args.model.is_file():  # said before torch and the envs load
        print(f"rover-eval: {_no_model_file(args.model)}", file=sys.stderr)
        return 1
    import torch

    torch.set_num_threads(1)  # batch-1 forwards: one thread is the fastest, and reproducible
    try:
        if scenarios is not None:
            return _main_suite(args, plan, scenarios)
        return _main_one(args, plan)
    except _EvalError as exc:
        print(exc, file=sys.stderr)
        return 1


def _main_one(args: argparse.Namespace, plan: _Plan) -> int:
    """rover-eval without --suite: one env's episodes, one table."""
    overrides = {k: v for k, v in (("pedestrian_mode", args.pedestrian_mode),
                                   ("n_pedestrians", args.n_pedestrians)) if v is not None}
    t0 = time.monotonic()
    results, frames, fps = _evaluate(args, plan, overrides, "", video=args.video is not None)
    summary = summarise(results)
    summary["wall_s"] = time.monotonic() - t0
    last = args.seed + args.episodes - 1
    print(format_table(summary, f"{plan.source.label} on {plan.place(args.env)}, "
                                f"seeds {args.seed}..{last}"))  # fmt: skip
    if args.dump is not None:
        args.dump.write_text(json.dumps([dataclasses.asdict(r) for r in results]))
    if args.video is not None and frames:
        write_video(frames, args.video, fps)
        print(f"wrote {args.video} ({len(frames)} frames)")
    if args.record is not None:
        print(f"recorded {args.episodes} episodes to {args.record}/episode_<seed>.mcap")
    if args.json:
        print(json.dumps(summary))
    return 0


def _main_suite(args: argparse.Namespace, plan: _Plan, scenarios: list[Scenario]) -> int:
    """rover-eval --suite: the agent over the scenarios, one table (each row also on stderr
    as it is done)."""
    from rover_train.suite import format_suite_row, format_suite_table, run_suite, suite_json

    rows = run_suite(
        scenarios,
        lambda sc: summarise_scenario(
            _evaluate(args, plan, sc.env_kwargs(), f" {sc.name}", video=False)[0]),
        progress=lambda sc, s: print("| " + " | ".join(format_suite_row(sc, s)) + " |",
                                     file=sys.stderr, flush=True),
    )  # fmt: skip
    where = f"{plan.entry}'s suite" if plan.entry is not None else ENV_IDS[args.env]
    last = args.seed + args.episodes - 1
    print(format_suite_table(rows, f"{plan.source.label} on {where}, "
                                   f"seeds {args.seed}..{last}"))  # fmt: skip
    if args.json:
        print(json.dumps(suite_json(rows)))
    return 0


def _evaluate(
    args: argparse.Namespace, plan: _Plan, env_kwargs: dict[str, Any], label: str, video: bool
) -> tuple[list[EpisodeResult], list[np.ndarray], float]:
    """``args.episodes`` episodes of ``plan``'s agent, spread over ``args.slots`` envs made
    with ``env_kwargs`` (a scenario's, or the pedestrians asked for): (results, video
    frames, fps)."""
    from shm_protocol.errors import ShmError

    envs: list[Any] = []
    try:
        try:
            for k in range(min(args.slots, args.episodes)):
                envs.append(_make_env(args, plan, k, env_kwargs,
                                      render=(video and k == 0) or args.record is not None))
        except ShmError as exc:
            kind = zoo.ENTRIES[plan.entry].kind if plan.entry is not None else args.env
            raise _EvalError(
                f"{exc}\n\nrover-eval on {ENV_IDS[kind]} needs the daemon: "
                f"av-daemon --name {args.name} --slots {args.slots}, or run it "
                f"under rover-pair --slots {args.slots} -- rover-eval ..."
            ) from exc
        status = StatusLine(f"eval {plan.source.label}{label}", args.episodes * args.max_steps,
                            every=STATUS_EVERY_S, stream=sys.stderr)  # fmt: skip
        frames: list[np.ndarray] = []
        results = evaluate_agents(
            [(env, plan.source.agent(env)) for env in envs], args.episodes, args.seed,
            args.max_steps, frames if video else None, args.video_episodes, status,
            args.record,
        )  # fmt: skip
        fps = 1.0 / float(getattr(envs[0].unwrapped, "control_dt", 0.05))
    finally:
        for env in envs:
            env.close()
    return results, frames, fps


def _make_env(args: argparse.Namespace, plan: _Plan, slot: int, env_kwargs: dict[str, Any],
              render: bool) -> Any:  # fmt: skip
    """One env of the evaluation: the zoo entry's (``env_kwargs`` override its keywords), or
    ``args.env`` in ``env_kwargs``' world (default ``args.world``) as the model was trained."""
    if plan.entry is not None:
        render_mode = {"render_mode": "rgb_array"} if render else {}
        if args.shield and zoo.ENTRIES[plan.entry].trainer != zoo.RL:  # the student's shield
            env_kwargs = {**env_kwargs, "camera_scan": True}  # reads the camera scan
        return entry_env(plan.entry, args.name, slot, **env_kwargs, **render_mode)
    return make_env(
        args.env, world=env_kwargs.get("world_n", args.world), slot=slot, name=args.name,
        task=args.task, camera_scan=trained_with_scan(args.model),
        pedestrian_mode=env_kwargs.get("pedestrian_mode", DEFAULT_MODE),
        n_pedestrians=env_kwargs.get("n_pedestrians"),
        render_mode="rgb_array" if render else None,
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
