"""Several back ends on the same stream: one table, one JSON, plots, one recording.

Each back end runs in a forked child process on the same in-memory dataset
(same seed, same observations), so its wall time and peak memory are its own:
``peak_rss_mb`` is the child's peak resident set above its resident set when
it started. Rerun logging happens afterwards in the parent, off the clock.
"""

from __future__ import annotations

import multiprocessing as mp
import resource
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphslam import registry
from graphslam.pipelines import planar as pipeline
from slamcore.errors import GraphSlamError
from slamcore.planar.records import Dataset
from slamcore.planar.geometry import wrap_angle

#: 95 % two-sided chi-square bounds are taken at this confidence.
NEES_CONFIDENCE = 0.95


@dataclass
class CompareEntry:
    backend: str
    result: pipeline.RunResult
    metrics: dict


def _run_one(dataset: Dataset, name: str, config_path, overrides, max_steps) -> tuple:
    backend = registry.make_backend(name, config_path=config_path, overrides=overrides)
    result = pipeline.run(dataset, backend, max_steps=max_steps, with_covariances=True)
    return result


def _child(conn, dataset, name, config_path, overrides, max_steps):
    try:
        start_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        result = _run_one(dataset, name, config_path, overrides, max_steps)
        peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        result.dataset = None  # the parent has it; don't send it back
        conn.send(("ok", result, (peak_kb - start_kb) / 1024.0))
    except GraphSlamError as e:
        conn.send(("error", str(e), None))
    except BaseException:  # report anything else with its traceback to the parent
        conn.send(("crash", traceback.format_exc(), None))
    finally:
        conn.close()


def run_isolated(dataset: Dataset, name: str, config_path=None, overrides=None,
                 max_steps=None) -> tuple[pipeline.RunResult, float]:
    """Run one back end in a forked child; returns its result and peak RSS (MB)."""
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, dataset, name, config_path, overrides,
                                            max_steps))
    proc.start()
    child.close()
    try:
        status, payload, peak_mb = parent.recv()
    except EOFError:
        proc.join()
        raise GraphSlamError(f"{name}: worker died (exit code {proc.exitcode})") from None
    except KeyboardInterrupt:
        proc.terminate()
        proc.join()
        raise
    proc.join()
    if status == "error":
        raise GraphSlamError(payload)
    if status == "crash":
        raise RuntimeError(f"{name} crashed in its worker:\n{payload}")
    payload.dataset = dataset
    return payload, peak_mb


def compare(dataset: Dataset, backends: list[str], *, config_path=None,
            overrides: dict[str, dict] | None = None, max_steps: int | None = None,
            isolate: bool = True, seed: int | None = None, progress=None) -> list[CompareEntry]:
    """Run each back end on ``dataset``; return results with their metrics.

    Args:
        overrides: per back-end config overrides, ``{name: {key: value}}``.
        isolate: run each back end in its own forked process (timing and memory
            are its own); False runs them in this process (no memory figure).
        progress: optional callable ``progress(name)`` called before each run.
    """
    entries = []
    for name in backends:
        if progress is not None:
            progress(name)
        ov = (overrides or {}).get(name, {})
        if isolate:
            result, peak_mb = run_isolated(dataset, name, config_path, ov, max_steps)
        else:
            result, peak_mb = _run_one(dataset, name, config_path, ov, max_steps), None
        m = pipeline.compute_metrics(result, seed=seed)
        m["peak_rss_mb"] = peak_mb
        if m.get("association") is not None:
            m["association"]["oracle_accuracy"] = oracle_association_accuracy(
                dataset, result.steps)
        m.update(pose_statistics(dataset, result))
        entries.append(CompareEntry(name, result, m))
    reference = next((e for e in entries if e.backend == "isam2"), None)
    if reference is not None:
        for e in entries:
            e.metrics["rms_to_isam2_m"] = rms_position_distance(e.result.estimate,
                                                                reference.result.estimate)
    return entries


