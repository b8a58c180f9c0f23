"""FastSLAM time per step against particle count and map size (and Victoria Park).

A seeded simulated run: a robot drives a circle through a field of landmarks
and sees about ``visible`` of them per step (range-bearing, known association).
Time per step (predict + update) is measured for FastSLAM 1.0 and 2.0 with N =
10, 30, 100, 300, 1000 particles, and for 2.0 with 100 particles against the
map size (50, 150, 500 landmarks). Prints a table, optionally writes JSON.

``--victoria-park`` runs FastSLAM 2.0 over the whole Victoria Park sequence
with 100 particles (and 1000 with ``--vp-particles 100 1000``), printing the
total time. The file's odometry covariance is scaled by ``--vp-odometry-scale``
(default 10): at 1 it is too confident for a particle filter and the estimate
drifts away from the landmarks. The data is read by
``graphslam.sources.planar.victoria_park`` (the reader every back end uses).

JSON (default ``benchmarks/results/fastslam.json``) and its PNG beside it.

    python benchmarks/bench_fastslam.py [--out FILE.json] [--victoria-park] [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from slamcore.planar import geometry as models
from filters.fastslam import FastSlam, FastSlamConfig
from slamcore.planar.records import Dataset
from graphslam.sources.planar.victoria_park import read_victoria_park
from slamcore.planar.records import Frame, Observation, Odometry


def simulated_run(n_landmarks: int, steps: int, seed: int = 0, visible: int = 8) -> Dataset:
    """Circle of radius 20 m in a landmark field; density set so ~``visible`` are in range."""
    rng = np.random.default_rng(seed)
    half = 30.0
    area = (2 * half) ** 2
    # sensor radius giving `visible` landmarks in view on average
    sensor_r = math.sqrt(visible * area / (n_landmarks * math.pi))
    lms = rng.uniform(-half, half, size=(n_landmarks, 2))
    u = np.array([0.5, 0.0, 0.5 / 20.0])
    Q = np.diag([0.02, 0.02, 0.005]) ** 2
    R = np.diag([0.1, 0.02]) ** 2
    x = np.array([20.0, 0.0, np.pi / 2])
    frames = []
    for k in range(steps):
        odo = None
        if k:
            x = models.compose(x, u)
            odo = Odometry(k - 1, k, u + rng.normal(0, np.sqrt(np.diag(Q))), Q)
        z = models.observe(np.broadcast_to(x, (n_landmarks, 3)), lms)
        seen = np.flatnonzero(z[:, 0] < sensor_r)
        obs = tuple(Observation(k, int(j), z[j] + rng.normal(0, np.sqrt(np.diag(R))), R)
                    for j in seen)
        frames.append(Frame(k, float(k), odo, obs, (), x.copy(), tuple(int(j) for j in seen)))
    return Dataset("bench-circle", frames, prior_wTb=np.array([20.0, 0.0, np.pi / 2]),
                   landmarks_true={j: lms[j] for j in range(n_landmarks)})


def run_backend(ds: Dataset, backend: FastSlam, pairs: list | None = None) -> float:
    """Seconds spent in initialize/predict/update over the whole dataset.

    ``pairs``, if given, collects ``(given landmark id, associated id)`` per
    observation (for scoring unknown association against the ids in the data).
    """
    t0 = time.perf_counter()
    for k, f in enumerate(ds.frames):
        if k == 0:
            backend.initialize(f.pose_id, ds.prior_wTb, ds.prior_covariance)
        else:
            backend.predict(f.odometry, f.pose_id)
        if f.observations:
            backend.update(f.observations)
            if pairs is not None:
                pairs.extend(zip([o.landmark_id for o in f.observations], backend.associations()))
    backend.estimate()
    return time.perf_counter() - t0


def plot(results: dict, out: Path) -> Path:
    """Time per step against particles (both versions) and against map size."""
    from plotting import Panel, save_figure  # beside this script

    vp, vl = results["vs_particles"], results["vs_landmarks"]
    per_n = {f"FastSLAM {v}.0": ([r["n_particles"] for r in vp if r["version"] == v],
                                 [r["ms_per_step"] for r in vp if r["version"] == v]) for v in (1, 2)}
    return save_figure(out, f"FastSLAM time per step, simulated circle ({results['steps']} steps, "
                            f"seed {results['seed']})", [
        Panel("against particle count (150 landmarks)", "particles", "time per step [ms]",
              per_n, logx=True, logy=True),
        Panel("against map size (FastSLAM 2.0, 100 particles)", "landmarks in the world",
              "time per step [ms]", {"FastSLAM 2.0, N=100": ([r["landmarks"] for r in vl],
                                                              [r["ms_per_step"] for r in vl])})])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "fastslam.json",
                    help="write results as JSON here (and its PNG beside it)")
    ap.add_argument("--quick", action="store_true",
                    help="20 steps, 10 and 30 particles, 50 and 150 landmarks")
    ap.add_argument("--steps", type=int, default=60, help="steps of the simulated run")
    ap.add_argument("--particles", type=int, nargs="+", default=[10, 30, 100, 300, 1000])
    ap.add_argument("--landmarks", type=int, nargs="+", default=[50, 150, 500])
    ap.add_argument("--victoria-park", action="store_true")
    ap.add_argument("--vp-particles", type=int, nargs="+", default=[100])
    ap.add_argument("--vp-odometry-scale", type=float, default=10.0,
                    help="odometry covariance scale (the file's covariance is too confident "
                         "for a particle filter: at 1 the estimate drifts away)")
    ap.add_argument("--vp-association", choices=["known", "unknown"], default="known",
                    help="unknown: the data's landmark ids are used only to score association")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.quick:
        args.steps, args.particles, args.landmarks = 20, [10, 30], [50, 150]

    results: dict = {"steps": args.steps, "seed": args.seed, "vs_particles": [],
                     "vs_landmarks": [], "victoria_park": []}
    ds = simulated_run(150, args.steps, args.seed)
    n_obs = sum(len(f.observations) for f in ds.frames)
    print(f"simulated: {args.steps} steps, 150 landmarks, {n_obs / args.steps:.1f} obs/step")
    print("final err m: last-pose position error of this one seeded run (not an average)")
    print(f"{'version':>7} {'N':>6} {'ms/step':>9} {'final err m':>11}")
    for version in (1, 2):
        for n in args.particles:
            b = FastSlam(FastSlamConfig(version=version, n_particles=n, seed=args.seed))
            dt = run_backend(ds, b)
            err = float(np.linalg.norm(b.current_pose()[:2] - ds.frames[-1].wTb_true[:2]))
            ms = 1e3 * dt / len(ds.frames)
            print(f"{version:>7} {n:>6} {ms:>9.2f} {err:>11.3f}")
            results["vs_particles"].append({"version": version, "n_particles": n,
                                            "ms_per_step": ms, "final_error_m": err})
    print(f"\n{'landmarks':>9} {'obs/step':>8} {'ms/step':>9}  (FastSLAM 2.0, N=100)")
    for n_lm in args.landmarks:
        ds_m = simulated_run(n_lm, args.steps, args.seed)
        b = FastSlam(FastSlamConfig(version=2, n_particles=100, seed=args.seed))
        dt = run_backend(ds_m, b)
        ms = 1e3 * dt / len(ds_m.frames)
        per = sum(len(f.observations) for f in ds_m.frames) / len(ds_m.frames)
        print(f"{n_lm:>9} {per:>8.1f} {ms:>9.2f}")
        results["vs_landmarks"].append({"landmarks": n_lm, "obs_per_step": per,
                                        "ms_per_step": ms})

    if args.victoria_park:
        vp = read_victoria_park()
        how = "graphslam.sources.planar.victoria_park"
        n_obs = sum(len(f.observations) for f in vp.frames)
        print(f"\nVictoria Park ({how}): {len(vp.frames)} poses, {n_obs} observations")
        for n in args.vp_particles:
            b = FastSlam(FastSlamConfig(version=2, n_particles=n, seed=args.seed,
                                        association=args.vp_association,
                                        odometry_covariance_scale=args.vp_odometry_scale))
            pairs: list = []
            dt = run_backend(vp, b, pairs)
            est = b.estimate()
            row = {"n_particles": n, "association": args.vp_association, "total_s": dt,
                   "odometry_covariance_scale": args.vp_odometry_scale,
                   "landmarks": int(len(est.landmark_ids)), "source": how}
            line = (f"FastSLAM 2.0, N={n}, {args.vp_association} association, odometry "
                    f"covariance x{args.vp_odometry_scale:g}: {dt:.2f} s total, "
                    f"{len(est.landmark_ids)} landmarks, {b.resample_count} resamplings")
            if args.vp_association == "unknown":
                from graphslam.evaluation.planar import association_accuracy

                acc = association_accuracy([p for p in pairs if p[0] is not None])
                row["association_accuracy"] = acc.accuracy
                line += f", association accuracy {acc['accuracy']:.3f}"
            print(line)
            results["victoria_park"].append(row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(results, f, indent=2)
    print(f"wrote {args.out}")
    plot(results, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
