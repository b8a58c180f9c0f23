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
3. Range and bearing noise, as functions of the measured range r (what a run
   knows; the true range would fit a little better and be of no use):
   ``sigma_r^2 = a^2 + (k r)^2`` (a camera reads range from a barcode's apparent
   size: a relative error) and ``sigma_b^2 = b^2 + (c / r)^2`` (a fixed lateral
   offset adds an angle that falls with range). The shape (the ratio of the two
   terms) by Student-t maximum likelihood; the scale so that the residuals
   divided by the model have a robust scale (1.4826 MAD) of 1, as the constant
   sigmas were fitted before. Reported: each model's fraction beyond 3 sigma,
   beside the constant robust sigma's, and the robust sigma per range bin.
4. The sightings' error correlation in time: the correlation of the normalised
   range and bearing errors (against the truth, each robot-landmark pair's median
   removed, clipped at 4 sigma) of every two sightings of one landmark by one
   robot, by the time between them, and the least-squares fit of ``share
   exp(-dt / tau)`` (one ``tau``, a share per component; each lag bin's squared
   residual weighed by its pair count). It is what the back ends need to weigh a
   burst of sightings as the few independent ones it is
   (:mod:`slamcore.planar.sighting_correlation`).
5. The camera's field and how reliably it reports a landmark there (what a
   missed sighting means, :class:`slamcore.planar.records.SensorField`): the
   field's half-width is the 99th percentile of the sightings' absolute bearings
   and its depth the 99th percentile of their ranges. Over the frames that
   report some landmark (a run knows nothing of the frames that report none),
   a landmark inside that field by the truth is reported in 35 % of them, but
   not independently: the misses come in runs (16 or more in a row between two
   sightings 5 % of the time, against 0.1 % for independent frames at 35 %).
   The EKF's pruning (:mod:`filters.landmark_existence`) treats frames as
   independent and removes a landmark after ``N`` misses in a row with ``(1 -
   p)^N = alpha``; the detection probability stored is therefore the ``p`` that
   puts that ``N`` at the measured ``1 - alpha`` quantile of the miss runs, with
   the EKF's default ``alpha``: ``p = 1 - alpha^(1 / N)``. With the 35 % a real
   landmark would be pruned after its 16th miss in a row, 50 times as often as
   ``alpha`` says.
6. The sightings' error tail: the measured quantiles of their squared Mahalanobis
   distance under the model, matched by a Student-t's degrees of freedom
   (:func:`sighting_tail`; ``[mrclam] sighting_error_dof``).
7. What the sightings of one frame share: the correlation of the normalised errors
   of two sightings of different landmarks in one frame, and the bearing error they
   share in radians (:func:`shared_scan_error`). Reported, not used by the reader:
   the back ends take a frame's sightings as independent of each other.

    python benchmarks/calibrate_mrclam.py [--data ../shared/data/mrclam6] [--quick]

``--quick``: robot 1 only, a coarse lag grid.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

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

from graphslam.sources.planar.mrclam import (MIN_MODEL_RANGE_M, MrclamConfig,  # noqa: E402
                                             frame_times, read_table, truth_at)
from filters.ekf_slam_config import EkfSlamConfig  # noqa: E402
from graphslam.sources.planar.mrclam_motion import MotionModel, held_commands, integrate  # noqa: E402
from slamcore.planar.geometry import between, wrap_angle  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

DATA = HERE.parent.parent / "shared" / "data" / "mrclam6"
COMMAND = "python benchmarks/calibrate_mrclam.py --out benchmarks/figures/calibrate_mrclam.json"
#: Length of the windows the noise is fitted on, s (module docstring, step 2).
FIT_WINDOW_S = 5.0
SIGHTING_NAMES = ("sigma_range_m", "sigma_range_per_m", "sigma_bearing_rad", "sigma_bearing_m")
CORRELATION_NAMES = ("correlation_time_s", "range_correlated_share", "bearing_correlated_share")
FIELD_NAMES = ("field_range_m", "field_half_fov_deg", "detection_prob")
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


