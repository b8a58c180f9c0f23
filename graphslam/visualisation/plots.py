"""Matplotlib figures (PNG files, no display): the only module that imports matplotlib."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from graphslam.evaluation.planar import errors_against_truth
from slamcore.errors import GraphSlamError
from slamcore.files import replacing
from slamcore.planar.records import Dataset


def plot_comparison(entries, dataset: Dataset, path: Path) -> Path:
    """PNG of finished runs (``CompareEntry``): trajectories over ground truth, and pose
    errors with 3-sigma bounds over time."""
    gt = dataset.ground_truth()
    lm = np.array(list(dataset.landmarks_true.values())).reshape(-1, 2) if dataset.landmarks_true else None
    # one line per robot of a joint run (--robot all): its poses in frame order were one
    # zig-zag line across the room (hostile pass 22), as the recording already splits them

    def strips(ids, xy) -> list[np.ndarray]:
        return [xy[mine] for mine in dataset.agent_groups(ids)]  # an empty line keeps its label

    tracks = [
        (
            e.backend,
            strips(e.result.estimate.pose_ids, e.result.estimate.wTb[:, :2]),
            e.result.estimate.landmarks_w,
        )
        for e in entries
    ]
    errors = []
    truth_strips = None
    if gt is not None:
        # the truth of the poses run, not of the whole log (--max-steps)
        ran = np.isin(gt[0], np.concatenate([e.result.estimate.pose_ids for e in entries]))
        truth_strips = strips(gt[0][ran], gt[1][ran][:, :2])
        gt_of = dict(zip(gt[0].tolist(), gt[1], strict=True))
        for e in entries:
            est = e.result.estimate
            has = np.array([int(i) in gt_of for i in est.pose_ids], dtype=bool)  # partial truth
            err = errors_against_truth(est.pose_ids[has], est.wTb[has], gt_of)
            s3 = (
                None
                if est.pose_covariances is None
                else 3 * np.sqrt(np.clip(np.einsum("nii->ni", est.pose_covariances[has]), 0, None))
            )
            steps = np.flatnonzero(has)
            for mine in dataset.agent_groups(est.pose_ids[has]):
                if len(mine):
                    errors.append((e.backend, steps[mine], err[mine], None if s3 is None else s3[mine]))
    return _comparison_figure(
        path,
        f"{dataset.name}: trajectories",
        truth_strips,
        lm,
        tracks,
        errors,
        ["x error [m]", "y error [m]", "heading error [rad]"],
        ("x [m]", "y [m]"),
        "error and 3-sigma bounds (filters: filtered; iSAM2: smoothed)",
        "step",
    )


def plot_visual_comparison(entries, sequence, path: Path) -> Path:
    """PNG of finished image-sequence runs (``CompareEntry`` with their ``nees``
    records): camera centres over the truth (seen along the truth's least-spread
    axis), aligned as their ATE is scored (a run without odometry by its Sim(3)
    fit: its own scale and frame are arbitrary), and the translation error in the
    camera frame with its 3-sigma bounds (after the NEES alignment) over the frames."""
    truth = None if sequence.wTc_true is None else np.asarray(sequence.wTc_true)[:, :3, 3]
    ref = truth if truth is not None else entries[0].result.estimate.wTc[:, :3, 3]
    # the two widest axes (a run cut before its first map holds no pose: x and y)
    a, b = sorted(np.argsort(np.ptp(ref, axis=0))[1:]) if len(ref) else (0, 1)
    tracks = []
    for e in entries:
        centres, landmarks = as_scored(e, truth)
        tracks.append((e.backend, centres[:, [a, b]], landmarks[:, [a, b]]))
    errors = [
        (
            e.backend,
            e.nees["frame_ids"],
            e.nees["errors"][:, :3],
            3 * np.sqrt(np.clip(np.einsum("nii->ni", e.nees["covariances"])[:, :3], 0, None)),
        )
        for e in entries
        if e.nees is not None
    ]
    n = max(e.result.frames for e in entries)
    truth_xy = None if truth is None else truth[:n, [a, b]]
    # image landmarks lie at any depth (KITTI's reach 260 m from a 2 m path): the
    # view is the paths', and the landmarks beyond it are counted, not drawn
    tracks, beyond, total = _within_view(tracks, truth_xy)
    said = f" ({beyond} of {total} landmarks of the runs beyond the view)" if beyond else ""
    return _comparison_figure(
        path,
        f"{sequence.name}: camera centres{said}",
        truth_xy,
        None,
        tracks,
        errors,
        [f"{c} error, camera [m]" for c in "xyz"],
        ("xyz"[a] + " [m]", "xyz"[b] + " [m]"),
        "error and 3-sigma bounds (EKF: filtered; iSAM2: smoothed)",
        "frame",
    )


#: The view around the camera paths: a quarter of their larger extent on each side
#: (the paths fill two thirds of it), ...
VIEW_MARGIN = 0.25
#: ... and at least a metre, so that a camera that hardly moved is seen with what it
#: saw at arm's length (a desk scene's depths).
VIEW_MARGIN_MIN_M = 1.0


def _within_view(tracks, truth_xy) -> tuple[list, int, int]:
    """``tracks`` (label, (N, 2) path, (L, 2) landmarks) with only the landmarks inside
    the box of the paths and ``truth_xy`` grown by the view margin; how many were left
    out, of how many."""
    paths = [xy for _, xy, _ in tracks] + ([] if truth_xy is None else [truth_xy])
    xy = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in paths])
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not len(xy):
        return tracks, 0, 0
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    margin = max(VIEW_MARGIN * float(np.max(hi - lo)), VIEW_MARGIN_MIN_M)
    lo, hi = lo - margin, hi + margin
    kept, beyond, total = [], 0, 0
    for label, path_xy, landmarks in tracks:
        inside = np.all((landmarks >= lo) & (landmarks <= hi), axis=1)
        kept.append((label, path_xy, landmarks[inside]))
        beyond += int(np.count_nonzero(~inside))
        total += len(landmarks)
    return kept, beyond, total


def as_scored(entry, truth) -> tuple[np.ndarray, np.ndarray]:
    """``(camera centres (N, 3), landmarks (L, 3))`` of a run mapped by the alignment its
    ATE uses (``metrics.alignment``: Sim(3) without odometry; a run with odometry
    starts at the true first pose and is drawn as it is)."""
    from graphslam.evaluation.spatial import align_umeyama

    est = entry.result.estimate
    centres = np.asarray(est.wTc)[:, :3, 3]
    landmarks = np.asarray(est.landmarks_w, dtype=np.float64).reshape(-1, 3)
    ids = np.asarray(est.frame_ids, dtype=np.int64)
    if truth is None or entry.metrics.alignment != "sim3" or len(ids) < 3 or ids.max() >= len(truth):
        return centres, landmarks
    try:
        s, R, t = align_umeyama(centres, truth[ids], with_scale=True)
    except GraphSlamError:  # an estimate that never moved has no scale to fit: drawn as it is
        return centres, landmarks
    return s * centres @ R.T + t, s * landmarks @ R.T + t


def _comparison_figure(
    path: Path,
    title: str,
    truth_xy,
    marks_xy,
    tracks,
    errors,
    error_labels,
    axis_labels,
    error_title: str,
    step_label: str,
) -> Path:
    """Trajectories ``(label, (N, 2) path or a list of them, (L, 2) landmarks)`` over
    ``truth_xy`` (the same) on the left; per error component, ``(label, steps, (N, r)
    errors, (N, r) 3-sigma or None)`` on the right (none without truth; a label may come
    once a robot). A list is drawn as separate lines of one colour, labelled once."""
    plt = _pyplot()
    n_err = len(error_labels) if errors else 0
    fig = plt.figure(figsize=(13, 7 if n_err else 6), constrained_layout=True)
    grid = fig.add_gridspec(max(n_err, 1), 2, width_ratios=[1.1, 1])
    ax = fig.add_subplot(grid[:, 0])
    if truth_xy is not None:
        for k, xy in enumerate(truth_xy if isinstance(truth_xy, list) else [truth_xy]):
            ax.plot(xy[:, 0], xy[:, 1], color="0.6", lw=2, label=None if k else "ground truth")
    if marks_xy is not None:
        ax.scatter(marks_xy[:, 0], marks_xy[:, 1], marker="x", color="0.6", s=12, label="true landmarks")
    for i, (label, path_xy, landmarks) in enumerate(tracks):
        for k, xy in enumerate(path_xy if isinstance(path_xy, list) else [path_xy]):
            ax.plot(xy[:, 0], xy[:, 1], lw=1, color=f"C{i}", label=None if k else label)
        if len(landmarks):
            ax.scatter(landmarks[:, 0], landmarks[:, 1], s=6, color=f"C{i}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(axis_labels[0])
    ax.set_ylabel(axis_labels[1])
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    if n_err:
        axes = [fig.add_subplot(grid[r, 1]) for r in range(n_err)]
        colour = {label: f"C{i}" for i, (label, *_) in enumerate(tracks)}
        shown: set[str] = set()
        for label, steps, err, s3 in errors:
            legend = None if label in shown else label
            shown.add(label)
            for r in range(n_err):
                axes[r].plot(steps, err[:, r], color=colour[label], lw=0.8, label=legend)
                if s3 is not None:
                    axes[r].fill_between(steps, -s3[:, r], s3[:, r], color=colour[label], alpha=0.15, lw=0)
        for r in range(n_err):
            axes[r].set_ylabel(error_labels[r])
            axes[r].axhline(0, color="0.5", lw=0.5)
        axes[0].set_title(error_title)
        axes[-1].set_xlabel(step_label)
        axes[0].legend(loc="upper left", fontsize=8)
    return _save(fig, path)


def plot_pose_graph(
    path: Path, title: str, xyz: np.ndarray, edge_rows: np.ndarray, odometry: np.ndarray, rejected: np.ndarray
) -> Path:
    """PNG of an optimised pose graph seen from above (3-D graphs projected on x-y):
    the odometry chain, kept closures (thin, grey) and rejected closures (red)."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    xy = np.asarray(xyz)[:, :2]
    fig, ax = plt.subplots(figsize=(7, 7), constrained_layout=True)
    kept = ~odometry & ~rejected
    for mask, color, width, label in (
        (kept, "0.75", 0.3, f"closures kept ({kept.sum()})"),
        (odometry, "C0", 0.8, "odometry"),
        (~odometry & rejected, "C3", 1.0, f"closures rejected ({(~odometry & rejected).sum()})"),
    ):
        segments = np.stack([xy[edge_rows[mask, 0]], xy[edge_rows[mask, 1]]], axis=1)
        # matplotlib's stubs take a Sequence only; its docs also take an (N, 2, 2) array
        ax.add_collection(
            LineCollection(
                segments,  # type: ignore[arg-type]
                colors=color,
                linewidths=width,
                label=label,
            )
        )
    ax.autoscale()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_precision_recall(points, operating: tuple[float | None, float], path: Path) -> Path:
    """PNG of a precision-recall curve (``PrPoint`` list, swept over the normalised
    score) with the operating point ``(precision, recall)`` of the run marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), constrained_layout=True)
    pts = [p for p in points if p.precision is not None]
    if pts:
        ax.plot(
            [p.recall for p in pts],
            [p.precision for p in pts],
            "-o",
            ms=3,
            lw=1,
            label="swept over the normalised score",
        )
    prec, rec = operating
    if prec is not None:
        ax.plot([rec], [prec], "r*", ms=14, label="operating point (defaults)")
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("recall (queries with a true match that got one)")
    ax.set_ylabel("precision")
    ax.set_title("place recognition: precision-recall")
    ax.grid(alpha=0.3)
    if pts or prec is not None:  # else matplotlib warns of an empty legend on stderr
        ax.legend(loc="lower left", fontsize=8)
    return _save(fig, path)


def _pyplot():
    """pyplot on the file-only Agg back end (no display on servers or CI)."""
    if "matplotlib" not in sys.modules:
        _private_config_dir_if_needed()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _private_config_dir_if_needed() -> None:
    """Give matplotlib a private temporary folder (removed at exit) when its default
    config or cache folder cannot be written (a read-only HOME): it makes one itself
    then, but says so in a paragraph on stderr each command (hostile pass 14)."""
    import atexit
    import shutil
    import tempfile

    if os.environ.get("MPLCONFIGDIR"):
        return
    home = Path(os.path.expanduser("~"))
    for variable, default in (("XDG_CONFIG_HOME", home / ".config"), ("XDG_CACHE_HOME", home / ".cache")):
        folder = Path(os.environ.get(variable) or default) / "matplotlib"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            writable = os.access(folder, os.W_OK)
        except OSError:
            writable = False
        if not writable:
            private = tempfile.mkdtemp(prefix="graphslam-matplotlib-")
            atexit.register(shutil.rmtree, private, True)
            os.environ["MPLCONFIGDIR"] = private
            return


#: ``--align`` as eval.png's first panel names it.
ALIGN_TITLES = {
    "none": "trajectories (not aligned)",
    "se3": "trajectories aligned (SE(3))",
    "sim3": "trajectories aligned (Sim(3), scale fitted)",
    "first": "trajectories aligned (first pose onto first pose)",
}
#: The time axis of eval.png per kind of reference stamps
#: (:func:`graphslam.pipelines.trajectory_eval.stamp_kind`).
STAMP_AXES = {
    "s": "time since first match [s]",
    "index": "stamp since first match (0, 1, 2, ...: frame indices or seconds)",
    "line": "pose since first match (no stamps: paired by line)",
}


def plot_trajectory_eval(results, path: Path, options=None) -> Path:
    """PNG of ``graphslam eval`` (``EstimateResult`` list): the aligned estimates over the
    reference (seen along its least-spread axis), ATE over time and along the path;
    ``options`` (:class:`~graphslam.evaluation.trajectory.EvalOptions`, None: eval's
    defaults) gives the alignment the title names."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8), constrained_layout=True)
    ref = results[0].result.ref[:, :3, 3]
    a, b = sorted(np.argsort(np.ptp(ref, axis=0))[1:])  # the two widest axes
    names = "xyz"
    axes[0].plot(ref[:, a], ref[:, b], color="0.5", lw=2, label="reference")
    for i, r in enumerate(results):
        res, name = r.result, r.label or Path(r.path).name
        p = res.est[:, :3, 3]
        axes[0].plot(p[:, a], p[:, b], color=f"C{i}", lw=1, label=name)
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(res.ref[:, :3, 3], axis=0), axis=1))])
        axes[1].plot(res.stamps_s - res.stamps_s[0], res.ate_trans_m, color=f"C{i}", lw=0.8, label=name)
        axes[2].plot(along, res.ate_trans_m, color=f"C{i}", lw=0.8, label=name)
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[0].set_xlabel(f"{names[a]} [m]")
    axes[0].set_ylabel(f"{names[b]} [m]")
    align = "se3" if options is None else options.align
    n_align = None if options is None else options.n_align
    axes[0].set_title(ALIGN_TITLES[align] + (f" on the first {n_align} matched poses" if n_align else ""))
    axes[0].legend(loc="best", fontsize=8)
    axes[1].set_xlabel(STAMP_AXES[results[0].stamps])
    axes[2].set_xlabel("distance along the reference [m]")
    for ax in axes[1:]:
        ax.set_ylabel("ATE [m]")
        ax.set_ylim(bottom=0)
    axes[1].set_title("translation error over time")
    axes[2].set_title("translation error along the path")
    return _save(fig, path)


