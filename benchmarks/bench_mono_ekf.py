"""Monocular EKF-SLAM per-frame cost versus corrections per frame and map size.

The paper's figures 5 and 7 (seed 003, section 5): a VGA camera (fx = 500)
sees simulated points; each frame the filter initialises up to 5 landmarks,
up to the map limit, and corrects at most ``max_corrections`` of them. The
camera moves sideways at 1 m/s on a circle of radius 2 m, 30 Hz, looking
outwards at 600 random points (about 75 in view), pixel noise 1 px, odometry
noise 5 mm and 3 mrad per frame (seeded).

Timed per frame (and per stage, columns pred / p_obs / upd, medians in ms):
``predict`` (odometry model) + ``predict_observations`` + ``update``
(one-point RANSAC, re-parametrisation, map management and
initialisation included); the median over the frames after the map first
fills (from frame 10) is reported with the 95th percentile, and the median
process CPU time per frame (``cpu ms``: less sensitive to other processes
on a shared machine than the wall clock, which also counts waiting for a
core).

Part A (figure 5): map limit 20, 5 initialisations per frame, corrections
1..20. Part B (figure 7): map limits 5..80 with re-parametrisation off (all
landmarks stay IDP, as in the figure) against corrections 1, 2, 5, 10, 20.

Baseline, measured in the same process for each configuration: the bare dense
EKF update of the same size (state n = the run's mean state size, 2k rows for
the run's mean number of corrections): ``PHt = P @ H.T; S = H @ PHt + R;
K = solve(S, PHt.T).T; x += K nu; P -= K @ PHt.T`` with a dense random ``H``.
It is what the covariance algebra alone costs without exploiting sparsity,
without projection, RANSAC or map management; ``ratio`` is the filter's
CPU time per frame over it.

The issue's target: the whole per-frame loop (detection, search, update) at
60 Hz or more, so the filter's share must stay well under 16.7 ms.

Each configuration runs ``--runs`` times and keeps the lowest median (the
machine may be shared); one BLAS thread. A calibration (fixed Python and
small-numpy work) is printed and stored so runs under different loads can
be compared.

Usage: ``python benchmarks/bench_mono_ekf.py [--out FILE.json] [--frames N]
[--runs R] [--quick]``; default output ``benchmarks/results/mono_ekf.json`` and
its figure ``mono_ekf.png`` beside it (part A against corrections, part B
against map size).
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

# One BLAS thread: the paper measured on one core, and the filter's matrices
# (n ~ 100) are too small for threads to pay (set before numpy loads BLAS).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from filters.mono_ekf import MonoEkf  # noqa: E402
from filters.mono_ekf_config import MonoEkfConfig  # noqa: E402
from slamcore.spatial.geometry import invert_pose, se3_exp  # noqa: E402
from slamcore.spatial.camera import project  # noqa: E402
from slamcore.spatial.records import PixelObservations  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
IMAGE_SIZE = (640, 480)
CORRECTIONS_A = tuple(range(1, 21))
MAP_SIZES_B = (5, 10, 20, 40, 80)
CORRECTIONS_B = (1, 2, 5, 10, 20)
WARMUP_FRAMES = 10


def make_world(seed: int, n_frames: int, n_points: int = 600, radius_m: float = 2.0,
               speed_mps: float = 1.0, rate_hz: float = 30.0, sigma_px: float = 1.0,
               sigma_t_m: float = 0.005, sigma_r_rad: float = 0.003):
    """Poses (N, 4, 4), odometry (N-1), its covariance (6, 6), observations per frame."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-8, -2, -8], [8, 2, 8], size=(4 * n_points, 3))
    pts = pts[np.hypot(pts[:, 0], pts[:, 2]) > radius_m + 2.5][:n_points]
    poses = []
    for th in np.arange(n_frames) * (speed_mps / rate_hz / radius_m):
        z = np.array([math.cos(th), 0.0, math.sin(th)])
        y = np.array([0.0, 1.0, 0.0])
        T = np.eye(4)
        T[:3, :3] = np.c_[np.cross(y, z), y, z]
        T[:3, 3] = radius_m * z
        poses.append(T)
    sig = np.array([sigma_t_m] * 3 + [sigma_r_rad] * 3)
    odo = [invert_pose(poses[k - 1]) @ poses[k] @ se3_exp(rng.normal(0.0, sig))
           for k in range(1, n_frames)]
    frames = []
    W, H = IMAGE_SIZE
    for T in poses:
        uv, depth = project(K, invert_pose(T), pts)
        ok = (depth > 0.1) & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5) \
            & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
        ids = np.flatnonzero(ok).astype(np.int64)
        frames.append(PixelObservations(ids, uv[ok] + rng.normal(0.0, sigma_px, (len(ids), 2)), sigma_px))
    return np.array(poses), odo, np.diag(sig ** 2), frames


