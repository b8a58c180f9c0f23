"""Pose-graph robustness against injected false loop closures (issue 6).

For each dataset (city10000, w10000), one process runs:

- the clean dataset with the plain configuration (the robust one without gate or kernel:
  Gaussian closures, the same fully converged LM polish):
  the **clean optimum**, reference for everything below; and with the robust
  configuration (``benchmarks/robust_isam2.toml`` by default);
- for each fraction f (default 0.1 and 0.3) the dataset with
  ``round(f * number of true loop closures)`` false closures added by
  :func:`graphslam.sources.planar.outliers.inject_false_closures` (f is false closures
  per true closure, odometry edges not counted; seed ``--seed``; the claims are
  at least 10 sigma off the ground truth for city10000, off the clean optimum
  for w10000), with the robust configuration on the whole dataset, and with the
  plain configuration on the first ``--plain-max-steps`` poses only: false
  closures between random far-apart poses destroy the sparsity of the problem,
  and a plain iSAM2 run slows from ~1 ms to ~1 s per step (hours on 10 000
  poses), so its damage is shown on a prefix, compared with the clean optimum
  of the same prefix.

Columns: ``ate_m`` ATE RMSE against ground truth after SE(2) alignment (city10000
only), ``ratio`` that over the clean optimum's ATE; ``rms_clean_m`` RMS position
distance (no alignment: both anchored by the same prior) to the clean optimum;
``rejected`` injected closures the final solution does not use: for the robust
configuration, held back by the gate or left out by the gated polish after
its last re-test (``Isam2Backend.rejected_loop_closures``); for the plain one, whose solution
uses them all, the injected closures left with a squared Mahalanobis residual
above 16.27 (chi-square 3 dof, 99.9 %), i.e. fought rather than absorbed;
``true_rej`` true closures rejected the same way. JSON goes to
``benchmarks/results/false_closures.json`` (or ``--out``), its figure beside it
(PNG: distance to the clean optimum and rejected false closures against f).
``--quick``: city10000's first 300 poses, f = 0.1, plain runs on 200 poses.

    python benchmarks/bench_false_closures.py [--dataset city10000 w10000]
        [--fractions 0.1 0.3] [--max-steps N] [--plain-max-steps 1500] [--seed 0]
        [--config benchmarks/robust_isam2.toml] [--quick] [--out FILE.json]

Targets: robust city10000 ATE <= 1.1 x clean; robust w10000 within 0.1 m RMS of
its clean optimum.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np

from graphslam import registry
from graphslam.pipelines.common import whole  # a cut run is no row
from graphslam.evaluation import planar as metrics
from graphslam.pipelines import planar as pipeline
from graphslam.backends import gtsam_convert as conv
from slamcore.config import load_section
from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
from graphslam.sources.planar.outliers import inject_false_closures, is_injected
import entry  # noqa: E402  (beside this script: its argparse types)

HERE = Path(__file__).resolve().parent
#: Chi-square 3 dof 99.9 % quantile: a plain run's closure with a larger squared
#: Mahalanobis residual counts as rejected (fought, not absorbed).
RESIDUAL_REJECT_R2 = 16.27


def rms_to(est, ref) -> float:
    """RMS position distance (m) over the pose ids of ``est`` (a prefix of ``ref``)."""
    index = {int(p): k for k, p in enumerate(ref.pose_ids)}
    rows = np.array([index[int(p)] for p in est.pose_ids])
    d = est.wTb[:, :2] - ref.wTb[rows, :2]
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))


def residual_rejected(dataset, estimate) -> tuple[int, int]:
    """(injected, true) closures with squared residual above RESIDUAL_REJECT_R2."""
    values = conv.estimate_values(estimate)
    inj = true = 0
    for frame in dataset.frames:
        for lc in frame.loop_closures:
            if 2.0 * conv.between_factor(lc).error(values) > RESIDUAL_REJECT_R2:
                if is_injected(lc):
                    inj += 1
                else:
                    true += 1
    return inj, true


def one_run(dataset, config, label, fraction, clean, clean_ate, plain_prefix=False):
    backend = Isam2Backend(config)
    result = whole(pipeline.run(dataset, backend))
    est = result.estimate
    n_inj = sum(is_injected(lc) for f in dataset.frames for lc in f.loop_closures)
    row = {"dataset": dataset.name, "config": label, "fraction": fraction,
           "poses": int(len(est.pose_ids)), "injected": n_inj, "wall_s": result.wall_s,
           "rms_clean_m": rms_to(est, clean), "ate_m": None, "ratio": None}
    gt = dataset.ground_truth()
    if gt is not None:
        row["ate_m"] = metrics.ate(est.pose_ids, est.wTb, *gt)["rmse_m"]
        row["ratio"] = row["ate_m"] / clean_ate
    if config.loop_closure_gate > 0:
        rej = backend.rejected_loop_closures()
        row["rejected"] = sum(is_injected(lc) for lc in rej)
        row["true_rej"] = len(rej) - row["rejected"]
        row["rejected_by"] = "gate/polish"
    else:
        row["rejected"], row["true_rej"] = residual_rejected(dataset, est)
        row["rejected_by"] = f"residual r2>{RESIDUAL_REJECT_R2}"
    row["final_error"] = float(backend.error())
    return row


def fmt(row) -> str:
    def f(v, spec):
        return "-" if v is None else format(v, spec)
    return (f"{row['dataset']:10s} {row['config']:8s} {row['fraction']:5.2f} {row['poses']:6d} "
            f"{row['injected']:6d} {f(row['ate_m'], '8.4f')} {f(row['ratio'], '6.3f')} "
            f"{row['rms_clean_m']:11.4f} {row['rejected']:6d} {row['true_rej']:8d} "
            f"{row['wall_s']:8.1f}")


HEADER = ("dataset    config   frac    poses injected ate_m   ratio  rms_clean_m rejected "
          "true_rej   wall_s")


def plot(rows: list[dict], out: Path) -> Path:
    """Per data set and configuration, against f: RMS distance to the clean optimum and the share
    of injected closures rejected."""
    from plotting import Panel, save_figure  # beside this script

    runs = {}
    for r in rows:
        runs.setdefault(f"{r['dataset']} {r['config']} ({r['poses']} poses)", []).append(r)
    dist = {k: ([r["fraction"] for r in v], [r["rms_clean_m"] for r in v]) for k, v in runs.items()}
    rej = {k: ([f"f = {r['fraction']:g}" for r in v if r["injected"]],
               [100 * r["rejected"] / r["injected"] for r in v if r["injected"]]) for k, v in runs.items()}
    return save_figure(out, "iSAM2 against injected false loop closures", [
        Panel("damage: distance to the clean optimum", "false closures per true closure (f)",
              "RMS distance to the clean optimum [m]", dist),
        Panel("false closures rejected (robust: gate/polish; plain: residual)",
              "false closures per true closure (f)", "injected closures rejected [%]",
              {k: v for k, v in rej.items() if v[0]}, kind="bar", ylim=(0, 105))])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", nargs="+", default=["city10000", "w10000"],
                    choices=["city10000", "w10000"])
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.1, 0.3])
    ap.add_argument("--max-steps", type=entry.count, default=None, help="use only the first N poses")
    ap.add_argument("--plain-max-steps", type=entry.count, default=1500,
                    help="poses of the plain runs with injected closures (0: skip them)")
    ap.add_argument("--seed", type=entry.seed, default=0)
    ap.add_argument("--config", type=Path, default=HERE / "robust_isam2.toml")
    ap.add_argument("--quick", action="store_true", help="a small prefix of city10000 (see the docstring)")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "false_closures.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, dataset=["city10000"], fractions=[0.1], max_steps=300, plain_max_steps=200)

    robust_cfg = load_section(Isam2Config, args.config)
    # plain: the robust configuration without its robustness (same polish tolerances)
    plain_cfg = dataclasses.replace(robust_cfg, loop_closure_gate=0.0, loop_closure_kernel="none",
                                    polish_method="lm")
    rows = []
    print(HEADER, flush=True)
    for name in args.dataset:
        ds = registry.load_dataset(name)
        if args.max_steps:
            ds = ds.truncated(args.max_steps)
        clean_backend = Isam2Backend(plain_cfg)
        clean_run = whole(pipeline.run(ds, clean_backend))
        clean = clean_run.estimate
        gt = ds.ground_truth()
        clean_ate = metrics.ate(clean.pose_ids, clean.wTb, *gt)["rmse_m"] if gt else None
        row = {"dataset": name, "config": "plain", "fraction": 0.0,
               "poses": int(len(clean.pose_ids)), "injected": 0, "wall_s": clean_run.wall_s,
               "rms_clean_m": 0.0, "ate_m": clean_ate, "ratio": 1.0 if gt else None,
               "rejected": 0, "true_rej": 0, "rejected_by": "-",
               "final_error": float(clean_backend.error())}
        rows.append(row)
        print(fmt(row), flush=True)
        rows.append(one_run(ds, robust_cfg, "robust", 0.0, clean, clean_ate))
        print(fmt(rows[-1]), flush=True)
        # claims must be false w.r.t. the truth (city10000) or the clean optimum (w10000)
        reference = gt if gt is not None else (clean.pose_ids, clean.wTb)
        prefix = None
        for fraction in args.fractions:
            bad = inject_false_closures(ds, fraction, seed=args.seed, reference=reference)
            rows.append(one_run(bad, robust_cfg, "robust", fraction, clean, clean_ate))
            print(fmt(rows[-1]), flush=True)
            if args.plain_max_steps:
                if prefix is None:
                    pre = ds.truncated(args.plain_max_steps)
                    prefix_run = whole(pipeline.run(pre, Isam2Backend(plain_cfg)))
                    pgt = pre.ground_truth()
                    pre_ate = (metrics.ate(prefix_run.estimate.pose_ids, prefix_run.estimate.wTb,
                                           *pgt)["rmse_m"] if pgt else None)
                    prefix = (prefix_run.estimate, pre_ate)
                    row = {"dataset": name, "config": "plain", "fraction": 0.0,
                           "poses": int(len(prefix[0].pose_ids)), "injected": 0,
                           "wall_s": prefix_run.wall_s, "rms_clean_m": 0.0, "ate_m": pre_ate,
                           "ratio": 1.0 if pgt else None, "rejected": 0, "true_rej": 0,
                           "rejected_by": "-"}
                    rows.append(row)
                    print(fmt(row), flush=True)
                # inject into the prefix so that the count is f x its own closures
                pre_bad = inject_false_closures(ds.truncated(args.plain_max_steps), fraction,
                                                seed=args.seed, reference=reference)
                rows.append(one_run(pre_bad, plain_cfg, "plain", fraction, prefix[0], prefix[1]))
                print(fmt(rows[-1]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"argv": sys.argv[1:], "seed": args.seed, "robust_config": str(args.config),
               "robust": robust_cfg.__dict__, "machine": platform.platform(),
               "date": time.strftime("%Y-%m-%d %H:%M:%S"), "rows": rows}
    entry.write_json(args.out, payload, indent=2, default=str)
    print(f"wrote {args.out}")
    plot(rows, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
