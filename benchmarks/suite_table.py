"""The scenario suite's table in RESULTS: ``rover-eval ENTRY --suite`` for the zoo's entries.

    nice -n 19 .venv/bin/python -m benchmarks.suite_table                   # every row of PLAN
    nice -n 19 .venv/bin/python -m benchmarks.suite_table --entries fused-maze --redo
    nice -n 19 .venv/bin/python -m benchmarks.suite_table --episodes 4 \\
        --entries lidar-maze --record runs/suite/smoke.json                 # a smoke run

Run from the repository root. For each entry of :data:`PLAN` (or ``--entries``) this runs
the command a user runs, ``rover-eval ENTRY --suite [SCENARIOS] --episodes N --json``
(under ``rover-pair`` for a fused entry, which starts the av-daemon at its default
precision on a segment name of its own), and writes the cells rover-eval printed
(:func:`rover_train.suite.format_suite_row`) to the record, so RESULTS shows what the
command prints, to the digit. Each entry's rows are saved as soon as it is done, so a
stopped run resumes where it was: entries already in the record are skipped unless
``--redo``. Each evaluation's output goes to ``--logs`` (default ``runs/suite/``).

The fused entries other than fused-maze are measured among 3 and 10 people, in their own
world and pedestrian mode, by ``benchmarks.contact_table`` on the same seeds; the suite
adds the other scenarios of their world.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.record_file import (
    add_record_arguments,
    note_cpu,
    read_record,
    record_args,
    save_record,
)
from rover_env.scenarios import SCENARIOS
from rover_train import zoo
from rover_train.suite import SUITE_COLUMNS, format_suite_row
from rover_train.zoo.registry import STUDENT_FUSED_KINDS

RECORD = Path("benchmarks/records/suite.json")
LOGS = Path("runs/suite")
TITLE = "The scenario suite, 200 episodes a scenario; 95 % Wilson intervals"
EPISODES = 200
# entry -> the --suite argument: "" is a bare --suite (every scenario of the entry's world)
PLAN = {
    "lidar-inspect": "", "lidar-maze": "", "rl-lidar-inspect": "", "rl-lidar-maze": "",
    "fused-maze": "", "rl-fused-inspect": "", "rl-fused-maze": "",
}  # fmt: skip
COLUMNS = ["entry", *SUITE_COLUMNS]
SECTION = "the-scenario-suite"
LOAD = "beside other runs (seeded episodes: load does not move them)"
NOTES = (
    "Each entry's rows are one `rover-eval ENTRY --suite --episodes 200 --json` (under "
    "rover-pair for fused-maze: the av-daemon at its default precision, which the row "
    "names, one slot; the rl-fused entries likewise), its cells as rover-eval prints them. "
    "Episode i of a scenario is reset with seed 100000 + i (the zoo's evaluation seeds) and "
    "ends at the goal, a termination or 600 steps. "
    "Collisions: episodes with a collision step in the seed's sense (the LIDAR under 0.3 m) "
    "or any touch of a person or the scenery, the headline the zoo's targets count; ped. "
    "contact (with its 95 % interval) and scenery contact are the touches alone; intimate: "
    "a pedestrian within 0.45 m at some step; intrusion: share of steps with a pedestrian "
    "within 1.2 m. The rl-fused entries sample their policy (a draw seeded by the "
    "observation), the others take its most likely action. Targets at the default density "
    "(3 people): lidar-inspect ≥ 90 / ≤ 10, lidar-maze ≥ 85 / ≤ 15, fused-maze ≥ 70 / ≤ 20, the "
    "rl-fused entries ≥ 90 / ≤ 10. The other fused entries among 3 and 10 "
    "people: [pedestrian contact](#pedestrian-contact-for-every-zoo-entry)."
)


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="The scenario suite's table: rover-eval --suite for the zoo's entries, "
                    "one resumable record.")  # fmt: skip
    p.add_argument("--entries", help="zoo entries, separated by commas (default: those of PLAN)")
    add_record_arguments(p, RECORD, EPISODES)
    p.add_argument("--logs", type=Path, default=LOGS, help=f"evaluation logs (default {LOGS})")
    args = p.parse_args(argv)
    names = args.entries.split(",") if args.entries else list(PLAN)
    unknown = [e for e in names if e not in zoo.names()]
    if unknown:
        p.error(f"not shipped zoo entries: {', '.join(unknown)} (shipped: "
                f"{', '.join(zoo.names())})")  # fmt: skip
    if args.episodes < 1:
        p.error("--episodes must be at least 1")
    args.entries = names
    return args


def eval_command(entry: str, episodes: int) -> list[str]:
    """The user's command for ``entry``'s suite rows."""
    bin_dir = Path(sys.executable).parent
    cmd = [str(bin_dir / "rover-eval"), entry, "--suite"]
    if PLAN.get(entry):
        cmd.append(PLAN[entry])
    cmd += ["--episodes", str(episodes), "--json"]
    if zoo.ENTRIES[entry].kind in STUDENT_FUSED_KINDS:
        cmd = [str(bin_dir / "rover-pair"), "--name", f"suite_{entry.replace('-', '_')}", "--",
               *cmd]  # fmt: skip
    return cmd


def user_command(entry: str, episodes: int) -> str:
    """:func:`eval_command` as a user types it (no paths, no segment name)."""
    cmd = eval_command(entry, episodes)
    if cmd[0].endswith("rover-pair"):
        cmd = ["rover-pair", *cmd[cmd.index("--"):]]
    return shlex.join([Path(cmd[0]).name if i == 0 else Path(c).name if c.startswith("/")
                       else c for i, c in enumerate(cmd)])  # fmt: skip


def suite_rows(entry: str, output: str) -> list[list[Any]]:
    """The record's rows from rover-eval's ``--json`` line (the last JSON object it printed;
    rover-pair prefixes its child's lines with ``[trainer]``)."""
    for line in reversed(output.splitlines()):
        line = line.strip().removeprefix("[trainer]").strip()
        if line.startswith("{"):
            by_scenario = json.loads(line)
            return [[entry, *format_suite_row(SCENARIOS[name], s)]
                    for name, s in by_scenario.items()]  # fmt: skip
    raise ValueError("rover-eval printed no --json line")


def run_entry(entry: str, args: argparse.Namespace) -> tuple[list[list[Any]] | None, str]:
    """One entry's suite: (its rows, "") or (None, what went wrong)."""
    args.logs.mkdir(parents=True, exist_ok=True)
    log = args.logs / f"{entry}-e{args.episodes}.log"
    cmd = eval_command(entry, args.episodes)
    print(f"[{_now()}] {entry}: {shlex.join(cmd)}", flush=True)
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    log.write_text(proc.stdout + proc.stderr)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or [""])[-1]
        return None, f"exit status {proc.returncode} after {wall:.0f} s ({log}): {last}"
    ready = re.search(r"av-daemon ready:.*? precision=(\w+)", proc.stdout + proc.stderr)
    label = f"{entry}, {ready.group(1)} daemon" if ready else entry
    if zoo.ENTRIES[entry].shield:
        label += ", shielded"  # behind the collision shield on its scan (rover_train.shield)
    try:
        return suite_rows(label, proc.stdout), ""
    except (ValueError, KeyError) as exc:
        return None, f"{exc} ({log})"


