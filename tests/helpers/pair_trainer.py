"""A minimal trainer for supervisor tests: a real peer of the daemon over shared memory.

It attaches to the daemon that rover-pair started (``ROVERAV_SHM_NAME``), writes camera
frames and waits for the fused frame computed from each, like RoverEnvFused does.

    --frames N          round trips to complete before exiting (0: run until signalled)
    --exit-code C       exit status after the last frame
    --kill-daemon-at K  SIGKILL the daemon (the fused segment's writer) after frame K, then
                        keep going: re-attach when the restarted daemon is back
    --kills N           with --kill-daemon-at K: kill N times, after frames K, 2K, ...
    --kill-gap S        ... and at least S seconds after the previous kill (the run goes on
                        past --frames until every kill is done and 2 frames came after
                        the last one, from the restarted daemon)
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from shm_protocol import FrameReader, FrameWriter, camera_name, slot_name  # noqa: E402
from shm_protocol.errors import ShmError  # noqa: E402


def attach(name: str, deadline: float) -> tuple[FrameWriter, FrameReader]:
    while True:
        try:
            fused = FrameReader(name, attach_timeout=1.0)
            cam = FrameWriter(camera_name(name), create=False)
            return cam, fused
        except ShmError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--exit-code", type=int, default=0)
    p.add_argument("--kill-daemon-at", type=int, default=-1)
    p.add_argument("--kills", type=int, default=1)
    p.add_argument("--kill-gap", type=float, default=0.0)
    args = p.parse_args()
    name = slot_name(os.environ["ROVERAV_SHM_NAME"], 0)
    print(f"trainer started pid={os.getpid()} name={name}", flush=True)
    cam, fused = attach(name, time.monotonic() + 20)
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, size=cam.shape, dtype=np.uint8)
    done = 0
    kills = 0
    last_kill = -float("inf")
    since_kill = 0

    def more_to_do() -> bool:
        if args.frames == 0 or done < args.frames:
            return True
        if args.kill_daemon_at > 0:  # every kill done, and the restarted daemon served us
            return kills < args.kills or since_kill < 2
        return False

    while more_to_do():
        try:
            seq = cam.publish(frame)
            out = fused.wait_for(source_seq=seq, timeout=5.0)
        except ShmError as exc:
            print(f"daemon lost ({type(exc).__name__}); re-attaching", flush=True)
            cam.close()
            fused.close()
            cam, fused = attach(name, time.monotonic() + 30)
            continue
        assert out.data.shape == (cam.shape[0], cam.shape[1], 3)
        done += 1
        since_kill += 1
        print(f"frame {done} source_seq={out.source_seq}", flush=True)
        due = args.kill_daemon_at > 0 and done >= args.kill_daemon_at * (kills + 1)
        if due and kills < args.kills and time.monotonic() - last_kill >= args.kill_gap:
            kills += 1
            since_kill = 0
            last_kill = time.monotonic()
            pid = fused.writer_pid
            print(f"killing daemon pid={pid}", flush=True)
            os.kill(pid, signal.SIGKILL)
    cam.close()
    fused.close()
    print("trainer finished", flush=True)
    return args.exit_code


if __name__ == "__main__":
    sys.exit(main())
