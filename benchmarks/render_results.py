"""Render the results tables from their records: benchmarks/records/*.json into RESULTS.md and
README.md, so that a figure lives in one place and the documents cannot drift from it.

    python benchmarks/render_results.py              # rewrite the tables in place
    python benchmarks/render_results.py --check      # exit 1, naming each stale table, with a diff
    python benchmarks/render_results.py --root DIR   # work on a copy of the repository at DIR

The record schema. One JSON object per table, ``benchmarks/records/NAME.json``; NAME is the
table's name in the markers below.

    title     str    what the table shows; rendered in bold as its caption
    section   str    the anchor of its section in benchmarks/RESULTS.md: GitHub's slug of the
                     "## " heading the table sits under (checked). A record without one is data
                     a benchmark is still writing: it is not rendered until it has one
    command   str    the command that produced the figures, several lines allowed (then
                     rendered as a bash block); left out when the table before it in the
                     section has the same command
    cpu       str    model name and instruction set, e.g. "AMD EPYC (family 25, model 1: Zen 3),
                     AVX2, FMA, no AVX-512, no VNNI; 2 vCPUs under KVM"; "not recorded" where the
                     measurement did not name it; a record whose rows came from several CPUs
                     names each with its rows (record_file.note_cpu keeps ``row_cpus`` for it)
    date      str    when, as recorded (UTC where the measurement said so)
    load      str    optional: the load average or what else ran (rendered "not recorded"
                     where absent)
    columns   [str]  the column headers
    align     str    optional: one letter a column, "l" or "r" (default: all "l")
    rows      [[str | int | float]]  the figures, a list a row; numbers render as Python's str()
                     of them, strings verbatim (inline markdown allowed, no "|")
    notes     str    a few sentences shown under the table ("" for none)
    raw       str    optional: the path of the benchmark's own --json output the rows came from
    headline  obj    optional: {"order": int, "what": str, "figure": str, "seed": str}, a row of
                     README.md's "Current figures" table (sorted by order; no dates in it), linked
                     to the record's section
Other keys are allowed and ignored (a benchmark may keep its own bookkeeping in its record).

A top-level JSON list in records/ is a benchmark's raw output (camera_scan_accuracy.json is
one): it is not a record and is not rendered.

Markers. RESULTS.md holds each record once between ``<!-- table:NAME -->`` and
``<!-- /table:NAME -->``; README.md holds ``<!-- table:current-figures -->`` ...
``<!-- /table:current-figures -->``. Everything between a pair of markers is this script's;
everything outside them is left alone. A record without markers, markers without a record,
a record under the wrong section or a malformed record is an error (exit 1).
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import sys
from pathlib import Path

README_TABLE = "current-figures"
REQUIRED = {
    "title": str,
    "command": str,
    "cpu": str,
    "date": str,
    "columns": list,
    "rows": list,
    "notes": str,
}
OPTIONAL = {"section": str, "load": str, "align": str, "raw": str, "headline": dict}
HEADLINE_KEYS = {"order": int, "what": str, "figure": str, "seed": str}
MARKER = re.compile(
    r"<!-- table:(?P<name>[\w.-]+) -->\n(?P<body>.*?)<!-- /table:(?P=name) -->\n", re.S
)
ISO_DATE = re.compile(r"\b\d{4}-\d{2}-\d{2}\b")


class RecordError(Exception):
    """A record, or the markers that place it, is not as the schema says."""


def slug(heading: str) -> str:
    """GitHub's anchor for a markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def load_records(records_dir: Path) -> dict[str, dict]:
    records: dict[str, dict] = {}
    for path in sorted(records_dir.glob("*.json")):
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise RecordError(f"{path}: not JSON: {e}") from e
        if isinstance(data, list):
            continue  # a benchmark's raw output
        if not isinstance(data, dict):
            raise RecordError(f"{path}: a record is a JSON object")
        validate(path.stem, data)
        records[path.stem] = data
    return records