def _metric_by(rows, group: str, metric: str = "ate_rmse_m") -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for r in rows:
        if r.get("status") == "ok" and r.get(metric) not in (None, "") and r.get(group) != "":
            out.setdefault(str(r[group]), []).append(float(r[metric]))
    return out


def plot_sweep(rows: list[dict], nees: dict, set_keys, out_dir: Path, writes=None) -> list[Path]:
    """The PNGs of ``graphslam sweep``: Monte Carlo NEES, ATE per back end, ATE per
    swept value; returns the files written. ``writes``: an
    :class:`~graphslam.outputs.writers.OutputWrites` that notes a plot the file system
    refuses and goes on to the next (without it the refusal is raised)."""
    from graphslam.evaluation.planar import NEES_CONFIDENCE, chi2_bounds

    plt = _pyplot()
    written: list[Path] = []

    def keep(fig, path: Path) -> None:
        if writes is None:
            written.append(_save(fig, path))
        elif writes({}, path.name, path, lambda p: _save(fig, p)):
            written.append(path)

    if nees:
        fig, ax = plt.subplots(figsize=(10, 5), constrained_layout=True)
        for i, (label, runs) in enumerate(sorted(nees.items())):
            # step 0 is the prior pose, known exactly: no error to score
            ax.plot(
                np.arange(1, runs.shape[1]),
                runs[:, 1:].mean(axis=0),
                color=f"C{i}",
                lw=0.8,
                label=f"{label} ({len(runs)} runs)",
            )
        for n_runs in sorted({len(r) for r in nees.values()}):
            lo, hi = chi2_bounds(3, n_runs, NEES_CONFIDENCE)
            ax.axhspan(
                lo, hi, color="0.5", alpha=0.15, lw=0, label=f"95 % bounds of the average of {n_runs} runs"
            )
        ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_ylabel("average pose NEES (3 dof)")
        ax.set_title(
            "Monte Carlo consistency: average NEES and 95 % chi-square bounds "
            "(filters: filtered; iSAM2: smoothed)"
        )
        ax.legend(loc="best", fontsize=8)
        keep(fig, out_dir / "sweep_nees.png")
    several = len({r.get("dataset") for r in rows}) > 1
    for group, name in [("label", "sweep_ate.png")] + [(k, f"sweep_{k}.png") for k in set_keys]:
        if group != "label" and len({str(r.get(group)) for r in rows if r.get(group) != ""}) < 2:
            continue
        # a swept value's box holds one back end (and dataset): pooled, iSAM2 and the
        # EKF made one box, and a value where one of them failed another mix
        data = _metric_by(
            [
                r if group == "label" else {**r, "group": _setting_group(r, group, several)}
                for r in rows
                if group == "label" or r.get(group) != ""
            ],
            "label" if group == "label" else "group",
        )
        if not data:
            continue
        fig, ax = plt.subplots(figsize=(max(5, 1.4 * len(data) + 2), 4.5), constrained_layout=True)
        labels = sorted(data)
        ax.boxplot([data[k] for k in labels])
        ax.set_xticks(np.arange(1, len(labels) + 1), labels, rotation=20)
        ax.set_xlabel("back end and swept settings" if group == "label" else f"{group}, back end")
        ax.set_ylabel("ATE RMSE [m]")
        n_in = sum(len(v) for v in data.values())
        n_all = sum(1 for r in rows if group == "label" or r.get(group) != "")
        missing = f" of {n_all} (the others failed or have no ATE)" if n_in < n_all else ""
        ax.set_title(f"ATE over {n_in} runs{missing}")
        keep(fig, out_dir / name)
    return written