#: Range bins of the per-bin robust sigmas in the report, m.
RANGE_BINS_M = (0.5, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0)


def robust_sigma(res: np.ndarray) -> float:
    """1.4826 MAD: the standard deviation of a Gaussian, whatever the tails."""
    return float(1.4826 * np.median(np.abs(res - np.median(res))))


def fit_sigma_model(res: np.ndarray, features: np.ndarray) -> np.ndarray:
    """Coefficients ``theta`` (F,) of ``sigma^2 = features @ theta^2`` (features
    (N, F)): shape by Student-t (5 dof) maximum likelihood, scale set so the
    normalised residuals' robust sigma is 1 (module docstring, step 3)."""
    from scipy.optimize import minimize

    res = res - np.median(res)

    def t_nll(log_theta2: np.ndarray) -> float:
        var = features @ np.exp(log_theta2)
        return float(np.sum(0.5 * np.log(var) + 3.0 * np.log1p(res**2 / (5.0 * var))))

    start = np.full(features.shape[1], 2.0 * np.log(robust_sigma(res)))
    fit = minimize(t_nll, start, method="Nelder-Mead",
                   options={"maxiter": 4000, "xatol": 1e-6, "fatol": 1e-9})
    theta = np.sqrt(np.exp(fit.x))
    return theta * robust_sigma(res / np.sqrt(features @ theta**2))


def sighting_model(ranges: np.ndarray, r_res: np.ndarray, b_res: np.ndarray) -> dict:
    """The fitted range and bearing models (module docstring, step 3) and their checks,
    as functions of the measured ``ranges`` (what a run knows)."""
    r = np.maximum(ranges, MIN_MODEL_RANGE_M)
    ones = np.ones_like(r)
    a, k = fit_sigma_model(r_res, np.stack([ones, r**2], axis=1))
    b, c = fit_sigma_model(b_res, np.stack([ones, 1.0 / r**2], axis=1))
    sig_r, sig_b = np.hypot(a, k * r), np.hypot(b, c / r)

    def beyond(res, sigma):
        return float(np.mean(np.abs(res - np.median(res)) > 3.0 * sigma))

    edges = np.asarray(RANGE_BINS_M)
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (ranges >= lo) & (ranges < hi)
        bins.append({"range_m": [float(lo), float(hi)], "n": int(m.sum()),
                     "range_sigma_m": robust_sigma(r_res[m]) if m.sum() > 1 else None,
                     "bearing_sigma_rad": robust_sigma(b_res[m]) if m.sum() > 1 else None})
    return {"sigma_range_m": float(a), "sigma_range_per_m": float(k),
            "sigma_bearing_rad": float(b), "sigma_bearing_m": float(c),
            "range_beyond_3_sigma": beyond(r_res, sig_r),
            "bearing_beyond_3_sigma": beyond(b_res, sig_b), "bins": bins}


def sightings_against_truth(folder: Path, logs: dict) -> list[dict]:
    """Per robot, every landmark sighting with truth at its time: ``time`` (N,),
    ``subject`` (N,), ``z`` (N, 2) measured range and bearing, and ``residual`` (N, 2)
    against the range and bearing the truth gives."""
    from graphslam.sources.planar.mrclam import read_subjects

    barcodes, landmarks = read_subjects(folder)
    out = []
    for log in logs.values():
        meas, truth = log["meas"], log["truth"]
        subject = np.array([barcodes.get(int(c), 0) for c in meas[:, 1]])
        keep = np.isin(subject, list(landmarks))
        p = truth_at(truth, meas[keep, 0])
        ok = np.isfinite(p).all(axis=1)
        m, sub, p = meas[keep][ok], subject[keep][ok], p[ok]
        d = np.array([landmarks[s] for s in sub]).reshape(-1, 2) - p[:, :2]
        residual = np.stack([m[:, 2] - np.hypot(d[:, 0], d[:, 1]),
                             wrap_angle(m[:, 3] - (np.arctan2(d[:, 1], d[:, 0]) - p[:, 2]))], axis=1)
        out.append({"time": m[:, 0], "subject": sub, "z": m[:, 2:4], "residual": residual})
    return out


