"""Landmark SLAM on real data with truth: UTIAS MRCLAM Dataset 6 (issue 31).

Every robot, every 2-D back end, with the barcodes as landmark ids (known
association) and without them (unknown association), and dead reckoning: ATE
(SE(2)-aligned, over the frames with Vicon truth), map error (matched landmarks,
after the trajectory's alignment and after the map's own), landmarks built and
recovered within 0.3 m. The reader's sensor model is the one
``benchmarks/calibrate_mrclam.py`` fitted; nothing here is tuned per robot.

    python benchmarks/bench_mrclam.py [--data ../shared/data/mrclam6] [--quick]

Then all five robots in one estimate (``--robot all``: shared landmarks, the
robots' sightings of each other, starts from the truth), in iSAM2 (JSON ``joint``),
in the EKF as a centralised filter (``joint_ekf``) and in FastSLAM 2.0 with every
robot in every particle, over the seeds (``joint_fastslam2_seeds``), each robot
scored on its own beside its own run (FastSLAM: the medians over the seeds); and
the joint iSAM2 and EKF without the ids (``joint_unknown``, ``joint_ekf_unknown``;
iSAM2's takes about 3.5 min).

``--quick``: robot 1's first 300 frames, known association. The PNG draws each
robot's trajectories and maps over the truth, and the ATE per robot.

The particle filters draw random numbers, so one seed is one sample of their ATE:
``--seeds 0 1 2 3 4`` (the default; ``--seeds`` with nothing skips it) also runs
FastSLAM 2.0 with each seed, both associations, and reports per robot the median,
least and largest ATE and the ratio of the medians (unknown over known ids), and
each seed's landmarks recovered within 0.3 m (``seeds_recovering_all``: the seeds that
recovered every one), in the JSON under ``fastslam2_seeds``. ``--pair-scans-in-order``: those
unknown-id runs pair each scan in its order (``[fastslam] pair_scans_jointly = false``; the
default pairs it as a whole). A landmark is
scored by the sightings the estimate's particle paired with it, through its ancestors
(``FastSlam.final_associations``).
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import math
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
from graphslam.sources.planar.mrclam import MrclamConfig, read_mrclam  # noqa: E402
from graphslam.sources.planar.mrclam_joint import read_mrclam_all  # noqa: E402
import entry  # noqa: E402  (beside this script: argparse types)

DATA = HERE.parent.parent / "shared" / "data" / "mrclam6"
BACKENDS = ("isam2", "ekf", "fastslam1", "fastslam2")


def one_run(dataset, backend: str, association: str, max_steps: int | None) -> dict:
    overrides = {"association": association}
    t0 = time.perf_counter()
    result = whole(pipeline.run(dataset, registry.make_backend(backend, overrides=overrides),
                                max_steps=max_steps))  # a cut run is no row
    m = pipeline.compute_metrics(result, with_graph_error=False)
    est = result.estimate
    return {"backend": backend, "association": association, "ate_m": m.ate_rmse_m,
            "odometry_ate_m": m.odometry_ate_rmse_m, "map_rmse_m": m.map_rmse_m,
            "map_rmse_m_map_aligned": m.map_rmse_m_map_aligned,
            "landmarks": int(len(est.landmark_ids)), "landmarks_recovered": m.landmarks_recovered,
            "association_accuracy": None if m.association is None else m.association.accuracy,
            "wall_s": time.perf_counter() - t0, "xy": est.wTb[:, :2], "pose_ids": est.pose_ids,
            "landmarks_xy": np.asarray(est.landmarks_w)}


def aligned(run: dict, gt) -> tuple[np.ndarray, np.ndarray]:
    """The run's trajectory and map moved by its ATE alignment onto the truth."""
    common, ia, ib = np.intersect1d(run["pose_ids"], gt[0], return_indices=True)
    R, t = metrics.align_se2(run["xy"][ia], gt[1][ib, :2])
    return run["xy"] @ R.T + t, run["landmarks_xy"].reshape(-1, 2) @ R.T + t


