"""Sequential against batch active search for the monocular EKF (issue 19 item 2).

The whole visual loop (:func:`graphslam.pipelines.spatial.run`: Harris front
end, ZNCC active search, monocular EKF with 20 landmarks and 10 corrections per
frame, 5 initialisations per frame, the sequence's own noisy odometry) on the
synthetic VGA image sequence, seeds ``--seeds``, three ways:

* ``batch`` (the floor: what a user runs by default): the frame is predicted
  once, every ellipse comes from that prediction, and the filter corrects with
  the 10 matches in one batch after the search (one-point RANSAC, then rescue
  by the chi-square gate);
* ``sequential`` (RT-SLAM, paper section 4.4): largest ellipse first, the
  filter corrects with each match as soon as it is found (gated alone), the
  landmarks still to search are re-predicted from the corrected state and
  re-sorted, the next one is searched inside its new, smaller ellipse;
* ``sequential + RANSAC 1 in 2`` (the paper's RT-SLAM variant, section 5.1:
  "une correction sur 2 se fait par la methode One-Point Ransac";
  ``ransac_every = 2``): the first 5 matches are found in their predicted
  ellipses and corrected together through one-point RANSAC, the other 5
  sequentially.

Per run: ATE (SE(3)-aligned RMSE, metres), time per frame (tracking and
filter, images rendered beforehand; ``timing.alternate`` alternates the three
orders run by run and reports the median wall time; the process CPU time per
frame of the last run is given too, and plotted: steadier on a loaded
machine), and the searches: landmarks searched
and found per frame, the share of searches that found a match inside their
ellipse (found / searched: a sequential ellipse that shrank past the true
point finds nothing, or a wrong point), the mean image fraction the ellipses
cover, and the share of matches the filter accepted (RANSAC / gate).

Usage: ``python benchmarks/bench_sequential_search.py [--seeds 0,1,2]
[--frames N] [--repeats R] [--quick] [--out FILE.json]``; default output
``benchmarks/results/sequential_search.json`` and the PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import timing  # noqa: E402  (beside this script)
from filters.mono_ekf import MonoEkf  # noqa: E402
from filters.mono_ekf_config import MonoEkfConfig  # noqa: E402
from frontend.active_search import ActiveSearchConfig  # noqa: E402
from frontend.harris import HarrisConfig  # noqa: E402
from frontend.tracking import Tracker, TrackerConfig  # noqa: E402
from graphslam.pipelines import spatial as vp  # noqa: E402
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images  # noqa: E402

#: label -> (order, ransac_every)
ORDERS = {"batch": ("batch", 0), "sequential": ("sequential", 0),
          "sequential + RANSAC 1 in 2": ("sequential", 2)}
CORRECTIONS = 10
COMMAND = "python benchmarks/bench_sequential_search.py"


class Prerendered:
    """An image sequence whose first frames are rendered beforehand (rendering is not
    part of the loop being timed); everything else is the wrapped sequence's."""

    def __init__(self, seq, frames: int):
        self._seq = seq
        self._images = [seq.load(k) for k in range(min(frames, len(seq)))]

    def load(self, k: int) -> np.ndarray:
        return self._images[k]

    def __len__(self) -> int:
        return len(self._images)

    def __getattr__(self, name):
        return getattr(self._seq, name)


class CpuTimedDetector:
    """Forwards ``detect`` to the tracker's detector and records each call's process CPU
    time (the very call the tracker makes, inside ``track``)."""

    def __init__(self, inner):
        self._inner = inner
        self.cpu_s: list[float] = []

    def detect(self, image):
        c = time.process_time()
        out = self._inner.detect(image)
        self.cpu_s.append(time.process_time() - c)
        return out

    def __getattr__(self, name):
        return getattr(self._inner, name)


