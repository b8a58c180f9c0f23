"""This project's iSAM2 loop against a bare gtsam.ISAM2 loop, same factors, same order.

Both loops see the same frames and make one ``ISAM2.update`` per frame with
the same factors and initial values; the bare loop gets its factors prebuilt
(outside the timing), so the ratio ours / bare is the whole overhead of our
records, conversion and back-end bookkeeping. Target: the team's
``timing.TARGETS["isam2"]`` (1.1). Floor: the bare ``gtsam.ISAM2`` loop, same
params (no polish on either side), one update per frame. Both loops are timed
by ``timing.alternate`` (alternated repeat by repeat, median, no best-of).

    python benchmarks/bench_isam2.py [--datasets victoria-park w10000] [--repeats 3] [--quick]
        [--out FILE.json]

The PNG beside the JSON shows both loops' times and the ratio against the target.
``--quick``: the first 300 frames of Victoria Park.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

import timing  # beside this script

from graphslam.backends import gtsam_convert as conv
from graphslam.pipelines.common import whole  # a cut run is no row
from graphslam import registry
from graphslam.pipelines import planar as pipeline
from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)


def prebuild(dataset, steps):
    """Per-frame factor graphs and the odometry / first-observation links to initialise from."""
    out = []
    seen_landmarks = set()
    for k, frame in enumerate(dataset.frames[:steps]):
        graph = gtsam.NonlinearFactorGraph()
        if k == 0:
            graph.add(conv.prior_factor(frame.pose_id, dataset.prior_wTb, dataset.prior_covariance))
            link = None
        else:
            odo = frame.odometry
            graph.add(conv.between_factor(odo))
            if odo.to_id == frame.pose_id:
                link = (X(odo.from_id), conv.pose2(odo.delta))
            else:
                link = (X(odo.to_id), conv.pose2(odo.delta).inverse())
        new_lms = []
        for obs in frame.observations:
            graph.add(conv.bearing_range_factor(obs, obs.landmark_id))
            if obs.landmark_id not in seen_landmarks:
                seen_landmarks.add(obs.landmark_id)
                r, b = obs.z
                new_lms.append((L(obs.landmark_id), np.array([r * np.cos(b), r * np.sin(b)])))
        for lc in frame.loop_closures:
            graph.add(conv.between_factor(lc))
        out.append((X(frame.pose_id), graph, link, new_lms))
    return out


#: ours / bare at most this (the team's target).
TARGET = timing.TARGETS["isam2"]


def bare_loop(dataset, prebuilt, params) -> gtsam.ISAM2:
    isam = gtsam.ISAM2(params)
    for k, (x_key, graph, link, new_lms) in enumerate(prebuilt):
        values = gtsam.Values()
        if link is None:
            pose = conv.pose2(dataset.prior_wTb)
        else:
            pose = isam.calculateEstimatePose2(link[0]).compose(link[1])
        values.insert(x_key, pose)
        for l_key, b_xy in new_lms:
            values.insert(l_key, pose.transformFrom(b_xy))
        isam.update(graph, values)
    return isam


def our_loop(dataset, steps, config) -> Isam2Backend:
    backend = Isam2Backend(config)
    whole(pipeline.run(dataset, backend, max_steps=steps))  # polish is off in config
    return backend


def summaries(rows: list[dict], command: str) -> list[dict]:
    """One summary row per data set (the README table's rows)."""
    return [timing.summary(
        f"2-D iSAM2 loop, {r['dataset']} ({r['steps']} steps)", r["ours_s"], r["bare_s"],
        target=TARGET, command=command.strip(), dataset=r["dataset"], steps=r["steps"],
        floor="a bare gtsam.ISAM2 loop, same params, one update per frame with the same "
              "factors prebuilt outside the timing") for r in rows]


def plot(rows: list[dict], out) -> object:
    """Wall time of both loops per data set, and ours / bare against the target."""
    from plotting import Panel, save_figure  # beside this script

    names = [f"{r['dataset']} ({r['steps']} steps)" for r in rows]
    return save_figure(out, "2-D iSAM2: our loop against a bare gtsam.ISAM2 loop, same factors", [
        Panel("wall time of the whole run (median of the repeats)", "data set", "wall time [s]",
              {"ours": (names, [r["ours_s"] for r in rows]),
               "bare gtsam.ISAM2": (names, [r["bare_s"] for r in rows])}, kind="bar"),
        Panel("overhead", "data set", "ours / bare", {"ratio": (names, [r["ratio"] for r in rows])},
              kind="bar", targets={f"target {TARGET}": TARGET, "parity": 1.0})])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["victoria-park", "w10000"])
    ap.add_argument("--steps", type=entry.count, default=None, help="first N frames only")
    ap.add_argument("--repeats", type=entry.count, default=3,
                    help="alternate ours/bare this many times; the median of each is kept")
    ap.add_argument("--quick", action="store_true",
                    help="the first 300 frames of Victoria Park, 2 repeats")
    ap.add_argument("--out", type=entry.output_file, default="benchmarks/results/bench_isam2.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, datasets=["victoria-park"], steps=300, repeats=2)
    command = "python benchmarks/bench_isam2.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    config = Isam2Config(polish=False)
    rows = []
    for name in args.datasets:
        ds = registry.load_dataset(name)
        steps = len(ds.frames) if args.steps is None else min(args.steps, len(ds.frames))
        prebuilt = prebuild(ds, steps)
        done = {}
        timed = timing.alternate({
            "ours": lambda: done.__setitem__("ours", our_loop(ds, steps, config)),
            "bare": lambda: done.__setitem__("bare", bare_loop(ds, prebuilt, config.isam2_params())),
        }, args.repeats, warmup=0)
        t_ours, t_bare = timed["ours"].median_s, timed["bare"].median_s
        e_ours = done["ours"].error()  # errors of the last repeat, outside the timing
        e_bare = done["bare"].getFactorsUnsafe().error(done["bare"].calculateEstimate())
        rows.append({"dataset": name, "steps": steps, "ours_s": t_ours, "bare_s": t_bare,
                     "ratio": t_ours / t_bare, "error_ours": e_ours, "error_bare": e_bare,
                     "timings": {k: timing.timing_dict(t) for k, t in timed.items()}})
        print(f"{name:14s} steps={steps:6d}  ours={t_ours:8.2f}s  bare={t_bare:8.2f}s  "
              f"ratio={t_ours / t_bare:5.3f} (target {TARGET})  error ours={e_ours:.6g} "
              f"bare={e_bare:.6g}", flush=True)
    from pathlib import Path

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {"benchmark": "isam2_overhead", "target_ratio": TARGET, "rows": rows,
                                "summaries": summaries(rows, command)}, indent=2)
    print(f"wrote {args.out}")
    plot(rows, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
