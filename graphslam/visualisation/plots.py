"""Matplotlib figures (PNG files, no display): the only module that imports matplotlib."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphslam.evaluation.planar import errors_against_truth
from slamcore.planar.records import Dataset


def plot_comparison(entries, dataset: Dataset, path: Path) -> Path:
    """PNG of finished runs (``CompareEntry``): trajectories over ground truth, and pose
    errors with 3-sigma bounds over time."""
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


def plot_pose_graph(path: Path, title: str, xyz: np.ndarray, edge_rows: np.ndarray,
                    odometry: np.ndarray, rejected: np.ndarray) -> Path:
    """PNG of an optimised pose graph seen from above (3-D graphs projected on x-y):
    the odometry chain, kept closures (thin, grey) and rejected closures (red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    xy = np.asarray(xyz)[:, :2]
    fig, ax = plt.subplots(figsize=(7, 7), constrained_layout=True)
    kept = ~odometry & ~rejected
    for mask, color, width, label in ((kept, "0.75", 0.3, f"closures kept ({kept.sum()})"),
                                      (odometry, "C0", 0.8, "odometry"),
                                      (~odometry & rejected, "C3", 1.0,
                                       f"closures rejected ({(~odometry & rejected).sum()})")):
        segments = np.stack([xy[edge_rows[mask, 0]], xy[edge_rows[mask, 1]]], axis=1)
        ax.add_collection(LineCollection(segments, colors=color, linewidths=width, label=label))
    ax.autoscale()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_precision_recall(points, operating: tuple[float | None, float], path: Path) -> Path:
    """PNG of a precision-recall curve (``PrPoint`` list, swept over the normalised
    score) with the operating point ``(precision, recall)`` of the run marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.5), constrained_layout=True)
    pts = [p for p in points if p.precision is not None]
    if pts:
        ax.plot([p.recall for p in pts], [p.precision for p in pts], "-o", ms=3, lw=1,
                label="swept over the normalised score")
    prec, rec = operating
    if prec is not None:
        ax.plot([rec], [prec], "r*", ms=14, label="operating point (defaults)")
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("recall (queries with a true match that got one)")
    ax.set_ylabel("precision")
    ax.set_title("place recognition: precision-recall")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
