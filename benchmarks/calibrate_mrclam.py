"""Calibrate the MRCLAM reader's sensor model against the Vicon truth (issue 31 item 1).

The defaults of :class:`graphslam.sources.planar.mrclam.MrclamConfig` come from
this script, run on every robot of Dataset 6:

1. Odometry lag and velocity scales: for each lag on a grid, the forward and
   angular scales that fit the 1 s relative motions (commands integrated) to the
   truth's in least squares; the lag with the smallest residual wins. One lag
   and one pair of scales for all robots (per-robot scales are reported).
2. Odometry noise: maximum likelihood (Student-t, 5 dof) of the six coefficients
   of :mod:`graphslam.sources.planar.mrclam_motion` on the relative motions over
   windows of :data:`FIT_WINDOW_S` (the covariance is linear in them, so each
   window's unit contributions are integrated once). Consistency is checked by
   the NEES (mean 3, median 2.37 for a consistent model) on the reader's frames
   and on windows of 1, 5 and 20 s. The errors are correlated in time (each
   robot's own scale differs from the common one by up to 2.5 %), so a fit on
   the reader's short frame-to-frame windows is overconfident over longer
   spans (median NEES 15.7 on 20 s windows) while a 5 s fit keeps the median
   within 1.6-4.4 from 1 to 20 s: a compromise between the frame-to-frame steps
   (0.2-1 s) and the longest stretches without a sighting (up to 78 s), which
   is where an overconfident odometry does the most harm.
3. Range and bearing noise: the robust scale (1.4826 MAD) of the sightings'
   residuals against the truth, and the fraction beyond 3 robust sigma.

    python benchmarks/calibrate_mrclam.py [--data ../shared/data/mrclam6] [--quick]

``--quick``: robot 1 only, a coarse lag grid.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from plotting import Panel, save_figure  # noqa: E402

from graphslam.sources.planar.mrclam import (MrclamConfig, frame_times, read_table,  # noqa: E402
                                             truth_at)
from graphslam.sources.planar.mrclam_motion import MotionModel, held_commands, integrate  # noqa: E402
from slamcore.planar.geometry import between, wrap_angle  # noqa: E402

DATA = HERE.parent.parent / "shared" / "data" / "mrclam6"
COMMAND = "python benchmarks/calibrate_mrclam.py --out benchmarks/figures/calibrate_mrclam.json"
#: Length of the windows the noise is fitted on, s (module docstring, step 2).
FIT_WINDOW_S = 5.0
NOISE_NAMES = ("a_s_m", "b_s_m2_per_s", "a_y_m", "a_theta_rad", "c_theta_rad2_per_m",
               "b_theta_rad2_per_s")


def load(folder: Path, robot: int) -> dict:
    odo, _ = read_table(folder / f"Robot{robot}_Odometry.dat", 3, "odometry")
    meas, _ = read_table(folder / f"Robot{robot}_Measurement.dat", 4, "measurement")
    truth, _ = read_table(folder / f"Robot{robot}_Groundtruth.dat", 4, "truth")
    return {"odo": odo, "meas": meas, "truth": truth}


def relative_truth(truth: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Truth's relative motion between consecutive ``times`` and which windows have it."""
    p = truth_at(truth, times)
    ok = np.isfinite(p).all(axis=1)
    rel = np.array([between(a, b) if (oa and ob) else np.full(3, np.nan)
                    for a, b, oa, ob in zip(p[:-1], p[1:], ok[:-1], ok[1:])])
    return rel, np.isfinite(rel).all(axis=1)


