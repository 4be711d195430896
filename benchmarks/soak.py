"""Chaos soak: a fused training run under rover-pair with a seeded schedule of faults.

    python -m benchmarks.soak --minutes 15 --seed 0

Runs ``rover-pair --slots S -- rover-train --env fused --timesteps N`` and, while it trains,
applies faults at times drawn from ``--seed``:

- the daemon SIGKILLed every 20-90 s (rover-pair restarts it; the envs truncate the episode
  in flight and carry on);
- once, the daemon SIGSTOPped for 5 s, then SIGCONTed;
- once, the trainer SIGTERMed (it saves; rover-pair exits), then the run is started again
  with ``rover-train --resume RUN_DIR``;
- once, the slot-0 fused segment unlinked from ``/dev/shm`` by hand while in use.

A fault waits until the run has recovered from the previous one, so each recovery time is
its own. Progress is read from the fused segments themselves (a fused frame is published
only in answer to an env step). At the end it checks that the run reached its requested
steps, that no segment of the run's name is left and no process of it is alive, and that
the final model loads and acts (``rover-eval`` for one short episode under rover-pair).

It prints a table (markdown, for ``RESULTS.md``) and writes ``soak.json`` into the run
directory. A robustness figure, not a speed figure: run it niced beside other work.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from shm_protocol import SHM_DIR, FrameReader, existing_segments, slot_name
from shm_protocol.errors import ShmError

ROOT = Path(__file__).resolve().parents[1]

KILL_GAP_S = (20.0, 90.0)
STOP_S = 5.0
POLL_S = 0.25


@dataclass
class Fault:
    kind: str
    planned_s: float
    applied_s: float | None = None
    recovered_s: float | None = None
    detail: str = ""
    count_from_s: float | None = None
    """Frames after this time (s since the start) count as recovery."""

    @property
    def recovery_s(self) -> float | None:
        if self.applied_s is None or self.recovered_s is None:
            return None
        return round(self.recovered_s - self.applied_s, 2)


def schedule(minutes: float, seed: int) -> list[Fault]:
    """The faults of one soak, in time order, drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    span = minutes * 60.0
    faults: list[Fault] = []
    t = float(rng.uniform(*KILL_GAP_S))
    while t < span - 30.0:
        faults.append(Fault("daemon SIGKILL", t))
        t += float(rng.uniform(*KILL_GAP_S))
    for kind, lo, hi in (("daemon SIGSTOP 5 s", 0.15, 0.35), ("trainer SIGTERM + resume", 0.4, 0.6),
                         ("segment unlinked", 0.7, 0.85)):  # fmt: skip
        faults.append(Fault(kind, float(rng.uniform(lo, hi)) * span))
    return sorted(faults, key=lambda f: f.planned_s)