def seed_spread(data: Path, robots: list[int], seeds: list[int], in_order: bool = False) -> dict:
    """FastSLAM 2.0's ATE over ``seeds`` per robot and association (module doc); ``in_order``:
    unknown ids pair each scan in its order (``[fastslam] pair_scans_jointly = false``)."""
    out = {"seeds": seeds, "pair_scans_jointly": not in_order, "robots": {}}
    for robot in robots:
        dataset = read_mrclam(data, MrclamConfig(robot=robot))
        per = {}
        for association in ("known", "unknown"):
            ates, recovered = [], []
            for seed in seeds:
                pairing = {"pair_scans_jointly": False} if in_order and association == "unknown" else {}
                backend = registry.make_backend("fastslam2", overrides={"association": association,
                                                                         "seed": seed, **pairing})
                result = whole(pipeline.run(dataset, backend))
                m = pipeline.compute_metrics(result, with_graph_error=False)
                ates.append(m.ate_rmse_m)
                recovered.append(m.landmarks_recovered)
            per[association] = {"ate_m": ates, "median_m": float(np.median(ates)),
                                "min_m": float(np.min(ates)), "max_m": float(np.max(ates)),
                                "landmarks_recovered": recovered,
                                "seeds_recovering_all": sum(r == len(dataset.landmarks_true) for r in recovered)}
        per["median_ratio"] = per["unknown"]["median_m"] / per["known"]["median_m"]
        out["robots"][str(robot)] = per
        print(f"robot {robot} fastslam2 over seeds {seeds}: known median "
              f"{per['known']['median_m']:.3f} m ({per['known']['min_m']:.3f}-{per['known']['max_m']:.3f}), "
              f"unknown median {per['unknown']['median_m']:.3f} m "
              f"({per['unknown']['min_m']:.3f}-{per['unknown']['max_m']:.3f}), "
              f"ratio of medians {per['median_ratio']:.2f}; landmarks recovered within "
              f"{metrics.MAP_RECOVERY_RADIUS_M} m known "
              f"{per['known']['landmarks_recovered']}, unknown {per['unknown']['landmarks_recovered']}",
              flush=True)
    return out


def joint_run(dataset, backend: str, rows: list[dict], association: str = "known") -> dict:
    """Every robot in one estimate, each robot's ATE printed beside its own run's (the
    same association)."""
    t0 = time.perf_counter()
    result = whole(pipeline.run(dataset, registry.make_backend(backend, overrides={"association": association})))
    m = pipeline.compute_metrics(result, with_graph_error=False)
    out = {"agents": m.agents, "map_rmse_m": m.map_rmse_m, "landmarks": int(len(result.estimate.landmark_ids)),
           "landmarks_recovered": m.landmarks_recovered, "wall_s": time.perf_counter() - t0}
    for name, a in m.agents.items():
        own = next((x["ate_m"] for x in rows if f"robot {x['robot']}" == name
                    and x["backend"] == backend and x["association"] == association), math.nan)
        print(f"{name} jointly ({backend}, {association} ids): ATE {a['ate_rmse_m']:.3f} m "
              f"(alone {own:.3f} m)", flush=True)
    print(f"jointly ({backend}, {association} ids): {out['landmarks']} landmarks, "
          f"{m.landmarks_recovered} recovered, {out['wall_s']:.0f} s", flush=True)
    return out