def validate(name: str, rec: dict) -> None:
    for key, kind in REQUIRED.items():
        if not isinstance(rec.get(key), kind):
            raise RecordError(f"record {name}: '{key}' must be a {kind.__name__}")
    for key, kind in OPTIONAL.items():
        if key in rec and not isinstance(rec[key], kind):
            raise RecordError(f"record {name}: '{key}' must be a {kind.__name__}")
    if "headline" in rec and "section" not in rec:
        raise RecordError(f"record {name}: a headline needs a section to link to")
    width = len(rec["columns"])
    align = rec.get("align", "l" * width)
    if len(align) != width or set(align) - {"l", "r"}:
        raise RecordError(f"record {name}: 'align' needs one l or r per column ({width})")
    for column in rec["columns"]:
        if "|" in str(column) or "\n" in str(column):
            raise RecordError(f"record {name}: the header {column!r} may not hold '|' or a "
                              "newline (it would split the table's columns)")  # fmt: skip
    for i, row in enumerate(rec["rows"]):
        if not isinstance(row, list) or len(row) != width:
            raise RecordError(f"record {name}: row {i} must be a list of {width} cells")
        for cell in row:
            if isinstance(cell, bool) or not isinstance(cell, (str, int, float)):
                raise RecordError(f"record {name}: row {i}: a cell is a string or a number")
            if "|" in str(cell) or "\n" in str(cell):
                raise RecordError(f"record {name}: row {i}: a cell may not hold '|' or a newline")
    if "headline" in rec:
        head = rec["headline"]
        for key, kind in HEADLINE_KEYS.items():
            if not isinstance(head.get(key), kind):
                raise RecordError(f"record {name}: headline '{key}' must be a {kind.__name__}")
        if any(ISO_DATE.search(head[k]) for k in ("what", "figure", "seed")):
            raise RecordError(f"record {name}: the README headline may not carry a date")


def cell_text(cell: str | int | float) -> str:
    return cell if isinstance(cell, str) else str(cell)


def markdown_table(columns: list[str], rows: list[list], align: str) -> str:
    lines = ["| " + " | ".join(columns) + " |"]
    lines.append("|" + "|".join("---:" if a == "r" else "---" for a in align) + "|")
    for row in rows:
        lines.append("| " + " | ".join(cell_text(c) for c in row) + " |")
    return "\n".join(lines) + "\n"


def render_record(rec: dict, with_command: bool) -> str:
    """A paragraph (caption, conditions, command, notes), then the table; a command of several
    lines goes in a bash block between them."""
    load = rec.get("load", "not recorded")
    para = [f"**{rec['title']}.** {rec['date']}; CPU: {rec['cpu']}; load: {load}."]
    command = rec["command"].strip()
    block = ""
    if with_command:
        if "\n" in command or "`" in command:
            block = f"```bash\n{command}\n```\n\n"
        else:
            para[0] += f" Command: `{command}`"
    if rec["notes"].strip():
        para.append(rec["notes"].strip())
    align = rec.get("align", "l" * len(rec["columns"]))
    table = markdown_table(rec["columns"], rec["rows"], align)
    return "\n".join(para) + "\n\n" + block + table


def render_results(text: str, records: dict[str, dict]) -> tuple[str, dict[str, str]]:
    """RESULTS.md with every table rendered, and each table's rendered body by name."""
    seen: dict[str, str] = {}
    headings = [(m.start(), slug(m.group(1))) for m in re.finditer(r"^## (.+)$", text, re.M)]
    last_command: dict[str, str] = {}

    def section_at(pos: int) -> str:
        current = ""
        for start, anchor in headings:
            if start > pos:
                break
            current = anchor
        return current

    def replace(m: re.Match[str]) -> str:
        name = m.group("name")
        if name not in records:
            raise RecordError(f"RESULTS.md has a table '{name}' with no record {name}.json")
        if name in seen:
            raise RecordError(f"RESULTS.md places the table '{name}' twice")
        rec = records[name]
        section = section_at(m.start())
        if "section" not in rec:
            raise RecordError(f"record {name} is placed in RESULTS.md but names no section")
        if section != rec["section"]:
            raise RecordError(
                f"table '{name}' sits under #{section or '(no section)'} in RESULTS.md, "
                f"its record says #{rec['section']}"
            )
        with_command = last_command.get(section) != rec["command"]
        last_command[section] = rec["command"]
        body = render_record(rec, with_command)
        seen[name] = body
        return f"<!-- table:{name} -->\n{body}<!-- /table:{name} -->\n"

    out = MARKER.sub(replace, text)
    missing = sorted(name for name, rec in records.items() if "section" in rec and name not in seen)
    if missing:
        raise RecordError(f"records not placed in RESULTS.md: {', '.join(missing)}")
    anchors = {anchor for _, anchor in headings}
    for name, rec in records.items():
        if "section" in rec and rec["section"] not in anchors:
            raise RecordError(f"record {name}: RESULTS.md has no section #{rec['section']}")
    return out, seen


