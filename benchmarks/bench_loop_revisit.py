"""Revisits at any frame rate: the covisibility rule against the old frame window (issue 33).

One process, the shipped vocabulary (``graphslam loops``' default), the
detector's defaults except ``[loops] mode``, compared in the same run:
``"covisibility"`` (the default: a query excludes the images it shares
tracked features with, :mod:`loopclosure.covisibility`) and ``"auto"`` (the
previous default: a 40-frame or 10 s window for video, overlapping
predecessors for a sparse folder).

Sequences, each with its truth:

- **synthetic** (the default synthetic image sequence, 300 VGA frames, 1.5
  laps of one room, K known), and the same subsampled by 2, 4 and 8 (at 8
  the revisit begins about 25 frames after the first pass). A closure is true
  when it lies within ``--tol`` original frames of a pair of the sequence's
  revisit rule, or its frames see the same place (more than half of one view's
  scene points seen by the other: the sequence's soft truth,
  ``SyntheticImageSequence.same_place``; ``false_by_rule`` counts the closures
  outside the rule); recall is over the frames that have a partner among the
  subsampled frames.
- **KITTI 07 driven twice**: frames 0-159 taken every ``step`` frames, then the
  drive again from frame ``step / 2`` (the same road, other images, as a
  second drive would give). Steps 2, 4, 8 and 10 (KITTI's 10 Hz taken at
  1 Hz): the second pass begins 80, 40, 20 and 16 frames after the first. A closure is true when it joins the two
  passes at most ``NEAR_M[1]`` m apart (ground truth); a closure inside a pass
  (the road just driven) is false. Recall is over the second pass's frames.
- **desk** (10 photos, photo 10 back at photo 1; no intrinsics): the closures.
- **KITTI 07 frames 0-159** (a drive with no revisit, K known): the closures.

Every closure's relative pose (``query T match``; rotation, and translation
direction where the cameras are at least ``MIN_BASELINE_M`` apart) is
compared with the truth: the table gives the largest rotation error (an
essential matrix over a baseline of 0.15-0.3 m with the scene 6 m away
gives up to about 3 degrees on the synthetic room, a right place all the same).

Also the wall time of the loop pass over 100 VGA images (the synthetic
sequence's first 100, ORB included, the images read from PNG files as
``graphslam loops`` reads them).

Prints a table, writes ``benchmarks/results/loop_revisit.json`` (or ``--out``)
and its PNG beside it. ``--quick``: synthetic 100 frames (subsampled by 1 and
4), KITTI twice at step 8, no timing pass.

    python benchmarks/bench_loop_revisit.py [--quick] [--data ../shared/data] [--out FILE]

Targets (issue 33): precision 1.0 everywhere; recall >= 0.98 on the synthetic
sequence at every subsampling, >= 0.8 on KITTI driven twice; the desk gives
only (10, 01), KITTI 07 0-159 nothing; 100 VGA images under 10 s.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import dataclasses
import platform
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from frontend.image import load_gray
from frontend.orb import OrbDetector
from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses
from graphslam.sources.spatial.sequence import folder_images
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from loopclosure.detector import LoopDetector, LoopDetectorConfig
from loopclosure.shipped import load_shipped_vocabulary
import entry  # noqa: E402  (beside this script: argparse types)

HERE = Path(__file__).resolve().parent
DATA_DEFAULT = HERE.parent.parent / "shared" / "data"
#: A closure joining the two drives at most this far apart (m) is the same place.
NEAR_M = (0.0, 5.0)
#: Translation directions of cameras closer than this are not scored (a unit vector
#: between two nearly coincident centres is noise).
MIN_BASELINE_M = 0.5
MODES = ("covisibility", "auto")
#: KITTI 07 driven twice every Nth frame: KITTI runs at 10 Hz, so 10 is a route
#: driven twice at 1 Hz (issue 33's held-out case).
KITTI_STEPS = (2, 4, 8, 10)


def run_detector(feats, vocab, mode: str, K=None) -> LoopDetector:
    """The detector with its defaults but ``mode`` over precomputed features."""
    det = LoopDetector(vocab, dataclasses.replace(LoopDetectorConfig(), mode=mode), K=K)
    for f in feats:
        det.process_features(f.xy_px, f.descriptors)
    return det


def synthetic_rows(seq, feats, vocab, steps, tol: int) -> list[dict]:
    """Precision and recall on the synthetic sequence subsampled by each of ``steps``."""
    rows = []
    for s in steps:
        idx = np.arange(0, len(feats), s)
        kept = set(idx.tolist())
        pairs = [(i, j) for i, j in seq.revisit_pairs if i in kept and j in kept]
        partners: dict[int, list[int]] = {}
        for i, j in pairs:
            partners.setdefault(j, []).append(i)
        for mode in MODES:
            t0 = time.perf_counter()
            det = run_detector([feats[k] for k in idx], vocab, mode, seq.K)
            oq = [(int(idx[c.query]), int(idx[c.match])) for c in det.closures]
            by_rule = [any(abs(m - i) <= tol for i, j in seq.revisit_pairs if abs(q - j) <= tol)
                       for q, m in oq]
            hit = {q for (q, m), t in zip(oq, by_rule) if t and q in partners}
            # a closure outside the revisit rule is true when its frames see the same place
            true = [t or seq.same_place(q, m) for (q, m), t in zip(oq, by_rule)]
            errors = pose_errors(det, seq.wTc_true, idx)
            row = _row(f"synthetic /{s}", mode, len(idx), oq, true, len(partners), len(hit), det,
                       time.perf_counter() - t0, errors,
                       false_by_rule=len(oq) - int(sum(by_rule)))
            # the closures outside the rule: distance, heading, shared view, rotation error
            row["outside_rule"] = [{**_apart(seq.wTc_true, q, m), "rotation_error_deg": e[0],
                                    "shared_view": seq.shared_view(q, m)}
                                   for (q, m), t, e in zip(oq, by_rule, errors) if not t]
            rows.append(row)
    return rows


def _apart(wTc: np.ndarray, q: int, m: int) -> dict:
    """Distance (m) and heading difference (deg) of two synthetic frames, for false closures."""
    fq, fm = wTc[q][:3, 2], wTc[m][:3, 2]
    dyaw = np.arctan2(fq[1], fq[0]) - np.arctan2(fm[1], fm[0])
    return {"query": q, "match": m,
            "distance_m": float(np.linalg.norm(wTc[q][:3, 3] - wTc[m][:3, 3])),
            "heading_deg": float(np.degrees(abs((dyaw + np.pi) % (2 * np.pi) - np.pi)))}


def kitti_twice_rows(feats, wTc: np.ndarray, K, vocab, steps) -> list[dict]:
    """KITTI 07 frames every ``step``, then again from ``step // 2`` (module docstring);
    ``wTc`` (N, 4, 4) the ground truth."""
    pos = wTc[:, :3, 3]
    rows = []
    for s in steps:
        first = np.arange(0, len(feats), s)
        second = np.arange(s // 2, len(feats), s)
        order = np.concatenate([first, second])
        n1 = len(first)
        d12 = np.linalg.norm(pos[second][:, None] - pos[first][None], axis=2)
        revisit = np.flatnonzero(d12.min(axis=1) <= NEAR_M[1])  # second-pass frames with a partner
        for mode in MODES:
            t0 = time.perf_counter()
            det = run_detector([feats[k] for k in order], vocab, mode, K)
            true, pairs = [], []
            for c in det.closures:
                cross = c.query >= n1 > c.match
                d = float(np.linalg.norm(pos[order[c.query]] - pos[order[c.match]]))
                true.append(bool(cross and d <= NEAR_M[1]))
                pairs.append((int(order[c.query]), int(order[c.match])))
            hit = {c.query - n1 for c, t in zip(det.closures, true) if t}
            rows.append(_row(f"KITTI 07 twice /{s}", mode, len(order), pairs, true, len(revisit),
                             len(hit & set(revisit.tolist())), det, time.perf_counter() - t0,
                             pose_errors(det, wTc, order), second_pass_starts_after=n1))
    return rows


def pose_errors(det, wTc: np.ndarray, frame_of) -> list[tuple[float, float]]:
    """Per closure: (rotation error deg, translation direction error deg or NaN when the
    cameras are under ``MIN_BASELINE_M`` apart) of its ``query T match`` against the truth
    (``wTc`` (N, 4, 4) camera-to-world, ``frame_of`` maps detector indices to its rows)."""
    out = []
    for c in det.closures:
        if c.R is None:
            continue
        T = np.linalg.inv(wTc[frame_of[c.query]]) @ wTc[frame_of[c.match]]
        cos = (np.trace(c.R.T @ T[:3, :3]) - 1) / 2
        rot = float(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        base = np.linalg.norm(T[:3, 3])
        tdir = float(np.degrees(np.arccos(np.clip(T[:3, 3] @ c.t_unit / base, -1, 1)))) \
            if base >= MIN_BASELINE_M else float("nan")
        out.append((rot, tdir))
    return out


def _row(name, mode, frames, pairs, true, n_revisit, n_hit, det, wall, errors=(), **extra) -> dict:
    n = len(pairs)
    rot = [e[0] for e in errors]
    tdir = [e[1] for e in errors if np.isfinite(e[1])]
    return {"sequence": name, "mode": mode, "frames": frames, "accepted": n,
            "false": n - int(sum(true)), "precision": sum(true) / n if n else None,
            "revisit_frames": n_revisit, "recalled_frames": n_hit,
            "recall": n_hit / n_revisit if n_revisit else None,
            "median_excluded": float(np.median(det.excluded)) if det.excluded else None,
            "false_closures": [p for p, t in zip(pairs, true) if not t],
            "max_rotation_error_deg": max(rot) if rot else None,
            "max_direction_error_deg": max(tdir) if tdir else None,
            "detect_s": wall, **extra}


def folder_closures(folder: Path, vocab, mode: str, K=None) -> list[tuple[str, str]]:
    paths = folder_images(folder)
    orb = OrbDetector(LoopDetectorConfig().orb)
    det = run_detector([orb.detect(load_gray(p)) for p in paths], vocab, mode, K)
    return [(paths[c.query].name, paths[c.match].name) for c in det.closures]


def timing_100_vga(seq, vocab) -> float:
    """Seconds for the loop pass over 100 VGA PNG files: read, ORB, detector (defaults)."""
    from graphslam.pipelines.place_recognition import detect_all, detect_loops

    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i in range(100):
            p = Path(tmp) / f"{i:04d}.png"
            cv2.imwrite(str(p), seq.load(i))
            paths.append(p)
        t0 = time.perf_counter()
        config = LoopDetectorConfig()
        feats = detect_all(paths, OrbDetector(config.orb))
        detect_loops(paths, LoopDetector(vocab, config), feats)
        return time.perf_counter() - t0


def plot(rows: list[dict], out: Path) -> Path:
    from plotting import Panel, save_figure  # beside this script

    names = sorted({r["sequence"] for r in rows}, key=[r["sequence"] for r in rows].index)

    def series(key, mode):
        by = {r["sequence"]: r for r in rows if r["mode"] == mode}
        return (names, [np.nan if by[n][key] is None else 100 * by[n][key] for n in names])

    return save_figure(out, "Loop closures on revisits: covisibility rule vs the old frame window", [
        Panel("recall", "sequence", "[%]", {f"{m}": series("recall", m) for m in MODES},
              kind="bar", ylim=(0, 105), targets={"target 80 %": 80.0}),
        Panel("precision", "sequence", "[%]", {f"{m}": series("precision", m) for m in MODES},
              kind="bar", ylim=(0, 105))])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (see the docstring)")
    ap.add_argument("--tol", type=entry.count_or_zero, default=2, help="synthetic: frame tolerance of a true closure")
    ap.add_argument("--data", type=Path, default=DATA_DEFAULT, help="the shared data folder")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "loop_revisit.json")
    args = ap.parse_args(argv)
    vocab = load_shipped_vocabulary()
    orb = OrbDetector(LoopDetectorConfig().orb)
    seq = make_synthetic_images(SyntheticImagesConfig(n_frames=100) if args.quick else None)
    feats = [orb.detect(seq.load(i)) for i in range(len(seq.image_paths))]
    rows = synthetic_rows(seq, feats, vocab, (1, 4) if args.quick else (1, 2, 4, 8), args.tol)
    out: dict = {"benchmark": "loop_revisit", "quick": args.quick}
    kdir = args.data / "kitti07"
    if (kdir / "image_0").is_dir():
        K, _ = read_kitti_calib(kdir / "calib.txt")
        wTc = read_kitti_poses(kdir / "poses.txt")
        kfeats = [orb.detect(load_gray(p)) for p in folder_images(kdir / "image_0")]
        rows += kitti_twice_rows(kfeats, wTc, K, vocab, (8,) if args.quick else KITTI_STEPS)
        if not args.quick:
            out["kitti07_closures"] = {m: len(run_detector(kfeats, vocab, m, K).closures)
                                       for m in MODES}
    else:  # said, not silently a benchmark of the synthetic revisits alone
        print(f"no KITTI 07 images at {kdir / 'image_0'}: its rows are left out", file=sys.stderr)
    desk = args.data / "slambook2_desk" / "images"
    if desk.is_dir():
        out["desk_closures"] = {m: folder_closures(desk, vocab, m) for m in MODES}
    else:
        print(f"no desk photos at {desk}: desk_closures is left out", file=sys.stderr)
    if not args.quick:
        out["loops_100_vga_s"] = timing_100_vga(seq, vocab)
    out["rows"] = rows
    out["machine"] = {"python": platform.python_version(), "platform": platform.platform()}
    print(f"{'sequence':22s} {'mode':13s} {'frames':>6s} {'closures':>8s} {'false':>5s} "
          f"{'precision':>9s} {'recall':>7s} {'excl.':>6s} {'max rot err':>11s} {'outside rule':>12s}")
    for r in rows:
        p = "-" if r["precision"] is None else f"{r['precision']:.3f}"
        rc = "-" if r["recall"] is None else f"{r['recall']:.3f}"
        print(f"{r['sequence']:22s} {r['mode']:13s} {r['frames']:6d} {r['accepted']:8d} "
              f"{r['false']:5d} {p:>9s} {rc:>7s} {r['median_excluded'] or 0:6.0f} "
              f"{r['max_rotation_error_deg'] or 0:10.2f}° {r.get('false_by_rule', '-'):>12}")
    for key in ("kitti07_closures", "desk_closures", "loops_100_vga_s"):
        if key in out:
            print(f"{key}: {out[key]}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, out, indent=1)
    print(f"wrote {args.out} and {plot(rows, args.out)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
