"""What looking is worth to the planner expert (issue 37): three teachers on the same episodes.

    PYTHONPATH=. .venv/bin/python benchmarks/gaze_value.py    # 100 episodes a row: ~10 min
    PYTHONPATH=. .venv/bin/python benchmarks/gaze_value.py --episodes 250 \
        --scenarios moon-crossing-3,inspect-crowd-3,inspect-crowd-10  # RESULTS.md's: ~20 min

(times on the shared 2-vCPU VM, one core's worth, beside other jobs).

Rows (``rover_train.imitation.expert``, the fused students' ``polite`` manners unless
``--manners``):

- **fixed teacher**: drives reacting only to the pedestrians its camera shows
  (``sees="camera"``), the camera fixed straight ahead (``gaze="fixed"``): what the fused
  entries are taught by;
- **gaze teacher**: the same driving, the camera turned by the gaze policy
  (``gaze="active"``: a pedestrian at risk, else where the path turns, else a slow scan);
- **all-seeing teacher**: reacts to every pedestrian all round (``sees="all"``), the camera
  fixed: what looking could at best give.

Optional rows: ``--student-fixed`` / ``--student-gaze``, a zoo entry's name (``fused-moon``,
``fused-gaze-moon``) or a student file (a gaze student's actions have 3 values; a fixed
one's 2, its camera kept ahead), driving on the fused image computed in this process from
the (turned) camera (``rover_train.imitation.dagger.FusedView``: the daemon's network on the
same frame). With both, the gaze student minus the fixed student, paired, is printed too.
``--hold-camera`` adds the gaze student once more with its pan head overruled, the camera
held ahead (its depth scan then sees what a fixed student's sees), and prints it minus the
gaze student that looks: what its looking costs or gains it, apart from how it drives.

    PYTHONPATH=. .venv/bin/python benchmarks/gaze_value.py --episodes 250 \
        --scenarios moon-crossing-3 --student-fixed fused-moon --student-gaze fused-gaze-moon

``--gif PATH`` (with both students) writes a clip of the first scenario: the episode in which
the gaze student had the nearest pedestrian in view most more often than the fixed student,
each student re-run with rendering (chase view with the view cone, grayscale, heatmap), the
gaze student above the fixed one, from ``--gif-lead`` steps before the gaze student first saw
the nearest pedestrian that the fixed one did not.

    PYTHONPATH=. .venv/bin/python benchmarks/gaze_value.py --episodes 60 \
        --scenarios moon-crossing-3 --student-fixed fused-moon --student-gaze fused-gaze-moon \
        --gif docs/gaze_students.gif   # the README's clip

Each row runs RoverEnv with the fused envs' reward constants (``RewardConfig.fused()``, so
episodes end as in RoverEnvFusedGaze) under :class:`~rover_train.wrappers.WithPanHead`,
which turns the sim's camera like the gaze env (180 deg/s servo): the teachers need no fused
image, so no daemon. Episode i of every row is ``reset(seed=--seed + i)`` (default the zoo's
evaluation seeds, ``EVAL_SEED_BASE``: no training uses them) and ends at the first goal, a
termination or ``--max-steps`` (600, the zoo's). Columns, with 90 % intervals over episodes:

- success: share of episodes that reached the goal (Wilson);
- ped. collisions: share of episodes with rover-pedestrian contact (``info
  ["pedestrian_collision"]``, either way round; Wilson);
- intrusion: share of steps with a pedestrian within 1.2 m (bootstrap over episodes);
- nearest in view: share of steps with the nearest pedestrian inside the camera's
  horizontal field of view within 10 m (``info["nearest_pedestrian_in_view"]``, as the
  fused envs report it; bootstrap over episodes);
- time to goal: mean simulated seconds of the successful episodes (bootstrap).

Under each scenario's table: the gaze teacher minus the fixed teacher, paired on the same
episodes (bootstrap over episodes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.machine import cpu_name  # noqa: E402
from fused_image import FUSED_SIZE  # noqa: E402
from rover_env import RoverEnv  # noqa: E402
from rover_env.gaze_discrete_env import N_PAN_MOVES  # noqa: E402
from rover_env.reward import RewardConfig  # noqa: E402
from rover_env.scenarios import Scenario, select_scenarios  # noqa: E402
from rover_train.evaluate import EpisodeResult, run_episode  # noqa: E402
from rover_train.imitation.expert import MANNERS, ExpertConfig, PlannerExpert  # noqa: E402
from rover_train.suite import wilson_interval  # noqa: E402
from rover_train.wrappers import WithPanHead, WithSeedTable  # noqa: E402
from rover_train.zoo import EVAL_MAX_STEPS, EVAL_SEED_BASE  # noqa: E402

DEFAULT_SCENARIOS = "moon-crossing-3,inspect-crowd-3"
DEFAULT_EPISODES = 100
CONFIDENCE = 0.90
Z = 1.6449  # two-sided 90 % normal quantile
BOOTSTRAP = 2000  # resamples of the episodes
TEACHERS: dict[str, dict[str, str]] = {
    "fixed teacher": {"sees": "camera", "gaze": "fixed"},
    "gaze teacher": {"sees": "camera", "gaze": "active"},
    "all-seeing teacher": {"sees": "all", "gaze": "fixed"},
}
COLUMNS = ("row", "episodes", "success", "ped. collisions", "intrusion", "nearest in view",
           "time to goal (s)")  # fmt: skip


@dataclass
class Episode:
    """One episode of one row: the evaluation's result and the in-view count."""

    result: EpisodeResult
    in_view_steps: int


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
            out.append(Episode(result, head.nearest_in_view_steps))
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
    often than the fixed student, among those the gaze student finished at the goal."""
    gaze, fixed = results[students["gaze student"]], results[students["fixed student"]]
    gain = [g.in_view_steps / max(g.result.steps, 1) - f.in_view_steps / max(f.result.steps, 1)
            if g.result.success else -math.inf for g, f in zip(gaze, fixed, strict=True)]
    return int(np.argmax(gain))


def write_clip(scenario: Scenario, students: dict[str, tuple[Path, bool]], seed: int,
               max_steps: int, path: Path, lead: int, length: int) -> str:  # fmt: skip
    """Re-run episode ``seed`` for each student with rendering and write the gaze student's
    frames above the fixed one's (every other step: real time). Returns a line saying what."""
    import cv2

    from benchmarks.gaze_crossing import video_frame, write_gif

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
def bootstrap(stat: Callable[[np.ndarray], np.ndarray], n: int, seed: int = 0) -> np.ndarray:
    """``stat`` of ``BOOTSTRAP`` resamples of ``n`` episodes (its argument: (B, n) indices)."""
    idx = np.random.default_rng(seed).integers(0, n, (BOOTSTRAP, n))
    return stat(idx)


