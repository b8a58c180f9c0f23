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

Scored against the sequence's truth (:func:`truth_scores`): each landmark's
true point is its first pixel back-projected through the rendered depth map
and the true camera (landmarks on a depth edge, where the pixel has no single
true point, are left out); ``outlier_share`` is the share of the matches the
filter accepted that lie more than 3 pixel sigmas from the true projection
(``gross_outlier_share``: 10 sigmas), ``truth_outside_share`` the share of
searches whose true point lay outside the ellipse searched (1 - gate
probability, 1 %, for consistent ellipses). Over the seeds, each order's ATE
minus the batch one's, paired by seed, with its standard error
(``ate_minus_batch_m``, ``ate_minus_batch_se_m``): the per-seed ATE moves by
about 0.01-0.03 m under an immaterial change (any change of which matches
are corrected changes the drift), so a mean difference within two standard
errors is no difference.

Usage: ``python benchmarks/bench_sequential_search.py [--seeds 0,1,2]
[--frames N] [--repeats R] [--quick] [--out FILE.json]``; default output
``benchmarks/results/sequential_search.json`` and the PNG beside it.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
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
from frontend.active_search_config import ActiveSearchConfig  # noqa: E402
from frontend.harris import HarrisConfig  # noqa: E402
from frontend.tracking import Tracker  # noqa: E402
from frontend.tracking_config import TrackerConfig  # noqa: E402
from graphslam.pipelines import spatial as vp  # noqa: E402
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

#: label -> (order, ransac_every, pixel sigma of the tracker and filter)
ORDERS = {"batch": ("batch", 0, 1.0), "sequential": ("sequential", 0, 1.0),
          "sequential + RANSAC 1 in 2": ("sequential", 2, 1.0)}
#: ``--control``: the batch order with the pixel sigma 1 % larger, a change of no
#: consequence to the method, run to measure how far the ATE moves by chance
#: (which matches are corrected changes, and the drift with it).
CONTROL = {"batch, sigma 1.01 px (control)": ("batch", 0, 1.01)}
CORRECTIONS = 10
#: Outlier thresholds against the true projection, in pixel sigmas (the tracker's 1 px).
OUTLIER_SIGMAS, GROSS_SIGMAS = 3.0, 10.0
#: A first pixel whose 3 x 3 depths differ by more than this fraction lies on a depth
#: edge (an occluding contour: foreground and background both in the corner).
DEPTH_EDGE = 0.05
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