def visual_run(seq, *, order: str = "batch", ransac_every: int = 0, corrections: int = CORRECTIONS,
               max_landmarks: int = 20, detector: str = "harris", arithmetic: str = "float",
               linearity_threshold: float = 0.1, frames: int | None = None) -> dict:
    """One monocular EKF run over ``seq`` (its first ``frames``; 5 initialisations per frame
    at most); returns
    its ATE, wall time, search counts and, per frame (frame 0 excluded), the process CPU
    seconds between the ends of consecutive frames (``frame_cpu_s``: steadier than the
    wall clock on a shared machine), those of detection (``frame_detect_cpu_s``) and the
    landmarks in the state (``frame_landmarks``)."""
    backend = MonoEkf(MonoEkfConfig(max_corrections=corrections, max_landmarks=max_landmarks,
                                    max_init_per_frame=5, linearity_threshold=linearity_threshold))
    tracker = Tracker(TrackerConfig(detector=detector), harris=HarrisConfig(arithmetic=arithmetic),
                      active_search=ActiveSearchConfig(order=order, ransac_every=ransac_every),
                      follow_unmapped=False)
    tracker.detector = detector_timer = CpuTimedDetector(tracker.detector)
    counts = {"searched": 0, "found": 0, "pixels": 0.0, "frames": 0}
    stamps, landmarks = [], []

    def on_frame(k, image, tracking, be):
        stamps.append(time.process_time())
        landmarks.append(be.num_landmarks)
        counts["searched"] += tracking.n_searched
        counts["found"] += tracking.n_found
        counts["pixels"] += tracking.image_fraction
        counts["frames"] += 1

    result = vp.run(seq, backend, tracker, config=vp.VisualRunConfig(odometry="sequence"),
                    on_frame=on_frame, max_frames=frames)
    if result.interrupted:  # SIGTERM / Ctrl-C stop a run between frames: not a full measurement
        raise SystemExit(f"run interrupted after {result.frames} frames")
    m = vp.compute_metrics(result)
    st = result.estimate.stats
    n = max(counts["frames"] - 1, 1)  # frame 0 has nothing to search
    detect_s = float(np.sum(result.tracking["detect_s"]))
    return {"ate_rmse_m": m.ate_rmse_m, "frames": result.frames, "wall_s": result.wall_s,
            "detect_s": detect_s, "searched_per_frame": counts["searched"] / n,
            "found_per_frame": counts["found"] / n,
            "inside_share": counts["found"] / max(counts["searched"], 1),
            "image_fraction": counts["pixels"] / n,
            "accepted_share": st["corrections"] / max(st["corrections"] + st["ransac_rejected"], 1),
            "wTc": result.estimate.wTc, "wTc_true": np.asarray(seq.wTc_true[:result.frames]),
            "wTc_odometry": result.odometry_wTc, "frame_cpu_s": np.diff(stamps),
            "frame_detect_cpu_s": np.asarray(detector_timer.cpu_s[1:]),
            "frame_landmarks": np.asarray(landmarks[1:])}


def bench_seed(seed: int, frames: int, repeats: int) -> dict:
    seq = Prerendered(make_synthetic_images(SyntheticImagesConfig(seed=seed)), frames)
    last: dict[str, dict] = {}

    def runner(label):
        order, every = ORDERS[label]
        return lambda: last.__setitem__(label, visual_run(seq, order=order, ransac_every=every))

    t = timing.alternate({label: runner(label) for label in ORDERS}, repeats, warmup=0)
    rows = {}
    for label, r in last.items():
        r["cpu_ms_per_frame"] = 1e3 * float(np.mean(r["frame_cpu_s"]))
        r = {k: v for k, v in r.items() if not k.startswith(("wTc", "frame_"))}
        r["ms_per_frame"] = 1e3 * t[label].median_s / r["frames"]
        r["timing"] = timing.timing_dict(t[label])
        rows[label] = r
    return rows


