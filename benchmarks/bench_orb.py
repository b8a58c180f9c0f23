"""ORB extraction against bare OpenCV, side by side in one process (issue 16).

:meth:`frontend.orb.OrbDetector.detect` (tracker defaults: 5000 candidates,
one per 32-px cell) against the least OpenCV can do for the same output:
``ORB.detect`` of the same candidates, then ``ORB.compute`` of exactly the
keypoints ours keeps (chosen beforehand, untimed, by ``OrbDetector.select``:
the cost of ``compute`` depends on the pyramid levels they sit on). Both use
the same ORB settings, image and OpenCV thread count (``--threads``, set with
``cv2.setNumThreads``; 1 by default, so CPU time is the work done, not pool
threads spinning), and both are run once on every frame before timing. They
alternate repeat by repeat on each KITTI 07 frame (``benchmarks/timing.py``),
each going first on every other repeat (CPU time, ``time.process_time``), so
machine load and caches hit both alike. The figure is the ratio of the medians over all frames and repeats
(never a best-of); the spread is the same ratio taken per repeat. Goal: at
most 1.1.

JSON (default ``benchmarks/results/orb.json``) and its PNG beside it.

    python benchmarks/bench_orb.py [--frames 40] [--repeats 5] [--threads 1] [--quick] [--out FILE.json]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # this working tree's packages, not an installed copy
sys.path.insert(0, str(HERE))

from frontend.orb import OrbConfig, OrbDetector  # noqa: E402
import timing  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

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
    ap.add_argument("--frames", type=entry.count, default=40)
    ap.add_argument("--repeats", type=entry.count, default=5)
    ap.add_argument("--threads", type=entry.count_or_zero, default=1, help="cv2.setNumThreads for both (0: OpenCV's default)")
    ap.add_argument("--quick", action="store_true", help="3 frames, 1 repeat")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "orb.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, frames=3, repeats=1)
    if args.threads:
        cv2.setNumThreads(args.threads)
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted(KITTI.glob("*.png"))[:args.frames]]
    ours = OrbDetector(OrbConfig())
    opencv = OrbDetector(OrbConfig())._orb()  # the same OpenCV settings, its own object
    chosen = []
    for img in images:  # also the warm-up of both
        ours.detect(img)
        chosen.append(ours.select(opencv.detect(img, None), img.shape).tolist())

    t_ours = np.zeros((args.repeats, len(images)))
    t_cv = np.zeros_like(t_ours)
    n_cand, n_kept = [], []
    for f, (img, keep) in enumerate(zip(images, chosen)):
        def run_ours(img=img):
            n_kept.append(len(ours.detect(img).xy_px))

        def run_opencv(img=img, keep=keep):
            kps = opencv.detect(img, None)
            opencv.compute(img, [kps[i] for i in keep])
            n_cand.append(len(kps))

        # warmed up above; each side goes first on every other repeat
        t = timing.alternate({"ours": run_ours, "opencv": run_opencv}, args.repeats, warmup=0,
                             clock=time.process_time)
        t_ours[:, f], t_cv[:, f] = t["ours"].samples_s, t["opencv"].samples_s
    ratio = float(np.median(t_ours) / np.median(t_cv))
    per_repeat = np.median(t_ours, axis=1) / np.median(t_cv, axis=1)
    print(f"KITTI 07, {len(images)} frames x {args.repeats}, {cv2.getNumThreads()} OpenCV thread(s): "
          f"{np.median(n_cand):.0f} candidates, {np.median(n_kept):.0f} kept; ours "
          f"{1000 * np.median(t_ours):.1f} ms, OpenCV detect + describe kept "
          f"{1000 * np.median(t_cv):.1f} ms: ratio {ratio:.3f} (per repeat "
          f"{per_repeat.min():.3f}-{per_repeat.max():.3f}; goal <= 1.1)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    summary = timing.summary(
        "ORB extraction", float(np.median(t_ours)), float(np.median(t_cv)),
        target=timing.TARGETS["orb"], unit="s CPU", frames=len(images),
        floor="OpenCV ORB detect + compute of the same kept keypoints, same settings, "
              "1 OpenCV thread", command="python benchmarks/bench_orb.py")
    entry.write_json(args.out, {"benchmark": "orb", "ratio": ratio, "summary": summary,
                                "ratio_per_repeat": per_repeat.tolist(),
                                "opencv_threads": cv2.getNumThreads(),
                                "ours_ms": 1000 * float(np.median(t_ours)),
                                "opencv_ms": 1000 * float(np.median(t_cv)),
                                "candidates": float(np.median(n_cand)),
                                "kept": float(np.median(n_kept))}, indent=2)
    plot(t_ours, t_cv, len(images), ratio, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
