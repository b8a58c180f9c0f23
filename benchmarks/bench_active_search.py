"""Active search on KITTI 07: accuracy protocol and time per frame against the number of corrections.

Two things live here (the test ``tests/frontend/test_active_search.py`` loads this file
for the first):

1. The KITTI 07 evaluation protocol (:func:`evaluate`), for consecutive frames
   (k, k+1):

   * landmarks: Harris corners of frame k (``HarrisDetector()`` defaults: 32 px
     cells, threshold 1e6), tracked into a partner frame k+2 (k-2 for the last
     pair) by pyramidal Lucas-Kanade with a forward-backward check (< 0.5 px),
     triangulated with the ground-truth poses (``cv2.triangulatePoints``) and
     kept only if well conditioned: reprojection error < 1 px in both views,
     depth in (1, 80) m, parallax angle >= 0.5 deg. Frame k+1 is never looked
     at to build them.
   * prediction: the ground-truth pose of k+1 perturbed by a seeded sample
     ``delta ~ N(0, Sigma)``, ``cTw_pred = se3_exp(delta) @ cTw_true``, with
     ``Sigma = diag(0.05 m, 0.05 m, 0.05 m, 0.2 deg, 0.2 deg, 0.2 deg)^2``
     (left camera-frame perturbation, translation first). The landmark is
     projected with the predicted pose; ``S = J_pose Sigma J_pose^T + (1 px)^2 I``.
     The landmark position itself is taken as exact (its triangulation error is
     not in S).
   * search: patches (11 x 11) cut in frame k at the Harris pixel, searched in
     frame k+1 (default config: 99 % gate, ZNCC >= 0.8, 20 corrections). With
     ``predict_appearance`` the patch is warped by the affine induced by the
     fronto-parallel plane through the point and the PREDICTED motion.
   * reference: the triangulated point projected with the TRUE pose of k+1
     (independent of frame k+1's pixels). "visible" = searched and that
     reference lies >= 8 px inside the image with positive depth. "found" = a
     match accepted; "wrong" = accepted and > 3 px from the reference. As a
     second, independent check, matches are compared with a pyramidal LK track
     k -> k+1 (forward-backward < 0.5 px): ``lk_disagree`` counts accepted
     matches > 3 px from a valid LK track.

2. The timing benchmark (:func:`bench`): active search time per frame against
   the number of corrections 1..20 (as in the paper's figure 5), on real KITTI
   frame pairs with the landmarks and covariances above, for the ZNCC
   (software) and nearest-Harris-point (hardware) modes. One process; prints a
   table and writes JSON (``--out``, default
   ``benchmarks/results/active_search.json``) and its figure beside it (PNG).

    python benchmarks/bench_active_search.py [--pairs 20] [--repeat 5] [--quick] [--out FILE.json]
    python benchmarks/bench_active_search.py --evaluate [--step 1]   # the accuracy protocol
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from frontend.active_search import ActiveSearch  # noqa: E402
from frontend.active_search_config import ActiveSearchConfig  # noqa: E402
from frontend.search_matchers import extract_patches  # noqa: E402
from slamcore.spatial.camera import (
    innovation_covariance, plane_induced_affine, # noqa: E402
                             pose_covariance, project, project_jacobians,
)
from slamcore.spatial.geometry import invert_pose, se3_exp
from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses
from frontend.harris import HarrisDetector  # noqa: E402
from frontend.image import load_gray  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

KITTI07 = ROOT.parent / "shared" / "data" / "kitti07"

#: Stated pose uncertainty of the prediction (per axis, camera frame, translation first).
SIGMA_T_M = 0.05
SIGMA_R_DEG = 0.2
SIGMA_PX = 1.0
#: Protocol thresholds.
WRONG_PX = 3.0
VISIBLE_MARGIN_PX = 8
MIN_PARALLAX_DEG = 0.5
MAX_REPROJ_PX = 1.0
DEPTH_RANGE_M = (1.0, 80.0)
FB_MAX_PX = 0.5

_LK = dict(winSize=(21, 21), maxLevel=3,
           criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))


def lk_track(a: np.ndarray, b: np.ndarray, xy: np.ndarray):
    """LK track of ``xy`` from image a to b with a forward-backward check: (xy_b (N, 2), ok (N,))."""
    p0 = np.ascontiguousarray(xy, dtype=np.float32).reshape(-1, 1, 2)
    if len(p0) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    p1, s1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **_LK)
    pb, s2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, **_LK)
    ok = (s1[:, 0] == 1) & (s2[:, 0] == 1) & (np.linalg.norm((pb - p0)[:, 0], axis=1) < FB_MAX_PX)
    return p1[:, 0].astype(np.float64), ok


class Kitti:
    """KITTI 07 frames, K and camera poses (``cTw[k]`` maps world = camera 0 at frame 0 into camera k)."""

    def __init__(self, root: Path = KITTI07):
        self.root = Path(root)
        self.K, _ = read_kitti_calib(self.root / "calib.txt")
        self.wTc = read_kitti_poses(self.root / "poses.txt")
        self.cTw = invert_pose(self.wTc)
        self._cache: dict[int, np.ndarray] = {}

    def __len__(self):
        return len(self.wTc)

    def image(self, k: int) -> np.ndarray:
        if k not in self._cache:
            if len(self._cache) > 8:
                self._cache.pop(next(iter(self._cache)))
            self._cache[k] = load_gray(self.root / "image_0" / f"{k:06d}.png")
        return self._cache[k]


@dataclass
class PairSetup:
    """Landmarks of frame k and their predictions in frame k+1."""

    k: int
    xy_k: np.ndarray        # (N, 2) Harris pixels in frame k
    p_w: np.ndarray         # (N, 3) triangulated points (world = camera 0 at frame 0)
    z_pred: np.ndarray      # (N, 2) predictions in k+1 (perturbed pose)
    S: np.ndarray           # (N, 2, 2)
    uv_ref: np.ndarray      # (N, 2) reference: projection with the true pose
    visible: np.ndarray     # (N,) bool
    n_harris: int
    affine: np.ndarray      # (N, 2, 2) patch warp k -> k+1 from the PREDICTED motion (fronto-parallel plane)


def setup_pair(data: Kitti, k: int, rng: np.random.Generator, detector=None) -> PairSetup:
    """Landmarks, predictions and references for the pair (k, k+1) (module docstring)."""
    detector = detector or HarrisDetector()
    K, cTw, wTc = data.K, data.cTw, data.wTc
    partner = k + 2 if k + 2 < len(data) else k - 2
    I0, I2 = data.image(k), data.image(partner)
    f = detector.detect(I0)
    x2, ok = lk_track(I0, I2, f.xy_px)
    x0 = f.xy_px[ok]
    x2 = x2[ok]
    if len(x0):
        X = cv2.triangulatePoints(K @ cTw[k][:3], K @ cTw[partner][:3], x0.T, x2.T)
        X = (X[:3] / X[3]).T
        uv0, z0 = project(K, cTw[k], X)
        uv2, z2 = project(K, cTw[partner], X)
        err = np.maximum(np.linalg.norm(uv0 - x0, axis=1), np.linalg.norm(uv2 - x2, axis=1))
        a = X - wTc[k][:3, 3]
        b = X - wTc[partner][:3, 3]
        cosang = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        ang = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
        lo, hi = DEPTH_RANGE_M
        good = ((err < MAX_REPROJ_PX) & (z0 > lo) & (z0 < hi) & (z2 > lo)
                & (ang >= MIN_PARALLAX_DEG) & np.all(np.isfinite(X), axis=1))
        x0, X = x0[good], X[good]
    else:
        X = np.zeros((0, 3))
    Sigma = pose_covariance(SIGMA_T_M, math.radians(SIGMA_R_DEG))
    delta = rng.multivariate_normal(np.zeros(6), Sigma)
    cTw_pred = se3_exp(delta) @ cTw[k + 1]
    z_pred, _, _, J_pose = project_jacobians(K, cTw_pred, X)
    S = innovation_covariance(J_pose, Sigma, SIGMA_PX)
    uv_ref, d_ref = project(K, cTw[k + 1], X)
    _, depth_k = project(K, cTw[k], X)
    affine = plane_induced_affine(K, cTw_pred @ wTc[k], x0, depth_k)
    H, W = data.image(k + 1).shape
    m = VISIBLE_MARGIN_PX
    vis = ((d_ref > 0) & (uv_ref[:, 0] >= m) & (uv_ref[:, 0] <= W - 1 - m)
           & (uv_ref[:, 1] >= m) & (uv_ref[:, 1] <= H - 1 - m))
    return PairSetup(k, x0, X, z_pred.reshape(-1, 2), S.reshape(-1, 2, 2), uv_ref.reshape(-1, 2), vis, len(f),
                     affine.reshape(-1, 2, 2))


@dataclass
class Totals:
    pairs: int = 0
    landmarks: int = 0
    searched: int = 0
    visible: int = 0
    found: int = 0
    wrong: int = 0
    lk_checked: int = 0
    lk_disagree: int = 0
    fractions: list = field(default_factory=list)
    fractions_sum: list = field(default_factory=list)
    search_s: list = field(default_factory=list)

    def summary(self) -> dict:
        return dict(pairs=self.pairs, landmarks_per_pair=self.landmarks / max(self.pairs, 1),
                    searched=self.searched, visible=self.visible, found=self.found, wrong=self.wrong,
                    found_rate=self.found / max(self.visible, 1), wrong_rate=self.wrong / max(self.found, 1),
                    image_fraction_mean=float(np.mean(self.fractions)) if self.fractions else 0.0,
                    image_fraction_max=float(np.max(self.fractions)) if self.fractions else 0.0,
                    image_fraction_sum_mean=float(np.mean(self.fractions_sum)) if self.fractions_sum else 0.0,
                    lk_checked=self.lk_checked, lk_disagree=self.lk_disagree,
                    search_ms_mean=1e3 * float(np.mean(self.search_s)) if self.search_s else 0.0)


def evaluate(pairs, config: ActiveSearchConfig | None = None, seed: int = 0, data: Kitti | None = None,
             lk_check: bool = True) -> dict:
    """Run the protocol on frame pairs (k, k+1) for k in ``pairs``; returns the summary dict."""
    data = data or Kitti()
    config = config or ActiveSearchConfig()
    search = ActiveSearch(config)
    harris = HarrisDetector()
    rng = np.random.default_rng(seed)
    tot = Totals()
    for k in pairs:
        ps = setup_pair(data, k, rng, harris)
        I0, I1 = data.image(k), data.image(k + 1)
        kw = {}
        if config.mode == "nearest":
            kw["features"] = harris.detect(I1)
        t0 = time.perf_counter()
        r = search.search(I1, ps.z_pred, ps.S, prev_image=I0, prev_xy=ps.xy_k, affine=ps.affine, **kw)
        tot.search_s.append(time.perf_counter() - t0)
        sv = r.searched & ps.visible
        fnd = r.found & sv
        err = np.linalg.norm(r.uv - ps.uv_ref, axis=1)
        tot.pairs += 1
        tot.landmarks += len(ps.p_w)
        tot.searched += int(r.searched.sum())
        tot.visible += int(sv.sum())
        tot.found += int(fnd.sum())
        tot.wrong += int((fnd & (err > WRONG_PX)).sum())
        tot.fractions.append(r.image_fraction)
        tot.fractions_sum.append(r.image_fraction_sum)
        if lk_check and fnd.any():
            x1, ok = lk_track(I0, I1, ps.xy_k)
            chk = fnd & ok
            tot.lk_checked += int(chk.sum())
            tot.lk_disagree += int((chk & (np.linalg.norm(r.uv - x1, axis=1) > WRONG_PX)).sum())
    return tot.summary()


def all_pairs(data: Kitti | None = None) -> range:
    """Every consecutive pair (k, k+1) of the sequence: 159 for KITTI 07's 160 frames."""
    n = len(data) if data is not None else len(read_kitti_poses(KITTI07 / "poses.txt"))
    return range(n - 1)