def sensor_field(folder: Path, logs: dict, per_robot: list[dict]) -> dict:
    """Step 5 of the module docstring: the field's depth and half-width and the
    detection probability inside it, over all robots and per robot."""
    from graphslam.sources.planar.mrclam import read_subjects

    _, landmarks = read_subjects(folder)
    ids = sorted(landmarks)
    L = np.array([landmarks[i] for i in ids]).reshape(-1, 2)
    z = np.concatenate([r["z"] for r in per_robot])
    depth = float(np.percentile(z[:, 0], 99))
    half = float(np.percentile(np.abs(z[:, 1]), 99))
    counts, runs = [], []
    for log, r in zip(logs.values(), per_robot, strict=True):
        times = np.unique(r["time"])
        p = truth_at(log["truth"], times)
        d = L[None, :, :] - p[:, None, :2]
        rng = np.hypot(d[..., 0], d[..., 1])
        brg = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - p[:, 2:3])
        inside = (rng <= depth) & (np.abs(brg) <= half)
        frame = np.searchsorted(times, r["time"])
        reported = np.zeros_like(inside)
        reported[frame, np.searchsorted(ids, r["subject"])] = True
        counts.append((int(inside.sum()), int((inside & reported).sum())))
        runs.extend(miss_runs(inside, reported))
    total = np.sum(counts, axis=0)
    alpha = EkfSlamConfig().prune_missed_alpha
    runs_a = np.array(runs)
    n_alpha = float(np.quantile(runs_a, 1.0 - alpha))
    return {"field_range_m": depth, "field_half_fov_deg": math.degrees(half),
            "detection_prob": 1.0 - alpha ** (1.0 / n_alpha),
            "alpha": alpha, "miss_run_quantile_frames": n_alpha, "miss_runs": int(runs_a.size),
            "miss_runs_16_or_more": float(np.mean(runs_a >= 16)),
            "frame_detection_prob": float(total[1] / total[0]),
            "per_robot_frame_detection_prob": [h / n for n, h in counts], "frames_in_field": int(total[0])}


def miss_runs(inside: np.ndarray, reported: np.ndarray) -> list[int]:
    """Lengths of the runs of frames (rows) in which a landmark (column) is
    ``inside`` the field and not ``reported``, each ended by a sighting (a run
    still open at the end of the log is not counted: its end is unknown)."""
    out = []
    for j in range(inside.shape[1]):
        n = 0
        for k in np.flatnonzero(inside[:, j] | reported[:, j]):
            if reported[k, j]:
                if n:
                    out.append(n)
                n = 0
            else:
                n += 1
    return out


def sighting_residuals(per_robot: list[dict]) -> dict:
    """Step 3 of the module docstring on :func:`sightings_against_truth`'s sightings."""
    r_res = [r["residual"][:, 0] for r in per_robot]
    b_res = [r["residual"][:, 1] for r in per_robot]
    ranges = [r["z"][:, 0] for r in per_robot]
    out: dict = {}
    for name, res in (("range_m", np.concatenate(r_res)), ("bearing_rad", np.concatenate(b_res))):
        med = float(np.median(res))
        sigma = robust_sigma(res)
        out[name] = {"median": med, "robust_sigma": sigma, "std": float(np.std(res)),
                     "beyond_3_sigma": float(np.mean(np.abs(res - med) > 3 * sigma)),
                     "n": int(res.size), "residuals": res}
    measured_range = np.concatenate(ranges)
    out["model"] = sighting_model(measured_range, out["range_m"]["residuals"],
                                  out["bearing_rad"]["residuals"])
    out["model"]["measured_range"] = measured_range
    return out