class Pair:
    """One rover-pair run: its output goes to a log and is parsed for pids and restarts."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str]) -> None:
        self.log = log_path.open("a")
        self.daemon_pid: int | None = None
        self.trainer_pid: int | None = None
        self.restarts = 0
        self.lines: list[str] = []
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, cwd=ROOT, env=env, start_new_session=True)
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.log.write(f"{time.time():.2f} {line}")
            self.log.flush()
            self.lines.append(line)
            if m := re.search(r"daemon ready \(pid (\d+)\)", line):
                self.daemon_pid = int(m.group(1))
            if m := re.search(r"trainer started \(pid (\d+)\)", line):
                self.trainer_pid = int(m.group(1))
            if re.search(r"\brestart \d+/\d+ of the", line):
                self.restarts += 1

    def wait(self, timeout: float | None = None) -> int:
        code = self.proc.wait(timeout)
        self._thread.join(5.0)
        return code


class Progress:
    """When did a fused frame last appear on any slot (read from the segments)."""

    def __init__(self, name: str, slots: int) -> None:
        self.names = [slot_name(name, i) for i in range(slots)]
        self.last_ts = 0.0
        self.last_change = time.monotonic()

    def poll(self) -> None:
        newest = self.last_ts
        for seg in self.names:
            try:
                reader = FrameReader(seg, attach_timeout=0.0, check_pid=False)
            except (ShmError, OSError, ValueError):
                continue
            try:
                frame = reader.latest()
                if frame is not None:
                    newest = max(newest, frame.timestamp)
            except (ShmError, OSError, ValueError):
                pass
            finally:
                reader.close()
        if newest > self.last_ts:
            self.last_ts = newest
            self.last_change = time.monotonic()


def _alive(pid: int | None) -> bool:
    if pid is None:
        return False
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except (FileNotFoundError, IndexError):
        return False


def orphans(name: str, run_dir: Path) -> list[str]:
    """Processes other than this one whose command line or environment names the run."""
    found = []
    needles = (name.encode(), str(run_dir).encode())
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes()
            envb = (entry / "environ").read_bytes()
        except OSError:
            continue
        if any(n in cmd or n in envb for n in needles) and _alive(int(entry.name)):
            text = cmd.replace(b"\0", b" ").decode(errors="replace")[:80]
            found.append(f"{entry.name}: {text}")
    return found


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=15.0, help="length of the fault schedule")
    p.add_argument("--seed", type=int, default=0, help="seed of the fault schedule")
    p.add_argument("--slots", type=int, default=2, help="envs (daemon slots)")
    p.add_argument("--timesteps", type=int, default=None,
                   help="steps to train (default: minutes x 60 x --rate)")
    p.add_argument("--rate", type=float, default=40.0,
                   help="expected training steps/s under faults, to size the run")
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "soak")
    args = p.parse_args(argv)
    timesteps = args.timesteps or int(args.minutes * 60 * args.rate)
    name = f"resil_soak_{os.getpid()}"
    run_dir = args.out.resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT), MUJOCO_GL="egl", PYTHONUNBUFFERED="1")
    pair = [sys.executable, str(ROOT / "launch" / "run_pair.py"), "--name", name, "--slots",
            str(args.slots), "--daemon-arg=--threads", "--daemon-arg=1", "--"]  # fmt: skip
    trainer = [sys.executable, "-m", "rover_train.train", "--no-progress"]
    first = trainer + ["--env", "fused", "--timesteps", str(timesteps), "--n-steps", "256",
                       "--batch-size", "128", "--n-epochs", "4", "--length", "300",
                       "--checkpoint-every", "4096", "--logdir", str(run_dir)]  # fmt: skip
    resume = trainer + ["--resume", str(run_dir)]
    faults = schedule(args.minutes, args.seed)
    log_path = run_dir / "soak.log"
    print(f"soak: {timesteps} steps, {args.slots} slot(s), {len(faults)} faults over "
          f"{args.minutes:g} min (seed {args.seed}); log {log_path}", flush=True)

    quiet = Path("/tmp/roverav_quiet")
    while quiet.exists():  # someone is measuring speed: do not start a CPU-heavy run now
        print("soak: waiting for the quiet window (/tmp/roverav_quiet) to end", flush=True)
        time.sleep(10)
    t0 = time.monotonic()
    pair_runs = [Pair(pair + first, log_path, env)]
    try:
        return _soak(args, name, run_dir, env, pair, resume, faults, log_path, timesteps, t0,
                     pair_runs)  # fmt: skip
    except KeyboardInterrupt:
        print("soak: interrupted; stopping the run (rover-pair cleans up)", flush=True)
        current = pair_runs[-1]
        if current.proc.poll() is None:
            os.killpg(current.proc.pid, signal.SIGTERM)
        current.wait(180)
        return 130


def _soak(args: argparse.Namespace, name: str, run_dir: Path, env: dict[str, str],
          pair: list[str], resume: list[str], faults: list[Fault], log_path: Path,
          timesteps: int, t0: float, pair_runs: list[Pair]) -> int:  # fmt: skip
    """The fault loop and the report (see the module docstring)."""
    current = pair_runs[0]
    progress = Progress(name, args.slots)
    pending = list(faults)
    last_fault: Fault | None = None
    unlinked: str | None = None
    stop_info: dict[str, object] = {}
    trainer_fault: Fault | None = None
    hard_deadline = t0 + args.minutes * 60 * 4 + 600
    while True:
        now = time.monotonic()
        progress.poll()
        if last_fault is not None and last_fault.recovered_s is None:
            since = last_fault.count_from_s
            if since is not None and progress.last_change > t0 + since:  # frames again
                last_fault.recovered_s = progress.last_change - t0
        code = current.proc.poll()
        if code is not None:
            current.wait()
            if code == 143 and trainer_fault is not None and not stop_info:
                stop_info = {"pair_status": code}
                current = Pair(pair + resume, log_path, env)  # the same run, resumed
                pair_runs.append(current)
                trainer_fault.count_from_s = time.monotonic() - t0
                continue
            break
        if now > hard_deadline:
            print("soak: hard deadline passed; stopping the run", flush=True)
            os.killpg(current.proc.pid, signal.SIGTERM)
            current.wait(120)
            break
        recovered = last_fault is None or last_fault.recovered_s is not None
        if pending and recovered and now - t0 >= pending[0].planned_s and current.daemon_pid:
            fault = pending.pop(0)
            fault.applied_s = fault.count_from_s = time.monotonic() - t0
            if fault.kind == "daemon SIGKILL":
                fault.detail = f"pid {current.daemon_pid}"
                os.kill(current.daemon_pid, signal.SIGKILL)
            elif fault.kind.startswith("daemon SIGSTOP"):
                pid = current.daemon_pid
                os.kill(pid, signal.SIGSTOP)
                time.sleep(STOP_S)
                os.kill(pid, signal.SIGCONT)
                fault.detail = f"pid {pid}"
            elif fault.kind.startswith("trainer"):
                fault.detail = f"pid {current.trainer_pid}"
                fault.count_from_s = None  # set when the resumed run starts
                trainer_fault = fault
                os.kill(current.trainer_pid, signal.SIGTERM)
            else:
                unlinked = slot_name(name, 0)
                os.unlink(os.path.join(SHM_DIR, unlinked))
                fault.detail = unlinked
            print(f"soak: t={fault.applied_s:7.1f} s  {fault.kind} ({fault.detail})", flush=True)
            last_fault = fault
        time.sleep(POLL_S)
    wall = time.monotonic() - t0
    final_status = current.proc.returncode
    time.sleep(1.0)
    left = existing_segments(name)
    strays = orphans(name, run_dir)

    if not (run_dir / "metrics.json").exists():
        print(f"soak: the run wrote no metrics.json (rover-pair status {final_status}); "
              f"see {log_path}", flush=True)  # fmt: skip
        return 1
    metrics = json.loads((run_dir / "metrics.json").read_text())
    record = json.loads((run_dir / "run.json").read_text())
    stop_steps = [h for h in record["history"] if h.get("status") == "interrupted"]
    rewound = sum(int(m.group(1)) for line in (log_path.read_text().splitlines())
                  for m in [re.search(r"\((\d+) collected steps not yet learned", line)] if m)
    rollout = 256 * args.slots
    straight_total = -(-timesteps // rollout) * rollout  # PPO stops after a whole rollout
    eval_cmd = [sys.executable, str(ROOT / "launch" / "run_pair.py"), "--name", f"{name}_eval",
                "--daemon-arg=--threads", "--daemon-arg=1", "--", sys.executable, "-m",
                "rover_train.evaluate", str(run_dir / "model.zip"), "--env", "fused",
                "--episodes", "1", "--max-steps", "50"]  # fmt: skip
    ev = subprocess.run(eval_cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    acts = ev.returncode == 0 and "success rate" in ev.stdout
    result = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_average": os.getloadavg(),
        "seed": args.seed, "minutes": args.minutes, "slots": args.slots,
        "wall_s": round(wall, 1), "final_pair_status": final_status,
        "steps_requested": timesteps,
        "steps_trained": metrics["timesteps"],
        "steps_a_straight_run_trains": straight_total,
        "steps_lost": straight_total - metrics["timesteps"],
        "steps_rewound_at_stop": rewound,
        "steps_at_stop_checkpoint": [h.get("steps_at_end") for h in stop_steps],
        "episodes": metrics["episodes"],
        "episodes_truncated_by_faults": metrics["episodes_truncated_by_faults"],
        "daemon_restarts": sum(r.restarts for r in pair_runs),
        "pair_runs": len(pair_runs), "resume_pair_status": stop_info.get("pair_status"),
        "faults": [dict(asdict(f), recovery_s=f.recovery_s) for f in faults],
        "segments_left": left, "orphans": strays,
        "final_model_loads_and_acts": acts,
        "eval_tail": ev.stdout[-600:] + ev.stderr[-600:],
    }
    (run_dir / "soak.json").write_text(json.dumps(result, indent=2, default=str))
    rows = [
        ("steps requested / trained", f"{timesteps} / {metrics['timesteps']} (a run that never "
         f"stopped: {straight_total})"),
        ("steps lost", f"{result['steps_lost']} (steps collected again after the stop, never "
         f"counted twice: {rewound})"),
        ("episodes / truncated by faults",
         f"{metrics['episodes']} / {metrics['episodes_truncated_by_faults']}"),
        ("daemon restarts", str(result["daemon_restarts"])),
        ("segments left / orphans", f"{len(left)} / {len(strays)}"),
        ("final model loads and acts", "yes" if acts else "NO"),
        ("wall time", f"{wall / 60:.1f} min, final rover-pair status {final_status}"),
    ]
    print(f"\n| soak (seed {args.seed}, {args.minutes:g} min, {args.slots} slots) | |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")
    print("\n| t (s) | fault | recovered after (s) |\n|---|---|---|")
    for f in faults:
        when = "not applied (run over)" if f.applied_s is None else f"{f.applied_s:.0f}"
        rec = "-" if f.recovery_s is None else f"{f.recovery_s:.1f}"
        print(f"| {when} | {f.kind} | {rec} |")
    ok = (metrics["timesteps"] >= timesteps and not left and not strays and acts
          and result["steps_lost"] <= 0)  # fmt: skip
    print(f"\ntargets {'met' if ok else 'MISSED'}; details in {run_dir / 'soak.json'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