def fit_lag_and_scales(logs: dict, lags: np.ndarray) -> dict:
    """Lag and scales (step 1 of the module docstring)."""
    unit = MotionModel(0.0, 1.0, 1.0, *([0.0] * 6))
    best = None
    for lag in lags:
        num, den, res = np.zeros(2), np.zeros(2), 0.0
        per_robot = {}
        for robot, log in logs.items():
            odo, truth = log["odo"], log["truth"]
            times = np.arange(max(odo[0, 0], truth[0, 0]) + 1, min(odo[-1, 0], truth[-1, 0]) - 1)
            model = MotionModel(lag, 1.0, 1.0, *([0.0] * 6))
            m, _ = integrate(*held_commands(odo[:, 0], odo[:, 1], odo[:, 2], model), times,
                             unit.coefficients())
            g, ok = relative_truth(truth, times)
            m, g = m[ok], g[ok]
            n_r = np.array([m[:, 0] @ g[:, 0], m[:, 2] @ g[:, 2]])
            d_r = np.array([m[:, 0] @ m[:, 0], m[:, 2] @ m[:, 2]])
            per_robot[robot] = (n_r / d_r).round(3).tolist()
            num, den = num + n_r, den + d_r
            log["_windows"] = (m, g)
        scale = num / den
        for log in logs.values():
            m, g = log["_windows"]
            res += float(np.sum((g[:, 0] - scale[0] * m[:, 0]) ** 2)
                         + np.sum(wrap_angle(g[:, 2] - scale[1] * m[:, 2]) ** 2))
        if best is None or res < best["residual"]:
            best = {"lag_s": float(lag), "forward_scale": float(scale[0]),
                    "angular_scale": float(scale[1]), "residual": res, "per_robot": per_robot}
    return best


def unit_covariances(log: dict, model: MotionModel, times: np.ndarray) -> tuple:
    """Per window: the motion, and the covariance of each noise coefficient set to 1."""
    cmds = held_commands(log["odo"][:, 0], log["odo"][:, 1], log["odo"][:, 2], model)
    units = []
    for j in range(6):
        coef = [0.0] * 6
        coef[j] = 1.0
        delta, cov = integrate(*cmds, times, tuple(coef))
        units.append(cov)
    return delta, np.stack(units, axis=1)  # (W, 3), (W, 6, 3, 3)


def windows(logs: dict, model: MotionModel, every_s: float | None) -> tuple:
    """Residuals (W, 3) and unit covariances (W, 6, 3, 3) over every robot's windows:
    the reader's frames (``every_s`` None) or fixed windows of ``every_s`` seconds."""
    E, U = [], []
    for log in logs.values():
        odo, truth, meas = log["odo"], log["truth"], log["meas"]
        if every_s is None:
            times = frame_times(odo[:, 0], meas[:, 0], MrclamConfig().frame_every_s)
        else:
            times = np.arange(odo[0, 0], odo[-1, 0], every_s)
        delta, units = unit_covariances(log, model, times)
        g, ok = relative_truth(truth, times)
        e = g - delta
        e[:, 2] = wrap_angle(e[:, 2])
        E.append(e[ok])
        U.append(units[ok])
    return np.concatenate(E), np.concatenate(U)


FLOOR = np.eye(3) * 1e-8  # the reader's COVARIANCE_FLOOR


def nll(log_coef: np.ndarray, E: np.ndarray, U: np.ndarray) -> float:
    cov = np.einsum("j,wjab->wab", np.exp(log_coef), U) + FLOOR
    sign, logdet = np.linalg.slogdet(cov)
    maha = np.einsum("wa,wab,wb->w", E, np.linalg.inv(cov), E)
    # Student-t (nu = 5) rather than Gaussian: Vicon glitches and wheel slips would
    # otherwise inflate every coefficient for a handful of windows
    return float(np.sum(0.5 * logdet + 0.5 * (5 + 3) * np.log1p(maha / 5)))


def fit_noise(E: np.ndarray, U: np.ndarray) -> np.ndarray:
    from scipy.optimize import minimize

    start = np.log([1e-3, 1e-5, 1e-4, 5e-3, 1e-3, 1e-4])
    res = minimize(nll, start, args=(E, U), method="Nelder-Mead",
                   options={"maxiter": 4000, "xatol": 1e-3, "fatol": 1e-3})
    return np.exp(res.x)


def mean_nees(coef: np.ndarray, E: np.ndarray, U: np.ndarray) -> dict:
    cov = np.einsum("j,wjab->wab", coef, U) + FLOOR
    maha = np.einsum("wa,wab,wb->w", E, np.linalg.inv(cov), E)
    return {"mean": float(np.mean(maha)), "median": float(np.median(maha)),
            "windows": int(len(maha)), "median_expected": 2.366}


