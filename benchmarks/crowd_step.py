"""Crowd models compared: cost per step for 20 agents, determinism, obstacles.

One scene for every model: 20 agents in a 12 x 12 m square with two 1 x 5 m walls, starts
1 m apart and goals drawn from one seed, 0.05 s steps (PySocialForce: its own fixed step),
200 steps timed after one untimed step. Determinism: the scene run twice, final positions
compared bit for bit. Licence: the wheel's metadata.

Candidates from the package lists: ``pyrvo`` (ORCA, RVO2 bindings), ``jupedsim`` (its
collision-free speed model and its social force model), ``PySocialForce`` (numba) and
``ir-sim`` (a whole robot simulator; its ORCA behaviour is ``pyrvo``). None is a dependency
of roverav: install them into a folder of their own without their dependencies (so that
roverav's numpy stays the one imported; add any other dependency a candidate asks for, e.g.
shapely for jupedsim) and put that folder on ``PYTHONPATH``,

    .venv/bin/pip install --no-deps --target /tmp/crowdsite pyrvo jupedsim pysocialforce shapely
    PYTHONPATH=/tmp/crowdsite .venv/bin/python -m benchmarks.crowd_step

Packages that do not import are reported as such; roverav's own ``rover_env.crowd`` (numba,
with routes on a grid, solid bodies and the rover) always runs.
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
import time
from collections.abc import Callable

import numpy as np

N, DT, STEPS = 20, 0.05, 200
WALLS = ((-2.5, -1.5, -2.5, 2.5), (1.5, 2.5, -2.5, 2.5))  # x0, x1, y0, y1
Result = tuple[float, np.ndarray]  # (seconds per step, final positions)


def scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(starts, goals) (N, 2): 1 m apart, 0.5 m clear of the walls."""
    rng = np.random.default_rng(seed)

    def free(p: np.ndarray) -> bool:
        return not any(x0 - 0.5 <= p[0] <= x1 + 0.5 and y0 - 0.5 <= p[1] <= y1 + 0.5
                       for x0, x1, y0, y1 in WALLS)  # fmt: skip

    out = []
    for _ in range(2):
        pts: list[np.ndarray] = []
        while len(pts) < N:
            p = rng.uniform(-5.5, 5.5, 2)
            if free(p) and all(np.hypot(*(p - q)) >= 1.0 for q in pts):
                pts.append(p)
        out.append(np.array(pts))
    return out[0], out[1]