def pose_statistics(dataset: Dataset, result: pipeline.RunResult) -> dict:
    """Final pose error and pose NEES against ground truth (where both exist)."""
    gt = dataset.ground_truth()
    est = result.estimate
    out = {"final_pose_error_m": None, "nees_mean": None, "nees_in_bounds_fraction": None}
    if gt is None:
        return out
    gt_of = dict(zip(gt[0].tolist(), gt[1]))
    err = errors_against_truth(est.pose_ids, est.wTb, gt_of)
    out["final_pose_error_m"] = float(np.linalg.norm(err[-1, :2]))
    if est.pose_covariances is not None:
        from graphslam.evaluation import planar as metrics

        nees = metrics.nees(err, est.pose_covariances)
        lo, hi = metrics.chi2_bounds(3, 1, NEES_CONFIDENCE)
        out["nees_mean"] = float(np.mean(nees))
        out["nees_in_bounds_fraction"] = float(np.mean((nees >= lo) & (nees <= hi)))
    return out


def oracle_association_accuracy(dataset: Dataset, steps: int | None = None) -> float | None:
    """Association accuracy of an oracle that knows the true poses, the true
    landmark positions and which landmarks each scan sees; None without that truth.

    Per scan it picks the assignment of observations to the visible landmarks
    with the least total squared Mahalanobis distance under each observation's
    own R (the Bayes choice given everything but the noise). Its errors are
    swaps between landmarks the sensor cannot separate (e.g. two landmarks
    0.3 m apart under 0.2 m range noise), so no estimator can be expected to
    beat it: it is the ceiling to read a back end's accuracy against.
    """
    from scipy.optimize import linear_sum_assignment

    from slamcore.planar import geometry as models

    truth = dataset.landmarks_true
    frames = dataset.frames if steps is None else dataset.frames[:steps]
    if not truth:
        return None
    n = correct = 0
    for f in frames:
        if not f.observations:
            continue
        if f.wTb_true is None or f.true_landmark_ids is None:
            return None
        ids = np.array(sorted(set(f.true_landmark_ids)))
        lm = np.array([truth[int(i)] for i in ids]).reshape(-1, 2)
        z = np.array([o.z for o in f.observations]).reshape(-1, 2)
        Rinv = np.linalg.inv(np.array([o.covariance for o in f.observations]))
        nu = models.innovation(z[:, None, :], models.observe(np.asarray(f.wTb_true)[None], lm)[None])
        d2 = np.einsum("mli,mij,mlj->ml", nu, Rinv, nu)
        rows, cols = linear_sum_assignment(d2)
        got = dict(zip(rows.tolist(), ids[cols].tolist()))
        for i, t in enumerate(f.true_landmark_ids):
            n += 1
            correct += int(got.get(i) == int(t))
    return correct / n if n else None


def errors_against_truth(pose_ids: np.ndarray, wTb: np.ndarray, gt_of: dict) -> np.ndarray:
    """(N, 3) ``estimate - truth`` (heading wrapped), unaligned: both share the prior frame."""
    truth = np.array([gt_of[int(i)] for i in pose_ids])
    err = wTb - truth
    err[:, 2] = wrap_angle(err[:, 2])
    return err


def rms_position_distance(a, b) -> float | None:
    """RMS distance (m) between the positions two estimates give the same pose ids."""
    common, ia, ib = np.intersect1d(a.pose_ids, b.pose_ids, return_indices=True)
    if len(common) == 0:
        return None
    d = a.wTb[ia, :2] - b.wTb[ib, :2]
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


COLUMNS = [
    ("backend", "backend", "s"),
    ("ate_rmse_m", "ATE [m]", ".3f"),
    ("final_pose_error_m", "final err [m]", ".3f"),
    ("rms_to_isam2_m", "RMS to iSAM2 [m]", ".3f"),
    ("nees_mean", "mean NEES", ".2f"),
    ("nees_in_bounds_fraction", "NEES in 95%", ".2f"),
    ("association_accuracy", "assoc acc", ".4f"),
    ("association_oracle", "oracle acc", ".4f"),
    ("association_unused", "obs unused", "d"),
    ("association_duplicates", "dup lm", "d"),
    ("wall_s", "wall [s]", ".2f"),
    ("steps_per_s", "steps/s", ".0f"),
    ("peak_rss_mb", "peak MB", ".0f"),
]


