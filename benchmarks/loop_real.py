"""Real-image figures of place recognition for ``bench_loop_pr.py --real`` (issue 16).

Every figure uses the defaults of ``graphslam loops`` (shipped vocabulary,
``[loops]`` and ``[loop_verify]`` defaults, mode chosen from the folder):

- **desk** (slambook2, 10 photos, photo 10 back at photo 1): the closures of
  the whole folder; target: (10, 01) and nothing else.
- **KITTI 07 frames 0-159** (no revisit): closures of the folder; target 0.
- **KITTI 07 pairs 1-5 m apart** (ground-truth positions; every 2nd frame
  as the older image): share verified by the verifier with K (the same
  place seen a few metres further on; a rate to report, not a target).
- **Lund door pairs**: all 66 pairs of the 12 photos, no intrinsics
  (fundamental matrix, as a folder without ``--intrinsics``): share verified.
- **different places**: pairs of images from different sets (desk, KITTI,
  Lund, gtsam's Balbianello) and KITTI 07 pairs more than 50 m apart;
  target: all rejected.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import numpy as np

from frontend.image import load_gray
from frontend.orb import OrbDetector
from graphslam.pipelines.place_recognition import (
    detect_all, detect_loops, folder_places, folder_timestamps,
)
from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses
from graphslam.sources.spatial.sequence import folder_images
from loopclosure.detector import LoopDetector, LoopDetectorConfig
from loopclosure.shipped import load_shipped_vocabulary
from loopclosure.verify import GeometricVerifier

#: KITTI 07 pairs this far apart (m, ground truth) count as the same place seen further on.
NEAR_M = (1.0, 5.0)
#: KITTI 07 pairs further apart than this (m) count as different places.
FAR_M = 50.0


def folder_run(folder: Path, vocab) -> dict:
    """``graphslam loops FOLDER`` with its defaults: closures as file-name pairs, mode, time."""
    t0 = time.perf_counter()
    paths = folder_images(folder)
    config = LoopDetectorConfig()
    feats = detect_all(paths, OrbDetector(config.orb))
    places = folder_places(feats, config, folder_timestamps(paths))
    det = detect_loops(paths, LoopDetector(vocab, config,
                                           mode=places.mode if config.mode == "auto" else None),
                       feats, timestamps=places.timestamps)
    return {"images": len(paths), "mode": places.describe(config),
            "closures": [(paths[c.query].name, paths[c.match].name) for c in det.closures],
            "candidates": len(det.records), "seconds": time.perf_counter() - t0}


def _features(paths, orb: OrbDetector | None = None) -> list:
    """``(features, (W, H))`` of each image, by ``orb`` (default: the loop detector's)."""
    orb = orb or OrbDetector(LoopDetectorConfig().orb)
    out = []
    for p in paths:
        img = load_gray(p)
        out.append((orb.detect(img), (float(img.shape[1]), float(img.shape[0]))))
    return out


def _verify(verifier, fa, fb, K=None):
    (a, sa), (b, sb) = fa, fb
    return verifier.verify(a.xy_px, a.descriptors, b.xy_px, b.descriptors, K, size_a=sa, size_b=sb)


def _rate(verifier, pairs, feats_a, feats_b, K=None) -> dict:
    ok = [bool(_verify(verifier, feats_a[j], feats_b[i], K).accepted) for i, j in pairs]
    return {"pairs": len(pairs), "verified": int(sum(ok)),
            "rate": sum(ok) / len(pairs) if pairs else None}


def real_figures(data: Path) -> dict:
    """All the figures of the module docstring, as one JSON-able dict."""
    t0 = time.perf_counter()
    vocab = load_shipped_vocabulary()
    load_s = time.perf_counter() - t0
    desk_dir, kitti_dir, lund_dir = (data / "slambook2_desk" / "images", data / "kitti07",
                                     data / "lund_door" / "images")
    out = {"vocabulary_load_s": load_s,
           "desk": folder_run(desk_dir, vocab), "kitti07": folder_run(kitti_dir / "image_0", vocab)}
    verifier = GeometricVerifier()
    K, _ = read_kitti_calib(kitti_dir / "calib.txt")
    pos = read_kitti_poses(kitti_dir / "poses.txt")[:, :3, 3]
    dist = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    kitti = _features(folder_images(kitti_dir / "image_0"))
    near = [(i, j) for i in range(0, len(kitti), 2) for j in range(i + 1, len(kitti))
            if NEAR_M[0] <= dist[i, j] <= NEAR_M[1]]
    out["kitti07_near_pairs"] = {**_rate(verifier, near, kitti, kitti, K), "metres": NEAR_M}
    lund = _features(folder_images(lund_dir))
    out["lund_pairs"] = _rate(verifier, list(itertools.combinations(range(len(lund)), 2)), lund, lund)
    far = [(i, j) for i in range(0, len(kitti), 8) for j in range(i + 1, len(kitti), 4)
           if dist[i, j] > FAR_M]
    far_rate = _rate(verifier, far, kitti, kitti, K)
    sets = {"desk": _features(folder_images(desk_dir)), "kitti07": kitti[::8], "lund": lund}
    try:
        import gtsam

        sets["balbianello"] = _features(sorted(Path(gtsam.findExampleDataFile("Balbianello"))
                                               .glob("*.jpg")))
    except (ImportError, RuntimeError):
        pass
    cross = {"pairs": 0, "verified": 0}
    for (na, fa), (nb, fb) in itertools.combinations(sets.items(), 2):
        for x, y in itertools.product(fa, fb):
            cross["pairs"] += 1
            cross["verified"] += bool(_verify(verifier, x, y).accepted)
    out["different_places"] = {"sets": sorted(sets), "cross_set": cross,
                               f"kitti07_over_{FAR_M:g}m": far_rate,
                               "rejected": cross["pairs"] - cross["verified"]
                               + far_rate["pairs"] - far_rate["verified"],
                               "pairs": cross["pairs"] + far_rate["pairs"]}
    out["total_s"] = time.perf_counter() - t0
    return out


def print_figures(r: dict) -> None:
    """The real-image table."""
    print(f"real images (shipped vocabulary, loaded in {r['vocabulary_load_s']:.2f} s):")
    for key, target in (("desk", "(10.png, 01.png) only"), ("kitti07", "none")):
        f = r[key]
        print(f"  {key}: {f['images']} images, {f['mode']}; closures {f['closures']} "
              f"(target: {target}), {f['seconds']:.1f} s")
    for key, what in (("kitti07_near_pairs", "KITTI 07 pairs 1-5 m apart"),
                      ("lund_pairs", "Lund door pairs")):
        f = r[key]
        print(f"  {what}: verified {f['verified']}/{f['pairs']} ({100 * f['rate']:.0f} %)")
    d = r["different_places"]
    print(f"  different places ({', '.join(d['sets'])} across sets; KITTI 07 > {FAR_M:g} m): "
          f"rejected {d['rejected']}/{d['pairs']}")