#: Probability at which the sightings' error tail is matched (step 6): the association
#: gate's (``[isam2] association_gate_prob``, ``[ekf] gate_prob``); the second is a check.
TAIL_PROBS = (0.999, 0.99)


def sighting_tail(sightings: dict) -> dict:
    """Step 6 of the module docstring: the measured ``d2`` quantiles of the sightings'
    errors under the fitted model, the Student-t dof that matches the first of
    :data:`TAIL_PROBS`, and that t's and the Gaussian's quantiles beside the measured."""
    from scipy.optimize import brentq

    from filters.association import t2_quantile

    model = sightings["model"]
    r = np.maximum(model["measured_range"], MIN_MODEL_RANGE_M)
    var_r = model["sigma_range_m"] ** 2 + (model["sigma_range_per_m"] * r) ** 2
    var_b = model["sigma_bearing_rad"] ** 2 + (model["sigma_bearing_m"] / r) ** 2
    e_r = sightings["range_m"]["residuals"] - sightings["range_m"]["median"]
    e_b = sightings["bearing_rad"]["residuals"] - sightings["bearing_rad"]["median"]
    d2 = e_r**2 / var_r + e_b**2 / var_b
    measured = {p: float(np.quantile(d2, p)) for p in TAIL_PROBS}
    dof = brentq(lambda n: t2_quantile(TAIL_PROBS[0], n) - measured[TAIL_PROBS[0]], 1.0, 1e6)
    return {"dof": float(dof), "n": int(d2.size),
            "quantiles": [{"prob": p, "measured_d2": measured[p], "student_t_d2": t2_quantile(p, dof),
                           "gaussian_d2": t2_quantile(p, math.inf)} for p in TAIL_PROBS]}


#: Lag bins of the sightings' error correlation, s (step 4): fine where it falls fast.
CORRELATION_LAGS_S = (0.0, 0.3, 0.6, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0)
#: Normalised residuals are clipped here before the correlation (the tails would rule it).
CORRELATION_CLIP = 4.0


def sighting_correlation(per_robot: list[dict], config: MrclamConfig) -> dict:
    """Step 4 of the module docstring: the correlation of the normalised range and bearing
    errors of two sightings of one landmark by one robot, by the time between them,
    and the fit ``c exp(-dt / tau)`` (one ``tau``, a share ``c`` per component)."""
    from scipy.optimize import least_squares

    from graphslam.sources.planar.mrclam import sighting_covariances

    edges = np.asarray(CORRELATION_LAGS_S)
    sums = np.zeros((2, len(edges) - 1, 2))  # component, bin, (sum of products, sum of squares)
    counts = np.zeros(len(edges) - 1)
    for robot in per_robot:
        sub, t = robot["subject"], robot["time"]
        sigma = np.sqrt(np.diagonal(sighting_covariances(config, robot["z"]), axis1=1, axis2=2))
        res = robot["residual"] / sigma
        for s in np.unique(sub):
            k = np.flatnonzero(sub == s)
            e = np.clip(res[k] - np.median(res[k], axis=0), -CORRELATION_CLIP, CORRELATION_CLIP)
            a, b = np.triu_indices(k.size, 1)
            where = np.digitize(np.abs(t[k[a]] - t[k[b]]), edges) - 1
            inside = (where >= 0) & (where < len(counts))
            a, b, where = a[inside], b[inside], where[inside]
            counts += np.bincount(where, minlength=len(counts))
            for c in range(2):
                sums[c, :, 0] += np.bincount(where, e[a, c] * e[b, c], minlength=len(counts))
                sums[c, :, 1] += np.bincount(where, 0.5 * (e[a, c] ** 2 + e[b, c] ** 2),
                                             minlength=len(counts))
    corr = sums[:, :, 0] / np.maximum(sums[:, :, 1], 1e-300)
    mids = 0.5 * (edges[:-1] + edges[1:])
    w = np.sqrt(counts / counts.max())  # a bin's correlation is known to about 1 / sqrt(pairs)

    def residual(q):
        tau, c_r, c_b = q
        model = np.exp(-mids / tau)
        return np.concatenate([w * (corr[0] - c_r * model), w * (corr[1] - c_b * model)])

    fit = least_squares(residual, [5.0, 0.9, 0.5], bounds=([0.1, 0.0, 0.0], [600.0, 1.0, 1.0]))
    tau, c_r, c_b = (float(v) for v in fit.x)
    return {"time_constant_s": tau, "range_share": c_r, "bearing_share": c_b,
            "lags_s": mids.tolist(), "pairs": counts.astype(int).tolist(),
            "range_correlation": corr[0].tolist(), "bearing_correlation": corr[1].tolist()}


