"""Looking learnt from the reward against its fixed twin: the zoo's RL pair on the same episodes.

    nice -n 5 .venv/bin/python -m benchmarks.looking_rl              # RESULTS.md's table
    .venv/bin/python -m benchmarks.looking_rl --rows inspect-crowd-3@100000:4 \\
        --record runs/looking_rl/smoke.json                            # a smoke run

Run from the repository root. The pair is ``rl-fused-gaze-inspect`` (PPO with a drive head and
a pan head on RoverEnvFusedGaze) and ``rl-fused-inspect-twin`` (the same recipe, the camera
fixed ahead on RoverEnvFused): ``--looking`` and ``--fixed`` take two other RL entries.

Each row, ``SCENARIO@SEED:EPISODES`` (a name of ``rover_env.scenarios``: the suite's or
``LOOKING_SCENARIOS``), runs ``rover-eval ENTRY --pedestrian-mode MODE --n-pedestrians N
--episodes E --seed SEED --dump FILE --json`` for both entries at once, each under its own
``rover-pair --slots 1`` (one daemon each), so episode i of both is ``reset(seed=SEED + i)``
in the entries' world, and each entry acts as ``zoo.load`` makes it act (sampling its policy,
seeded, behind its collision shield), except that a shielded entry keeps the berth from people
its recipe trained behind (``--person-margin 0.3``): the pair is compared as trained, while the
zoo ships both with a wider berth (``DRIVE_PERSON_MARGIN_M``, measured by
``benchmarks.contact_table``). The episodes' results and the logs go to ``--logs``
(default ``runs/looking_rl/``).

Columns: each agent's success / episodes with a person touched, and looking minus fixed in
points on the same episodes, with 90 % paired bootstrap intervals over episodes
(``rover_train.imitation.gaze_value``'s). The issue's target for a looking preset: +10
points success, or at most half the fixed twin's episodes with a person touched, the interval
clear of 0. Each row goes to the record (``--record``, default
``benchmarks/records/looking_rl.json``) when done, replacing a row of the same scenario and
seeds; rows there are skipped unless ``--redo``, so a stopped run resumes.
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
from benchmarks.machine import cpu_description
from benchmarks.record_file import read_record, save_record
from rover_train import zoo
from rover_train.evaluate import EpisodeResult
from rover_train.looking_pair import COLUMNS, ROWS, TITLE, Row, parse_row, row_cells
from rover_train.shield import ShieldConfig
from rover_train.zoo.registry import LOOKING_RL_PAIR

RECORD = Path("benchmarks/records/looking_rl.json")
LOGS = Path("runs/looking_rl")
LOOKING, FIXED = LOOKING_RL_PAIR
TRAINED_PERSON_MARGIN_M = ShieldConfig().person_margin_m
"""The shield's berth from people that the pair's recipe trains behind, which the pair is
compared at."""


def run_pair(row: Row, entries: tuple[str, str], logs: Path) -> list[list[EpisodeResult]]:
    """Both entries on ``row``'s episodes at once; RuntimeError naming the log that failed."""
    wrong = [e for e in entries if zoo.ENTRIES[e].world != row.scenario.world]
    if wrong:
        raise ValueError(f"{', '.join(wrong)} drive another world than the row "
                         f"{row.scenario.name}")  # fmt: skip
    logs.mkdir(parents=True, exist_ok=True)
    procs = []
    try:
        for i, entry in enumerate(entries):
            stem = f"{entry}-{row.scenario.name}-{row.seed}-e{row.episodes}"
            dump, log = logs / f"{stem}.json", logs / f"{stem}.log"
            dump.unlink(missing_ok=True)
            sc = row.scenario
            flags = ["--pedestrian-mode", sc.mode, "--n-pedestrians", str(sc.n_pedestrians),
                     "--episodes", str(row.episodes), "--seed", str(row.seed)]  # fmt: skip
            if zoo.ENTRIES[entry].shield:
                flags += ["--person-margin", str(TRAINED_PERSON_MARGIN_M)]
            cmd = eval_command(entry, flags, dump, f"look_{os.getpid()}_{i}", quiet_daemon=True)
            print(f"[{now()}] {shlex.join(cmd)}", flush=True)
            with log.open("w") as out:
                proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
            procs.append((proc, dump, log))
        return [dumped_episodes(proc.wait(), dump, log, row.episodes) for proc, dump, log in procs]
    finally:  # one failed or we were stopped: rover-pair stops its daemon on SIGTERM
        for proc, _, _ in procs:
            if proc.poll() is None:
                proc.terminate()
                proc.wait()


def load_record(path: Path) -> dict[str, Any]:
    return read_record(path, {"title": TITLE, "columns": COLUMNS, "rows": []})


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="The zoo's looking RL entry against its fixed "
                                            "twin, paired on the same episodes")  # fmt: skip
    p.add_argument("--looking", default=LOOKING, help=f"the looking entry (default {LOOKING})")
    p.add_argument("--fixed", default=FIXED, help=f"its fixed twin (default {FIXED})")
    p.add_argument(
        "--rows",
        default=",".join(ROWS),
        help="SCENARIO@SEED:EPISODES, separated by commas (default RESULTS.md's)",
    )
    p.add_argument("--record", type=Path, default=RECORD, help=f"default {RECORD}")
    p.add_argument("--logs", type=Path, default=LOGS, help=f"episode dumps (default {LOGS})")
    p.add_argument("--redo", action="store_true", help="run rows already in the record again")
    args = p.parse_args(argv)
    for entry in (args.looking, args.fixed):
        if entry not in zoo.names() or zoo.ENTRIES[entry].trainer != zoo.RL:
            p.error(
                f"{entry}: not a shipped RL zoo entry (those: "
                f"{', '.join(n for n in zoo.names() if zoo.ENTRIES[n].trainer == zoo.RL)})"
            )
    try:
        rows = [parse_row(r) for r in args.rows.split(",") if r.strip()]
    except ValueError as exc:
        p.error(f"--rows: {exc}")
    for row in rows:
        key = [row.label, row.episodes, row.seeds]
        if not args.redo and any(r[:3] == key for r in load_record(args.record)["rows"]):
            print(f"[{now()}] {row.scenario.name} {row.seeds}: in the record, skipped")
            continue
        t0 = time.monotonic()
        looking, fixed = run_pair(row, (args.looking, args.fixed), args.logs)
        cells = row_cells(row, looking, fixed)
        record = load_record(args.record)
        record["rows"] = [r for r in record["rows"] if r[:3] != key] + [cells]
        order = {r.label: i for i, r in enumerate(map(parse_row, ROWS))}
        record["rows"].sort(key=lambda r: (order.get(r[0], len(order)), r[2]))
        record.update(title=TITLE, columns=COLUMNS, cpu=cpu_description(),
                      date=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d"),
                      command=f".venv/bin/python -m benchmarks.looking_rl --looking "
                              f"{args.looking} --fixed {args.fixed}")  # fmt: skip
        save_record(args.record, record)
        print(
            f"[{now()}] {' | '.join(map(str, cells))} ({(time.monotonic() - t0) / 60:.1f} min)",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