def sighting_residuals(folder: Path, logs: dict) -> dict:
    from graphslam.sources.planar.mrclam import read_subjects

    barcodes, landmarks = read_subjects(folder)
    r_res, b_res = [], []
    for log in logs.values():
        meas, truth = log["meas"], log["truth"]
        subject = np.array([barcodes.get(int(c), 0) for c in meas[:, 1]])
        keep = np.isin(subject, list(landmarks))
        p = truth_at(truth, meas[keep, 0])
        lm = np.array([landmarks[s] for s in subject[keep]])
        ok = np.isfinite(p).all(axis=1)
        d = lm[ok] - p[ok, :2]
        r_res.append(meas[keep, 2][ok] - np.hypot(d[:, 0], d[:, 1]))
        b_res.append(wrap_angle(meas[keep, 3][ok] - (np.arctan2(d[:, 1], d[:, 0]) - p[ok, 2])))
    out = {}
    for name, res in (("range_m", np.concatenate(r_res)), ("bearing_rad", np.concatenate(b_res))):
        med = float(np.median(res))
        sigma = float(1.4826 * np.median(np.abs(res - med)))
        out[name] = {"median": med, "robust_sigma": sigma, "std": float(np.std(res)),
                     "beyond_3_sigma": float(np.mean(np.abs(res - med) > 3 * sigma)),
                     "n": int(res.size), "residuals": res}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calibrate_mrclam.json"))
    args = ap.parse_args(argv)
    robots = [1] if args.quick else [1, 2, 3, 4, 5]
    logs = {r: load(args.data, r) for r in robots}
    lags = np.arange(0.0, 0.61, 0.3 if args.quick else 0.05)
    motion = fit_lag_and_scales(logs, lags)
    model = MotionModel(motion["lag_s"], motion["forward_scale"], motion["angular_scale"],
                        *([0.0] * 6))
    coef = fit_noise(*windows(logs, model, FIT_WINDOW_S))
    checks = {"frames": mean_nees(coef, *windows(logs, model, None))}
    for every in (1.0, 5.0, 20.0):
        checks[f"{every:g} s"] = mean_nees(coef, *windows(logs, model, every))
    sightings = sighting_residuals(args.data, logs)
    default = MrclamConfig()
    report = {
        "robots": robots, "data": str(args.data), "command": COMMAND,
        "odometry": {k: v for k, v in motion.items() if k != "residual"},
        "noise": dict(zip(NOISE_NAMES, coef.tolist())),
        "nees": checks,
        "sightings": {k: {kk: vv for kk, vv in v.items() if kk != "residuals"}
                      for k, v in sightings.items()},
        "defaults_in_use": {"lag_s": default.odometry_lag_s,
                            "forward_scale": default.forward_scale,
                            "angular_scale": default.angular_scale,
                            **{n: getattr(default, n) for n in NOISE_NAMES},
                            "sigma_range_m": default.sigma_range_m,
                            "sigma_bearing_rad": default.sigma_bearing_rad},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps({k: report[k] for k in ("odometry", "noise", "nees", "sightings")}, indent=1))
    panels = []
    for name, unit in (("range_m", "m"), ("bearing_rad", "rad")):
        res = sightings[name]["residuals"]
        sigma = sightings[name]["robust_sigma"]
        edges = np.linspace(-5 * sigma, 5 * sigma, 41)
        counts, _ = np.histogram(res, edges)
        centres = 0.5 * (edges[:-1] + edges[1:])
        gauss = res.size * (edges[1] - edges[0]) * np.exp(-0.5 * (centres / sigma) ** 2) / (
            sigma * math.sqrt(2 * math.pi))
        panels.append(Panel(f"{name} residual against the truth", f"residual [{unit}]", "sightings",
                            {"measured": (centres.tolist(), counts.tolist()),
                             "N(0, robust sigma)": (centres.tolist(), gauss.tolist())}))
    names = list(checks)
    panels.append(Panel("odometry consistency (mean NEES, 3 = consistent)", "window", "NEES",
                        {"mean": (names, [checks[n]["mean"] for n in names]),
                         "median (2.37 expected)": (names, [checks[n]["median"] for n in names])},
                        kind="bar", targets={"3": 3.0}))
    save_figure(args.out, "MRCLAM sensor calibration against Vicon truth", panels)


if __name__ == "__main__":
    main()
