"""The house's rules, checked by import: the product runs without the lab, packages import
only the rooms docs/architecture.md lets them, and no modules import each other in a circle."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("shm_protocol", "fused_image", "rover_env", "active_vision", "launch",
            "rover_train", "roverav_cli")  # fmt: skip
LAB = ("active_vision.training", "rover_train.imitation")

RUNTIME = f"""
import sys
import active_vision, active_vision.daemon, active_vision.perception, active_vision.backends
import rover_env, launch.run_pair, rover_train.train, rover_train.evaluate
from rover_train import zoo
agent = zoo.load("lidar-maze")
env = zoo.make_env("lidar-maze")
obs, _ = env.reset(seed=0)
agent.reset()
env.step(agent.act(obs))
env.close()
lab = sorted(m for m in sys.modules if m.startswith({LAB!r}))
print("LAB", lab)
"""


def test_the_product_runs_without_importing_the_lab() -> None:
    """The daemon, the envs, the supervisor, the trainer and an agent of zoo.load driving
    an episode: none of them imports a lab wing."""
    out = subprocess.run([sys.executable, "-c", RUNTIME], capture_output=True, text=True,
                         cwd=ROOT, timeout=300, env={"MUJOCO_GL": "egl", "PATH": "/usr/bin"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert "LAB []" in out.stdout, out.stdout


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports() -> dict[str, set[str]]:
    """Project module -> the project modules it imports (anywhere in it: module level or in
    a function, ``from pkg import module`` resolved to the module)."""
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    modules = {_module_name(p) for p in files}
    graph: dict[str, set[str]] = {}
    for path in files:
        name = _module_name(path)
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                deps.add(node.module)
                deps.update(f"{node.module}.{a.name}" for a in node.names)
        graph[name] = {d for d in deps if d in modules and d != name}
    return graph


def test_no_runtime_module_imports_a_lab_wing() -> None:
    graph = _imports()
    bad = sorted(f"{m} -> {d}" for m, deps in graph.items() if not m.startswith(LAB)
                 for d in deps if d.startswith(LAB))  # fmt: skip
    assert not bad, bad


@pytest.mark.parametrize("package, forbidden", [
    ("shm_protocol", PACKAGES[1:]),
    ("roverav_cli", PACKAGES[1:6]),  # the shared flags: shm_protocol's names only
    ("fused_image", PACKAGES[:1] + PACKAGES[2:]),
    ("rover_env", ("active_vision", "launch", "rover_train")),
    ("active_vision", ("rover_env", "launch", "rover_train")),
    ("launch", ("rover_env", "rover_train")),
])  # fmt: skip
def test_each_room_imports_only_what_it_may(package: str, forbidden: tuple[str, ...]) -> None:
    """docs/architecture.md's import table, for the product (the lab wings import the product)."""
    graph = _imports()
    bad = sorted(f"{m} -> {d}" for m, deps in graph.items()
                 if (m == package or m.startswith(package + ".")) and not m.startswith(LAB)
                 for d in deps if d.split(".")[0] in forbidden)  # fmt: skip
    assert not bad, bad


def test_no_import_circle() -> None:
    """Between modules (a package's ``__init__`` re-exporting its own modules does not
    count: that is how a package exports its API)."""
    graph = _imports()
    for m, deps in graph.items():
        graph[m] = {d for d in deps if not m or not d.startswith(m + ".")}
    seen: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        seen[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if seen.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in seen:
                found = visit(d)
                if found:
                    return found
        stack.pop()
        seen[m] = 2
        return None

    for m in sorted(graph):
        if m not in seen:
            circle = visit(m)
            assert circle is None, " -> ".join(circle)


def test_no_test_imports_a_benchmark() -> None:
    """Benchmarks are benchmarks: what a test checks lives in the package it measures."""
    bad = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])  # fmt: skip
            bad += [f"{path.relative_to(ROOT)}: {n}" for n in names
                    if n == "benchmarks" or n.startswith("benchmarks.")]  # fmt: skip
    assert not bad, bad


def test_no_benchmark_edits_sys_path() -> None:
    """Benchmarks run from the repository root as ``python -m benchmarks.NAME`` against the
    installed packages: none reaches for ``sys.path``."""
    bad = []
    for path in sorted((ROOT / "benchmarks").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and node.attr == "path"
                    and isinstance(node.value, ast.Name) and node.value.id == "sys"):  # fmt: skip
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not bad, bad