def joint_seeds(dataset, seeds: list[int]) -> dict:
    """FastSLAM 2.0 with every robot in every particle (known ids): each robot's ATE per
    seed, their median, and the map error and landmarks recovered per seed."""
    per: dict[str, list[float]] = {}
    maps, recovered = [], []
    for seed in seeds:
        backend = registry.make_backend("fastslam2", overrides={"seed": seed})
        m = pipeline.compute_metrics(whole(pipeline.run(dataset, backend)), with_graph_error=False)
        for name, a in m.agents.items():
            per.setdefault(name, []).append(a["ate_rmse_m"])
        maps.append(m.map_rmse_m)
        recovered.append(m.landmarks_recovered)
    return {"seeds": seeds, "map_rmse_m": maps, "landmarks_recovered": recovered,
            "agents": {name: {"ate_m": v, "median_m": float(np.median(v))} for name, v in per.items()}}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--robots", type=int, nargs="+", choices=range(1, 6), default=[1, 2, 3, 4, 5])
    ap.add_argument("--no-joint", dest="joint", action="store_false",
                    help="leave out the run of all robots in one graph (about 4.5 min)")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/mrclam.json"))
    ap.add_argument("--seeds", type=entry.seed, nargs="*", default=[0, 1, 2, 3, 4],
                    help="FastSLAM 2.0 seeds for the spread of its ATE (none: skip)")
    ap.add_argument("--pair-scans-in-order", action="store_true",
                    help="the seeds' unknown-id runs pair each scan in its order "
                         "([fastslam] pair_scans_jointly = false)")
    args = ap.parse_args(argv)
    if args.quick:  # smoke sizes for the options not given: no seed spread unless --seeds
        entry.quick_sizes(ap, argv, args, robots=[1], seeds=[])
    robots = args.robots
    max_steps = 300 if args.quick else None
    associations = ("known",) if args.quick else ("known", "unknown")
    rows, panels = [], []
    for robot in robots:
        dataset = read_mrclam(args.data, MrclamConfig(robot=robot))
        gt = dataset.ground_truth()
        runs = []
        for association in associations:
            for backend in BACKENDS:
                run = one_run(dataset, backend, association, max_steps)
                runs.append(run)
                rows.append({"robot": robot, **{k: v for k, v in run.items()
                                                if k not in ("xy", "pose_ids", "landmarks_xy")}})
                print(f"robot {robot} {backend:9s} {association:7s} ATE {run['ate_m']:.3f} m "
                      f"(odometry {run['odometry_ate_m']:.3f}) map {run['map_rmse_m']:.3f} "
                      f"landmarks {run['landmarks']} recovered {run['landmarks_recovered']} "
                      f"{run['wall_s']:.1f} s", flush=True)
        n = max_steps or len(dataset.frames)
        in_run = gt[0] < n
        truth_lm = np.array(list(dataset.landmarks_true.values()))
        series = {"truth": (gt[1][in_run, 0].tolist(), gt[1][in_run, 1].tolist())}
        for run in runs:
            if run["association"] == "known":
                xy, _ = aligned(run, gt)
                series[run["backend"]] = (xy[:, 0].tolist(), xy[:, 1].tolist())
        isam2 = next(r for r in runs if r["backend"] == "isam2")
        _, lm = aligned(isam2, gt)
        series["landmarks (truth)"] = (truth_lm[:, 0].tolist(), truth_lm[:, 1].tolist())
        series["landmarks (isam2)"] = (lm[:, 0].tolist(), lm[:, 1].tolist())
        panels.append(Panel(f"robot {robot}: known ids, aligned", "x [m]", "y [m]", series,
                            kind="map", points=("landmarks (truth)", "landmarks (isam2)")))
    joint = joint_ekf = joint_fs2 = joint_unknown = joint_ekf_unknown = None
    if not args.quick and args.joint:
        dataset = read_mrclam_all(args.data, MrclamConfig(all_robots=True))
        joint, joint_ekf = (joint_run(dataset, backend, rows) for backend in ("isam2", "ekf"))
        joint_unknown, joint_ekf_unknown = (joint_run(dataset, backend, rows, "unknown")
                                            for backend in ("isam2", "ekf"))
        if args.seeds:
            joint_fs2 = joint_seeds(dataset, args.seeds)
    names = [f"robot {r}" for r in robots]
    ate = {}
    for association in associations:
        for backend in BACKENDS:
            vals = [next((x["ate_m"] for x in rows if x["robot"] == r and x["backend"] == backend
                          and x["association"] == association), None) for r in robots]
            if any(v is not None for v in vals):
                ate[f"{backend} {association}"] = (names, [v or 0.0 for v in vals])
    ate["dead reckoning"] = (names, [next(x["odometry_ate_m"] for x in rows if x["robot"] == r)
                                     for r in robots])
    for label, run in (("isam2 known", joint), ("ekf known", joint_ekf),
                       ("isam2 unknown", joint_unknown), ("ekf unknown", joint_ekf_unknown)):
        if run is not None:
            ate[f"{label}, all robots in one graph"] = (
                names, [run["agents"].get(n, {}).get("ate_rmse_m", 0.0) for n in names])
    if joint_fs2 is not None:
        ate["fastslam2 known, all robots in one graph (median of seeds)"] = (
            names, [joint_fs2["agents"].get(n, {}).get("median_m", 0.0) for n in names])
    panels.append(Panel("ATE per robot", "robot", "ATE [m]", ate, kind="bar", logy=True,
                        targets={"iSAM2 bound 0.12 m": 0.12}))
    spread = None if not args.seeds else seed_spread(args.data, robots, args.seeds,
                                                                     args.pair_scans_in_order)
    if joint_fs2 is not None and spread is not None:
        for name, a in joint_fs2["agents"].items():
            alone = spread["robots"][name.split()[-1]]["known"]["median_m"]
            print(f"{name} jointly (fastslam2, median of seeds): ATE {a['median_m']:.3f} m "
                  f"(alone {alone:.3f} m)", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # the command as run (the seeds and --no-joint change what the JSON holds)
    command = "python benchmarks/bench_mrclam.py " + " ".join(sys.argv[1:] if argv is None else argv)
    entry.write_json(args.out, {"command": command.strip(),
                                "rows": rows, "joint": joint, "joint_ekf": joint_ekf,
                                "joint_unknown": joint_unknown, "joint_ekf_unknown": joint_ekf_unknown,
                                "joint_fastslam2_seeds": joint_fs2, "fastslam2_seeds": spread},
                               indent=1, trailing_newline=True)
    save_figure(args.out, "MRCLAM Dataset 6: landmark SLAM against Vicon truth", panels,
                ncols=3)


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
