"""Reading and writing one record of ``benchmarks/records/`` from a benchmark that fills it
row by row (a stopped run resumes from the rows already there)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from benchmarks.machine import cpu_description


def read_record(path: Path, empty: dict[str, Any]) -> dict[str, Any]:
    """The record at ``path``, or ``empty`` when there is none yet. A record of an older
    table (its columns differ from ``empty``'s) starts anew as ``empty``, keeping the README
    headline it held."""
    if not path.is_file():
        return dict(empty)
    record: dict[str, Any] = json.loads(path.read_text())
    if "columns" in empty and record.get("columns") != empty["columns"]:
        kept = {"headline": record["headline"]} if "headline" in record else {}
        return {**empty, **kept}
    return record


def save_record(path: Path, record: dict[str, Any]) -> None:
    """Write ``record`` whole: a stop mid-write leaves the last whole record."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    tmp.replace(path)


def note_cpu(record: dict[str, Any], key: str, keys: list[str]) -> None:
    """Record that the rows of ``key`` were measured on this machine, in ``row_cpus`` (row
    key to CPU, in the order of ``keys``, the record's row keys, ``ENTRY`` or ``ENTRY@PART``;
    a record that had none gives the rows measured before its one ``cpu``), and set ``cpu``
    to name each CPU with the rows measured on it, so a record filled on two machines says
    which figure came from which."""
    order = list(dict.fromkeys(keys))
    before = record.get("cpu", "")
    cpus = dict(record.get("row_cpus") or {k: before for k in order if before})
    cpus[key] = cpu_description()
    cpus = {k: cpus[k] for k in order if k in cpus}
    by_cpu: dict[str, list[str]] = {}
    for k, cpu in cpus.items():
        by_cpu.setdefault(cpu, []).append(k)
    record["row_cpus"] = cpus
    record["cpu"] = (next(iter(by_cpu)) if len(by_cpu) == 1 else
                     "; ".join(f"{cpu} ({', '.join(_shown(ks, cpus))})"
                               for cpu, ks in by_cpu.items()))  # fmt: skip


def _shown(keys: list[str], cpus: dict[str, str]) -> list[str]:
    """``keys`` as a record's CPU note names them: keys ``ENTRY@PART`` whose every part was
    measured on one CPU are named by ``ENTRY`` alone."""
    out: list[str] = []
    for key in keys:
        entry = key.split("@")[0]
        parts = {c for k, c in cpus.items() if k.split("@")[0] == entry}
        name = entry if len(parts) == 1 else key
        if name not in out:
            out.append(name)
    return out


def record_args(given: list[str], row_flags: tuple[str, ...] = ("--entries",),
                switches: tuple[str, ...] = ("--redo",)) -> list[str]:  # fmt: skip
    """A resumable benchmark's command line as its record shows it: ``row_flags`` (with
    their values) and ``switches`` only pick which rows a run refreshes, so the record's
    command leaves them out."""
    out, skip = [], False
    for arg in given:
        if skip:
            skip = False
        elif arg in row_flags:
            skip = True
        elif arg not in switches and not arg.startswith(tuple(f"{f}=" for f in row_flags)):
            out.append(arg)
    return out


def add_record_arguments(p: argparse.ArgumentParser, record: Path, episodes: int) -> None:
    """The flags every resumable table takes: ``--episodes`` a row, ``--record`` and
    ``--redo`` (run rows the record already has again)."""
    p.add_argument("--episodes", type=int, default=episodes,
                   help=f"episodes a row (default {episodes})")  # fmt: skip
    p.add_argument("--record", type=Path, default=record, help=f"the record (default {record})")
    p.add_argument("--redo", action="store_true", help="run rows the record already has again")
