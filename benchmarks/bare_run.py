"""The floor of ``bench_command.py``: what a user would write instead of ``graphslam run``.

Read the data set (``gtsam.load2D`` for Victoria Park and w10000, a plain line
loop for city10000, whose format load2D does not read), stream it into
``gtsam.ISAM2`` one update per new pose with the settings ``graphslam run``
uses by default (Cholesky, relinearise threshold 0.1, skip 10; the first
pose held by a 1e-6 prior), polish with Levenberg-Marquardt (100 iterations,
relative and absolute tolerance 1e-5), write ``trajectory.tum`` (same
format: ``t x y z qx qy qz qw``, the pose id as time, 9 significant digits)
and print the final graph error. gtsam and numpy only: no graphslam import.

    python benchmarks/bare_run.py victoria-park|w10000|city10000 OUT_DIR [--max-poses N]
"""

from __future__ import annotations

import sys
from pathlib import Path

import gtsam
import numpy as np

#: The wheel's files of each data set; city10000's edge noise is gtsam's City10000 example's.
FILES = {"victoria-park": "victoria_park.txt", "w10000": "w10000.graph",
         "city10000": "T1_city10000_04.txt"}
CITY_SIGMAS = np.array([1 / 30, 1 / 30, 1 / 100])


def load(name: str) -> list:
    """The data set's factors, in file order."""
    path = gtsam.findExampleDataFile(FILES[name])
    if name == "victoria-park":  # file order: each pose, then what is seen from it
        graph, _ = gtsam.load2D(path)
        return [graph.at(i) for i in range(graph.size())]
    if name == "w10000":
        graph, _ = gtsam.load2D(path)
        return by_pose([graph.at(i) for i in range(graph.size())])
    noise = gtsam.noiseModel.Diagonal.Sigmas(CITY_SIGMAS)
    factors = []
    with open(path) as f:
        for line in f:
            tok = line.split()  # EDGE2 a _ b ambiguous n x y theta [...]: first hypothesis
            if tok:
                factors.append(gtsam.BetweenFactorPose2(
                    int(tok[1]), int(tok[3]),
                    gtsam.Pose2(float(tok[6]), float(tok[7]), float(tok[8])), noise))
    return by_pose(factors)


def by_pose(factors: list) -> list:
    """Pose-graph edges in pose order, as ``graphslam run`` adds them: each pose with
    the edge from its predecessor first, then its other edges to earlier poses."""
    def key(f):
        a, b = f.keys()
        return max(a, b), abs(int(a) - int(b)) != 1

    return sorted(factors, key=key)


def solve(factors: list, max_poses: int | None) -> tuple[gtsam.ISAM2, list[int]]:
    """One iSAM2 update per new pose; a pose starts from odometry, a landmark from its first sighting."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.1)
    params.relinearizeSkip = 10
    params.setFactorization("CHOLESKY")
    isam = gtsam.ISAM2(params)
    graph, values, poses, known = gtsam.NonlinearFactorGraph(), gtsam.Values(), [], set()

    def pose(key):
        return values.atPose2(key) if values.exists(key) else isam.calculateEstimatePose2(key)

    for f in factors:
        if isinstance(f, gtsam.BetweenFactorPose2):
            a, b = f.keys()
            new = b if b not in known else a if a not in known else None
            if not poses:  # the first pose (the lower id, as the run takes it), held by the prior
                first, new = min(a, b), max(a, b)
            if new is not None:
                if not poses:
                    graph.add(gtsam.PriorFactorPose2(first, gtsam.Pose2(),
                                                     gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
                    values.insert(first, gtsam.Pose2())
                    poses.append(first)
                    known.add(first)
                elif max_poses is not None and len(poses) >= max_poses:
                    break
                else:
                    isam.update(graph, values)
                    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
                z = f.measured()
                values.insert(new, pose(a).compose(z) if new == b else pose(b).compose(z.inverse()))
                poses.append(new)
                known.add(new)
        else:  # BearingRangeFactor2D: pose, landmark
            x_key, l_key = f.keys()
            if l_key not in known:
                z = f.measured()
                b, r = z.bearing().theta(), z.range()
                values.insert(l_key, pose(x_key).transformFrom(np.array([r * np.cos(b), r * np.sin(b)])))
                known.add(l_key)
        graph.add(f)
    isam.update(graph, values)
    return isam, poses


def main(argv=None) -> int:
    import argparse  # (the standard library: the script stays bare of the toolkit)

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name", choices=tuple(FILES))
    ap.add_argument("out", type=Path, help="folder for trajectory.tum")
    ap.add_argument("--max-poses", type=int, default=None, help="the first poses only")
    args = ap.parse_args(argv)
    out = args.out
    isam, poses = solve(load(args.name), args.max_poses)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(100)
    lm.setRelativeErrorTol(1e-5)
    lm.setAbsoluteErrorTol(1e-5)
    graph = isam.getFactorsUnsafe()
    result = gtsam.LevenbergMarquardtOptimizer(graph, isam.calculateEstimate(), lm).optimize()
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "trajectory.tum", "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for key in poses:
            p = result.atPose2(key)
            half = 0.5 * p.theta()
            f.write(f"{key} {p.x():.9g} {p.y():.9g} 0 0 0 {np.sin(half):.9g} {np.cos(half):.9g}\n")
    print(f"final_error {graph.error(result):.9g}  poses {len(poses)}  "
          f"landmarks {sum(1 for k in result.keys() if gtsam.Symbol(k).chr() == ord('l'))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
