"""Precision and recall of loop closures on the synthetic image sequence (issue 6).

One process: render the default synthetic image sequence
(:func:`graphslam.sources.spatial.synthetic_images.make_synthetic_images`, 300 VGA
frames, 1.5 laps), ORB features, a vocabulary tree trained on the sequence
itself (as ``graphslam loops`` does without ``--vocab``: 10-way tree of
depth 3, the 300 strongest descriptors per image), then
:class:`loopclosure.detector.LoopDetector` with its defaults, and a few
variants that loosen one safeguard at a time to show what each buys.

Definitions (``revisit_pairs`` of the sequence is the ground truth, ``(i, j)``
with ``i < j``; tolerance ``--tol`` frames, default 2):

- a closure ``(q, m)`` (query q, earlier match m) is **true by the rule** when
  it is a true pair or within the index tolerance of one: some true ``(i, j)``
  has ``|m - i| <= tol`` and ``|q - j| <= tol``. **Strict** also asks ``j == q``
  (the query frame itself has a true partner near m). A closure is **true**
  (precision = true / accepted) when it is true by the rule or its frames see
  the same place (the sequence's soft truth,
  :meth:`~graphslam.sources.spatial.synthetic_images.SyntheticImageSequence.same_place`:
  more than half of one view's scene points seen by the other), e.g. (196, 0)
  of the default sequence: 0.54 m and 21 deg apart (the rule takes <= 1 m and
  <= 10 deg), 81 % of the query's points in the match. The JSON gives all
  three precisions and the distance and heading of every strict miss;
- **recall** = the fraction of frames j that have at least one true partner
  (some ``(i, j)`` in ``revisit_pairs``) for which the detector accepted at
  least one true closure ``(j, m)``.

Optionally (``--kitti DIR``, default ``../shared/data/kitti07`` when present)
it also runs the default detector on KITTI 07 frames, a drive with no revisit,
and counts closures (the target is 0).

Prints one table and writes JSON to ``benchmarks/results/loop_pr.json`` (or
``--out``) and its figure beside it (PNG: precision, strict precision and
recall, accepted and false closures, per variant). ``--quick``: a 100-frame
sequence (same room, 1.5 laps), the default variant only, KITTI 07's first 20
frames.

``--real`` instead measures real images with the defaults of ``graphslam
loops`` (shipped vocabulary): the slambook2 desk, KITTI 07 frames 0-159, KITTI
07 pairs 1-5 m apart, the Lund door pairs and pairs of different places
(``benchmarks/loop_real.py`` says what each is), written to
``benchmarks/results/loop_pr_real.json`` and its PNG beside it.

    python benchmarks/bench_loop_pr.py [--tol 2] [--no-variants] [--kitti DIR|none] [--quick] [--out FILE]
    python benchmarks/bench_loop_pr.py --real [--data ../shared/data] [--out FILE]

Targets: 100 % precision, recall >= 80 %; no closure on KITTI 07.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import dataclasses
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from frontend.orb import OrbDetector
from graphslam.pipelines.place_recognition import train_vocabulary
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from loopclosure.detector import LoopDetector, LoopDetectorConfig
from loopclosure.verify import VerifyConfig
import entry  # noqa: E402  (beside this script: argparse types)

HERE = Path(__file__).resolve().parent
KITTI_DEFAULT = HERE.parent.parent / "shared" / "data" / "kitti07"


def precision_recall(closures, revisit_pairs, tol: int, wTc: np.ndarray | None = None,
                     same_place=None) -> dict:
    """Precision (same place, by the rule, strict), recall and counts (definitions in the
    module docstring); ``same_place(q, m)`` the sequence's soft truth, or None."""
    partners: dict[int, list[int]] = {}
    for i, j in revisit_pairs:
        partners.setdefault(int(j), []).append(int(i))
    strict = [any(abs(c.match - i) <= tol for i in partners.get(c.query, [])) for c in closures]
    true = [any(abs(c.match - i) <= tol for j in range(c.query - tol, c.query + tol + 1)
                for i in partners.get(j, [])) for c in closures]
    by_rule = true
    if same_place is not None:
        true = [t or bool(same_place(c.query, c.match)) for c, t in zip(closures, by_rule)]
    hit = {c.query for c, t in zip(closures, strict) if t} & set(partners)
    misses = []
    for c, t in zip(closures, strict):
        if not t:
            m = {"query": c.query, "match": c.match}
            if wTc is not None:
                fq, fm = wTc[c.query][:3, 2], wTc[c.match][:3, 2]
                dyaw = np.arctan2(fq[1], fq[0]) - np.arctan2(fm[1], fm[0])
                m["distance_m"] = float(np.linalg.norm(wTc[c.query][:3, 3] - wTc[c.match][:3, 3]))
                m["heading_deg"] = float(np.degrees(abs((dyaw + np.pi) % (2 * np.pi) - np.pi)))
            misses.append(m)
    n = len(closures)
    return {"accepted": n, "true": int(sum(true)), "false": n - int(sum(true)),
            "precision": sum(true) / n if n else None,
            "false_by_rule": n - int(sum(by_rule)),
            "precision_by_rule": sum(by_rule) / n if n else None,
            "false_strict": n - int(sum(strict)),
            "precision_strict": sum(strict) / n if n else None,
            "revisit_frames": len(partners), "recalled_frames": len(hit),
            "recall": len(hit) / len(partners) if partners else None,
            "false_closures": [(c.query, c.match) for c, t in zip(closures, true) if not t],
            "strict_misses": misses}


