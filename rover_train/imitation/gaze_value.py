"""What looking is worth to the planner expert and its students: rows of one scenario's
episodes driven by three teachers (``rover_train.imitation.expert``), optionally by zoo
students, with 90 % intervals and the paired differences of the same episodes, and a clip of
both students. ``benchmarks/gaze_value.py`` runs and prints it (its docstring says what each
row and column is); the results are in benchmarks/RESULTS.md, "Looking, for the teacher" and
"Looking, for the students".

Each row runs RoverEnv with the fused envs' reward constants (``RewardConfig.fused()``) under
:class:`~rover_train.wrappers.WithPanHead`, which turns the sim's camera like the gaze env:
the teachers need no fused image, so no daemon; a student row computes its fused image in
this process (:class:`~rover_train.imitation.dagger.WithFusedView`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fused_image import FUSED_SIZE
from rover_env import RoverEnv
from rover_env.gaze_discrete_env import N_PAN_MOVES
from rover_env.reward import RewardConfig
from rover_env.scenarios import Scenario
from rover_train.evaluate import EpisodeResult, run_episode
from rover_train.imitation.expert import ExpertConfig, PlannerExpert
from rover_train.suite import bootstrap, percentile_interval, wilson_interval
from rover_train.wrappers import FirstContact, WithPanHead, WithSeedTable

Z = 1.6449  # two-sided 90 % normal quantile (PAIRED_CONFIDENCE's)
TEACHERS: dict[str, dict[str, str]] = {
    "fixed teacher": {"sees": "camera", "gaze": "fixed"},
    "gaze teacher": {"sees": "camera", "gaze": "active"},
    "all-seeing teacher": {"sees": "all", "gaze": "fixed"},
}
"""The teacher rows: their :class:`ExpertConfig` fields beside the manners."""


@dataclass
class Episode:
    """One episode of one row: the evaluation's result and the in-view count."""

    result: EpisodeResult
    in_view_steps: int
    first_contact: FirstContact | None = None
    """The episode's first pedestrian contact: whether that person had been in view before."""


HELD_ROW = "gaze student, camera held ahead"
"""The ``--hold-camera`` row's label."""


def teacher_act(
    env: Any, world: str, config: ExpertConfig
) -> tuple[Callable[[], None], Callable[[Any], Any]]:
    """(reset, act) of the planner expert with ``config`` on ``env`` (it reads the state)."""
    expert = PlannerExpert(world, config)
    return expert.reset, lambda _obs: expert.act_env(env)


def student_path(value: str) -> Path:
    """A student row's argument: a zoo entry's name (its shipped file) or a file."""
    from rover_train import zoo

    if value in zoo.ENTRIES:
        return zoo.ENTRIES[value].path
    return Path(value)


def student_act(
    path: Path, gaze: bool, hold_camera: bool = False, table: bool = False
) -> tuple[Callable[[], None], Callable[[Any], Any]]:
    """(reset, act) of a zoo student file; a fixed student's camera stays ahead, and so does
    a gaze student's with ``hold_camera`` (its pan target overruled by 0). With ``table`` the
    env takes the seed's ``Discrete(180)`` and the student must be a discrete one (a fixed
    one's ``Discrete(60)`` action is taken with no pan move)."""
    from rover_train.zoo import StudentAgent

    if not path.is_file():
        raise SystemExit(f"{path}: no such student file (give a zoo entry's name or a file "
                         "made by rover_train.imitation.distill)")  # fmt: skip
    agent = StudentAgent.load(path)
    if agent.spec.table != table:
        raise SystemExit(f"{path}: a discrete student drives the seed's table: give --table"
                         if agent.spec.table else
                         f"{path}: --table drives the seed's table, and this student takes "
                         "continuous actions: give a discrete one or drop --table")  # fmt: skip
    if table:
        if gaze != agent.spec.gaze:
            raise SystemExit(f"{path}: {'not ' if gaze else ''}a Discrete(180) gaze student")

        def act_table(obs: Any) -> int:
            a = int(agent.act(obs))
            if not gaze:
                return a * N_PAN_MOVES  # Discrete(60) -> the same cell, no pan move
            return a - a % N_PAN_MOVES if hold_camera else a

        return agent.reset, act_table

    def act(obs: Any) -> np.ndarray:
        a = np.asarray(agent.act(obs), dtype=np.float32).reshape(-1)
        if gaze and a.shape != (3,):
            raise SystemExit(f"--student-gaze {path}: its actions have {a.size} values, "
                             "not [speed, heading, pan target]")  # fmt: skip
        if gaze and not hold_camera:
            return a
        # the camera ahead, in a new array: the agent may keep the action it returned
        return np.concatenate([a[:2], [0.0]]).astype(np.float32)

    return agent.reset, act