def _setting_group(row: dict, key: str, several_datasets: bool) -> str:
    """The box of ``row`` in the plot of the swept ``key``: its value, back end, dataset."""
    where = f" {Path(str(row.get('dataset'))).name}" if several_datasets else ""
    return f"{row.get(key)}\n{row['backend']}{where}"


def _save(fig, path: Path) -> Path:
    """Write ``fig`` to ``path`` whole (through a temporary file) and close it."""
    import matplotlib.pyplot as plt

    try:
        _drawable_texts(fig)
        with replacing(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
    return path


def _drawable_texts(fig) -> None:
    """Every text of ``fig`` drawable: a file name that is not UTF-8 (Latin-1 bytes,
    held by Python as lone surrogates) in a title or a legend makes matplotlib's font
    code raise; such characters are drawn as U+FFFD instead."""
    from matplotlib.text import Text

    for t in fig.findobj(Text):
        text = t.get_text()
        if any("\udc80" <= c <= "\udcff" for c in text):
            t.set_text(text.encode("utf-8", "surrogateescape").decode("utf-8", "replace"))


def plot_pose_graph_comparison(
    path: Path,
    title: str,
    tracks: dict[str, np.ndarray],
    truth_xyz: np.ndarray | None,
    wall_s: dict[str, float],
    final_cost: dict[str, float],
) -> Path:
    """PNG of ``compare`` on a pose graph: each solver's positions ((N, 3), seen from
    above) over the truth's if any, and each solver's wall time labelled with its final cost."""
    plt = _pyplot()
    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(12, 5.5), constrained_layout=True, gridspec_kw={"width_ratios": [2, 1]}
    )
    if truth_xyz is not None:
        ax.plot(truth_xyz[:, 0], truth_xyz[:, 1], color="0.6", lw=2.5, label="ground truth")
    for i, (name, xyz) in enumerate(tracks.items()):
        ax.plot(xyz[:, 0], xyz[:, 1], color=f"C{i}", lw=0.9, ls=("-", "--", ":")[i % 3], label=name)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8)
    ax.set_title("estimates seen from above (first pose fixed)")
    names = list(wall_s)
    bars = bx.bar(names, [wall_s[n] for n in names], color=[f"C{i}" for i in range(len(names))])
    for b, n in zip(bars, names, strict=True):
        bx.annotate(
            f"cost {final_cost[n]:.6g}",
            (b.get_x() + b.get_width() / 2, b.get_height()),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    bx.set_ylabel("wall time [s]")
    bx.set_title("time to the optimum")
    fig.suptitle(title)
    return _save(fig, path)