def _entry(row: list[Any]) -> str:
    """The zoo entry of a record row (a fused row's cell also names the daemon's precision)."""
    return str(row[0]).split(",")[0]


def _now() -> str:
    return dt.datetime.now(dt.UTC).strftime("%H:%M:%S")


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    given = sys.argv[1:] if argv is None else argv
    command = "\n".join([
        shlex.join([".venv/bin/python", "-m", "benchmarks.suite_table", *record_args(given)]),
        "# which runs, for each entry, the command a user runs:",
        *(user_command(entry, args.episodes) for entry in PLAN),
    ])  # fmt: skip
    empty = {"title": TITLE, "section": SECTION, "command": command, "cpu": "", "date": "",
             "load": LOAD, "columns": COLUMNS, "align": "ll" + "r" * (len(COLUMNS) - 2),
             "rows": [], "notes": NOTES}  # fmt: skip
    failed = 0
    for entry in args.entries:
        record = read_record(args.record, empty)
        if any(_entry(row) == entry for row in record["rows"]) and not args.redo:
            print(f"[{_now()}] {entry}: in the record, skipped", flush=True)
            continue
        rows, error = run_entry(entry, args)
        record = read_record(args.record, empty)
        record.update(title=TITLE, command=command, notes=NOTES)
        errors = {k: v for k, v in record.pop("errors", {}).items() if k != entry}
        if rows is None:
            failed += 1
            errors[entry] = error
            print(f"[{_now()}] {entry}: FAILED: {error}", flush=True)
        else:
            kept = [r for r in record["rows"] if _entry(r) != entry]
            order = list(PLAN) + [e for e in zoo.names() if e not in PLAN]
            record["rows"] = sorted(kept + rows, key=lambda r: order.index(_entry(r)))
            note_cpu(record, entry, [_entry(r) for r in record["rows"]])
            dates = record.setdefault("entry_dates", {})
            dates[entry] = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
            record["date"] = f"{min(dates.values())} to {max(dates.values())}"
            for row in rows:
                print(f"[{_now()}] " + " | ".join(map(str, row)), flush=True)
        if errors:
            record["errors"] = errors
        save_record(args.record, record)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