def run_pyrvo() -> Result:
    import pyrvo

    start, goal = scene()
    sim = pyrvo.RVOSimulator(DT, 2.0, 10, 2.0, 1.0, 0.3, 1.5)
    for p in start:
        sim.add_agent((float(p[0]), float(p[1])))
    for x0, x1, y0, y1 in WALLS:
        sim.add_obstacle([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
    sim.process_obstacles()

    def step() -> None:
        for i in range(N):
            p = sim.get_agent_position(i)
            d = goal[i] - (p.x, p.y)
            v = d / max(float(np.hypot(*d)), 1e-9) * min(1.3, float(np.hypot(*d)))
            sim.set_agent_pref_velocity(i, (float(v[0]), float(v[1])))
        sim.do_step()

    step()
    t0 = time.perf_counter()
    for _ in range(STEPS):
        step()
    el = (time.perf_counter() - t0) / STEPS
    pos = np.array([(sim.get_agent_position(i).x, sim.get_agent_position(i).y) for i in range(N)])
    return el, pos


def run_jupedsim(model_name: str) -> Result:
    import jupedsim as jps
    import shapely

    start, goal = scene()
    area = shapely.Polygon([(-6, -6), (6, -6), (6, 6), (-6, 6)])
    for x0, x1, y0, y1 in WALLS:
        area = area.difference(shapely.box(x0, y0, x1, y1))
    sim = jps.Simulation(model=getattr(jps, model_name)(), geometry=area, dt=DT)
    params = getattr(jps, model_name + "AgentParameters")
    for p, g in zip(start, goal, strict=True):
        stage = sim.add_waypoint_stage((float(g[0]), float(g[1])), 0.3)
        journey = sim.add_journey(jps.JourneyDescription([stage]))
        sim.add_agent(params(journey_id=journey, stage_id=stage,
                             position=(float(p[0]), float(p[1]))))  # fmt: skip
    sim.iterate()
    t0 = time.perf_counter()
    for _ in range(STEPS):
        sim.iterate()
    el = (time.perf_counter() - t0) / STEPS
    return el, np.array([a.position for a in sim.agents()])


def run_pysocialforce() -> Result:
    cwd = os.getcwd()
    os.chdir(tempfile.mkdtemp())  # its logger opens ./file.log on import
    try:
        import pysocialforce as psf
    finally:
        os.chdir(cwd)

    logging.disable(logging.CRITICAL)  # it logs numba's compilation at DEBUG
    start, goal = scene()
    state = np.zeros((N, 6))
    state[:, :2], state[:, 4:6] = start, goal
    lines = []
    for x0, x1, y0, y1 in WALLS:
        lines += [(x0, x1, y0, y0), (x0, x1, y1, y1), (x0, x0, y0, y1), (x1, x1, y0, y1)]
    sim = psf.Simulator(state, groups=None, obstacles=lines)
    sim.step(1)  # numba compiles here (seconds)
    t0 = time.perf_counter()
    sim.step(STEPS)
    el = (time.perf_counter() - t0) / STEPS
    return el, sim.peds.state[:, :2].copy()


def run_roverav() -> Result:
    from rover_env.crowd import CROWD_DT, Crowd
    from rover_env.worlds import make_world

    crowd = Crowd(make_world("moon"), N)  # moon's pedestrian area (12 x 12 m, 35 rocks)
    crowd.reset(np.random.default_rng(0), (0.0, 0.0))
    for _ in range(100):  # warm the route cache
        crowd.advance(CROWD_DT, (0.0, 0.0))
    t0 = time.perf_counter()
    for _ in range(STEPS):
        crowd.advance(CROWD_DT, (0.0, 0.0))
    return (time.perf_counter() - t0) / STEPS, crowd.pos.copy()


CANDIDATES: dict[str, tuple[str, Callable[[], Result], str, str]] = {
    # name: (package, run, obstacles, licence)
    "pyrvo (ORCA)": ("pyrvo", run_pyrvo, "polygons", "not declared (RVO2: Apache-2.0)"),
    "jupedsim CollisionFreeSpeedModel": (
        "jupedsim", lambda: run_jupedsim("CollisionFreeSpeedModel"),
        "walkable polygon (shapely)", "LGPL-3.0+"),
    "jupedsim SocialForceModel": (
        "jupedsim", lambda: run_jupedsim("SocialForceModel"),
        "walkable polygon (shapely)", "LGPL-3.0+"),
    "PySocialForce": ("pysocialforce", run_pysocialforce, "line segments", "MIT"),
    "roverav rover_env.crowd": ("numba", run_roverav, "world footprints, grid routes", "ours"),
}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.parse_args(argv)
    print(f"# {N} agents, {STEPS} steps; us per step; deterministic = two runs bit-identical")
    print()
    print("| model | us / step | deterministic | obstacles | licence |")
    print("|---|---:|---|---|---|")
    for name, (package, run, obstacles, licence) in CANDIDATES.items():
        try:
            cost, a = run()
            _, b = run()
            det = "yes" if np.array_equal(a, b) else "no"
            print(f"| {name} | {cost * 1e6:,.0f} | {det} | {obstacles} | {licence} |")
        except ImportError:
            print(f"| {name} | not installed ({package}) | | {obstacles} | {licence} |")
        except Exception as exc:  # a candidate that fails on the scene is a result too
            print(f"| {name} | failed: {type(exc).__name__}: {str(exc)[:80]} | | {obstacles} "
                  f"| {licence} |")  # fmt: skip


if __name__ == "__main__":
    main()