def percentile_interval(samples: np.ndarray) -> tuple[float, float]:
    a = (1.0 - CONFIDENCE) / 2 * 100
    finite = samples[np.isfinite(samples)]
    if len(finite) == 0:
        return math.nan, math.nan
    lo, hi = np.percentile(finite, [a, 100 - a])
    return float(lo), float(hi)


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
    return {
        "episodes": n,
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


# --- table ----------------------------------------------------------------------------------
def _pct(v: list[float] | None, digits: int = 0) -> str:
    if v is None:
        return "n/a"
    value, lo, hi = (100 * x for x in v)
    return f"{value:.{digits}f} % [{lo:.{digits}f}-{hi:.{digits}f}]"


def _num(v: list[float] | None) -> str:
    if v is None:
        return "n/a"
    return f"{v[0]:.1f} [{v[1]:.1f}-{v[2]:.1f}]"


def format_table(rows: list[tuple[str, dict[str, Any]]]) -> str:
    cells = [list(COLUMNS)]
    for label, s in rows:
        cells.append([
            label, str(s["episodes"]), _pct(s["success"]), _pct(s["pedestrian_collisions"]),
            _pct(s["intrusion"], 1), _pct(s["nearest_in_view"], 1), _num(s["time_to_goal_s"]),
        ])  # fmt: skip
    lines = ["| " + " | ".join(cells[0]) + " |", "|---|" + "---:|" * (len(COLUMNS) - 1)]
    lines += ["| " + " | ".join(row) + " |" for row in cells[1:]]
    return "\n".join(lines)


def format_difference(d: dict[str, list[float]], who: str = "teacher",
                      rows: tuple[str, str] = ("gaze", "fixed")) -> str:  # fmt: skip
    def pts(v: list[float]) -> str:
        return f"{100 * v[0]:+.1f} points [{100 * v[1]:+.1f}, {100 * v[2]:+.1f}]"

    return (f"{rows[0]} {who} - {rows[1]} {who} (paired): success {pts(d['success'])}, "
            f"ped. collisions {pts(d['pedestrian_collisions'])}, nearest in view "
            f"{pts(d['nearest_in_view'])}")  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, help="per row")
    p.add_argument("--seed", type=int, default=EVAL_SEED_BASE, help="episode i uses seed + i")
    p.add_argument("--max-steps", type=int, default=EVAL_MAX_STEPS)
    p.add_argument(
        "--scenarios",
        default=DEFAULT_SCENARIOS,
        help="scenario names (rover_env.scenarios), separated by commas",
    )
    p.add_argument(
        "--manners",
        choices=sorted(MANNERS),
        default="polite",
        help="the teachers' pedestrian terms (polite: the fused entries' teacher)",
    )
    p.add_argument("--student-fixed", type=student_path, metavar="ENTRY|FILE",
                   help="a fused zoo student (camera kept ahead): an entry's name or a file")
    p.add_argument("--student-gaze", type=student_path, metavar="ENTRY|FILE",
                   help="a gaze zoo student (3-value actions): an entry's name or a file")
    p.add_argument("--hold-camera", action="store_true",
                   help="also the gaze student with its camera held ahead (pan head overruled)")
    p.add_argument("--json", type=Path, help="write the rows and differences here")
    p.add_argument("--table", action="store_true",
                   help="every row through the seed's Discrete(180) table (the teachers "
                        "labelling its nearest action); students must be discrete ones")
    p.add_argument("--gif", type=Path, help="write a clip of both students (give both)")
    p.add_argument("--gif-lead", type=int, default=20,
                   help="clip steps before the gaze student first sees what the fixed one does not")
    p.add_argument("--gif-steps", type=int, default=80, help="clip length in steps")
    args = p.parse_args(argv)
    if args.episodes < 2 or args.max_steps < 1:
        p.error("--episodes must be at least 2 and --max-steps at least 1")
    if args.hold_camera and args.student_gaze is None:
        p.error("--hold-camera overrules a gaze student's pan: give --student-gaze too")
    if args.gif is not None and (args.student_gaze is None or args.student_fixed is None):
        p.error("--gif shows both students: give --student-fixed and --student-gaze")
    if args.gif is not None and args.table:
        p.error("--gif shows the continuous students: drop --table")
    try:
        scenarios = select_scenarios(args.scenarios)
    except ValueError as exc:
        p.error(f"--scenarios: {exc}")
    last = args.seed + args.episodes - 1
    table = ", through the seed's Discrete(180) table" if args.table else ""
    print(f"gaze_value: {args.episodes} episodes a row (seeds {args.seed}..{last}, at most "
          f"{args.max_steps} steps), {args.manners} teachers{table}; CPU {cpu_name()}")  # fmt: skip
    report: dict[str, Any] = {"args": {k: str(v) for k, v in vars(args).items()}, "scenarios": {}}
    t0 = time.monotonic()
    for scenario in scenarios:
        results: dict[str, list[Episode]] = {}
        for label, fields in TEACHERS.items():
            config = ExpertConfig.with_manners(args.manners, **fields)

            def teacher(env: Any, world: str = scenario.world,
                        config: ExpertConfig = config) -> Any:  # fmt: skip
                return teacher_act(env, world, config)

            results[label] = run_row(scenario, label, teacher, args.episodes, args.seed,
                                     args.max_steps, table=args.table)  # fmt: skip
        students = {}
        for label, path, gaze, hold in (
            ("fixed student", args.student_fixed, False, False),
            ("gaze student", args.student_gaze, True, False),
            (HELD_ROW, args.student_gaze if args.hold_camera else None, True, True),
        ):
            if path is not None:
                students[label] = f"{label} ({path.name})"
                results[students[label]] = run_row(
                    scenario, label,
                    lambda _env, path=path, gaze=gaze, hold=hold: student_act(
                        path, gaze, hold, args.table),
                    args.episodes, args.seed, args.max_steps, fused_view=True, table=args.table,
                )  # fmt: skip
        rows = [(label, summarise(eps)) for label, eps in results.items()]
        diff = paired_difference(results["gaze teacher"], results["fixed teacher"])
        print(f"\n{scenario.name}\n")
        print(format_table(rows))
        print("\n" + format_difference(diff))
        student_diff = held_diff = None
        if "fixed student" in students and "gaze student" in students:
            student_diff = paired_difference(results[students["gaze student"]],
                                             results[students["fixed student"]])  # fmt: skip
            print(format_difference(student_diff, "student"))
        if HELD_ROW in students:
            held_diff = paired_difference(results[students[HELD_ROW]],
                                          results[students["gaze student"]])  # fmt: skip
            print(format_difference(held_diff, "student", ("held ahead", "looking")))
        report["scenarios"][scenario.name] = {
            "rows": dict(rows), "gaze_minus_fixed": diff,
            "gaze_student_minus_fixed_student": student_diff,
            "held_camera_minus_looking": held_diff,
            "episodes": {k: [dataclasses.asdict(e.result) | {"in_view_steps": e.in_view_steps}
                             for e in v] for k, v in results.items()},
        }  # fmt: skip
        if args.gif is not None and scenario is scenarios[0]:
            k = clip_episode(results, students)
            print(write_clip(scenario, {"gaze student": (args.student_gaze, True),
                                        "fixed student": (args.student_fixed, False)},
                             args.seed + k, args.max_steps, args.gif, args.gif_lead,
                             args.gif_steps))  # fmt: skip
    print(f"\n{time.monotonic() - t0:.0f} s wall")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