def visual_run(seq, *, order: str = "batch", ransac_every: int = 0, sigma_px: float = 1.0,
               corrections: int = CORRECTIONS,
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
    tracker = Tracker(TrackerConfig(detector=detector, sigma_px=sigma_px), harris=HarrisConfig(arithmetic=arithmetic),
                      active_search=ActiveSearchConfig(order=order, ransac_every=ransac_every),
                      follow_unmapped=False)
    tracker.detector = detector_timer = CpuTimedDetector(tracker.detector)
    counts = {"searched": 0, "found": 0, "pixels": 0.0, "frames": 0}
    stamps, landmarks = [], []
    log = {"first": [], "accepted": [], "searched": [], "spent": 0.0}

    def on_frame(k, image, tracking, be):
        c = time.process_time()
        stamps.append(c - log["spent"])  # the recording below is not the loop's time
        landmarks.append(be.num_landmarks)
        counts["searched"] += tracking.n_searched
        counts["found"] += tracking.n_found
        counts["pixels"] += tracking.image_fraction
        counts["frames"] += 1
        record(log, k, tracking, be.last_update)
        log["spent"] += time.process_time() - c

    result = vp.run(seq, backend, tracker, config=vp.VisualRunConfig(odometry="sequence"),
                    on_frame=on_frame, max_frames=frames)
    if result.interrupted:  # SIGTERM / Ctrl-C stop a run between frames: not a full measurement
        raise SystemExit(f"run interrupted after {result.frames} frames")
    m = vp.compute_metrics(result)
    st = result.estimate.stats
    n = max(counts["frames"] - 1, 1)  # frame 0 has nothing to search
    detect_s = float(np.sum(result.tracking["detect_s"]))
    return {**truth_scores(seq, log, sigma_px, tracker.search_config.gate),
            "ate_rmse_m": m.ate_rmse_m, "frames": result.frames, "wall_s": result.wall_s,
            "detect_s": detect_s, "searched_per_frame": counts["searched"] / n,
            "found_per_frame": counts["found"] / n,
            "inside_share": counts["found"] / max(counts["searched"], 1),
            "image_fraction": counts["pixels"] / n,
            "accepted_share": st["corrections"] / max(st["corrections"] + st["ransac_rejected"], 1),
            "wTc": result.estimate.wTc, "wTc_true": np.asarray(seq.wTc_true[:result.frames]),
            "wTc_odometry": result.odometry_wTc, "frame_cpu_s": np.diff(stamps),
            "frame_detect_cpu_s": np.asarray(detector_timer.cpu_s[1:]),
            "frame_landmarks": np.asarray(landmarks[1:])}


def record(log: dict, k: int, tracking, last_update: dict) -> None:
    """Frame ``k``'s first pixels of new landmarks, accepted matches and searched
    ellipses, as ``(k, track id, ...)`` rows of ``log`` (scored after the run)."""
    obs = tracking.observations
    uv = dict(zip(obs.track_ids.tolist(), obs.uv_px))
    log["first"] += [(k, t, uv[t]) for t in last_update["initialised"].tolist()]
    log["accepted"] += [(k, t, uv[t]) for t in last_update["corrected"].tolist() if t in uv]
    log["searched"] += [(k, int(tracking.pred_ids[j]), tracking.pred_uv[j], tracking.pred_S[j])
                        for j in np.flatnonzero(tracking.searched)]


def truth_scores(seq, log: dict, sigma_px: float, gate: float) -> dict:
    """Accepted matches and searched ellipses of one run against the true projections
    (module docstring); ``log`` from :func:`record`, ``gate`` the ellipses' squared
    Mahalanobis bound."""
    Kinv = np.linalg.inv(np.asarray(seq.K, dtype=np.float64))
    truth, frames = {}, {}
    for k, t, uv in log["first"]:
        frames.setdefault(k, []).append((t, uv))
    for k, firsts in frames.items():
        depth, wTc = seq.render(k)[1], np.asarray(seq.wTc_true[k])
        H, W = depth.shape
        for t, uv in firsts:
            u, v = int(np.clip(round(uv[0]), 1, W - 2)), int(np.clip(round(uv[1]), 1, H - 2))
            win = depth[v - 1:v + 2, u - 1:u + 2]
            if not np.all(np.isfinite(win)) or np.ptp(win) > DEPTH_EDGE * win.min():
                continue  # a depth edge: no single true point
            p_c = Kinv @ np.array([uv[0], uv[1], 1.0]) * float(depth[v, u])
            truth[t] = wTc[:3, :3] @ p_c + wTc[:3, 3]

    def true_uv(k, t):
        return seq.project(k, truth[t][None])[0][0]

    err = np.array([np.linalg.norm(uv - true_uv(k, t)) for k, t, uv in log["accepted"] if t in truth])
    d2 = np.array([e @ np.linalg.solve(S, e) for k, t, z, S in log["searched"] if t in truth
                   for e in [true_uv(k, t) - z]])
    return {"outlier_share": float(np.mean(err > OUTLIER_SIGMAS * sigma_px)) if len(err) else 0.0,
            "gross_outlier_share": float(np.mean(err > GROSS_SIGMAS * sigma_px)) if len(err) else 0.0,
            "truth_outside_share": float(np.mean(d2 > gate)) if len(d2) else 0.0,
            "scored_accepted": int(len(err)), "scored_searched": int(len(d2))}


def paired_difference(per_seed: dict, seeds: list[int], label: str) -> tuple[float, float | None]:
    """Mean over ``seeds`` of ``label``'s ATE minus the batch one's, and its standard error
    (m; None from one seed)."""
    d = np.array([per_seed[s][label]["ate_rmse_m"] - per_seed[s]["batch"]["ate_rmse_m"] for s in seeds])
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else None


def bench_seed(seed: int, frames: int, repeats: int, labels: dict) -> dict:
    seq = Prerendered(make_synthetic_images(SyntheticImagesConfig(seed=seed)), frames)
    last: dict[str, dict] = {}

    def runner(label):
        order, every, sigma = labels[label]
        return lambda: last.__setitem__(label, visual_run(seq, order=order, ransac_every=every,
                                                          sigma_px=sigma))

    t = timing.alternate({label: runner(label) for label in labels}, repeats, warmup=0)
    rows = {}
    for label, r in last.items():
        r["cpu_ms_per_frame"] = 1e3 * float(np.mean(r["frame_cpu_s"]))
        r = {k: v for k, v in r.items() if not k.startswith(("wTc", "frame_"))}
        r["ms_per_frame"] = 1e3 * t[label].median_s / r["frames"]
        r["timing"] = timing.timing_dict(t[label])
        rows[label] = r
    return rows


def plot(seeds: list[int], per_seed: dict, out: Path, labels: dict) -> Path:
    from plotting import Panel, save_figure  # beside this script

    names = [str(s) for s in seeds]

    def series(key, scale=1.0):
        return {label: (names, [scale * per_seed[s][label][key] for s in seeds]) for label in labels}

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
    ap.add_argument("--seeds", type=entry.int_list, default=[0, 1, 2], help="synthetic sequence seeds, comma-separated")
    ap.add_argument("--frames", type=entry.count, default=300, help="frames per run (the sequence has 300)")
    ap.add_argument("--repeats", type=entry.count, default=2, help="alternated runs per order (median)")
    ap.add_argument("--control", action="store_true",
                    help="also run the batch order with a 1 %% larger pixel sigma (chance variation)")
    ap.add_argument("--quick", action="store_true", help="seed 0, 30 frames, one run each")
    ap.add_argument("--out", type=entry.output_file,
                    default=Path(__file__).resolve().parent / "results" / "sequential_search.json")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, seeds=[0], frames=30, repeats=1)
    seeds = args.seeds
    per_seed = {}
    labels = {**ORDERS, **(CONTROL if args.control else {})}
    print(f"{'seed':>4} {'order':<31} {'ATE m':>7} {'ms/frame':>8} {'cpu ms':>6} {'srch':>5} {'found':>5} "
          f"{'inside %':>8} {'image %':>7} {'accept %':>8} {'outl %':>6} {'gross %':>7} {'true out %':>10}")
    with timing.blas_threads(1):
        for s in seeds:
            per_seed[s] = bench_seed(s, args.frames, args.repeats, labels)
            for label, r in per_seed[s].items():
                print(f"{s:>4} {label:<31} {r['ate_rmse_m']:>7.4f} {r['ms_per_frame']:>8.1f} "
                      f"{r['cpu_ms_per_frame']:>6.1f} "
                      f"{r['searched_per_frame']:>5.1f} {r['found_per_frame']:>5.1f} "
                      f"{100 * r['inside_share']:>8.1f} {100 * r['image_fraction']:>7.2f} "
                      f"{100 * r['accepted_share']:>8.1f} {100 * r['outlier_share']:>6.2f} "
                      f"{100 * r['gross_outlier_share']:>7.2f} {100 * r['truth_outside_share']:>10.2f}",
                      flush=True)
    mean = {label: {k: float(np.mean([per_seed[s][label][k] for s in seeds]))
                    for k in ("ate_rmse_m", "ms_per_frame", "cpu_ms_per_frame", "inside_share",
                              "image_fraction", "outlier_share", "gross_outlier_share",
                              "truth_outside_share")}
            for label in labels}
    for label in labels:
        mean[label]["ate_minus_batch_m"], mean[label]["ate_minus_batch_se_m"] = \
            paired_difference(per_seed, seeds, label)
    print("\nmean over seeds:")
    for label, m in mean.items():
        print(f"  {label:<31} ATE {m['ate_rmse_m']:.4f} m, {m['ms_per_frame']:.1f} ms/frame "
              f"(CPU {m['cpu_ms_per_frame']:.1f}), "
              f"inside {100 * m['inside_share']:.1f} %, image {100 * m['image_fraction']:.2f} %, "
              f"ATE - batch {m['ate_minus_batch_m']:+.4f} +- {m['ate_minus_batch_se_m'] or 0.0:.4f} m (SE), "
              f"accepted outliers {100 * m['outlier_share']:.2f} % (gross {100 * m['gross_outlier_share']:.2f} %), "
              f"truth outside ellipse {100 * m['truth_outside_share']:.2f} %")
    floor = "the batch order: one prediction per frame, the 10 matches corrected at once " \
            "(same tracker, filter and sequence)"
    # the sizes that ran, --quick's too (it left out those the user gave with it)
    cmd = COMMAND + " --quick" * args.quick + f" --seeds {','.join(map(str, seeds))} --frames {args.frames}" \
        + (" --control" if args.control else "")
    summaries = [timing.summary(f"sequential active search ({label}), time per frame",
                                mean[label]["ms_per_frame"] / 1e3, mean["batch"]["ms_per_frame"] / 1e3,
                                target=None, floor=floor, command=cmd,
                                ate_rmse_m=mean[label]["ate_rmse_m"],
                                batch_ate_rmse_m=mean["batch"]["ate_rmse_m"],
                                ate_minus_batch_m=mean[label]["ate_minus_batch_m"],
                                ate_minus_batch_se_m=mean[label]["ate_minus_batch_se_m"],
                                cpu_ratio=mean[label]["cpu_ms_per_frame"] / mean["batch"]["cpu_ms_per_frame"],
                                inside_share=mean[label]["inside_share"])
                 for label in ORDERS if label != "batch"]
    payload = {"benchmark": "sequential_search", "corrections_per_frame": CORRECTIONS,
               "seeds": seeds, "frames": args.frames, "repeats": args.repeats,
               "results": {str(s): v for s, v in per_seed.items()}, "mean": mean,
               "summaries": summaries}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, payload, indent=2, trailing_newline=True)
    print(f"wrote {args.out}")
    plot(seeds, per_seed, args.out, labels)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
