"""Where a camera agent's pedestrian contacts come from: for each episode's first contact, was
the person touched ever in the camera's view before it, and where were they first seen?

    rover-pair --slots 1 -- .venv/bin/python -m benchmarks.contact_origins \\
        runs/demo-shield-inspect/checkpoints/ppo_401408_steps.zip --env fused \\
        --pedestrian-mode blind-crossing --n-pedestrians 3 --episodes 600 --label "fixed"

A contact with a person never in a fixed camera's view is what looking could ever win; one
with a person seen in good time is the driving's. The agent is a rover-train model driven as
trained (``rover_train.evaluate.load_policy``: its waypoint, table and shield; actions
sampled, each draw seeded by ``--seed`` and the observation, as rover-eval ``--sample``).
Episode i is rover-eval's (``rover_train.evaluate.run_episode`` from ``reset(seed=--seed +
i)``, ending at the goal, a termination or 600 steps). The view is the camera's each step
(``rover_train.wrappers.ContactOrigins``): ahead for RoverEnvFused, turned for the gaze env.
``--save`` puts the row in ``records/looking_contact_origins.json`` (replacing one of the
same label); render RESULTS after.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

from benchmarks.record_file import save_record
from rover_train.envs import make_env
from rover_train.evaluate import load_policy, run_episode
from rover_train.wrappers import ContactOrigins
from roverav_cli import EVAL_SEED_BASE

RECORD = Path(__file__).parent / "records" / "looking_contact_origins.json"
MAX_STEPS = 600


def run(model: Path, env_kind: str, world: str, mode: str, people: int, episodes: int,
        seed: int) -> dict[str, Any]:  # fmt: skip
    """The contacts' origins over ``episodes`` episodes (see the module docstring)."""
    env = ContactOrigins(make_env(env_kind, world=world, task="nav", camera_scan=True,
                                  pedestrian_mode=mode, n_pedestrians=people))  # fmt: skip
    seen_at: list[tuple[float, float]] = []
    contacts = unseen = successes = 0
    try:
        agent = load_policy(model, env, deterministic=False, seed=seed)
        for i in range(episodes):  # rover-eval's episode: the same steps, the same success
            successes += run_episode(env, agent, seed + i, MAX_STEPS, None).success
            contact = env.first_contact
            if contact is None:
                continue
            contacts += 1
            if contact.first_seen is None:
                unseen += 1
            else:
                seen_at.append(contact.first_seen)
    finally:
        env.close()
    return {
        "episodes": episodes, "success": successes, "contacts": contacts,
        "never_in_view": unseen,
        "first_seen_m_median": statistics.median(d for d, _ in seen_at) if seen_at else None,
        "first_seen_abs_bearing_deg_median": (statistics.median(abs(b) for _, b in seen_at)
                                              if seen_at else None),  # fmt: skip
    }  # fmt: skip


def row(label: str, scenario: str, seeds: str, r: dict[str, Any]) -> list[Any]:
    share = f"{100 * r['never_in_view'] / r['contacts']:.0f} %" if r["contacts"] else "—"
    where = ("—" if r["first_seen_m_median"] is None else
             f"{r['first_seen_m_median']:.1f} m, {r['first_seen_abs_bearing_deg_median']:.0f}°")
    return [label, scenario, r["episodes"], seeds, r["contacts"], r["never_in_view"], share, where]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("model", type=Path)
    p.add_argument("--env", default="fused", choices=("fused", "fused-gaze"))
    p.add_argument("--world", default="inspect")
    p.add_argument("--pedestrian-mode", default="crowd")
    p.add_argument("--n-pedestrians", type=int, default=3)
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=EVAL_SEED_BASE)
    p.add_argument("--label", default=None, help="the row's agent label (default: the model)")
    p.add_argument("--scenario", default=None, help="the row's scenario name (default: from "
                   "the world, mode and size)")
    p.add_argument("--save", action="store_true")
    args = p.parse_args()
    r = run(args.model, args.env, args.world, args.pedestrian_mode, args.n_pedestrians,
            args.episodes, args.seed)  # fmt: skip
    scenario = args.scenario or f"{args.world}-{args.pedestrian_mode}-{args.n_pedestrians}"
    seeds = f"{args.seed}..{args.seed + args.episodes - 1}"
    out = row(args.label or str(args.model), scenario, seeds, r)
    print(json.dumps({**r, "row": out}))
    if args.save:
        record = json.loads(RECORD.read_text()) if RECORD.exists() else {"rows": []}
        record["rows"] = [x for x in record.get("rows", [])
                          if (x[0], x[1], x[3]) != (out[0], out[1], out[3])] + [out]  # fmt: skip
        save_record(RECORD, record)


if __name__ == "__main__":
    main()
