"""Pedestrian contact for every zoo entry among 3 and among 10 people.

    nice -n 19 .venv/bin/python -m benchmarks.contact_table                # every entry
    nice -n 19 .venv/bin/python -m benchmarks.contact_table --entries lidar-maze,fused-maze
    nice -n 19 .venv/bin/python -m benchmarks.contact_table --episodes 4 \\
        --entries lidar-inspect --record runs/contact/smoke.json          # a smoke run

Run from the repository root (``benchmarks`` is imported as a namespace package there).
For each shipped zoo entry (``--entries``, default all, in :data:`ORDER`: the LIDAR entries, which
are fast, first) and each crowd size of :data:`PEOPLE`, ``rover-eval ENTRY --episodes N
--n-pedestrians P --seed S --dump FILE`` runs ``--episodes`` (default 200) episodes on the
zoo's evaluation seeds (``zoo.EVAL_SEED_BASE`` on): the entry's own env, world and
pedestrian mode, only the crowd size set. A fused entry needs the Active Vision daemon:
its evaluation runs under ``rover-pair --name contact_<pid> --slots 1``, which starts the
daemon on its own segment name and removes its segments when done. Each (entry, people)
row is written to the record (``--record``, default
``benchmarks/records/pedestrian_contact.json``) as soon as it is done, so a stopped run
resumes where it was: rows already there are skipped unless ``--redo``. The episodes'
results (``--dump``) and each evaluation's output go to ``--logs`` (default
``runs/contact/``).

Columns: success, the headline collision share (a collision step in the seed's sense or
any touch of a person or the scenery, what the zoo's targets count), the seed's collision
share alone, pedestrian contact with its 95 % Wilson interval, intimate-space intrusion (a
pedestrian within 0.45 m at some step), all shares of episodes, and whether the entry meets
the zoo's safety target: pedestrian contact in at most 3 % of episodes among 3 people, at most 7 %
among 10 (the point estimate; the interval says how sure that is).
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.entry_eval import dumped_episodes, eval_command, now
from benchmarks.record_file import (
    add_record_arguments,
    note_cpu,
    read_record,
    record_args,
    save_record,
)
from rover_env.pedestrians import DEFAULT_MODE
from rover_train import zoo
from rover_train.evaluate import EpisodeResult, summarise
from rover_train.suite import wilson_interval
from rover_train.zoo.registry import EVAL_SEED_BASE

RECORD = Path("benchmarks/records/pedestrian_contact.json")
LOGS = Path("runs/contact")
TITLE = "Pedestrian contact for every zoo entry"
PEOPLE = (3, 10)
TARGET = {3: 0.03, 10: 0.07}  # the zoo's safety target: most pedestrian contact, share of episodes
EPISODES = 200
# the LIDAR entries first (seconds a row), then the fused ones (the daemon's network: slow)
ORDER = (
    "lidar-inspect", "lidar-maze", "rl-lidar-inspect", "rl-lidar-maze", "rl-fused-inspect",
    "rl-fused-maze", "rl-fused-gaze-inspect", "rl-fused-inspect-twin",
    "fused-maze", "fused-inspect", "fused-moon", "discrete-inspect",
    "fused-gaze-inspect", "fused-gaze-moon", "fused-gaze-discrete-inspect",
    "fused-moon-rl", "fused-gaze-moon-rl",
)  # fmt: skip
COLUMNS = [
    "entry", "env", "world", "people", "episodes", "success %",
    "collision % (headline, contact counted)", "seed collision %",
    "pedestrian contact % [95 % interval]", "intimate intrusion %", "meets target",
    "seeds", "pedestrian mode", "wall (min)",
]  # fmt: skip
NOTES = (
    "One rover-eval run per (entry, people): the entry's own env, world and pedestrian mode "
    "(crowd unless the entry names another: pacing for lidar-maze-rl, crossing for the moon "
    "entries), only --n-pedestrians set; episode i is reset with seed 100000 + i (the zoo's "
    "evaluation seeds) and ends at the goal, a termination or 600 steps. The fused entries "
    "ran under rover-pair (the av-daemon at its default precision, one slot). "
    "Shares are of episodes. Collision % is the headline the zoo's targets count: a "
    "collision step in the seed's sense (info['collision']) or any touch of a person or the "
    "scenery (info['contact']); seed collision % is the first alone. Pedestrian contact: the "
    "rover's body touched a pedestrian (either way round), with its 95 % Wilson interval. "
    "Intimate intrusion: a pedestrian within 0.45 m at some step, centre to centre; the bodies "
    "touch first (contact episodes' closest centres were 0.42-0.64 m apart), so it counts "
    "only the deepest contacts and is no separate warning. Meets target: pedestrian "
    "contact (the point estimate) at most 3 % among 3 people (the default crowd), at most "
    "7 % among 10. The entries made for 10 people (fused-inspect-10, "
    "fused-gaze-inspect-10 and their -rl fine-tunes), retired on 2026-12-03 "
    "(rover_train.zoo.registry.RETIRED), keep their rows, last: their 3-people row is the "
    "default crowd's target (3 %), their 10-people row their own crowd's (7 %). The RL "
    "entries drive as zoo.load makes them: behind their collision shield at the entry's "
    "drive-time settings (EntrySpec.shield_settings: rl-fused-inspect and the looking pair "
    "0.6 m off a person, rl-fused-maze 0.3; on the LIDAR, rl-lidar-maze 0.15 m off every "
    "return, rl-lidar-inspect 0.15 m off walls and 0.45 m off people, told apart by the "
    "world's map); docs/decisions.md gives their rows before. Rows were written as each "
    "finished; an entry absent from the rows was not run (or failed: see errors)."
)


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="Pedestrian contact for every zoo entry among 3 and 10 people "
                    "(the zoo's safety targets), one resumable record.")  # fmt: skip
    p.add_argument("--entries", help="zoo entries, separated by commas (default: all)")
    p.add_argument(
        "--people",
        default=",".join(map(str, PEOPLE)),
        help="crowd sizes, separated by commas (default 3,10)",
    )
    add_record_arguments(p, RECORD, EPISODES)
    p.add_argument(
        "--seed",
        type=int,
        default=EVAL_SEED_BASE,
        help=f"first episode's seed (default the zoo's {EVAL_SEED_BASE})",
    )
    p.add_argument(
        "--logs",
        type=Path,
        default=LOGS,
        help=f"episode dumps and evaluation logs (default {LOGS})",
    )
    args = p.parse_args(argv)
    shipped = zoo.names()  # an entry the zoo knows but does not ship has no file to run
    names = args.entries.split(",") if args.entries else [e for e in ORDER if e in shipped]
    names += [] if args.entries else [e for e in shipped if e not in names]
    unknown = [e for e in names if e not in zoo.ENTRIES]
    if unknown:
        p.error(f"not zoo entries: {', '.join(unknown)} (known: {', '.join(zoo.ENTRIES)})")
    args.entries = names
    args.people = [int(n) for n in args.people.split(",")]
    bad = [n for n in args.people if n not in TARGET]
    if bad:
        p.error(f"--people: the targets are set for {sorted(TARGET)} only, got {bad}")
    if args.episodes < 1:
        p.error("--episodes must be at least 1")
    return args


def load_record(path: Path) -> dict[str, Any]:
    return read_record(path, {"title": TITLE, "command": "", "cpu": "", "date": "",
                              "columns": COLUMNS, "rows": [], "notes": NOTES})  # fmt: skip


def _pct(share: float) -> float:
    return round(100.0 * share, 1)


def row_for(entry: str, people: int, episodes: int, seed: int, results: list[EpisodeResult],
            wall_s: float) -> list[Any]:  # fmt: skip
    spec = zoo.ENTRIES[entry]
    s = summarise(results)
    n = len(results)
    contacts = sum(r.pedestrian_contact for r in results)
    lo, hi = wilson_interval(contacts, n)
    contact = s["pedestrian_contact_rate"]
    return [
        entry, spec.kind, spec.world, people, n, _pct(s["success_rate"]),
        _pct(s["collision_rate"]), _pct(s["seed_collision_rate"]),
        f"{_pct(contact)} [{_pct(lo)}, {_pct(hi)}]", _pct(s["intimate_intrusion_rate"]),
        "yes" if contact <= TARGET[people] + 1e-12 else "no", f"{seed}..{seed + episodes - 1}",
        spec.env_kwargs.get("pedestrian_mode", DEFAULT_MODE), round(wall_s / 60.0, 1),
    ]  # fmt: skip


def run_row(entry: str, people: int, args: argparse.Namespace) -> tuple[list[Any] | None, str]:
    """One (entry, people) evaluation: (its row, "") or (None, what went wrong)."""
    args.logs.mkdir(parents=True, exist_ok=True)
    stem = f"{entry}-p{people}-e{args.episodes}"
    dump, log = args.logs / f"{stem}.json", args.logs / f"{stem}.log"
    dump.unlink(missing_ok=True)
    flags = ["--episodes", str(args.episodes), "--n-pedestrians", str(people), "--seed",
             str(args.seed)]  # fmt: skip
    cmd = eval_command(entry, flags, dump, f"contact_{os.getpid()}")
    print(f"[{now()}] {entry}, {people} people: {shlex.join(cmd)}", flush=True)
    t0 = time.monotonic()
    with log.open("w") as out:
        rc = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, check=False).returncode
    wall = time.monotonic() - t0
    try:
        results = dumped_episodes(rc, dump, log, args.episodes)
    except RuntimeError as exc:
        return None, f"{exc} (after {wall:.0f} s)"
    return row_for(entry, people, args.episodes, args.seed, results, wall), ""




def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    given = sys.argv[1:] if argv is None else argv
    command = shlex.join([".venv/bin/python", "-m", "benchmarks.contact_table",
                          *record_args(given)])  # fmt: skip
    done = {(row[0], row[3]) for row in load_record(args.record)["rows"]}
    failed = 0
    for entry in args.entries:
        for people in args.people:
            if (entry, people) in done and not args.redo:
                print(f"[{now()}] {entry}, {people} people: in the record, skipped", flush=True)
                continue
            row, error = run_row(entry, people, args)
            record = load_record(args.record)
            record.update(title=TITLE, command=command, columns=COLUMNS, notes=NOTES,
                          date=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d"))  # fmt: skip
            errors = {k: v for k, v in record.pop("errors", {}).items()
                      if k != f"{entry}/{people}"}  # fmt: skip
            if row is None:
                failed += 1
                errors[f"{entry}/{people}"] = error
                print(f"[{now()}] {entry}, {people} people: FAILED: {error}", flush=True)
            else:
                record["rows"] = [r for r in record["rows"] if (r[0], r[3]) != (entry, people)]
                record["rows"].append(row)
                rank = {e: i for i, e in enumerate(dict.fromkeys((*ORDER, *zoo.ENTRIES)))}
                record["rows"].sort(key=lambda r: (rank.get(r[0], len(rank)), r[3]))
                note_cpu(record, f"{entry}@{people}", [f"{r[0]}@{r[3]}" for r in record["rows"]])
                cells = zip(COLUMNS[4:], row[4:], strict=True)
                print(
                    f"[{now()}] {entry}, {people} people: "
                    + ", ".join(f"{c} {v}" for c, v in cells),
                    flush=True,
                )
            if errors:
                record["errors"] = errors
            save_record(args.record, record)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
