"""What looking is worth to the planner expert: three teachers on the same episodes.

    .venv/bin/python -m benchmarks.gaze_value    # 100 episodes a row: ~10 min
    .venv/bin/python -m benchmarks.gaze_value --episodes 250 \
        --scenarios moon-crossing-3,inspect-crowd-3,inspect-crowd-10  # RESULTS.md's: ~20 min

(times on the shared 2-vCPU VM, one core's worth, beside other jobs).

The rows, the statistics and the clip are :mod:`rover_train.imitation.gaze_value`'s; this
script runs and prints them.

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

    .venv/bin/python -m benchmarks.gaze_value --episodes 250 \
        --scenarios moon-crossing-3 --student-fixed fused-moon --student-gaze fused-gaze-moon

``--gif PATH`` (with both students) writes a clip of the first scenario: the episode in which
the gaze student had the nearest pedestrian in view most more often than the fixed student,
each student re-run with rendering (chase view with the view cone, grayscale, heatmap), the
gaze student above the fixed one, from ``--gif-lead`` steps before the gaze student first saw
the nearest pedestrian that the fixed one did not.

    .venv/bin/python -m benchmarks.gaze_value --episodes 60 \
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
- time to goal: mean simulated seconds of the successful episodes (bootstrap);
- contacts never in view before: of the episodes with a contact, those whose first contact
  was with a person who had not been inside the row's camera view (within 10 m, a
  geometric test) at any earlier step; the others' median distance and |bearing| from the
  rover when first in view. For the fixed rows this bounds what looking could win: a
  contact with a person the fixed camera saw is one that looking elsewhere cannot prevent
  by seeing them sooner.

Under each scenario's table: the gaze teacher minus the fixed teacher, paired on the same
episodes (bootstrap over episodes).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.machine import cpu_name
from rover_env.scenarios import select_scenarios
from rover_train.imitation.expert import MANNERS
from rover_train.imitation.gaze_value import (
    TEACHERS,
    clip_episode,
    compare,
    student_path,
    write_clip,
)
from rover_train.zoo import EVAL_MAX_STEPS, EVAL_SEED_BASE

DEFAULT_SCENARIOS = "moon-crossing-3,inspect-crowd-3"
TEACHER_ROWS = tuple(TEACHERS)
DEFAULT_EPISODES = 100
COLUMNS = ("row", "episodes", "success", "ped. collisions", "intrusion", "nearest in view",
           "time to goal (s)", "contacts never in view before")  # fmt: skip


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


def _never(s: dict[str, Any]) -> str:
    """'k of m' contact episodes whose person had never been in the camera's view before,
    and where the others were first seen (median distance, median |bearing|)."""
    k, m = s["contacts_never_in_view"]
    where = s["contacts_first_seen_median"]
    seen = f"; the others first seen {where[0]:.1f} m, {where[1]:.0f}°" if where else ""
    return f"{k} of {m}{seen}" if m else "no contact"


def format_table(rows: list[tuple[str, dict[str, Any]]]) -> str:
    cells = [list(COLUMNS)]
    for label, s in rows:
        cells.append([
            label, str(s["episodes"]), _pct(s["success"]), _pct(s["pedestrian_collisions"]),
            _pct(s["intrusion"], 1), _pct(s["nearest_in_view"], 1), _num(s["time_to_goal_s"]),
            _never(s),
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
    p.add_argument("--no-all-seeing", action="store_true",
                   help="leave out the all-seeing teacher's row (the fixed and gaze rows only)")
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
        rows = TEACHER_ROWS[:2] if args.no_all_seeing else TEACHER_ROWS
        c = compare(scenario, args.episodes, args.seed, args.max_steps, args.manners,
                    args.student_fixed, args.student_gaze, args.hold_camera,
                    args.table, rows)  # fmt: skip
        print(f"\n{scenario.name}\n")
        print(format_table(c.rows))
        print("\n" + format_difference(c.gaze_minus_fixed))
        if c.student_diff is not None:
            print(format_difference(c.student_diff, "student"))
        if c.held_diff is not None:
            print(format_difference(c.held_diff, "student", ("held ahead", "looking")))
        report["scenarios"][scenario.name] = c.report()
        if args.gif is not None and scenario is scenarios[0]:
            k = clip_episode(c.results, c.students)
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
