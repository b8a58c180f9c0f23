"""ORB extraction against bare OpenCV, side by side in one process (issue 16).

:meth:`frontend.orb.OrbDetector.detect` (tracker defaults: 5000 candidates,
one per 32-px cell) against the least OpenCV can do for the same output:
``ORB.detect`` of the same candidates, then ``ORB.compute`` of exactly the
keypoints ours keeps (chosen beforehand, untimed, by ``OrbDetector.select``:
the cost of ``compute`` depends on the pyramid levels they sit on). The two alternate frame by frame on KITTI 07 frames
(CPU time, ``time.process_time``), so machine load hits both alike; the
figure is the ratio of the medians. Goal: at most 1.1.

JSON (default ``benchmarks/results/orb.json``) and its PNG beside it.

    python benchmarks/bench_orb.py [--frames 40] [--repeats 5] [--quick] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from frontend.orb import OrbConfig, OrbDetector

HERE = Path(__file__).resolve().parent
KITTI = HERE.parent.parent / "shared" / "data" / "kitti07" / "image_0"


def plot(t_ours: list[float], t_cv: list[float], n_frames: int, ratio: float, out: Path) -> Path:
    """CPU time per frame, ours against OpenCV, frame by frame (median over the repeats)."""
    from plotting import Panel, save_figure  # beside this script

    k = list(range(n_frames))
    ours = 1e3 * np.median(np.reshape(t_ours, (-1, n_frames)), axis=0)
    cv = 1e3 * np.median(np.reshape(t_cv, (-1, n_frames)), axis=0)
    return save_figure(out, "ORB on KITTI 07: OrbDetector against bare OpenCV", [
        Panel(f"CPU time per frame; ratio of medians {ratio:.3f} (goal <= 1.1)", "KITTI 07 frame",
              "CPU time [ms] (median over the repeats)",
              {"OrbDetector.detect": (k, ours),
               "OpenCV detect + compute of the kept keypoints": (k, cv)})], ncols=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="3 frames, 1 repeat")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "orb.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.repeats = 3, 1
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted(KITTI.glob("*.png"))[:args.frames]]
    ours = OrbDetector(OrbConfig())
    opencv = OrbDetector(OrbConfig())._orb()  # the same OpenCV settings, its own object
    t_ours, t_cv, n_cand, n_kept = [], [], [], []
    chosen = []
    for img in images:
        kps = opencv.detect(img, None)
        chosen.append(ours.select(kps, img.shape))
    for _ in range(args.repeats):
        for img, keep in zip(images, chosen):
            t0 = time.process_time()
            kept = len(ours.detect(img).xy_px)
            t1 = time.process_time()
            kps = opencv.detect(img, None)
            opencv.compute(img, [kps[i] for i in keep])
            t2 = time.process_time()
            t_ours.append(t1 - t0)
            t_cv.append(t2 - t1)
            n_cand.append(len(kps))
            n_kept.append(kept)
    ratio = float(np.median(t_ours) / np.median(t_cv))
    print(f"KITTI 07, {len(images)} frames x {args.repeats}: {np.median(n_cand):.0f} candidates, "
          f"{np.median(n_kept):.0f} kept; ours {1000 * np.median(t_ours):.1f} ms, OpenCV "
          f"detect + describe kept {1000 * np.median(t_cv):.1f} ms: ratio {ratio:.3f} (goal <= 1.1)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "orb", "ratio": ratio,
                                    "ours_ms": 1000 * float(np.median(t_ours)),
                                    "opencv_ms": 1000 * float(np.median(t_cv)),
                                    "candidates": float(np.median(n_cand)),
                                    "kept": float(np.median(n_kept))}, indent=2))
    plot(t_ours, t_cv, len(images), ratio, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