def plot(seeds: list[int], per_seed: dict, out: Path) -> Path:
    from plotting import Panel, save_figure  # beside this script

    names = [str(s) for s in seeds]

    def series(key, scale=1.0):
        return {label: (names, [scale * per_seed[s][label][key] for s in seeds]) for label in ORDERS}

    return save_figure(out, f"Sequential vs batch active search, mono EKF, {CORRECTIONS} corrections "
                            "per frame, synthetic VGA sequence", [
        Panel("trajectory error (lower is better)", "seed", "ATE RMSE [m]", series("ate_rmse_m"),
              kind="bar"),
        Panel("time per frame (tracking + filter)", "seed", "process CPU ms per frame",
              series("cpu_ms_per_frame"), kind="bar"),
        Panel("searches that found a match inside their ellipse", "seed", "found / searched [%]",
              series("inside_share", 100.0), kind="bar", ylim=(80.0, 100.5)),
        Panel("image covered by the search ellipses", "seed", "image fraction [%]",
              series("image_fraction", 100.0), kind="bar")])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2", help="synthetic sequence seeds, comma-separated")
    ap.add_argument("--frames", type=int, default=300, help="frames per run (the sequence has 300)")
    ap.add_argument("--repeats", type=int, default=2, help="alternated runs per order (median)")
    ap.add_argument("--quick", action="store_true", help="seed 0, 30 frames, one run each")
    ap.add_argument("--out", type=Path,
                    default=Path(__file__).resolve().parent / "results" / "sequential_search.json")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    if args.quick:
        seeds, args.frames, args.repeats = seeds[:1], 30, 1
    per_seed = {}
    print(f"{'seed':>4} {'order':<27} {'ATE m':>7} {'ms/frame':>8} {'cpu ms':>6} {'srch':>5} {'found':>5} "
          f"{'inside %':>8} {'image %':>7} {'accept %':>8}")
    with timing.blas_threads(1):
        for s in seeds:
            per_seed[s] = bench_seed(s, args.frames, args.repeats)
            for label, r in per_seed[s].items():
                print(f"{s:>4} {label:<27} {r['ate_rmse_m']:>7.4f} {r['ms_per_frame']:>8.1f} "
                      f"{r['cpu_ms_per_frame']:>6.1f} "
                      f"{r['searched_per_frame']:>5.1f} {r['found_per_frame']:>5.1f} "
                      f"{100 * r['inside_share']:>8.1f} {100 * r['image_fraction']:>7.2f} "
                      f"{100 * r['accepted_share']:>8.1f}", flush=True)
    mean = {label: {k: float(np.mean([per_seed[s][label][k] for s in seeds]))
                    for k in ("ate_rmse_m", "ms_per_frame", "cpu_ms_per_frame", "inside_share",
                              "image_fraction")}
            for label in ORDERS}
    print("\nmean over seeds:")
    for label, m in mean.items():
        print(f"  {label:<27} ATE {m['ate_rmse_m']:.4f} m, {m['ms_per_frame']:.1f} ms/frame "
              f"(CPU {m['cpu_ms_per_frame']:.1f}), "
              f"inside {100 * m['inside_share']:.1f} %, image {100 * m['image_fraction']:.2f} %")
    floor = "the batch order: one prediction per frame, the 10 matches corrected at once " \
            "(same tracker, filter and sequence)"
    cmd = COMMAND + (" --quick" if args.quick else f" --seeds {args.seeds} --frames {args.frames}")
    summaries = [timing.summary(f"sequential active search ({label}), time per frame",
                                mean[label]["ms_per_frame"] / 1e3, mean["batch"]["ms_per_frame"] / 1e3,
                                target=None, floor=floor, command=cmd,
                                ate_rmse_m=mean[label]["ate_rmse_m"],
                                batch_ate_rmse_m=mean["batch"]["ate_rmse_m"],
                                cpu_ratio=mean[label]["cpu_ms_per_frame"] / mean["batch"]["cpu_ms_per_frame"],
                                inside_share=mean[label]["inside_share"])
                 for label in ORDERS if label != "batch"]
    payload = {"benchmark": "sequential_search", "corrections_per_frame": CORRECTIONS,
               "seeds": seeds, "frames": args.frames, "repeats": args.repeats,
               "results": {str(s): v for s, v in per_seed.items()}, "mean": mean,
               "summaries": summaries}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}")
    plot(seeds, per_seed, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