def bench(n_pairs: int = 20, repeat: int = 5, caps=range(1, 21), seed: int = 0) -> list[dict]:
    """Mean active-search time per frame (ms) against the number of corrections, both modes."""
    data = Kitti()
    rng = np.random.default_rng(seed)
    harris = HarrisDetector()
    ks = np.linspace(0, len(data) - 2, n_pairs).round().astype(int)
    setups = []
    for k in ks:
        ps = setup_pair(data, int(k), rng, harris)
        I1 = data.image(int(k) + 1)
        patches = extract_patches(data.image(int(k)), ps.xy_k, ActiveSearchConfig().patch_size_px)
        setups.append((ps, I1, patches, harris.detect(I1)))
    rows = []
    for cap in caps:
        row = {"corrections": int(cap)}
        for mode in ("zncc", "nearest"):
            s = ActiveSearch(mode=mode, max_corrections=int(cap))
            times, found, searched, frac = [], 0, 0, []
            for ps, I1, patches, feats in setups:
                best = math.inf
                for _ in range(repeat):
                    t0 = time.perf_counter()
                    r = s.search(I1, ps.z_pred, ps.S, patches=patches, features=feats)
                    best = min(best, time.perf_counter() - t0)
                times.append(best)
                found += r.n_found
                searched += len(r.order)
                frac.append(r.image_fraction)
            row[f"{mode}_ms"] = 1e3 * float(np.mean(times))
            row[f"{mode}_hz"] = 1.0 / float(np.mean(times))
            row[f"{mode}_searched_per_frame"] = searched / len(setups)
            row[f"{mode}_found_per_frame"] = found / len(setups)
            row[f"{mode}_image_fraction"] = float(np.mean(frac))
        rows.append(row)
    return rows