def make_env(scenario: Scenario, max_steps: int, fused_view: bool,
             render_mode: str | None = None, table: bool = False) -> Any:  # fmt: skip
    size = {"size": FUSED_SIZE} if fused_view else {}  # the students read the fused image
    env: Any = WithPanHead(RoverEnv(**scenario.env_kwargs(), length=max_steps,
                                    reward_config=RewardConfig.fused(), render_mode=render_mode,
                                    **size))  # fmt: skip
    if table:
        env = WithSeedTable(env)
    if fused_view:
        from rover_train.imitation.dagger import WithFusedView

        env = WithFusedView(env)
    return env


def run_row(
    scenario: Scenario,
    label: str,
    agent: Callable[[Any], tuple[Callable[[], None], Callable[[Any], Any]]],
    episodes: int,
    seed: int,
    max_steps: int,
    fused_view: bool = False,
    table: bool = False,
) -> list[Episode]:
    """``episodes`` episodes of one row; ``agent(env)`` gives its (reset, act)."""
    env = make_env(scenario, max_steps, fused_view, table=table)
    head = env
    while not isinstance(head, WithPanHead):
        head = head.env
    reset, act = agent(env)
    out = []
    t0 = time.monotonic()
    try:
        for i in range(episodes):
            reset()
            result = run_episode(env, act, seed + i, max_steps, None)
            out.append(Episode(result, head.nearest_in_view_steps, head.first_contact))
    finally:
        env.close()
    wall = time.monotonic() - t0
    steps = sum(e.result.steps for e in out)
    print(f"  {scenario.name} / {label}: {episodes} episodes, {steps} steps in {wall:.0f} s",
          file=sys.stderr, flush=True)  # fmt: skip
    return out


CLIP_PANEL = 128  # px: the height of each student's strip in the clip


def clip_episode(results: dict[str, list[Episode]], students: dict[str, str]) -> int:
    """The episode in which the gaze student had the nearest pedestrian in view most more
    often than the fixed student, among those the gaze student finished at the goal.

    :raises ValueError: ``students`` lacks the gaze or the fixed student's row.
    """
    missing = {"gaze student", "fixed student"} - set(students)
    if missing:
        raise ValueError(f"the clip shows both students: no {' and no '.join(sorted(missing))}")
    gaze, fixed = results[students["gaze student"]], results[students["fixed student"]]
    gain = [g.in_view_steps / max(g.result.steps, 1) - f.in_view_steps / max(f.result.steps, 1)
            if g.result.success else -math.inf for g, f in zip(gaze, fixed, strict=True)]
    return int(np.argmax(gain))


