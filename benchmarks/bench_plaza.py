"""Range-only SLAM on the CMU Plaza logs of gtsam's wheel (issue 31 item 5).

Plaza1 and Plaza2: dead reckoning and ranges to four radio beacons, run through
iSAM2 (``RangeFactor2D``, each beacon placed by trilateration of its first
ranges, :mod:`graphslam.backends.planar.range_init`; noise from gtsam's
``RangeISAMExample_plaza2.cpp``). Reported against the logs' truth, as gtsam's
example reports it: ATE of iSAM2 and of the dead reckoning (SE(2)-aligned),
and the beacons' map error (after the trajectory's alignment and after the
map's own).

    python benchmarks/bench_plaza.py [--quick] [--out benchmarks/results/plaza.json]

``--quick``: Plaza2's first :data:`QUICK_STEPS` frames. The PNG draws each
log's trajectories and beacons over the truth, and the ATE bars.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from plotting import Panel, save_figure  # noqa: E402

from graphslam import registry  # noqa: E402
from graphslam.evaluation import planar as metrics  # noqa: E402
from graphslam.pipelines import planar as pipeline  # noqa: E402
from graphslam.pipelines.common import whole  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

COMMAND = "python benchmarks/bench_plaza.py --out benchmarks/figures/plaza.json"
#: Frames of the quick run: the four beacons are placed by frame 321 of Plaza2.
QUICK_STEPS = 600


def one_run(name: str, max_steps: int | None) -> tuple[dict, dict]:
    """Row of the table and what the figure needs, for one log."""
    dataset = registry.load_dataset(name)
    t0 = time.perf_counter()
    result = whole(pipeline.run(dataset, registry.make_backend("isam2"), max_steps=max_steps))
    wall_s = time.perf_counter() - t0
    m = pipeline.compute_metrics(result, with_graph_error=False)
    est = result.estimate
    row = {"dataset": name, "steps": result.steps, "ranges": sum(
               len(f.observations) for f in dataset.frames[:result.steps]),
           "ate_m": m.ate_rmse_m, "odometry_ate_m": m.odometry_ate_rmse_m,
           "map_rmse_m": m.map_rmse_m, "map_rmse_m_map_aligned": m.map_rmse_m_map_aligned,
           "beacons": int(len(est.landmark_ids)), "beacons_true": len(dataset.landmarks_true or {}),
           "numerical_recoveries": result.numerical_recoveries, "wall_s": wall_s,
           "notes": list(dataset.notes)}
    gt = dataset.ground_truth()
    odo_ids, odo_wTb = pipeline.dead_reckoning(dataset, result.steps)
    series = {"truth": _xy(gt[1][gt[0] < result.steps])}
    series["dead reckoning"] = _xy(_aligned(odo_ids, odo_wTb[:, :2], gt)[0])
    xy, beacons = _aligned(est.pose_ids, est.wTb[:, :2], gt, np.asarray(est.landmarks_w))
    series["isam2"] = _xy(xy)
    truth_lm = np.array(list(dataset.landmarks_true.values())).reshape(-1, 2)
    series["beacons (truth)"] = _xy(truth_lm)
    series["beacons (isam2)"] = _xy(beacons)
    return row, series


def _xy(a: np.ndarray) -> tuple[list, list]:
    a = np.asarray(a).reshape(-1, np.asarray(a).shape[-1] if np.asarray(a).size else 2)
    return a[:, 0].tolist(), a[:, 1].tolist()


def _aligned(ids, xy, gt, points=None):
    """``xy`` (and ``points``) moved by the SE(2) alignment of the trajectory onto the truth."""
    _, ia, ib = np.intersect1d(ids, gt[0], return_indices=True)
    R, t = metrics.align_se2(xy[ia], gt[1][ib, :2])
    moved = None if points is None else points.reshape(-1, 2) @ R.T + t
    return xy @ R.T + t, moved


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"Plaza2's first {QUICK_STEPS} frames only")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/plaza.json"))
    args = ap.parse_args(argv)
    names = ("plaza2",) if args.quick else ("plaza1", "plaza2")
    max_steps = QUICK_STEPS if args.quick else None
    rows, panels = [], []
    for name in names:
        row, series = one_run(name, max_steps)
        rows.append(row)
        print(f"{name}: {row['steps']} steps, {row['ranges']} ranges: iSAM2 ATE "
              f"{row['ate_m']:.3f} m, dead reckoning {row['odometry_ate_m']:.3f} m, beacons "
              f"{row['map_rmse_m']:.3f} m ({row['beacons']} of {row['beacons_true']}), "
              f"{row['wall_s']:.1f} s", flush=True)
        panels.append(Panel(f"{name}: trajectories and beacons, aligned", "x [m]", "y [m]",
                            series))
    labels = [r["dataset"] for r in rows]
    panels.append(Panel("ATE against the truth", "log", "ATE [m]",
                        {"isam2 (range-only)": (labels, [r["ate_m"] for r in rows]),
                         "dead reckoning": (labels, [r["odometry_ate_m"] for r in rows]),
                         "beacon map RMSE": (labels, [r["map_rmse_m"] or 0.0 for r in rows])},
                        kind="bar", logy=True))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {"command": COMMAND + (" --quick" if args.quick else ""),
                                "rows": rows}, indent=1, trailing_newline=True)
    save_figure(args.out, "Plaza range-only SLAM (iSAM2) against the truth", panels,
                ncols=len(panels))


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