def run(config: MonoEkfConfig, world) -> dict:
    poses, odo, Q, frames = world
    ekf = MonoEkf(config)
    ekf.initialize(0, poses[0], np.zeros((6, 6)), K, IMAGE_SIZE)
    ekf.update(frames[0])
    times, cpu, stages, sizes, corr, lms = [], [], [], [], [], []
    for k in range(1, len(poses)):
        c0 = time.process_time()
        t0 = time.perf_counter()
        ekf.predict(k, odo[k - 1], Q)
        t1 = time.perf_counter()
        ekf.predict_observations()
        t2 = time.perf_counter()
        ekf.update(frames[k])
        t3 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        times.append(t3 - t0)
        stages.append((t1 - t0, t2 - t1, t3 - t2))
        sizes.append(ekf.state_size)
        corr.append(len(ekf.last_update["corrected"]) + len(ekf.last_update["rejected"]))
        lms.append(ekf.num_landmarks)
    t = np.array(times[WARMUP_FRAMES:])
    st = 1e3 * np.median(np.array(stages[WARMUP_FRAMES:]), axis=0)
    est = ekf.estimate()
    return {"frame_ms_median": 1e3 * float(np.median(t)),
            "frame_cpu_ms_median": 1e3 * float(np.median(cpu[WARMUP_FRAMES:])),
            "predict_ms_median": float(st[0]), "predict_observations_ms_median": float(st[1]),
            "update_ms_median": float(st[2]),
            "frame_ms_p95": 1e3 * float(np.percentile(t, 95)),
            "fps_median": float(1.0 / np.median(t)),
            "mean_state_size": float(np.mean(sizes[WARMUP_FRAMES:])),
            "mean_landmarks": float(np.mean(lms[WARMUP_FRAMES:])),
            "mean_corrections": float(np.mean(corr[WARMUP_FRAMES:])),
            "reparametrised": int(est.stats["reparametrised"]),
            "ransac_rejected": int(est.stats["ransac_rejected"])}


def calibration_ms() -> dict:
    """Fixed work to compare machines and loads: 10^6 Python additions and
    10^4 tiny numpy calls (``np.zeros(3)``), median of 5, ms."""
    def py():
        s = 0
        for i in range(1_000_000):
            s += i
        return s

    def nz():
        for _ in range(10_000):
            np.zeros(3)

    out = {}
    for name, fn in (("python_1e6_adds_ms", py), ("numpy_1e4_small_calls_ms", nz)):
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        out[name] = 1e3 * float(np.median(ts))
    return out


