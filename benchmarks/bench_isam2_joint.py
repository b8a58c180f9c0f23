"""Every MRCLAM robot in one iSAM2 graph: where a new pose starts, timed (issue 31 item 4).

One process, the joint stream of UTIAS MRCLAM Dataset 6 (``--robot all``: five
robots' frames interleaved in time, their sightings of each other, known ids),
run twice and alternated ``--repeats`` times:

- ``ours``: the back end as it is. A new pose starts from the estimate of the
  pose its odometry extends when that is the latest pose, else (another robot's
  latest) from that pose's linearisation point
  (:meth:`graphslam.backends.planar.isam2.Isam2Backend._seed`);
- ``estimate``: the baseline, every new pose started from the estimate of the
  pose it extends (the route before: a back-substitution down to that pose's
  clique per frame).

Reported: the wall time of each (median of the repeats, the final polish
included), their ratio, the final cost over the whole graph (the one that
reaches the lower optimum) and each robot's ATE for both, in the JSON. One robot's runs take the first branch only, so
they are unchanged (``benchmarks/check_digests.py``).

    python benchmarks/bench_isam2_joint.py [--frames 4000] [--repeats 1] [--quick] [--out FILE.json]

``--frames 0``: the whole stream (15 745 frames, about 5 min in all); ``--quick``: the
first 300 frames.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import timing  # noqa: E402
from plotting import Panel, save_figure  # noqa: E402

from graphslam import registry  # noqa: E402
from graphslam.backends.planar.isam2 import Isam2Backend  # noqa: E402
from graphslam.pipelines import planar as pipeline  # noqa: E402
from graphslam.pipelines.common import whole  # noqa: E402
from graphslam.sources.planar.mrclam import MrclamConfig  # noqa: E402
from graphslam.sources.planar.mrclam_joint import read_mrclam_all  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

DATA = HERE.parent.parent / "shared" / "data" / "mrclam6"
COMMAND = "python benchmarks/bench_isam2_joint.py --frames 0 --out benchmarks/figures/isam2_joint.json"


class EstimateSeeded(Isam2Backend):
    """The baseline: every new pose starts from the estimate of the pose it extends."""

    def _seed(self, pose_id):
        return self._pose(pose_id)


def one_run(dataset, make, steps):
    backend = make()
    t0 = time.perf_counter()
    result = whole(pipeline.run(dataset, backend, max_steps=steps))  # a cut run is no row
    wall = time.perf_counter() - t0
    m = pipeline.compute_metrics(result, with_graph_error=True)
    return wall, {name: a["ate_rmse_m"] for name, a in m.agents.items()}, m.final_error


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--frames", type=entry.count_or_zero, default=4000, help="frames of the joint stream (0: all)")
    ap.add_argument("--repeats", type=entry.count, default=1)
    ap.add_argument("--quick", action="store_true", help="the first 300 frames (a smoke run)")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "isam2_joint.json")
    args = ap.parse_args(argv)
    dataset = read_mrclam_all(args.data, MrclamConfig(all_robots=True))
    if args.quick:  # smoke size unless --frames is given (--quick --frames 50 ran 300)
        entry.quick_sizes(ap, argv, args, frames=300)
    steps = args.frames or None
    routes = {
        "ours": lambda: registry.make_backend("isam2"),
        "estimate": lambda: EstimateSeeded(registry.make_backend("isam2").config),
    }
    walls: dict[str, list[float]] = {k: [] for k in routes}
    ates: dict[str, dict[str, float]] = {}
    costs: dict[str, float] = {}
    for _ in range(args.repeats):
        for name, make in routes.items():
            wall, ate, cost = one_run(dataset, make, steps)
            walls[name].append(wall)
            ates[name], costs[name] = ate, cost
            print(f"{name:9s} {wall:7.1f} s  final cost {cost:.6g}  ATE "
                  + " ".join(f"{a:.4f}" for a in ate.values()), flush=True)
    med = {k: statistics.median(v) for k, v in walls.items()}
    diff = max(abs(ates["ours"][r] - ates["estimate"][r]) for r in ates["ours"])
    ratio = med["estimate"] / med["ours"]
    print(f"frames {steps or len(dataset.frames)}: estimate-seeded / ours = {ratio:.2f} "
          f"({med['estimate']:.1f} s / {med['ours']:.1f} s); largest ATE difference {diff:.2e} m")
    frames = steps or len(dataset.frames)
    summary = timing.summary(
        f"2-D iSAM2, MRCLAM Dataset 6, five robots in one graph ({frames} frames)", med["ours"],
        med["estimate"], target=None, command=COMMAND,
        floor="the same back end starting every new pose from the estimate of the pose it "
              "extends (the route before)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {
        "benchmark": "isam2_joint", "frames": frames, "repeats": args.repeats,
        "wall_s": walls, "median_s": med, "ratio_estimate_over_ours": ratio,
        "ate_m": ates, "largest_ate_difference_m": diff, "final_cost": costs, "summary": summary,
        "machine": {"python": platform.python_version(), "platform": platform.platform()},
    }, indent=2, trailing_newline=True)
    print(f"wrote {args.out}")
    robots = list(ates["ours"])
    save_figure(args.out, f"MRCLAM Dataset 6, five robots in one iSAM2 graph ({frames} frames)", [
        Panel("wall time", "new pose starts from", "s", {"median": (list(med), list(med.values()))},
              kind="bar"),
        Panel("ATE per robot", "robot", "ATE [m]",
              {name: (robots, [ates[name][r] for r in robots]) for name in routes}, kind="bar"),
    ], ncols=2)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
