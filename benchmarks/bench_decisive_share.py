"""The loop verifier's decisive share against the number of ORB features per image.

``[loop_verify] decisive_share`` (0.25) accepts a pair below both coverage tests when
its inliers are that share of the features of each image (of the one with more). It
was set at the loop detector's 1000 features; a user may ask for fewer or more
(``[loops.orb] n_features``). This measures, for each feature count, on real images
no one on the team made:

- **other places**: KITTI 07 frames 0-159, every 4th frame against every 2nd later
  one over 40 m apart (ground truth): the largest share of inliers and the 99th
  percentile. These are the hardest negatives: the same houses and trees further on;
- **the same street**: KITTI 07 pairs 1-5 m apart (every 2nd query frame): the median
  share, and the part at or above the threshold;
- **overlapping neighbours**: the ten desk photos, each against the next and the
  next against it (no intrinsics): the largest share.

Every pair is verified with the share test off (``decisive_share = 0``) so its
inliers are counted whatever the coverage tests decide. The share is a fraction of
the features, so it should not move with their number; this says whether it does.

    python benchmarks/bench_decisive_share.py [--features 250 500 1000 2000] [--quick]

``--quick``: 250 features and a tenth of the pairs (a smoke run of the script).
Writes ``benchmarks/results/decisive_share.json`` (or ``--out``) and a PNG beside it.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from loop_real import _features, _verify  # noqa: E402
from plotting import Panel, save_figure  # noqa: E402

from frontend.orb import OrbDetector  # noqa: E402
from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses  # noqa: E402
from graphslam.sources.spatial.sequence import folder_images  # noqa: E402
from loopclosure.detector import LoopDetectorConfig  # noqa: E402
from loopclosure.verify import GeometricVerifier, VerifyConfig  # noqa: E402
import entry  # noqa: E402  (beside this script: argparse types)

DATA = HERE.parent.parent / "shared" / "data"
#: KITTI pairs further apart than this (m) are other places; these near are the same street.
FAR_M, NEAR_M = 40.0, (1.0, 5.0)


def _shares(verifier: GeometricVerifier, pairs, feats, K=None) -> np.ndarray:
    """Inliers / features of the image with more, for each pair ``(i, j)`` (j verified against i)."""
    out = []
    for i, j in pairs:
        (a, _), (b, _) = feats[j], feats[i]
        out.append(_verify(verifier, feats[j], feats[i], K).n_inliers / max(len(a), len(b), 1))
    return np.asarray(out, dtype=np.float64)


def measure(data: Path, n_features: int, thin: int = 1) -> dict:
    """The module docstring's figures at ``n_features`` (``thin``: every thin-th pair)."""
    t0 = time.perf_counter()
    kitti_dir = data / "kitti07"
    K, _ = read_kitti_calib(kitti_dir / "calib.txt")
    xyz = read_kitti_poses(kitti_dir / "poses.txt")[:, :3, 3]
    dist = np.linalg.norm(xyz[:, None] - xyz[None], axis=2)
    orb = OrbDetector(dataclasses.replace(LoopDetectorConfig().orb, n_features=n_features))
    kitti = _features(folder_images(kitti_dir / "image_0"), orb)
    desk = _features(folder_images(data / "slambook2_desk" / "images"), orb)
    verifier = GeometricVerifier(VerifyConfig(decisive_share=0.0))
    n = len(kitti)
    far = [(i, j) for i in range(0, n, 4) for j in range(i + 1, n, 2) if dist[i, j] > FAR_M][::thin]
    near = [(i, j) for i in range(0, n, 2) for j in range(i + 1, n) if NEAR_M[0] <= dist[i, j] <= NEAR_M[1]]
    near = near[::thin]
    far_s, near_s = _shares(verifier, far, kitti, K), _shares(verifier, near, kitti, K)
    steps = [(i, i + 1) for i in range(len(desk) - 1)]
    desk_s = _shares(verifier, steps + [(j, i) for i, j in steps], desk)  # both orders
    threshold = VerifyConfig().decisive_share
    return {
        "n_features": n_features,
        "features_found_median": float(np.median([len(f) for f, _ in kitti])),
        "other_places": {"pairs": len(far), "max": float(far_s.max()), "p99": float(np.quantile(far_s, 0.99))},
        "same_street": {
            "pairs": len(near),
            "median": float(np.median(near_s)),
            "at_or_above_threshold": float(np.mean(near_s >= threshold)),
        },
        "desk_neighbours": {"pairs": len(desk_s), "max": float(desk_s.max())},
        "seconds": time.perf_counter() - t0,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--features", type=entry.count, nargs="+", default=[250, 500, 1000, 2000])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "decisive_share.json")
    args = ap.parse_args(argv)
    if args.quick:  # smoke sizes for the options not given (--quick --features 500 ran 250)
        entry.quick_sizes(ap, argv, args, features=[250])
    counts, thin = args.features, 10 if args.quick else 1
    rows = []
    for n in counts:
        r = measure(args.data, n, thin)
        rows.append(r)
        print(
            f"{n} features: other places ({r['other_places']['pairs']} pairs) max {r['other_places']['max']:.3f}, "
            f"p99 {r['other_places']['p99']:.3f}; same street ({r['same_street']['pairs']}) median "
            f"{r['same_street']['median']:.3f}, {100 * r['same_street']['at_or_above_threshold']:.1f} % at or "
            f"above the threshold; desk neighbours max {r['desk_neighbours']['max']:.3f}; {r['seconds']:.0f} s",
            flush=True,
        )
    threshold = VerifyConfig().decisive_share
    out = {"decisive_share": threshold, "far_m": FAR_M, "near_m": NEAR_M, "quick": args.quick, "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, out, indent=1)
    xs = [r["n_features"] for r in rows]
    save_figure(
        args.out,
        "Loop verifier: inlier share of a pair against the ORB features per image (KITTI 07, desk)",
        [
            Panel(
                "share of the features explained by one geometry",
                "ORB features per image",
                "inliers / features of the image with more",
                {
                    f"other places over {FAR_M:g} m: largest": (xs, [r["other_places"]["max"] for r in rows]),
                    "desk neighbours: largest": (xs, [r["desk_neighbours"]["max"] for r in rows]),
                    f"same street {NEAR_M[0]:g}-{NEAR_M[1]:g} m: median": (
                        xs,
                        [r["same_street"]["median"] for r in rows],
                    ),
                },
                logx=True,
                targets={f"decisive_share {threshold:g}": threshold},
            )
        ],
    )
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
