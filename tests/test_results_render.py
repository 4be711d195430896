"""The results tables are rendered from benchmarks/records/: the committed RESULTS.md and
README.md match their records, a changed record is caught naming its table, and README.md
stays a manual (short, no dates)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RENDER = ROOT / "benchmarks" / "render_results.py"


def _check(root: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(RENDER), "--check", "--root", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_committed_tables_match_their_records() -> None:
    done = _check(ROOT)
    assert done.returncode == 0, done.stdout + done.stderr


def test_a_changed_record_is_a_stale_table(tmp_path: Path) -> None:
    (tmp_path / "benchmarks").mkdir()
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copy(ROOT / "benchmarks" / "RESULTS.md", tmp_path / "benchmarks" / "RESULTS.md")
    shutil.copytree(ROOT / "benchmarks" / "records", tmp_path / "benchmarks" / "records")
    assert _check(tmp_path).returncode == 0

    record_path = tmp_path / "benchmarks" / "records" / "ipc_latency.json"
    record = json.loads(record_path.read_text())
    record["rows"][0][1] = 12345  # a p50 that was never measured
    record_path.write_text(json.dumps(record))

    done = _check(tmp_path)
    assert done.returncode == 1
    assert "stale table: ipc_latency" in done.stdout
    assert "12345" in done.stdout  # the diff shows the figure


def test_a_bar_in_a_header_or_a_cell_is_refused_naming_the_record(tmp_path: Path) -> None:
    (tmp_path / "benchmarks").mkdir()
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copy(ROOT / "benchmarks" / "RESULTS.md", tmp_path / "benchmarks" / "RESULTS.md")
    shutil.copytree(ROOT / "benchmarks" / "records", tmp_path / "benchmarks" / "records")
    record_path = tmp_path / "benchmarks" / "records" / "ipc_latency.json"
    record = json.loads(record_path.read_text())
    for where in ("columns", "rows"):
        bad = json.loads(json.dumps(record))
        if where == "columns":
            bad["columns"][0] = "median |latency|"
        else:
            bad["rows"][0][0] = "a | b"
        record_path.write_text(json.dumps(bad))
        done = _check(tmp_path)
        assert done.returncode == 1
        assert "ipc_latency" in done.stdout + done.stderr
        assert "may not hold '|'" in done.stdout + done.stderr


def test_readme_is_a_short_manual_without_dates() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    assert not re.search(r"\b\d{4}-\d{2}-\d{2}\b", text)
