"""Software Harris (float, with tessellation) against cv2.cornerHarris + the same cell selection.

Both run in the same process on the same KITTI 07 frame, interleaved, and the
median of ``--repeats`` runs is kept. Ours: 5x5 Gaussian, central differences,
5x5 Gaussian window, R, tessellation (``HarrisDetector(arithmetic="float")``).
OpenCV: ``cv2.cornerHarris(image, blockSize=5, ksize=3, k)`` (Sobel, box
window) then the same ``tessellate``. Target: ours / OpenCV <= 2. The fixed-point
detector is timed too, and its approximation errors against the float one are
printed.

JSON (default ``benchmarks/results/harris.json``) and its PNG beside it.

    python benchmarks/bench_harris.py [--frame N] [--repeats 20] [--quick] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from frontend.harris import (  # noqa: E402
    GAUSS5_FLOAT,
    GAUSS5_INT,
    RESPONSE_SHIFT,
    HarrisConfig,
    HarrisDetector,
    harris_response_fixed,
    harris_response_float,
    tessellate,
)
from frontend.image import load_gray  # noqa: E402

KITTI = ROOT.parent / "shared" / "data" / "kitti07" / "image_0"


def cv_detect(image, cfg):
    r = cv2.cornerHarris(image, blockSize=5, ksize=3, k=cfg.k)
    return tessellate(r, cfg.cell_size_px, cfg.border_px, 0.0)


def plot(result: dict, labels: dict, out: Path) -> Path:
    """Median time per frame of each detector, with the target (twice OpenCV)."""
    from plotting import Panel, save_figure  # beside this script

    med = result["median_s"]
    names = [labels[k] for k in med]
    return save_figure(out, f"Harris on KITTI 07 frame {result['frame']:06d} "
                            f"({result['shape'][1]}x{result['shape'][0]}), median of {result['repeats']}", [
        Panel(f"ours float / OpenCV = {result['ratio_float_over_opencv']:.2f}", "detector",
              "time per frame [ms]", {"median": (names, [1e3 * v for v in med.values()])}, kind="bar",
              targets={"target: 2 x OpenCV": result["target_ratio"] * 1e3 * med["opencv"]})], ncols=1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="3 repeats")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "harris.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats = 3

    image = load_gray(KITTI / f"{args.frame:06d}.png")
    cfg = HarrisConfig()
    ours = HarrisDetector(cfg)
    fixed = HarrisDetector(cfg, arithmetic="fixed")
    runs = {"ours_float": lambda: ours.detect(image), "opencv": lambda: cv_detect(image, cfg),
            "ours_fixed": lambda: fixed.detect(image)}
    times = {k: [] for k in runs}
    for fn in runs.values():
        fn()                                                   # warm-up
    for _ in range(args.repeats):
        for name, fn in runs.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    ratio = med["ours_float"] / med["opencv"]

    # Fixed-point approximation errors on this frame.
    rf = harris_response_float(image, cfg.k)[5:-5, 5:-5]
    ri = harris_response_fixed(image, cfg.k_num)[5:-5, 5:-5] / 2.0**RESPONSE_SHIFT
    strong = np.abs(rf) > cfg.threshold
    rel = np.abs(ri[strong] - rf[strong]) / np.abs(rf[strong])
    a, b = ours.detect(image), fixed.detect(image)
    sa = {(int(c), *map(float, p)) for c, p in zip(a.cell, a.xy_px)}
    sb = {(int(c), *map(float, p)) for c, p in zip(b.cell, b.xy_px)}
    approx = {
        "gauss_tap_max_abs_err": float(np.max(np.abs(np.array(GAUSS5_INT) / 256 - GAUSS5_FLOAT))),
        "k_fixed": cfg.k_num / 1024, "k_rel_err": cfg.k_num / 1024 / cfg.k - 1,
        "response_rel_err_median": float(np.median(rel)),
        "response_rel_err_p99": float(np.percentile(rel, 99)),
        "points_identical": len(sa & sb), "points_union": len(sa | sb),
    }

    h, w = image.shape
    print(f"KITTI 07 frame {args.frame:06d} ({w}x{h}), cells {cfg.cell_size_px} px, "
          f"median of {args.repeats}")
    print(f"{'detector':<28}{'ms/frame':>10}{'points':>8}")
    npts = {"ours_float": len(a), "opencv": len(cv_detect(image, cfg)[0]), "ours_fixed": len(b)}
    labels = {"ours_float": "ours float64 + cells", "opencv": "cv2.cornerHarris + cells",
              "ours_fixed": "ours fixed point + cells"}
    for k in runs:
        print(f"{labels[k]:<28}{med[k] * 1e3:>10.2f}{npts[k]:>8}")
    print(f"ratio ours float / OpenCV: {ratio:.2f} (target <= 2)")
    print("fixed-point approximations: " + ", ".join(
        f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in approx.items()))
    result = {"frame": args.frame, "shape": [h, w], "repeats": args.repeats,
              "median_s": med, "ratio_float_over_opencv": ratio, "target_ratio": 2.0,
              "points": npts, "fixed_point": approx}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    plot(result, labels, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
