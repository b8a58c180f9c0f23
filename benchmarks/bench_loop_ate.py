"""What loop closures buy the visual iSAM2: ATE with and without them (issue 6).

One process, the default synthetic image sequence (300 VGA frames, 1.5 laps,
the sequence's noisy odometry), the default Harris front end, and four runs of
:func:`graphslam.pipelines.spatial.run`:

- ``local map``: landmarks predicted for active search only if observed within
  the last ``--window`` frames (``isam2_visual.predict_window_frames``), so an
  old place is recognised only by a loop closure: without closures this is
  visual odometry, the "same run without loop closure" of issue 6;
- ``full map`` (the default): every mapped landmark in view is predicted, so
  active search itself re-finds old landmarks on a revisit;

each without and with :class:`graphslam.pipelines.loop_closing.VisualLoopCloser` (the
detector with its defaults and a 1000-word tree trained on the sequence, the
metric PnP pose, the redundancy rule). Closures are checked against the
sequence's revisit pairs (within 2 frames: ``revisit_pair_closures``) and, as
``bench_loop_revisit.py`` counts frames that see the same place, a later visit of it
(``SyntheticImageSequence.later_visit``) counting as true too (``true_closures``;
``outside_rule`` lists the others as (query, match)).

    python benchmarks/bench_loop_ate.py [--window 30] [--odometry none] [--quick] [--out FILE]

``--odometry none``: the same four runs from the camera alone (monocular start,
PnP tracking; ATE after the Sim(3) fit), where closures are PnP poses against
the old map in its own scale. ``--window 10 --odometry none`` is the setting of
``tests/graphslam/backends/test_camera_alone.py``'s local-map closure test.

JSON (default ``benchmarks/results/loop_ate.json``) and its PNG beside it
(ATE per run, odometry alone for scale). ``--quick``: an 80-frame sequence
(the first 0.8 lap of the same room: a smoke run of the code path).

Target (issue 6): with closures, ATE at most half of the same run without.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import platform
import sys
import time
from pathlib import Path

from tqdm import tqdm

from frontend.orb import OrbDetector
from frontend.tracking import Tracker
from frontend.tracking_config import TrackerConfig
from graphslam.pipelines import spatial as vp
from graphslam.pipelines.common import whole  # a cut run is no row
from graphslam.pipelines.place_recognition import train_vocabulary
from loopclosure.detector import LoopDetectorConfig
from graphslam.backends.spatial.isam2 import VisualIsam2Backend
from graphslam.backends.spatial.isam2_config import VisualIsam2Config
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from graphslam.pipelines.loop_closing import VisualLoopCloser
from loopclosure.detector import LoopDetector
import entry  # noqa: E402  (beside this script: argparse types)

HERE = Path(__file__).resolve().parent


def plot(rows: list[dict], n_frames: int, out: Path) -> Path:
    """ATE of the four runs (without and with closures, per map mode), odometry alone for scale."""
    from plotting import Panel, save_figure  # beside this script

    modes = list(dict.fromkeys(r["mode"] for r in rows))
    series = {("with loop closures" if loops else "without"):
              (modes, [next(r["ate_rmse_m"] for r in rows if r["mode"] == m and r["loops"] == loops)
                       for m in modes]) for loops in (False, True)}
    title = f"Visual iSAM2 with and without loop closures, synthetic sequence ({n_frames} frames)"
    return save_figure(out, title, [
        Panel("ATE (target: with closures at most half of without)", "map used by active search",
              "ATE RMSE [m]", series, kind="bar",
              targets=({} if rows[0]["odometry_ate_rmse_m"] is None
                       else {"odometry alone": rows[0]["odometry_ate_rmse_m"]}))], ncols=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window", type=entry.count, default=30,
                    help="prediction window of the local-map runs, frames (default 30)")
    ap.add_argument("--odometry", choices=("sequence", "none"), default="sequence",
                    help="the sequence's noisy odometry (default) or none: the camera alone")
    ap.add_argument("--quick", action="store_true", help="an 80-frame sequence (smoke size)")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "loop_ate.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)

    seq = make_synthetic_images(SyntheticImagesConfig(n_frames=80) if args.quick else None)
    orb = OrbDetector(LoopDetectorConfig().orb)  # the detector's own ORB, as graphslam run --loops
    t0 = time.perf_counter()
    descs = [orb.detect(seq.load(i)).descriptors
             for i in tqdm(range(len(seq)), desc="vocabulary ORB", file=sys.stderr, leave=False)]
    vocab = train_vocabulary(descs, 1000)
    vocab_s = time.perf_counter() - t0
    partners: dict[int, list[int]] = {}
    for i, j in seq.revisit_pairs:
        partners.setdefault(int(j), []).append(int(i))

    rows = []
    for mode, window in (("local map", args.window), ("full map", 0)):
        for loops in (False, True):
            closer = VisualLoopCloser(LoopDetector(vocab, K=seq.K)) if loops else None
            alone = {"robot_model": "constant_velocity"} if args.odometry == "none" else {}
            backend = VisualIsam2Backend(VisualIsam2Config(predict_window_frames=window, **alone))
            res = whole(vp.run(seq, backend, Tracker(TrackerConfig(), follow_unmapped=True,
                                                camera_alone=args.odometry == "none"),
                               config=vp.VisualRunConfig(odometry=args.odometry),
                               loop_closer=closer, progress=True))
            m = vp.compute_metrics(res).to_dict()
            row = {"mode": mode, "window": window, "loops": loops, "ate_rmse_m": m["ate_rmse_m"],
                   "odometry_ate_rmse_m": m["odometry_ate_rmse_m"], "wall_s": res.wall_s,
                   "odometry": args.odometry, "alignment": m["alignment"]}
            if closer is not None:
                strict = [any(abs(c.frame_a - i) <= 2 for j in range(c.frame_b - 2, c.frame_b + 3)
                              for i in partners.get(j, [])) for c in closer.closures]
                # outside the revisit rule, a later visit of the same place still counts as true
                # (bench_loop_revisit.py's soft truth); a recent frame does not
                same = [t or seq.later_visit(c.frame_b, c.frame_a)
                        for c, t in zip(closer.closures, strict, strict=True)]
                row.update(closer.stats, true_closures=sum(same), revisit_pair_closures=sum(strict),
                           outside_rule=[(c.frame_b, c.frame_a) for c, t in zip(closer.closures, strict,
                                                                              strict=True) if not t])
            rows.append(row)

    print(f"synthetic image sequence, {len(seq)} frames, path "
          f"{vp.compute_metrics(res).path_length_m:.2f} m; vocabulary {vocab.n_words_} words "
          f"({vocab_s:.1f} s)")
    head = (f"{'mode':<10} {'loops':>5} {'ATE [m]':>8} {'ratio':>6} {'added':>6} {'true':>5} "
            f"{'redund.':>7} {'pnp rej.':>8} {'wall [s]':>8}")
    print(head)
    print("-" * len(head))
    for r in rows:
        base = next(b for b in rows if b["mode"] == r["mode"] and not b["loops"])
        ratio = r["ate_rmse_m"] / base["ate_rmse_m"]
        print(f"{r['mode']:<10} {'yes' if r['loops'] else 'no':>5} {r['ate_rmse_m']:>8.4f} "
              f"{ratio:>6.2f} {r.get('closures', ''):>6} {r.get('true_closures', ''):>5} "
              f"{r.get('redundant', ''):>7} {r.get('pnp_rejected', ''):>8} {r['wall_s']:>8.1f}")
        r["ratio_to_without"] = ratio
    if rows[0]["odometry_ate_rmse_m"] is not None:
        print(f"odometry alone: ATE {rows[0]['odometry_ate_rmse_m']:.4f} m")
    else:
        print(f"camera alone: ATE after the {rows[0]['alignment']} fit")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {"benchmark": "loop_ate", "rows": rows, "vocabulary_s": vocab_s,
                                "machine": {"python": platform.python_version(),
                                            "platform": platform.platform()}}, indent=2)
    print(f"wrote {args.out}")
    plot(rows, len(seq), args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
