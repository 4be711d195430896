"""Training success by steps: the share of each 100k steps' training episodes that reached the
goal, from a rover-train run's own episode log, as a row of RESULTS' camera-agent training
table (``records/camera_agent_training.json``).

    .venv/bin/python -m benchmarks.training_bins runs/rl-fused-maze-shield \
        --label "maze behind the shield (--shield)"            # print the row
    .venv/bin/python -m benchmarks.training_bins runs/demo/run --label "..." --save

The episode log is the newest checkpoint's (``*.state.pkl``), else ``metrics.json``'s: a run
that is still going, or was stopped, counts every episode up to its newest checkpoint. A bin
with fewer than ``--min-episodes`` episodes is shown as "—". ``--save`` puts the row in the
record (replacing a row of the same label, else after the others); render RESULTS after.
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path
from typing import Any

from benchmarks.record_file import save_record

RECORD = Path(__file__).parent / "records" / "camera_agent_training.json"
BIN_STEPS = 100_000
MIN_EPISODES = 20


def episode_log(run: Path) -> list[dict[str, Any]]:
    """The run's training episodes: its newest checkpoint's log, else metrics.json's."""
    states = sorted((run / "checkpoints").glob("*.state.pkl"),
                    key=lambda p: int(p.name.split("_")[-2]))  # fmt: skip
    if states:
        with states[-1].open("rb") as f:
            return list(pickle.load(f)["episode_log"])  # noqa: S301 - our own run's file
    metrics = run / "metrics.json"
    if metrics.is_file():
        return list(json.loads(metrics.read_text())["episode_log"])
    raise SystemExit(f"{run}: no checkpoint and no metrics.json: not a rover-train run directory")


def success_bins(episodes: list[dict[str, Any]], bins: int,
                 min_episodes: int = MIN_EPISODES) -> list[str]:  # fmt: skip
    """``bins`` cells: the success share of the episodes that ended in each 100k steps."""
    cells = []
    for k in range(bins):
        inside = [e for e in episodes if k * BIN_STEPS <= e["timestep"] < (k + 1) * BIN_STEPS]
        cells.append(f"{100 * sum(e['success'] for e in inside) / len(inside):.0f} %"
                     if len(inside) >= min_episodes else "—")  # fmt: skip
    return cells


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path, help="a rover-train run directory (--logdir)")
    p.add_argument("--label", required=True, help="the row's first cell")
    p.add_argument("--min-episodes", type=int, default=MIN_EPISODES)
    p.add_argument("--save", action="store_true", help="put the row in the record")
    args = p.parse_args(argv)
    record = json.loads(RECORD.read_text())
    row = [args.label, *success_bins(episode_log(args.run), len(record["columns"]) - 1,
                                     args.min_episodes)]  # fmt: skip
    print(" | ".join(row))
    if args.save:
        rows = [r for r in record["rows"] if r[0] != args.label]
        at = next((i for i, r in enumerate(record["rows"]) if r[0] == args.label), len(rows))
        record["rows"] = rows[:at] + [row] + rows[at:]
        save_record(RECORD, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