def render_readme(text: str, records: dict[str, dict]) -> tuple[str, dict[str, str]]:
    rows = []
    placed = [rec for rec in records.values() if "headline" in rec]
    for rec in sorted(placed, key=lambda rec: rec["headline"]["order"]):
        head = rec["headline"]
        link = f"[{head['what']}](benchmarks/RESULTS.md#{rec['section']})"
        rows.append([link, head["figure"], head["seed"]])
    body = markdown_table(["what", "figure", "the seed's way"], rows, "lll")
    block = f"<!-- table:{README_TABLE} -->\n{body}<!-- /table:{README_TABLE} -->\n"
    found = [m for m in MARKER.finditer(text)]
    if [m.group("name") for m in found] != [README_TABLE]:
        raise RecordError(f"README.md must hold exactly one table, '{README_TABLE}'")
    m = found[0]
    return text[: m.start()] + block + text[m.end() :], {README_TABLE: body}


def blocks(text: str) -> dict[str, str]:
    return {m.group("name"): m.group("body") for m in MARKER.finditer(text)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if stale")
    parser.add_argument(
        "--root",
        type=Path,
        default=Path(__file__).resolve().parents[1],
        help="the repository (default: the one holding this script)",
    )
    args = parser.parse_args(argv)
    root: Path = args.root
    results_path = root / "benchmarks" / "RESULTS.md"
    readme_path = root / "README.md"
    try:
        records = load_records(root / "benchmarks" / "records")
        results_old = results_path.read_text()
        readme_old = readme_path.read_text()
        results_new, _ = render_results(results_old, records)
        readme_new, _ = render_readme(readme_old, records)
    except (RecordError, OSError) as e:
        print(f"render_results: {e}", file=sys.stderr)
        return 1
    unplaced = sorted(name for name, rec in records.items() if "section" not in rec)
    unplaced_note = f" (not placed yet, no section: {', '.join(unplaced)})" if unplaced else ""
    stale = []
    for path, old, new in (
        (results_path, results_old, results_new),
        (readme_path, readme_old, readme_new),
    ):
        if old == new:
            continue
        old_blocks, new_blocks = blocks(old), blocks(new)
        for name, body in new_blocks.items():
            if old_blocks.get(name) != body:
                stale.append(name)
                if args.check:
                    print(f"stale table: {name} in {path.relative_to(root)}")
                    diff = difflib.unified_diff(
                        (old_blocks.get(name) or "").splitlines(keepends=True),
                        body.splitlines(keepends=True),
                        f"{path.name} (committed) table:{name}",
                        f"{path.name} (rendered from records/{name}.json) table:{name}",
                    )
                    sys.stdout.writelines(diff)
        if not args.check:
            path.write_text(new)
    if args.check:
        if stale:
            names = ", ".join(stale)
            print(f"{len(stale)} stale table(s): {names}; run python benchmarks/render_results.py")
            return 1
        print(f"render_results: {len(records)} records, every table current{unplaced_note}")
        return 0
    print(
        f"render_results: {len(records)} records; rewrote {', '.join(stale) or 'nothing'}"
        f"{unplaced_note}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
