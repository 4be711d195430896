"""The main job: train PPO on RoverEnvFused for a short budget, then evaluate it.

Run under the supervisor so the daemon is there (``make demo`` does this):

    rover-pair -- python -m rover_train.demo --timesteps 20000

Leaves under ``--out`` (default ``runs/demo``): ``model.zip``, ``metrics.json``,
``learning_curve.png``, ``eval.txt`` (the evaluation table, trained and random policy),
``eval.mp4`` (chase view beside the three fused channels) and ``eval_still.png``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from collections.abc import Sequence
from pathlib import Path

from rover_train import evaluate, train


def _eval(argv: list[str]) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = evaluate.main(argv)
    if code != 0:
        raise SystemExit(f"rover-eval {' '.join(argv)} failed with status {code}")
    return buf.getvalue()


def save_still(video: Path, png: Path) -> None:
    """The video frame that shows the most pedestrian heatmap (else the middle one), as PNG.

    Frames are the chase view beside the gray, heatmap and depth panels (equal widths).
    """
    import cv2

    cap = cv2.VideoCapture(str(video))
    best, best_score, frames = None, -1.0, []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
        w = frame.shape[1] // 4
        score = float(frame[:, 2 * w : 3 * w].mean())
        if score > best_score:
            best, best_score = frame, score
    cap.release()
    if best is None:
        return
    if best_score < 1.0:  # no pedestrian anywhere: the middle frame
        best = frames[len(frames) // 2]
    cv2.imwrite(str(png), best)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="rover_train.demo", description=__doc__.split("\n")[0])
    p.add_argument("--env", choices=["fused", "discrete", "lidar"], default="fused")
    p.add_argument("--world", default="maze")
    p.add_argument("--timesteps", type=int, default=20_000)
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--max-steps", type=int, default=400)
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    args = p.parse_args(argv)
    out = args.out
    code = train.main(
        [
            "--env", args.env, "--world", args.world, "--algo", "ppo",
            "--timesteps", str(args.timesteps), "--logdir", str(out), "--length", "1000",
            "--checkpoint-every", str(max(args.timesteps // 2, 1)), "--no-progress",
        ]
    )  # fmt: skip
    if code != 0:
        return code
    common = ["--env", args.env, "--world", args.world, "--episodes", str(args.episodes),
              "--max-steps", str(args.max_steps)]  # fmt: skip
    trained = _eval([str(out / "model.zip"), *common, "--video", str(out / "eval.mp4"),
                     "--video-episodes", str(args.episodes)])  # fmt: skip
    random = _eval(["--policy", "random", *common])
    report = trained + "\n" + random
    (out / "eval.txt").write_text(report)
    save_still(out / "eval.mp4", out / "eval_still.png")
    print(report)
    print(f"demo outputs in {out}/: model.zip metrics.json learning_curve.png eval.txt eval.mp4")
    return 0


if __name__ == "__main__":
    sys.exit(main())