def dense_baseline_ms(n: int, k: int, repeats: int = 100, seed: int = 0) -> float:
    """Median time of the bare dense EKF update (n state, 2k rows), ms."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(n, 8)) * 0.05
    P = B @ B.T + 0.01 * np.eye(n)
    x = np.zeros(n)
    H = rng.normal(size=(2 * k, n))
    R = np.eye(2 * k)
    nu = rng.normal(size=2 * k)
    P0 = P.copy()

    def once():
        PHt = P @ H.T
        S = H @ PHt + R
        Kg = np.linalg.solve(S, PHt.T).T
        x[:] += Kg @ nu
        P[:] -= Kg @ PHt.T

    once()
    ts = []
    for _ in range(repeats):
        P[:] = P0
        t0 = time.perf_counter()
        once()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def plot(rows: list[dict], frames: int, out: Path) -> Path:
    """Part A: ms per frame against corrections; part B: against the map size, per correction cap."""
    from plotting import Panel, save_figure  # beside this script

    a = [r for r in rows if r["part"] == "A"]
    b = [r for r in rows if r["part"] == "B"]
    corr = [r["max_corrections"] for r in a]
    part_a = {"wall, median": (corr, [r["frame_ms_median"] for r in a]),
              "CPU, median": (corr, [r["frame_cpu_ms_median"] for r in a]),
              "bare dense EKF update (same n, k)": (corr, [r["dense_update_ms"] for r in a])}
    part_b = {f"{c} corrections": ([r["max_landmarks"] for r in b if r["max_corrections"] == c],
                                   [r["frame_cpu_ms_median"] for r in b if r["max_corrections"] == c])
              for c in dict.fromkeys(r["max_corrections"] for r in b)}
    target = {"60 Hz whole loop (16.7 ms)": 1e3 / 60}
    return save_figure(out, f"Monocular EKF-SLAM: predict + predict_observations + update per frame "
                            f"(simulated VGA camera, {frames} frames)", [
        Panel("A: against corrections (map of 20, re-parametrisation on)", "corrections per frame (cap)",
              "time per frame [ms]", part_a, targets=target, logy=True),
        Panel("B: against map size (all IDP)", "landmarks in the map (limit)", "CPU time per frame [ms]",
              part_b, targets=target, logy=True)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=entry.output_file,
                    default=Path(__file__).resolve().parent / "results" / "mono_ekf.json")
    ap.add_argument("--frames", type=entry.count, default=150, help="frames per configuration")
    ap.add_argument("--seed", type=entry.seed, default=0)
    ap.add_argument("--runs", type=entry.count, default=2,
                    help="runs per configuration; the lowest median is kept (shared machines)")
    ap.add_argument("--quick", action="store_true", help="a few configurations only")
    args = ap.parse_args(argv)
    world = make_world(args.seed, args.frames)
    corr_a = (1, 10, 20) if args.quick else CORRECTIONS_A
    maps_b = (5, 20) if args.quick else MAP_SIZES_B
    corr_b = (1, 10) if args.quick else CORRECTIONS_B
    load0 = os.getloadavg()
    calib = calibration_ms()
    print(f"calibration: {calib['python_1e6_adds_ms']:.0f} ms for 10^6 Python additions, "
          f"{calib['numpy_1e4_small_calls_ms']:.1f} ms for 10^4 np.zeros(3); "
          f"load average {load0[0]:.1f} on {os.cpu_count()} cores")

    def row(part, max_lm, max_corr, reparam):
        cfg = MonoEkfConfig(max_landmarks=max_lm, max_corrections=max_corr, max_init_per_frame=5,
                            linearity_threshold=0.1 if reparam else 0.0)
        r = min((run(cfg, world) for _ in range(args.runs)), key=lambda d: d["frame_ms_median"])
        base = dense_baseline_ms(int(round(r["mean_state_size"])), max(1, int(round(r["mean_corrections"]))))
        r.update({"part": part, "max_landmarks": max_lm, "max_corrections": max_corr,
                  "reparametrise": reparam, "dense_update_ms": base,
                  "ratio": r["frame_cpu_ms_median"] / base})
        print(f"{part:>4} {max_lm:>5d} {max_corr:>5d} {r['mean_state_size']:>6.0f} "
              f"{r['mean_corrections']:>6.1f} {r['frame_ms_median']:>8.2f} {r['frame_ms_p95']:>8.2f} "
              f"{r['frame_cpu_ms_median']:>7.2f} "
              f"{r['predict_ms_median']:>6.2f} {r['predict_observations_ms_median']:>6.2f} "
              f"{r['update_ms_median']:>6.2f} "
              f"{r['fps_median']:>8.0f} {base:>9.3f} {r['ratio']:>6.1f}", flush=True)
        return r

    print(f"{'part':>4} {'map':>5} {'corr':>5} {'state':>6} {'used':>6} {'ms med':>8} {'ms p95':>8} "
          f"{'cpu ms':>7} "
          f"{'pred':>6} {'p_obs':>6} {'upd':>6} {'frames/s':>8} {'dense ms':>9} {'ratio':>6}")
    rows = [row("A", 20, c, True) for c in corr_a]
    rows += [row("B", m, c, False) for m in maps_b for c in corr_b]
    head = next(r for r in rows if r["part"] == "A" and r["max_corrections"] == 10) \
        if 10 in corr_a else rows[0]
    print(f"20 landmarks, 10 corrections: {head['frame_ms_median']:.2f} ms per frame "
          f"({head['fps_median']:.0f} frames/s; CPU time {head['frame_cpu_ms_median']:.2f} ms) "
          "for predict + predict_observations + update; "
          f"load average {load0[0]:.1f} on {os.cpu_count()} cores")
    payload = {"benchmark": "mono_ekf", "numpy": np.__version__,
               "python": platform.python_version(), "machine": platform.machine(),
               "cpu_count": os.cpu_count(), "load_average_start": load0,
               "load_average_end": os.getloadavg(), "frames": args.frames, "seed": args.seed,
               "warmup_frames": WARMUP_FRAMES, "runs": args.runs, "calibration": calib,
               "timed": "predict + predict_observations + update, per frame, median after warm-up",
               "ratio_definition": "frame_cpu_ms_median / dense_update_ms (bare dense EKF update, "
                                   "same n and k)",
               "results": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, payload, indent=2, trailing_newline=True)
    print(f"wrote {args.out}")
    plot(rows, args.frames, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