def write_clip(scenario: Scenario, students: dict[str, tuple[Path, bool]], seed: int,
               max_steps: int, path: Path, lead: int, length: int) -> str:  # fmt: skip
    """Re-run episode ``seed`` for each student with rendering and write the gaze student's
    frames above the fixed one's (every other step: real time). Returns a line saying what."""
    import cv2

    frames: dict[str, list[np.ndarray]] = {}
    seen: dict[str, list[bool]] = {}
    fps = 10.0
    for label, (file, gaze) in students.items():
        env = make_env(scenario, max_steps, fused_view=True, render_mode="rgb_array")
        reset, act = student_act(file, gaze)
        frames[label], seen[label] = [], []
        try:
            obs, _ = env.reset(seed=seed)
            reset()
            for _ in range(max_steps):
                obs, _, terminated, truncated, info = env.step(act(obs))
                frame = video_frame(env, obs, panel=CLIP_PANEL)
                cv2.putText(frame, label, (6, CLIP_PANEL - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                            (255, 255, 255), 1, cv2.LINE_AA)  # fmt: skip
                frames[label].append(frame)
                seen[label].append(bool(info["nearest_pedestrian_in_view"]))
                if info["goals_reached"] > 0 or terminated or truncated:
                    break
            fps = 0.5 / env.unwrapped.control_dt
        finally:
            env.close()
    g, f = seen["gaze student"], seen["fixed student"]
    only = [i for i in range(len(g)) if g[i] and not (i < len(f) and f[i])]
    lo = max(0, (only[0] if only else 0) - lead)
    rows = []
    for i in range(lo, lo + length, 2):
        pair = [fr[min(i, len(fr) - 1)] for fr in (frames["gaze student"], frames["fixed student"])]
        rows.append(np.concatenate(pair, axis=0))  # the last frame held once an episode ends
    write_gif(rows, path, fps)
    return (f"wrote {path}: {scenario.name}, seed {seed}, steps {lo}..{lo + length}, gaze "
            f"student above, fixed below")


# --- statistics -----------------------------------------------------------------------------
def ratio_interval(num: np.ndarray, den: np.ndarray) -> tuple[float, float]:
    """Interval of ``sum(num) / sum(den)`` over episodes (bootstrap)."""
    return percentile_interval(bootstrap(lambda i: num[i].sum(1) / np.maximum(den[i].sum(1), 1),
                                         len(num)))  # fmt: skip


def summarise(episodes: list[Episode]) -> dict[str, Any]:
    """The row's figures, each as ``[value, low, high]`` (time to goal None without a
    success)."""
    n = len(episodes)
    r = [e.result for e in episodes]
    success = np.array([x.success for x in r], dtype=float)
    contact = np.array([x.pedestrian_contact for x in r], dtype=float)
    steps = np.array([x.steps for x in r], dtype=float)
    intrude = np.array([x.intrusion_steps for x in r], dtype=float)
    view = np.array([e.in_view_steps for e in episodes], dtype=float)
    ttg = np.array([x.time_to_goal if x.time_to_goal is not None else math.nan for x in r])

    def share(k: np.ndarray) -> list[float]:
        return [float(k.mean()), *wilson_interval(int(k.sum()), n, Z)]

    def ratio(num: np.ndarray) -> list[float]:
        return [float(num.sum() / max(steps.sum(), 1)), *ratio_interval(num, steps)]

    ok = success > 0
    time_to_goal = None
    if ok.any():
        times = ttg[ok]
        samples = bootstrap(lambda i: times[i].mean(1), len(times))
        time_to_goal = [float(times.mean()), *percentile_interval(samples)]
    contacts = [e.first_contact for e in episodes if e.first_contact is not None]
    unseen = [c for c in contacts if not c.seen_before]
    seen_at = np.array([c.first_seen for c in contacts if c.first_seen is not None]).reshape(-1, 2)
    return {
        "episodes": n,
        "contacts_never_in_view": [len(unseen), len(contacts)],
        "contacts_first_seen_median": (None if not len(seen_at) else
                                       [float(np.median(seen_at[:, 0])),
                                        float(np.median(np.abs(seen_at[:, 1])))]),  # fmt: skip
        "success": share(success),
        "pedestrian_collisions": share(contact),
        "intrusion": ratio(intrude),
        "nearest_in_view": ratio(view),
        "time_to_goal_s": time_to_goal,
        "steps": int(steps.sum()),
    }


def paired_difference(a: list[Episode], b: list[Episode]) -> dict[str, list[float]]:
    """``a`` minus ``b`` on the same episodes: success and collision shares (points) and
    the in-view share, each ``[difference, low, high]`` (paired bootstrap)."""
    n = len(a)

    def arrays(rows: list[Episode]) -> dict[str, np.ndarray]:
        return {
            "success": np.array([e.result.success for e in rows], float),
            "pedestrian_collisions": np.array([e.result.pedestrian_contact for e in rows], float),
            "view": np.array([e.in_view_steps for e in rows], float),
            "steps": np.array([e.result.steps for e in rows], float),
        }

    x, y = arrays(a), arrays(b)
    out = {}
    for key in ("success", "pedestrian_collisions"):
        d = x[key] - y[key]
        out[key] = [float(d.mean()), *percentile_interval(bootstrap(lambda i, d=d: d[i].mean(1),
                                                                    n))]  # fmt: skip

    def view_diff(i: np.ndarray) -> np.ndarray:
        return (x["view"][i].sum(1) / x["steps"][i].sum(1)
                - y["view"][i].sum(1) / y["steps"][i].sum(1))  # fmt: skip

    whole = np.arange(n)[None, :]
    out["nearest_in_view"] = [float(view_diff(whole)[0]),
                              *percentile_interval(bootstrap(view_diff, n))]  # fmt: skip
    return out



# --- one scenario ---------------------------------------------------------------------------
@dataclass
class Comparison:
    """One scenario's rows: each row's episodes, its figures and the paired differences."""

    scenario: str
    results: dict[str, list[Episode]]
    """Row label -> its episodes (a student's label names its file)."""
    students: dict[str, str]
    """``"fixed student"``, ``"gaze student"``, ``HELD_ROW`` -> that row's label in results."""
    rows: list[tuple[str, dict[str, Any]]]
    """(label, :func:`summarise`) of each row, teachers first."""
    gaze_minus_fixed: dict[str, list[float]]
    student_diff: dict[str, list[float]] | None = None
    """The gaze student minus the fixed student (both given)."""
    held_diff: dict[str, list[float]] | None = None
    """The gaze student with its camera held ahead minus the one that looks."""

    def report(self) -> dict[str, Any]:
        """The scenario's JSON: rows, differences and every episode's result."""
        return {
            "rows": dict(self.rows), "gaze_minus_fixed": self.gaze_minus_fixed,
            "gaze_student_minus_fixed_student": self.student_diff,
            "held_camera_minus_looking": self.held_diff,
            "episodes": {k: [dataclasses.asdict(e.result) | {
                "in_view_steps": e.in_view_steps,
                "first_contact": None if e.first_contact is None
                else dataclasses.asdict(e.first_contact)
                | {"seen_before": e.first_contact.seen_before}} for e in v]
                for k, v in self.results.items()},
        }  # fmt: skip


def compare(
    scenario: Scenario,
    episodes: int,
    seed: int,
    max_steps: int,
    manners: str = "polite",
    student_fixed: Path | None = None,
    student_gaze: Path | None = None,
    hold_camera: bool = False,
    table: bool = False,
    teachers: tuple[str, ...] = tuple(TEACHERS),
) -> Comparison:
    """The ``teachers`` (labels of :data:`TEACHERS`, all three by default; the fixed and
    the gaze teacher always) with ``manners`` and the students given on episodes ``seed`` ..
    ``seed + episodes - 1`` of ``scenario``; ``hold_camera`` adds the gaze student with its
    camera held ahead; ``table`` drives every row through the seed's Discrete(180) table.

    :raises ValueError: ``hold_camera`` without ``student_gaze``, or fewer than 2 episodes.
    """
    if episodes < 2 or max_steps < 1:
        raise ValueError("episodes must be at least 2 and max_steps at least 1")
    if hold_camera and student_gaze is None:
        raise ValueError("hold_camera overrules a gaze student's pan: give student_gaze too")
    results: dict[str, list[Episode]] = {}
    unknown = set(teachers) - set(TEACHERS)
    if unknown:
        raise ValueError(f"unknown teacher row(s) {sorted(unknown)}: choose from {list(TEACHERS)}")
    for label, fields in TEACHERS.items():
        if label not in teachers and label not in ("fixed teacher", "gaze teacher"):
            continue
        config = ExpertConfig.with_manners(manners, **fields)

        def teacher(env: Any, world: str = scenario.world, config: ExpertConfig = config) -> Any:
            return teacher_act(env, world, config)

        results[label] = run_row(scenario, label, teacher, episodes, seed, max_steps,
                                 table=table)  # fmt: skip
    students: dict[str, str] = {}
    for label, path, gaze, hold in (
        ("fixed student", student_fixed, False, False),
        ("gaze student", student_gaze, True, False),
        (HELD_ROW, student_gaze if hold_camera else None, True, True),
    ):
        if path is not None:
            students[label] = f"{label} ({path.name})"
            results[students[label]] = run_row(
                scenario, label,
                lambda _env, path=path, gaze=gaze, hold=hold: student_act(path, gaze, hold, table),
                episodes, seed, max_steps, fused_view=True, table=table,
            )  # fmt: skip
    out = Comparison(
        scenario=scenario.name, results=results, students=students,
        rows=[(label, summarise(eps)) for label, eps in results.items()],
        gaze_minus_fixed=paired_difference(results["gaze teacher"], results["fixed teacher"]),
    )  # fmt: skip
    if "fixed student" in students and "gaze student" in students:
        out.student_diff = paired_difference(results[students["gaze student"]],
                                             results[students["fixed student"]])  # fmt: skip
    if HELD_ROW in students:
        out.held_diff = paired_difference(results[students[HELD_ROW]],
                                          results[students["gaze student"]])  # fmt: skip
    return out


# --- video ----------------------------------------------------------------------------
def video_frame(env: Any, obs: dict[str, np.ndarray], panel: int = 192) -> np.ndarray:
    """One clip frame: the chase view, the fused image's grayscale and heatmap, the pan."""
    import cv2

    chase = cv2.resize(env.render(), (panel * 4 // 3, panel), interpolation=cv2.INTER_AREA)
    fused = obs["fused_image"]
    gray = (np.clip(fused[:, :, 0], 0, 1) * 255).astype(np.uint8)
    heat = (np.clip(fused[:, :, 1], 0, 1) * 255).astype(np.uint8)
    gray = np.repeat(cv2.resize(gray, (panel, panel))[:, :, None], 3, 2)
    heat = cv2.applyColorMap(cv2.resize(heat, (panel, panel)), cv2.COLORMAP_INFERNO)[:, :, ::-1]
    frame = np.concatenate([chase, gray, heat], axis=1)
    pan = math.degrees(float(obs.get("gaze", np.zeros(1))[0]))
    cv2.putText(frame, f"pan {pan:+.0f} deg", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                (255, 255, 255), 1, cv2.LINE_AA)  # fmt: skip
    return frame


def write_gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """``frames`` (RGB uint8) as a looping GIF at ``fps``."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:],
                   duration=int(1000 / fps), loop=0, optimize=True)  # fmt: skip


