"""FastSLAM time per step against particle count and map size, beside a numpy floor.

A seeded simulated run: a robot drives a circle through a field of 150
landmarks and sees about 10 of them per step (range-bearing, known
association). For FastSLAM 1.0 and 2.0 with N = 10, 100, 1000 particles, ours
(:class:`filters.fastslam.FastSlam`) and the floor filter the whole run from
scratch, alternated repeat by repeat (``timing.alternate``, medians, one BLAS
thread); the ratio is ours / floor per observation (target
``timing.TARGETS["fastslam"]``). FastSLAM 2.0 with 100 particles is also timed
against the map size (50, 150, 500 landmarks).

The floor (:class:`FloorFastSlam`) is the same filter written plainly in numpy
on dense arrays: poses (N, 3), landmark means (N, L, 2) and covariances
(N, L, 2, 2), vectorised over particles, one observation at a time. Per step:
motion sampling; for 2.0 the Montemerlo et al. (2003) proposal refined by each
observation of a known landmark (except where the innovation lies beyond the
misread gate, widened by the cloud's spread), with its weight, then one pose draw; the
per-particle landmark EKF update (1.0: with its weight) or the initialisation
of a new landmark from the inverse observation model; the weighted mean and
covariance of the cloud; systematic resampling when ESS < 0.5 N (every
particle's map copied). It draws the same random numbers in the same order as
ours, so the two estimates agree to round-off: the benchmark stops if they
differ by more than ``FLOOR_AGREEMENT_M`` (a floor could be cheap by being
wrong). It leaves out what ours does besides: the back-end contract's checks
(observation kinds, pose ids), unknown association, odometry stored new->old
and its covariance scale, the float64 noise floor and Joseph / eigen fallbacks
of :mod:`filters.numerics` (their checks run in ours on every update) and the
recovery counters, and the map shared between particles (ours copies pointers
when resampling, the floor copies every landmark).

``--victoria-park`` runs FastSLAM 2.0 over the whole Victoria Park sequence
with 100 particles (and 1000 with ``--vp-particles 100 1000``), printing the
total time. The file's odometry covariance is scaled by ``--vp-odometry-scale``
(default 10): at 1 it is too confident for a particle filter and the estimate
drifts away from the landmarks. The data is read by
``graphslam.sources.planar.victoria_park`` (the reader every back end uses).

JSON (default ``benchmarks/results/fastslam.json``, with ``summaries``: one
per version and particle count) and its PNG beside it.

    python benchmarks/bench_fastslam.py [--out FILE.json] [--repeats R] [--victoria-park] [--quick]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages

import timing  # noqa: E402  (beside this script)
from filters.fastslam import FastSlam  # noqa: E402
from filters.fastslam_config import FastSlamConfig  # noqa: E402
from graphslam.sources.planar.victoria_park import read_victoria_park  # noqa: E402
from slamcore.planar import geometry as models  # noqa: E402
from slamcore.planar.records import Dataset, Frame, Observation, Odometry  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)


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


# --------------------------------------------------------------------- the floor
_LOG_2PI = math.log(2.0 * math.pi)
#: 2.0's misread gate: the 0.999 quantile of a 2-dof chi-square (Gaussian sightings), closed form
MISREAD_GATE_D2 = -2.0 * math.log(1.0 - 0.999)
#: Ours and the floor draw the same random numbers in the same order, so their
#: estimates differ by round-off only (seen: below 1e-13 m); metres.
FLOOR_AGREEMENT_M = 1e-6


def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _inv2(S):
    """Inverse and determinant of (n, 2, 2) matrices (closed form)."""
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    inv = np.empty_like(S)
    inv[:, 0, 0], inv[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
    inv[:, 0, 1], inv[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
    return inv, det


def _observe(x, m):
    """Predicted [range, bearing] (n, 2), H_m (n, 2, 2) and H_x (n, 2, 3) of landmarks m."""
    dx, dy = m[:, 0] - x[:, 0], m[:, 1] - x[:, 1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    zhat = np.stack([r, np.arctan2(dy, dx) - x[:, 2]], axis=1)
    H_m = np.stack([dx / r, dy / r, -dy / q, dx / q], axis=1).reshape(-1, 2, 2)
    H_x = np.zeros((len(x), 2, 3))
    H_x[:, :, :2] = -H_m
    H_x[:, 1, 2] = -1.0
    return zhat, H_m, H_x


class FloorFastSlam:
    """The floor: FastSLAM 1.0 / 2.0 written plainly on dense per-particle arrays.

    Known association, forward odometry. Poses ``x (N, 3)``, landmark means
    ``mu (N, L, 2)`` and covariances ``P (N, L, 2, 2)`` (L grows by doubling),
    log weights ``(N,)``, every particle's path ``(N, T, 3)`` (copied whole at each
    resampling, as the maps are; the estimate is the best particle's path, as ours).
    Draws come from one ``default_rng(seed)`` in the same order as ours (initial
    cloud, motion noise, 2.0's pose draw, resampling).
    """

    def __init__(self, version: int, n_particles: int, seed: int, ess_fraction: float = 0.5):
        self.version, self.n, self.ess_fraction = version, n_particles, ess_fraction
        self.rng = np.random.default_rng(seed)
        self.mu = np.zeros((n_particles, 16, 2))
        self.P = np.zeros((n_particles, 16, 2, 2))
        self.col: dict[int, int] = {}
        self.logw = np.full(n_particles, -math.log(n_particles))
        self.x = self.proposal = None
        self.means: list[np.ndarray] = []
        self.covs: list[np.ndarray] = []
        self.path = np.zeros((n_particles, 16, 3))
        self.t = 0

    def initialize(self, x0: np.ndarray, cov: np.ndarray) -> None:
        self.x = x0 + self.rng.standard_normal((self.n, 3)) @ np.linalg.cholesky(cov).T
        self.x[:, 2] = _wrap(self.x[:, 2])

    def predict(self, u: np.ndarray, Q: np.ndarray) -> None:
        eps = self.rng.standard_normal((self.n, 3)) @ np.linalg.cholesky(Q).T
        c, s = np.cos(self.x[:, 2]), np.sin(self.x[:, 2])
        if self.version == 2:  # proposal prior: mean x (+) u, covariance J_u Q J_u^T
            J_u = np.zeros((self.n, 3, 3))
            J_u[:, 0, 0], J_u[:, 0, 1], J_u[:, 1, 0], J_u[:, 1, 1] = c, -s, s, c
            J_u[:, 2, 2] = 1.0
            self.proposal = (self._compose(c, s, u), J_u @ Q @ J_u.transpose(0, 2, 1))
        self.x = self._compose(c, s, u + eps)

    def _compose(self, c, s, u):
        u = np.broadcast_to(u, (self.n, 3))
        x = self.x
        return np.stack([x[:, 0] + c * u[:, 0] - s * u[:, 1], x[:, 1] + s * u[:, 0] + c * u[:, 1],
                         _wrap(x[:, 2] + u[:, 2])], axis=1)

    def update(self, observations) -> None:
        obs = []
        for o in observations:
            c, new = self._column(o.landmark_id)
            obs.append((c, np.asarray(o.z), o.covariance, new))
        if not obs:  # nothing to weigh: the motion-sampled cloud is the estimate
            self._record(np.exp(self.logw))
            return
        keep = [None] * len(obs)
        if self.version == 2 and self.proposal is not None:
            kept = iter(self._sample_proposal([(c, z, R) for c, z, R, new in obs if not new]))
            keep = [None if new else next(kept) for _, _, _, new in obs]
        self.proposal = None
        for (c, z, R, new), k in zip(obs, keep):
            if new:
                self._new_landmark(c, z, R)
            else:
                self._landmark_update(c, z, R, weigh=self.version == 1, keep=k)
        self.logw -= self.logw.max() + math.log(np.sum(np.exp(self.logw - self.logw.max())))
        w = np.exp(self.logw)
        self._record(w)
        if 1.0 / np.sum(w * w) < self.ess_fraction * self.n:
            self._resample(w)

    def _column(self, lid: int):
        if lid in self.col:
            return self.col[lid], False
        if len(self.col) == self.mu.shape[1]:  # grow L by doubling
            self.mu = np.concatenate([self.mu, np.zeros_like(self.mu)], axis=1)
            self.P = np.concatenate([self.P, np.zeros_like(self.P)], axis=1)
        self.col[lid] = len(self.col)
        return self.col[lid], True

    def _sample_proposal(self, known) -> list[np.ndarray]:
        """2.0: refine N(x_hat, Q) by each known landmark's observation, weigh, draw the pose.
        A particle whose innovation lies beyond the 0.999 gate under its proposal, its
        landmark, R and the prior cloud's weighted covariance keeps its proposal (a
        misread id, as ours, whose landmark step then leaves that particle's record too):
        the (N,) keep mask of each observation."""
        mu_x, S_x = (a.copy() for a in self.proposal)
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        th = mu_x[:, 2]
        mean = np.array([w @ mu_x[:, 0], w @ mu_x[:, 1], math.atan2(w @ np.sin(th), w @ np.cos(th))])
        d = mu_x - mean
        d[:, 2] = _wrap(d[:, 2])
        cloud = (d * w[:, None]).T @ d
        cloud = 0.5 * (cloud + cloud.T)
        kept = []
        for c, z, R in known:
            m, P = self.mu[:, c], self.P[:, c]
            zhat, H_m, H_x = _observe(mu_x, m)
            nu = z - zhat
            nu[:, 1] = _wrap(nu[:, 1])
            SHt = S_x @ H_x.transpose(0, 2, 1)
            HPHt = H_m @ P @ H_m.transpose(0, 2, 1)
            L = H_x @ SHt + HPHt + R
            Linv, det = _inv2(L)
            self.logw += (-0.5 * np.einsum("ni,nij,nj->n", nu, Linv, nu) - 0.5 * np.log(det)
                          - _LOG_2PI)
            Ginv, _ = _inv2(H_x @ (S_x + cloud) @ H_x.transpose(0, 2, 1) + HPHt + R)
            keep = np.einsum("ni,nij,nj->n", nu, Ginv, nu) <= MISREAD_GATE_D2
            kept.append(keep)
            K = SHt @ Linv
            mu_x = np.where(keep[:, None], mu_x + np.einsum("nij,nj->ni", K, nu), mu_x)
            mu_x[:, 2] = _wrap(mu_x[:, 2])
            S_new = S_x - K @ SHt.transpose(0, 2, 1)
            S_x = np.where(keep[:, None, None], 0.5 * (S_new + S_new.transpose(0, 2, 1)), S_x)
        eps = self.rng.standard_normal((self.n, 3))
        self.x = mu_x + np.einsum("nij,nj->ni", np.linalg.cholesky(S_x), eps)
        self.x[:, 2] = _wrap(self.x[:, 2])
        return kept

    def _landmark_update(self, c: int, z, R, weigh: bool, keep=None) -> None:
        m, P = self.mu[:, c], self.P[:, c]
        zhat, H_m, _ = _observe(self.x, m)
        nu = z - zhat
        nu[:, 1] = _wrap(nu[:, 1])
        PHt = P @ H_m.transpose(0, 2, 1)
        Sinv, det = _inv2(H_m @ PHt + R)
        if weigh:
            self.logw += (-0.5 * np.einsum("ni,nij,nj->n", nu, Sinv, nu) - 0.5 * np.log(det)
                          - _LOG_2PI)
        K = PHt @ Sinv
        m_new = m + np.einsum("nij,nj->ni", K, nu)
        P_new = P - K @ PHt.transpose(0, 2, 1)
        P_new = 0.5 * (P_new + P_new.transpose(0, 2, 1))
        if keep is not None:
            m_new = np.where(keep[:, None], m_new, m)
            P_new = np.where(keep[:, None, None], P_new, P)
        self.mu[:, c], self.P[:, c] = m_new, P_new

    def _new_landmark(self, c: int, z, R) -> None:
        a = self.x[:, 2] + z[1]
        ca, sa = np.cos(a), np.sin(a)
        self.mu[:, c, 0] = self.x[:, 0] + z[0] * ca
        self.mu[:, c, 1] = self.x[:, 1] + z[0] * sa
        G = np.stack([ca, -z[0] * sa, sa, z[0] * ca], axis=1).reshape(-1, 2, 2)
        self.P[:, c] = G @ R @ G.transpose(0, 2, 1)

    def _record(self, w: np.ndarray) -> None:
        """Weighted mean pose and cloud covariance of this step (the trajectory estimate)."""
        th = self.x[:, 2]
        mean = np.array([w @ self.x[:, 0], w @ self.x[:, 1],
                         math.atan2(w @ np.sin(th), w @ np.cos(th))])
        d = self.x - mean
        d[:, 2] = _wrap(d[:, 2])
        self.means.append(mean)
        self.covs.append((d * w[:, None]).T @ d)
        self.best = int(np.argmax(w))
        if self.t == self.path.shape[1]:  # grow T by doubling
            self.path = np.concatenate([self.path, np.zeros_like(self.path)], axis=1)
        self.path[:, self.t] = self.x
        self.t += 1

    def _resample(self, w: np.ndarray) -> None:
        """Systematic resampling; every particle's map is copied (dense arrays)."""
        cdf = np.cumsum(w)
        cdf[-1] = 1.0
        pos = (self.rng.random() + np.arange(self.n)) / self.n
        parents = np.minimum(np.searchsorted(cdf, pos, side="right"), self.n - 1)
        L = len(self.col)
        self.x = self.x[parents]
        self.mu[:, :L] = self.mu[parents, :L]
        self.P[:, :L] = self.P[parents, :L]
        self.path[:, : self.t] = self.path[parents, : self.t]
        self.best = int(np.flatnonzero(parents == self.best)[0])
        self.logw = np.full(self.n, -math.log(self.n))

    def trajectory(self) -> np.ndarray:
        """(T, 3) the best particle's path."""
        return self.path[self.best, : self.t]

    def landmarks(self) -> dict[int, np.ndarray]:
        """The best particle's landmark means by id."""
        return {lid: self.mu[self.best, c] for lid, c in self.col.items()}


def run_floor(ds: Dataset, floor: FloorFastSlam) -> FloorFastSlam:
    """The floor over the whole dataset (the same frames and observations as ours)."""
    for k, f in enumerate(ds.frames):
        if k == 0:
            floor.initialize(ds.prior_wTb, ds.prior_covariance)
        else:
            floor.predict(np.asarray(f.odometry.delta), np.asarray(f.odometry.covariance))
        floor.update(f.observations)
    return floor


def against_floor(ds: Dataset, version: int, n: int, seed: int, repeats: int) -> dict:
    """Ours and the floor over the same run, alternated (``timing.alternate``, 1 BLAS thread).

    Each timed call filters the whole run from a fresh filter (made untimed in
    ``setup``). Raises if the two estimates differ by more than
    :data:`FLOOR_AGREEMENT_M`: a floor that disagrees could be cheap by being wrong.
    """
    made: dict = {}
    setup = {"ours": lambda: made.update(ours=FastSlam(FastSlamConfig(
                 version=version, n_particles=n, seed=seed))),
             "floor": lambda: made.update(floor=FloorFastSlam(version, n, seed))}
    calls = {"ours": lambda: run_backend(ds, made["ours"]),
             "floor": lambda: run_floor(ds, made["floor"])}
    with timing.blas_threads(1):
        t = timing.alternate(calls, repeats, setup=setup)
    ours, floor = made["ours"], made["floor"]
    agreement = floor_agreement_m(ours, floor)
    if not agreement <= FLOOR_AGREEMENT_M:
        raise RuntimeError(f"FastSLAM {version}.0, N={n}: the floor's estimate is "
                           f"{agreement:.3g} m from ours (tolerance {FLOOR_AGREEMENT_M} m): "
                           "the ratio would mean nothing")
    n_obs = sum(len(f.observations) for f in ds.frames)
    return {"version": version, "n_particles": n, "ours": timing.timing_dict(t["ours"]),
            "floor": timing.timing_dict(t["floor"]),
            "ms_per_step": 1e3 * t["ours"].median_s / len(ds.frames),
            "floor_ms_per_step": 1e3 * t["floor"].median_s / len(ds.frames),
            "us_per_observation": 1e6 * t["ours"].median_s / n_obs,
            "floor_us_per_observation": 1e6 * t["floor"].median_s / n_obs,
            "ratio": t["ours"].median_s / t["floor"].median_s, "agreement_m": agreement,
            "final_error_m": float(np.linalg.norm(ours.current_pose()[:2]
                                                  - ds.frames[-1].wTb_true[:2])),
            "resamplings": ours.resample_count}


def floor_agreement_m(ours: FastSlam, floor: FloorFastSlam) -> float:
    """Largest distance between ours' and the floor's trajectory points and best-map landmarks."""
    est = ours.estimate()
    d_traj = np.linalg.norm(est.wTb[:, :2] - floor.trajectory()[:, :2], axis=1)
    lms = floor.landmarks()
    d_lm = [np.linalg.norm(m - lms[int(i)]) for i, m in zip(est.landmark_ids, est.landmarks_w)]
    return float(max(d_traj.max(), max(d_lm, default=0.0)))


def plot(results: dict, out: Path) -> Path:
    """Time per step of ours and the floor per version, their ratio, and time against map size."""
    from plotting import Panel, save_figure  # beside this script

    vp, vl = results["vs_particles"], results["vs_landmarks"]
    panels, ratio = [], {}
    for v in (1, 2):
        rows = [r for r in vp if r["version"] == v]
        ns = [r["n_particles"] for r in rows]
        panels.append(Panel(f"FastSLAM {v}.0: ours and the numpy floor (150 landmarks)",
                            "particles", "time per step [ms]",
                            {"ours": (ns, [r["ms_per_step"] for r in rows]),
                             "floor": (ns, [r["floor_ms_per_step"] for r in rows])},
                            logx=True, logy=True))
        ratio[f"FastSLAM {v}.0"] = (ns, [r["ratio"] for r in rows])
    target = timing.TARGETS["fastslam"]
    top = max([target] + [y for _, ys in ratio.values() for y in ys])
    ms = [r["ms_per_step"] for r in vl]
    panels += [
        Panel("ours / floor (median of alternated repeats)", "particles", "time ratio", ratio,
              logx=True, targets={f"target {target}": target}, ylim=(0.0, 1.15 * top)),
        Panel("against map size (FastSLAM 2.0, 100 particles, one run each)",
              "landmarks in the world", "time per step [ms]",
              {"FastSLAM 2.0, N=100": ([r["landmarks"] for r in vl], ms)},
              ylim=(0.0, 1.2 * max(ms, default=1.0)))]
    return save_figure(out, f"FastSLAM time per step, simulated circle ({results['steps']} steps, "
                            f"{results['obs_per_step']:.1f} observations a step, seed "
                            f"{results['seed']})", panels)


FLOOR_WORDS = ("the same FastSLAM step written plainly in numpy on dense (N, L, 2) means and "
               "(N, L, 2, 2) covariances, vectorised over particles, known association, "
               "same draws (bench_fastslam.FloorFastSlam)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=entry.output_file, default=Path(__file__).resolve().parent / "results" / "fastslam.json",
                    help="write results as JSON here (and its PNG beside it)")
    ap.add_argument("--quick", action="store_true",
                    help="20 steps, 10 and 100 particles, 50 and 150 landmarks, 2 repeats")
    ap.add_argument("--steps", type=entry.count, default=60, help="steps of the simulated run")
    ap.add_argument("--particles", type=entry.count, nargs="+", default=[10, 100, 1000])
    ap.add_argument("--repeats", type=entry.count, default=7,
                    help="alternated repeats of ours and the floor (medians are reported)")
    ap.add_argument("--landmarks", type=entry.count, nargs="+", default=[50, 150, 500])
    ap.add_argument("--victoria-park", action="store_true")
    ap.add_argument("--vp-particles", type=entry.count, nargs="+", default=[100])
    ap.add_argument("--vp-odometry-scale", type=entry.positive, default=10.0,
                    help="odometry covariance scale (the file's covariance is too confident "
                         "for a particle filter: at 1 the estimate drifts away)")
    ap.add_argument("--vp-association", choices=["known", "unknown"], default="known",
                    help="unknown: the data's landmark ids are used only to score association")
    ap.add_argument("--seed", type=entry.seed, default=0)
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, steps=20, particles=[10, 100], landmarks=[50, 150], repeats=2)
    command = "python benchmarks/bench_fastslam.py " + " ".join(
        sys.argv[1:] if argv is None else argv)

    ds = simulated_run(150, args.steps, args.seed)
    n_obs = sum(len(f.observations) for f in ds.frames)
    results: dict = {"steps": args.steps, "seed": args.seed, "obs_per_step": n_obs / args.steps,
                     "repeats": args.repeats, "floor_agreement_tolerance_m": FLOOR_AGREEMENT_M,
                     "vs_particles": [], "vs_landmarks": [], "victoria_park": [], "summaries": []}
    print(f"simulated: {args.steps} steps, 150 landmarks, {n_obs / args.steps:.1f} obs/step; "
          f"ours and the floor alternated {args.repeats} times (medians), 1 BLAS thread")
    print("final err m: last-pose position error of this one seeded run (not an average); "
          "agree m: largest distance between ours' and the floor's estimates")
    print(f"{'version':>7} {'N':>6} {'ms/step':>9} {'floor ms':>9} {'ratio':>6} {'us/obs':>8} "
          f"{'final err m':>11} {'agree m':>8}")
    for version in (1, 2):
        for n in args.particles:
            r = against_floor(ds, version, n, args.seed, args.repeats)
            print(f"{version:>7} {n:>6} {r['ms_per_step']:>9.2f} {r['floor_ms_per_step']:>9.2f} "
                  f"{r['ratio']:>6.2f} {r['us_per_observation']:>8.1f} {r['final_error_m']:>11.3f} "
                  f"{r['agreement_m']:>8.1e}")
            results["vs_particles"].append(r)
            results["summaries"].append(timing.summary(
                f"FastSLAM {version}.0, {n} particles", r["ours"]["median_s"] / n_obs,
                r["floor"]["median_s"] / n_obs, target=timing.TARGETS["fastslam"],
                floor=FLOOR_WORDS, command=command, unit="s per observation",
                version=version, n_particles=n))
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
    entry.write_json(args.out, results, indent=2)
    print(f"wrote {args.out}")
    plot(results, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