def detect(features, vocab, config, verify_config, K, desc: str):
    det = LoopDetector(vocab, config, verify_config, K=K)
    t0 = time.perf_counter()
    for f in tqdm(features, desc=desc, unit="img", file=sys.stderr, leave=False):
        det.process_features(f.xy_px, f.descriptors)
    return det, time.perf_counter() - t0


def plot(rows: list[dict], kitti: dict | None, n_frames: int, out: Path) -> Path:
    """Per variant: precision, strict precision and recall; accepted and false closures."""
    from plotting import Panel, save_figure  # beside this script

    names = [r["variant"] for r in rows]

    def pct(key):
        return [math.nan if r[key] is None else 100 * r[key] for r in rows]

    on_kitti = "" if kitti is None else f"; KITTI 07 ({kitti['frames']} frames): {kitti['closures']} closures"
    return save_figure(out, f"Loop closures on the synthetic image sequence ({n_frames} frames){on_kitti}", [
        Panel("precision and recall", "variant", "[%]",
              {"precision": (names, pct("precision")), "strict precision": (names, pct("precision_strict")),
               "recall": (names, pct("recall"))}, kind="bar", ylim=(0, 105),
              targets={"recall target 80 %": 80.0}),
        Panel("closures", "variant", "closures", {"accepted": (names, [r["accepted"] for r in rows]),
                                                  "false": (names, [r["false"] for r in rows])}, kind="bar")])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tol", type=entry.count_or_zero, default=2, help="frame tolerance of a true closure (default 2)")
    ap.add_argument("--no-variants", action="store_true", help="only the default configuration")
    ap.add_argument("--kitti", default=None,
                    help="KITTI odometry folder with image_0/ (default: ../shared/data/kitti07 "
                         "if present; 'none' to skip)")
    ap.add_argument("--out", type=entry.output_file, default=None,
                    help="JSON to write (default benchmarks/results/loop_pr.json, "
                         "loop_pr_real.json with --real)")
    ap.add_argument("--real", action="store_true", help="real images instead (see the docstring)")
    ap.add_argument("--quick", action="store_true",
                    help="100 frames, default variant, KITTI's first 20 (see the docstring)")
    ap.add_argument("--data", type=Path, default=KITTI_DEFAULT.parent,
                    help="the shared data folder (default ../shared/data)")
    args = ap.parse_args(argv)
    if args.kitti not in (None, "none") and not (Path(args.kitti) / "image_0").is_dir():
        # a folder named and not there was passed over, "kitti07": null, exit 0 (pass 23)
        ap.error(f"--kitti {args.kitti}: no KITTI folder with image_0/ there (none: leave KITTI out)")
    if args.real:
        return real_main(args.data, args.out or HERE / "results" / "loop_pr_real.json")
    args.out = args.out or HERE / "results" / "loop_pr.json"

    base = LoopDetectorConfig()
    vbase = VerifyConfig()
    timings = {}
    t0 = time.perf_counter()
    seq = make_synthetic_images(SyntheticImagesConfig(n_frames=100) if args.quick else None)
    images = [seq.load(i) for i in tqdm(range(len(seq.image_paths)), desc="render", file=sys.stderr,
                                        leave=False)]
    timings["render_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    orb = OrbDetector(base.orb)
    feats = [orb.detect(im) for im in tqdm(images, desc="ORB", file=sys.stderr, leave=False)]
    timings["orb_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    vocab = train_vocabulary([f.descriptors for f in feats], 1000)
    timings["vocab_train_s"] = time.perf_counter() - t0

    variants = [("default", base, vbase)]
    if not (args.no_variants or args.quick):
        variants += [
            ("no feature-share test", base, dataclasses.replace(vbase, min_feature_share=0.0)),
            ("consistency_k=1", dataclasses.replace(base, consistency_k=1), vbase),
            ("no share, k=1, window 20", dataclasses.replace(base, mode="video", consistency_k=1,
                                                             exclude_recent=20),
             dataclasses.replace(vbase, min_feature_share=0.0)),
        ]
    rows = []
    for name, cfg, vcfg in variants:
        det, wall = detect(feats, vocab, cfg, vcfg, seq.K, name)
        pr = precision_recall(det.closures, seq.revisit_pairs, args.tol, seq.wTc_true,
                              seq.same_place)
        rejected = {}
        for r in det.records:
            if not r.accepted:
                key = r.reason.split(" (")[0]
                rejected[key] = rejected.get(key, 0) + 1
        rows.append({"variant": name, **pr, "detect_s": wall, "ms_per_frame": 1000 * wall / len(feats),
                     "rejections": rejected, "loops": dataclasses.asdict(cfg),
                     "loop_verify": dataclasses.asdict(vcfg)})

    kitti = None
    kdir = KITTI_DEFAULT if args.kitti is None else (None if args.kitti == "none" else Path(args.kitti))
    if kdir is not None and (kdir / "image_0").is_dir():
        from graphslam.sources.spatial.sequence import folder_images
        from frontend.image import load_gray

        t0 = time.perf_counter()
        paths = folder_images(kdir / "image_0")[:20 if args.quick else None]
        kf = [orb.detect(load_gray(p)) for p in tqdm(paths, desc="KITTI ORB", file=sys.stderr,
                                                       leave=False)]
        kvoc = train_vocabulary([f.descriptors for f in kf], 1000)
        det, _ = detect(kf, kvoc, base, vbase, None, "KITTI")
        kitti = {"folder": str(kdir), "frames": len(paths), "closures": len(det.closures),
                 "candidates": len(det.records), "total_s": time.perf_counter() - t0,
                 "closure_pairs": [(paths[c.query].name, paths[c.match].name) for c in det.closures]}

    print(f"synthetic image sequence: {len(images)} frames {seq.image_size[0]}x{seq.image_size[1]}, "
          f"{len(seq.revisit_pairs)} revisit pairs, {rows[0]['revisit_frames']} revisit frames; "
          f"vocabulary {vocab.n_words_} words; tolerance {args.tol} frames")
    print(f"timings: render {timings['render_s']:.1f} s, ORB {timings['orb_s']:.1f} s, "
          f"vocabulary {timings['vocab_train_s']:.1f} s")
    head = (f"{'variant':<26} {'accepted':>8} {'false':>6} {'precision':>9} {'strict':>7} "
            f"{'recall':>7} {'ms/frame':>9}")
    print(head)
    print("-" * len(head))

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f}%"

    for r in rows:
        print(f"{r['variant']:<26} {r['accepted']:>8} {r['false']:>6} {pct(r['precision']):>9} "
              f"{pct(r['precision_strict']):>7} {pct(r['recall']):>7} {r['ms_per_frame']:>9.1f}")
    for m in rows[0]["strict_misses"]:
        print(f"default, strict miss: query {m['query']} match {m['match']}: "
              f"{m.get('distance_m', float('nan')):.2f} m, {m.get('heading_deg', float('nan')):.1f} deg apart")
    if kitti is not None:
        print(f"KITTI 07 ({kitti['frames']} frames, default detector, vocabulary trained on the "
              f"folder): {kitti['closures']} closures ({kitti['total_s']:.1f} s)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {
        "benchmark": "loop_pr", "sequence": dataclasses.asdict(seq.config), "tolerance_frames": args.tol,
        "vocabulary_words": vocab.n_words_, "timings": timings, "variants": rows, "kitti07": kitti,
        "machine": {"python": platform.python_version(), "platform": platform.platform()},
    }, indent=2, default=lambda o: o.item() if isinstance(o, np.generic) else str(o))
    print(f"wrote {args.out}")
    plot(rows, kitti, len(images), args.out)
    return 0


