"""SE-Sync's certificate on pose-graph estimates (issue 32 item 5): its verdict,
gap and time beside the solve's.

Per file, in one process: the default solve (``auto``) and, where one is known,
an estimate stopped in a local minimum (batch LM from the odometry chain on
the torus, from LAGO on the Manhattan walk); each is certified
(:mod:`graphslam.backends.posegraph.certificate`), and the certificate's time is
reported over its solve's (no target: the check is a local solve of SE-Sync's
problem plus one sparse factorisation, and its cost depends on how far that
problem's optimum lies from the file's).

    python benchmarks/bench_posegraph_certificate.py [--quick] [--out FILE.json]

``--quick``: the torus and the Manhattan walk only. The full run adds gtsam's
sphere2500 and w10000 and a 3-D grid of 8000 poses (about 4 minutes).
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import gtsam
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from plotting import Panel, save_figure  # noqa: E402

from graphslam.backends.posegraph import certificate as cert  # noqa: E402
from graphslam.backends.posegraph.config import PoseGraphConfig  # noqa: E402
from graphslam.backends.posegraph.solver import solve  # noqa: E402
from graphslam.sources.posegraph_files import read_pose_graph_file  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

COMMAND = ("python benchmarks/bench_posegraph_certificate.py "
           "--out benchmarks/figures/posegraph_certificate.json")


def torus_file(folder: Path) -> Path:
    from tests.posegraphs import edges_with_closures, graph_lines, torus, write

    T = torus(10, 10)
    n = len(T)
    closures = [(k - 10, k) for k in range(10, n)] + [(k, (k + 10) % n) for k in range(n - 10, n)]
    lines = graph_lines(T, edges_with_closures(n, closures), sigma=0.2, seed=1, vertices=False)
    return write(folder / "torus100.g2o", lines)


def grid_file(folder: Path, side: int = 20) -> Path:
    """A 3-D grid of ``side**3`` poses (random orientations, 0.3 rad), odometry along
    rows plus the neighbours in y and z, 0.02 of noise: the kind of graph whose
    elimination fills most."""
    from tests.posegraphs import graph_lines, write

    rng = np.random.default_rng(0)
    truth = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.3, 3)), gtsam.Point3(x, y, z))
             for z in range(side) for y in range(side) for x in range(side)]

    def index(x, y, z):
        return (z * side + y) * side + x

    edges = [(k - 1, k) for k in range(1, side ** 3)]
    for z in range(side):
        for y in range(side):
            for x in range(side):
                edges += [(index(x, y, z), index(x, y + 1, z))] if y + 1 < side else []
                edges += [(index(x, y, z), index(x, y, z + 1))] if z + 1 < side else []
    return write(folder / "grid8000.g2o", graph_lines(truth, edges, sigma=0.02, seed=1,
                                                       vertices=False))


def cases(quick: bool, folder: Path) -> list[tuple[str, Path, str, list[tuple[str, PoseGraphConfig, str]]]]:
    """``(name, path, toro noise, [(estimate, config, solver)])``."""
    from tests.posegraphs import manhattan_walk

    local = [("default (auto)", PoseGraphConfig(), "auto")]
    out = [("torus100", torus_file(folder), "information",
            local + [("batch from odometry", PoseGraphConfig(init="odometry"), "batch")]),
           ("manhattan300", manhattan_walk(folder), "information",
            local + [("batch from LAGO", PoseGraphConfig(), "batch")])]
    if not quick:
        out += [("sphere2500", Path(gtsam.findExampleDataFile("sphere2500.txt")), "sqrt_information",
                 local),
                ("w10000", Path(gtsam.findExampleDataFile("w10000.graph")), "information", local),
                ("grid8000", grid_file(folder), "information",
                 [("batch", PoseGraphConfig(), "batch")])]
    return out


def bench(name: str, path: Path, noise: str, estimates) -> list[dict]:
    graph = read_pose_graph_file(path, noise)
    rows = []
    for label, config, solver in estimates:
        config = dataclasses.replace(config, toro_noise=noise)
        t0 = time.perf_counter()
        result = solve(graph, config, solver)
        solve_s = time.perf_counter() - t0
        c = cert.certify(graph, result.params, ~result.rejected)
        row = {"file": name, "estimate": label, "poses": graph.n_poses, "edges": graph.n_edges,
               "final_cost": result.final_cost, "solve_s": solve_s, **c.to_dict()}
        row.pop("covers")
        rows.append(row)
        gap = "-" if c.relative_gap is None else f"{c.relative_gap:.1e}"
        print(f"{name:13s} {label:20s} cost {result.final_cost:14.8g}  certified "
              f"{str(c.certified):5s} gap {gap:8s} neg {c.negative_pivots}  move "
              f"{c.max_translation_change_m:.3g} m {c.max_rotation_change_deg:.3g} deg  "
              f"check {c.wall_s:.2f} s / solve {solve_s:.2f} s")
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/posegraph_certificate.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [r for n, p, noise, est in cases(args.quick, Path(tmp)) for r in bench(n, p, noise, est)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    ratios = [r["wall_s"] / r["solve_s"] for r in rows]
    entry.write_json(args.out, {"command": COMMAND + (" --quick" if args.quick else ""),
                                "rows": rows,
                                "check_over_solve_median": float(np.median(ratios))},
                               indent=1, trailing_newline=True)
    names = [f"{r['file']}\n{r['estimate']}" for r in rows]
    save_figure(args.out, "SE-Sync's certificate of pose-graph estimates", [
        Panel("check time over solve time", "estimate", "check / solve",
              {"certified": ([n for n, r in zip(names, rows, strict=True) if r["certified"]],
                             [q for q, r in zip(ratios, rows, strict=True) if r["certified"]]),
               "not certified": ([n for n, r in zip(names, rows, strict=True) if not r["certified"]],
                                 [q for q, r in zip(ratios, rows, strict=True) if not r["certified"]])},
              kind="bar"),
        Panel("final cost", "estimate", "cost", {"final cost": (names, [r["final_cost"] for r in rows])},
              kind="bar", logy=True)])


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
