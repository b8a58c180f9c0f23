"""FastSLAM with unknown ids on the default synthetic world: a scan's sightings paired in
order against paired as a whole (``[fastslam] pair_scans_jointly``).

The default synthetic world (spread landmarks, the course's noise) is run once per filter
seed by FastSLAM 1.0 and 2.0 (100 particles, unknown association), each way. Unknown-id
runs on it either hold the loop (ATE 0.4-1.1 m) or lose it (1.4-4.4 m):
:data:`LOST_ATE_M` splits the two. Per version and way: the ATEs, their median, the runs
above :data:`LOST_ATE_M` and the median association accuracy. Seeds 0-199 by default: which
runs lose the loop changes with any change to the filter's random draws, so 30 seeds
could not tell the two ways apart (13 losses against 8 there, 65 against 56 over 200).
The clustered landmarks of MRCLAM are measured by ``benchmarks/bench_mrclam.py`` (in order:
``--pair-scans-in-order``).

    python benchmarks/bench_scan_pairing.py [--seeds 0 1 ...] [--versions 1 2] [--quick] [--out FILE.json]

``--quick``: seed 0, FastSLAM 2.0, the first 200 steps. JSON (default
``benchmarks/results/scan_pairing.json``) and its PNG beside it (each way's ATEs sorted).
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from filters.fastslam import FastSlam  # noqa: E402
from filters.fastslam_config import FastSlamConfig  # noqa: E402
from graphslam.evaluation import planar as metrics  # noqa: E402
from graphslam.pipelines import planar as pipeline  # noqa: E402
from graphslam.pipelines.common import whole  # noqa: E402
from graphslam.sources.planar.synthetic import make_synthetic  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

#: ATE above which a run lost the loop (the two modes of the ATEs lie either side), m.
LOST_ATE_M = 1.3


def spread(version: int, joint: bool, seeds: list[int], max_steps: int | None = None) -> dict:
    """One way of pairing, one version, over ``seeds``."""
    data = make_synthetic()
    ates, accuracy = [], []
    for seed in seeds:
        config = FastSlamConfig(version=version, n_particles=100, association="unknown", seed=seed,
                                pair_scans_jointly=joint)
        result = whole(pipeline.run(data, FastSlam(config), max_steps=max_steps))
        ates.append(pipeline.compute_metrics(result, with_graph_error=False).ate_rmse_m)
        accuracy.append(metrics.association_accuracy(result.associations).accuracy)
    return {"ate_m": ates, "median_ate_m": float(np.median(ates)),
            "lost": int(np.sum(np.array(ates) > LOST_ATE_M)),
            "median_accuracy": float(np.median(accuracy))}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=entry.seed, nargs="+", default=list(range(200)))
    ap.add_argument("--versions", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    ap.add_argument("--quick", action="store_true", help="seed 0, FastSLAM 2.0, 200 steps")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/scan_pairing.json"))
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, seeds=[0], versions=[2])
    max_steps = 200 if args.quick else None
    out = {"command": "python benchmarks/bench_scan_pairing.py " + " ".join(sys.argv[1:]),
           "seeds": args.seeds, "lost_ate_m": LOST_ATE_M, "rows": {}}
    for version in args.versions:
        for joint in (False, True):
            row = spread(version, joint, args.seeds, max_steps)
            name = f"fastslam{version} {'jointly' if joint else 'in order'}"
            out["rows"][name] = row
            print(f"{name:22s} median ATE {row['median_ate_m']:.2f} m, lost {row['lost']} of "
                  f"{len(args.seeds)}, median accuracy {row['median_accuracy']:.3f}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, out, indent=1)
    print(f"wrote {args.out}")
    plot(out, args.out)


def plot(out: dict, path: Path) -> Path:
    """Each version and way's ATEs sorted against the share of seeds at or below them (200
    seeds per series drawn seed by seed are unreadable), the lost-loop line across."""
    from plotting import Panel, save_figure  # beside this script

    series = {}
    for name, row in out["rows"].items():
        ates = sorted(row["ate_m"])
        series[f"{name} (lost {row['lost']})"] = ([(i + 1) / len(ates) for i in range(len(ates))], ates)
    return save_figure(path, "FastSLAM, unknown ids, default synthetic world: scans paired in order or jointly", [
        Panel(f"ATE over {len(out['seeds'])} filter seeds, sorted", "share of seeds", "ATE [m]", series,
              logy=True, targets={f"loop lost above {LOST_ATE_M} m": LOST_ATE_M})])


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