def plot_real(r: dict, out: Path) -> Path:
    """``--real``: share of pairs verified (same places high, different places 0) and closures found."""
    from plotting import Panel, save_figure  # beside this script

    d = r["different_places"]
    kinds = ["KITTI 07 pairs 1-5 m apart", "Lund door pairs", "different places"]
    shares = [100 * r["kitti07_near_pairs"]["verified"] / max(r["kitti07_near_pairs"]["pairs"], 1),
              100 * r["lund_pairs"]["verified"] / max(r["lund_pairs"]["pairs"], 1),
              100 * (d["pairs"] - d["rejected"]) / max(d["pairs"], 1)]
    folders = [f"desk ({r['desk']['images']} photos; target 1)", f"KITTI 07 ({r['kitti07']['images']} "
               "frames; target 0)"]
    title = "Place recognition on real images (graphslam loops defaults, shipped vocabulary)"
    return save_figure(out, title, [
        Panel("geometric verification", "image pairs", "pairs verified [%]",
              {"verified": (kinds, shares)}, kind="bar", ylim=(0, 105)),
        Panel("closures of whole folders", "folder", "closures accepted",
              {"closures": (folders, [len(r["desk"]["closures"]), len(r["kitti07"]["closures"])])},
              kind="bar")])


def real_main(data: Path, out: Path) -> int:
    """``--real``: the real-image figures, printed and written as JSON."""
    sys.path.insert(0, str(HERE))
    from loop_real import print_figures, real_figures

    r = real_figures(data)
    print_figures(r)
    out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(out, {"benchmark": "loop_pr_real", **r, "machine": {
        "python": platform.python_version(), "platform": platform.platform()}}, indent=2)
    print(f"wrote {out}")
    plot_real(r, out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