def format_table(entries: list[CompareEntry]) -> str:
    """Plain-text table of the comparison; columns with no value anywhere are left out."""
    rows = []
    for e in entries:
        m = dict(e.metrics)
        a = m.get("association") or {}
        m["association_accuracy"] = a.get("accuracy")
        # the oracle's ceiling, observations left unused (counted as wrong) and
        # extra estimated landmarks mapped to an already-taken true landmark
        m["association_oracle"] = a.get("oracle_accuracy")
        m["association_unused"] = a.get("unused")
        m["association_duplicates"] = a.get("duplicates")
        rows.append(m)
    cols = [c for c in COLUMNS if any(r.get(c[0]) is not None for r in rows)]
    cells = [[h for _, h, _ in cols]]
    for r in rows:
        cells.append(["n/a" if r.get(k) is None else format(r[k], f) for k, _, f in cols])
    widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
    lines = ["  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths)))
             for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def plot(entries: list[CompareEntry], dataset: Dataset, path: Path) -> Path:
    """PNG: trajectories over ground truth, and pose errors with 3-sigma bounds over time."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no display on servers or CI
    import matplotlib.pyplot as plt

    gt = dataset.ground_truth()
    n_err = 3 if gt is not None else 0
    fig = plt.figure(figsize=(13, 7 if n_err else 6), constrained_layout=True)
    grid = fig.add_gridspec(max(n_err, 1), 2, width_ratios=[1.1, 1])
    ax = fig.add_subplot(grid[:, 0])
    if gt is not None:
        ax.plot(gt[1][:, 0], gt[1][:, 1], color="0.6", lw=2, label="ground truth")
    if dataset.landmarks_true:
        lm = np.array(list(dataset.landmarks_true.values()))
        ax.scatter(lm[:, 0], lm[:, 1], marker="x", color="0.6", s=12, label="true landmarks")
    for i, e in enumerate(entries):
        est = e.result.estimate
        ax.plot(est.wTb[:, 0], est.wTb[:, 1], lw=1, color=f"C{i}", label=e.backend)
        if len(est.landmarks_w):
            ax.scatter(est.landmarks_w[:, 0], est.landmarks_w[:, 1], s=6, color=f"C{i}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{dataset.name}: trajectories")
    ax.legend(loc="best", fontsize=8)
    if gt is not None:
        gt_of = dict(zip(gt[0].tolist(), gt[1]))
        labels = ["x error [m]", "y error [m]", "heading error [rad]"]
        axes = [fig.add_subplot(grid[r, 1]) for r in range(3)]
        for i, e in enumerate(entries):
            est = e.result.estimate
            err = errors_against_truth(est.pose_ids, est.wTb, gt_of)
            steps = np.arange(len(err))
            for r in range(3):
                axes[r].plot(steps, err[:, r], color=f"C{i}", lw=0.8, label=e.backend)
                if est.pose_covariances is not None:
                    s3 = 3 * np.sqrt(np.clip(est.pose_covariances[:, r, r], 0, None))
                    axes[r].fill_between(steps, -s3, s3, color=f"C{i}", alpha=0.15, lw=0)
        for r in range(3):
            axes[r].set_ylabel(labels[r])
            axes[r].axhline(0, color="0.5", lw=0.5)
        axes[0].set_title("error and 3-sigma bounds (filters: filtered; iSAM2: smoothed)")
        axes[-1].set_xlabel("step")
        axes[0].legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def record(entries: list[CompareEntry], dataset: Dataset, recorder) -> None:
    """One Rerun recording, one entity subtree per back end, on the step timeline."""
    n = max(e.result.steps for e in entries)
    recorder.start(dataset, n)
    for e in entries:
        est = e.result.estimate
        for k in range(len(est.pose_ids)):
            recorder.log.set_step(k)
            cov = None if est.pose_covariances is None else est.pose_covariances[k]
            recorder.log.log_pose(e.backend, est.wTb[k], cov, recorder.color_index(e.backend))
        recorder.finish(e.backend, e.result)