def plot(rows: list[dict], pairs: int, repeat: int, out: Path) -> Path:
    """Figure 5's shape: time per frame and matches found against the correction cap."""
    from plotting import Panel, save_figure  # beside this script

    caps = [r["corrections"] for r in rows]
    modes = {"zncc": "ZNCC (software)", "nearest": "nearest Harris point (hardware)"}
    return save_figure(out, f"Active search on KITTI 07: {pairs} frame pairs, best of {repeat}", [
        Panel("time per frame", "corrections per frame (cap)", "active search time [ms]",
              {lab: (caps, [r[f"{m}_ms"] for r in rows]) for m, lab in modes.items()}),
        Panel("landmarks matched", "corrections per frame (cap)", "found per frame",
              {lab: (caps, [r[f"{m}_found_per_frame"] for r in rows]) for m, lab in modes.items()}),
    ])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=entry.count, default=20, help="KITTI frame pairs timed (spread over the sequence)")
    ap.add_argument("--repeat", type=entry.count, default=5, help="repetitions per frame (the best is kept)")
    ap.add_argument("--quick", action="store_true", help="2 pairs, 1 repetition (a smoke run)")
    ap.add_argument("--out", type=entry.output_file, help="write the results as JSON (timing default: "
                    "benchmarks/results/active_search.json, and its PNG beside it)")
    ap.add_argument("--evaluate", action="store_true", help="run the accuracy protocol instead")
    ap.add_argument("--step", type=entry.count, default=1, help="with --evaluate: every step-th pair")
    ap.add_argument("--max-corrections", type=entry.count_or_zero, default=20, help="with --evaluate (0 = no cap)")
    ap.add_argument("--mode", default="zncc", choices=("zncc", "nearest"), help="with --evaluate")
    ap.add_argument("--predict-appearance", action="store_true",
                    help="with --evaluate: warp patches by the predicted motion (fronto-parallel plane)")
    args = ap.parse_args(argv)
    if args.evaluate:
        data = Kitti()
        cfg = ActiveSearchConfig(mode=args.mode, max_corrections=args.max_corrections,
                                 predict_appearance=args.predict_appearance)
        t0 = time.perf_counter()
        res = evaluate(all_pairs(data)[::args.step], cfg, data=data)
        res["wall_s"] = time.perf_counter() - t0
        res["config"] = dict(cfg.__dict__)
        print(json.dumps(res, indent=2))
        if args.out:
            entry.write_json(args.out, res, indent=2)
        return 0
    if args.quick:
        entry.quick_sizes(ap, argv, args, pairs=2, repeat=1)
    t0 = time.perf_counter()
    rows = bench(args.pairs, args.repeat)
    print(f"active search on KITTI 07, {args.pairs} frame pairs, best of {args.repeat}, one process")
    print(f"{'corr':>4} | {'zncc ms':>8} {'Hz':>8} {'found':>6} {'img %':>6} | "
          f"{'nearest ms':>10} {'Hz':>8} {'found':>6}")
    for r in rows:
        print(f"{r['corrections']:>4} | {r['zncc_ms']:8.3f} {r['zncc_hz']:8.0f} {r['zncc_found_per_frame']:6.1f} "
              f"{100 * r['zncc_image_fraction']:6.2f} | {r['nearest_ms']:10.3f} {r['nearest_hz']:8.0f} "
              f"{r['nearest_found_per_frame']:6.1f}")
    print(f"total {time.perf_counter() - t0:.1f} s")
    out = args.out or ROOT / "benchmarks" / "results" / "active_search.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(out, {"pairs": args.pairs, "repeat": args.repeat, "rows": rows}, indent=2)
    plot(rows, args.pairs, args.repeat, out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