def shared_scan_error(per_robot: list[dict], config: MrclamConfig) -> dict:
    """Step 7 of the module docstring: what two sightings of different landmarks in one
    frame share of their errors. Per robot and landmark the median error is removed;
    errors beyond :data:`CORRELATION_CLIP` model sigmas are left out. Returns the
    correlation of the normalised range and bearing errors over every such pair, and
    the bearing error they share in radians, the square root of the mean product."""
    from graphslam.sources.planar.mrclam import sighting_covariances

    products = np.zeros(2)  # normalised range, bearing
    squares = np.zeros(2)
    shared_b = 0.0  # sum of raw bearing products, rad^2
    pairs = 0
    for robot in per_robot:
        sub, t = robot["subject"], robot["time"]
        sigma = np.sqrt(np.diagonal(sighting_covariances(config, robot["z"]), axis1=1, axis2=2))
        e = robot["residual"].copy()
        for s in np.unique(sub):
            e[sub == s] -= np.median(e[sub == s], axis=0)
        n = e / sigma
        keep = np.all(np.abs(n) <= CORRELATION_CLIP, axis=1)
        frames, inverse = np.unique(t, return_inverse=True)
        for f in np.flatnonzero(np.bincount(inverse[keep], minlength=len(frames)) >= 2):
            k = np.flatnonzero(keep & (inverse == f))
            a, b = np.triu_indices(k.size, 1)
            a, b = k[a], k[b]
            a, b = a[sub[a] != sub[b]], b[sub[a] != sub[b]]
            products += np.sum(n[a] * n[b], axis=0)
            squares += np.sum(0.5 * (n[a] ** 2 + n[b] ** 2), axis=0)
            shared_b += float(np.sum(e[a, 1] * e[b, 1]))
            pairs += a.size
    corr = products / np.maximum(squares, 1e-300)
    return {"pairs": pairs, "range_correlation": float(corr[0]), "bearing_correlation": float(corr[1]),
            "bearing_shared_sigma_rad": math.sqrt(max(shared_b / max(pairs, 1), 0.0))}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/calibrate_mrclam.json"))
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
    per_robot = sightings_against_truth(args.data, logs)
    sightings = sighting_residuals(per_robot)
    default = MrclamConfig()
    correlation = sighting_correlation(per_robot, default)
    field = sensor_field(args.data, logs, per_robot)
    tail = sighting_tail(sightings)
    shared = shared_scan_error(per_robot, default)
    report = {
        "robots": robots, "data": str(args.data), "command": COMMAND,
        "odometry": {k: v for k, v in motion.items() if k != "residual"},
        "noise": dict(zip(NOISE_NAMES, coef.tolist())),
        "nees": checks,
        "sightings": {k: {kk: vv for kk, vv in v.items() if kk not in ("residuals", "measured_range")}
                      for k, v in sightings.items()},
        "correlation": correlation,
        "sensor_field": field,
        "sighting_tail": tail,
        "shared_scan_error": shared,
        "defaults_in_use": {"sighting_error_dof": default.sighting_error_dof, "lag_s": default.odometry_lag_s,
                            "forward_scale": default.forward_scale,
                            "angular_scale": default.angular_scale,
                            **{n: getattr(default, n) for n in NOISE_NAMES},
                            **{n: getattr(default, n) for n in SIGHTING_NAMES},
                            **{n: getattr(default, n) for n in CORRELATION_NAMES},
                            **{n: getattr(default, n) for n in FIELD_NAMES}},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, report, indent=1, trailing_newline=True)
    print(json.dumps({k: report[k] for k in ("odometry", "noise", "nees", "sightings")}, indent=1))
    print(json.dumps({k: v for k, v in correlation.items() if not isinstance(v, list)}, indent=1))
    print(json.dumps({"sensor_field": field, "sighting_tail": tail, "shared_scan_error": shared}, indent=1))
    model = sightings["model"]
    ranges = model["measured_range"]
    model_sigma = {"range_m": np.hypot(model["sigma_range_m"], model["sigma_range_per_m"] * ranges),
                   "bearing_rad": np.hypot(model["sigma_bearing_rad"],
                                           model["sigma_bearing_m"]
                                           / np.maximum(ranges, MIN_MODEL_RANGE_M))}
    grid = np.linspace(RANGE_BINS_M[0], RANGE_BINS_M[-1], 50)
    curves = {"range_m": np.hypot(model["sigma_range_m"], model["sigma_range_per_m"] * grid),
              "bearing_rad": np.hypot(model["sigma_bearing_rad"], model["sigma_bearing_m"] / grid)}
    panels = []
    for name, unit in (("range_m", "m"), ("bearing_rad", "rad")):
        key = "range_sigma_m" if name == "range_m" else "bearing_sigma_rad"
        rows = [b for b in model["bins"] if b[key] is not None]
        mids = [0.5 * sum(b["range_m"]) for b in rows]
        panels.append(Panel(f"{name}: robust sigma by measured range", "measured range [m]",
                            f"sigma [{unit}]",
                            {"per bin": (mids, [b[key] for b in rows]),
                             "model": (grid.tolist(), curves[name].tolist()),
                             "constant": (grid[[0, -1]].tolist(),
                                          [sightings[name]["robust_sigma"]] * 2)}))
        z = (sightings[name]["residuals"] - sightings[name]["median"]) / model_sigma[name]
        edges = np.linspace(-5.0, 5.0, 41)
        counts, _ = np.histogram(z, edges)
        centres = 0.5 * (edges[:-1] + edges[1:])
        gauss = z.size * (edges[1] - edges[0]) * np.exp(-0.5 * centres**2) / math.sqrt(2 * math.pi)
        panels.append(Panel(f"{name} residual / model sigma", "normalised residual", "sightings",
                            {"measured": (centres.tolist(), counts.tolist()),
                             "N(0, 1)": (centres.tolist(), gauss.tolist())}))
    lags = np.asarray(correlation["lags_s"])
    fitted = np.exp(-lags / correlation["time_constant_s"])
    panels.append(Panel("sighting errors: correlation by time apart", "time apart [s]", "correlation",
                        {"range": (lags.tolist(), correlation["range_correlation"]),
                         "range fit": (lags.tolist(), (correlation["range_share"] * fitted).tolist()),
                         "bearing": (lags.tolist(), correlation["bearing_correlation"]),
                         "bearing fit": (lags.tolist(),
                                         (correlation["bearing_share"] * fitted).tolist())}))
    names = list(checks)
    panels.append(Panel("odometry consistency (mean NEES, 3 = consistent)", "window", "NEES",
                        {"mean": (names, [checks[n]["mean"] for n in names]),
                         "median (2.37 expected)": (names, [checks[n]["median"] for n in names])},
                        kind="bar", targets={"3": 3.0}))
    save_figure(args.out, "MRCLAM sensor calibration against Vicon truth", panels)


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
