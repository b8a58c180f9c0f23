"""EKF-SLAM update against a plain in-place BLAS update of the same size (issue 20 item 3, issue 17 item 5).

For n landmarks (state size N = 3 + 2n) this loads a filter with a random SPD
covariance and times one :meth:`filters.ekf_slam.EkfSlam.update` with a single
range-bearing observation of one mapped landmark (known association, the
default OC Jacobians, every safeguard on), alternated repeat by repeat in one
process with two others (``timing.alternate``, medians, BLAS pinned to one
thread unless ``--threads`` says otherwise):

- **floor** (the target's ratio, ``ratio = ours / floor``): the same update
  written plainly in numpy as a user would, :func:`floor_update`: predict z and
  its 2x5 Jacobian on the pose and landmark columns, ``S = H P[J, J] H^T + R``
  from those 5 columns, ``K = P[:, J] H^T S^-1``, ``x += K v``, and ``P``
  downdated in place by ``scipy.linalg.blas.dgemm(-1, K, P[:, J] H^T,
  beta=1, c=P.T, trans_b=1, overwrite_c=1)`` on the Fortran view of the
  C-ordered ``P``: no N x N temporary and no copy of ``P``. (``dsyrk`` would
  update only one triangle, leaving the user to mirror it: dgemm is the plain
  full-matrix call.)
- **bare downdate** (informational, ``ratio_vs_downdate``): that dgemm call
  alone, the O(N^2) part every update pays; issue 20 quoted 19.6, 9.9, 6.3,
  3.0, 1.68 and 1.22 at n = 50..2000 against it before this work.

The target is ``timing.TARGETS["ekf"]`` (1.2; issue 17 asked 1.5) on
``ours / floor`` at every size; the JSON's ``summary`` is the worst size.

Usage: ``python benchmarks/bench_ekf_update.py [--out FILE.json] [--repeats R]
[--sizes 50 100 ...] [--threads T] [--quick]``; default output
``benchmarks/results/ekf_update.json`` and its PNG beside it.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import platform
import sys
from pathlib import Path

import numpy as np
from scipy.linalg.blas import dgemm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import timing  # noqa: E402  (beside this script)
from filters.ekf_slam import EkfSlam  # noqa: E402
from filters.ekf_slam_config import EkfSlamConfig  # noqa: E402
from slamcore.planar import geometry as models  # noqa: E402
from slamcore.planar.records import Observation  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

SIZES = (50, 100, 200, 500, 1000, 2000)
QUICK_SIZES = (50, 200)
FLOOR = ("the same one-landmark range-bearing update in plain numpy, P downdated in place "
         "by scipy.linalg.blas.dgemm (beta=1, overwrite_c) on P's Fortran view")


def random_state(rng: np.random.Generator, n_lm: int) -> tuple[np.ndarray, np.ndarray]:
    """A state with ``n_lm`` landmarks and an SPD covariance built in O(N^2 k)."""
    N = 3 + 2 * n_lm
    x = np.r_[0.0, 0.0, 0.1, rng.uniform(-20, 20, size=2 * n_lm)]
    B = rng.normal(size=(N, 8)) * 0.05  # low rank plus a diagonal (A A^T would be O(N^3))
    P = B @ B.T
    P[np.diag_indices(N)] += 0.01
    return x, P


def floor_update(x: np.ndarray, P: np.ndarray, i: int, z: np.ndarray, R: np.ndarray) -> None:
    """One EKF update of ``x`` and the C-ordered ``P`` with landmark columns ``i, i+1``, plainly."""
    J = [0, 1, 2, i, i + 1]
    dx, dy = x[i] - x[0], x[i + 1] - x[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z_hat = np.array([r, np.arctan2(dy, dx) - x[2]])
    H = np.array([[-dx / r, -dy / r, 0.0, dx / r, dy / r],
                  [dy / q, -dx / q, -1.0, -dy / q, dx / q]])
    PHt = P[:, J] @ H.T  # (N, 2)
    S = H @ PHt[J] + R
    K = PHt @ np.linalg.inv(S)
    v = z - z_hat
    v[1] = (v[1] + np.pi) % (2 * np.pi) - np.pi
    x += K @ v
    x[2] = (x[2] + np.pi) % (2 * np.pi) - np.pi
    dgemm(-1.0, K, PHt, beta=1.0, c=P.T, trans_b=1, overwrite_c=1)  # P -= K (P H^T)^T in place


def bench(n_lm: int, repeats: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    x, P = random_state(rng, n_lm)
    ekf = EkfSlam(EkfSlamConfig(initial_capacity=n_lm))
    ekf.load_state(0, x, P)
    slot = n_lm // 2
    i = 3 + 2 * slot
    R = np.diag([0.04, 0.003])
    z = models.observe(x[:3], x[i:i + 2]) + np.array([0.05, 0.01])
    obs = [Observation(0, slot, z, R)]
    xf, Pf = x.copy(), P.copy()
    Pb = P.copy()
    K = rng.normal(size=(x.size, 2)) * 1e-4
    PHt = rng.normal(size=(x.size, 2)) * 1e-4
    number = max(1, 1000 // x.size)  # calls per sample: only the shortest are timed in groups
    t = timing.alternate({
        "ours": lambda: ekf.update(obs),
        "floor": lambda: floor_update(xf, Pf, i, z, R),
        "downdate": lambda: dgemm(-1.0, K, PHt, beta=1.0, c=Pb.T, trans_b=1, overwrite_c=1),
    }, repeats, number=number)
    ours, floor, bare = (t[k].median_s for k in ("ours", "floor", "downdate"))
    return {"landmarks": n_lm, "state_size": x.size, "calls_per_sample": number,
            "update_s": ours, "floor_s": floor, "downdate_s": bare,
            "ratio": ours / floor, "ratio_vs_downdate": ours / bare,
            "timings": {k: timing.timing_dict(v) for k, v in t.items()}}


def plot(rows: list[dict], out: Path) -> Path:
    """Times against the map size (log-log) and the two ratios."""
    from plotting import Panel, save_figure  # beside this script

    n = [r["landmarks"] for r in rows]
    series = {"EkfSlam.update (one observation)": (n, [1e3 * r["update_s"] for r in rows]),
              "floor: plain numpy update, in-place dgemm": (n, [1e3 * r["floor_s"] for r in rows]),
              "bare in-place dgemm downdate": (n, [1e3 * r["downdate_s"] for r in rows])}
    target = timing.TARGETS["ekf"]
    return save_figure(out, "EKF-SLAM update against a plain in-place BLAS update", [
        Panel("median time per update", "landmarks", "time [ms]", series, logx=True, logy=True),
        Panel("overhead", "landmarks", "ratio",
              {"update / floor (target)": (n, [r["ratio"] for r in rows]),
               "update / bare downdate": (n, [r["ratio_vs_downdate"] for r in rows]),
               f"target {target:g}": (n, [target] * len(n))}, logx=True)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=entry.output_file, help="write the results as JSON here (and its PNG beside it)",
                    default=Path(__file__).resolve().parent / "results" / "ekf_update.json")
    ap.add_argument("--repeats", type=entry.count, default=31)
    ap.add_argument("--sizes", type=entry.count, nargs="+", default=list(SIZES))
    ap.add_argument("--threads", type=entry.count_or_zero, default=1,
                    help="BLAS threads for ours and the floor alike (0: leave as they are)")
    ap.add_argument("--quick", action="store_true", help=f"sizes {QUICK_SIZES}, 5 repeats")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, sizes=list(QUICK_SIZES), repeats=5)
    rows = []
    print(f"{'landmarks':>9} {'state':>6} {'update ms':>10} {'floor ms':>9} {'dgemm ms':>9} "
          f"{'ratio':>6} {'/dgemm':>7}")
    with timing.blas_threads(args.threads or None):
        for n in args.sizes:
            r = bench(n, args.repeats)
            rows.append(r)
            print(f"{r['landmarks']:>9d} {r['state_size']:>6d} {1e3 * r['update_s']:>10.4f} "
                  f"{1e3 * r['floor_s']:>9.4f} {1e3 * r['downdate_s']:>9.4f} {r['ratio']:>6.2f} "
                  f"{r['ratio_vs_downdate']:>7.2f}", flush=True)
    worst = max(rows, key=lambda r: r["ratio"])
    given = sys.argv[1:] if argv is None else list(argv)
    command = " ".join(["python benchmarks/bench_ekf_update.py", *given])
    summary = timing.summary(
        "EKF-SLAM update (worst size)", worst["update_s"], worst["floor_s"],
        target=timing.TARGETS["ekf"], floor=FLOOR, command=command,
        landmarks=worst["landmarks"], ratios={str(r["landmarks"]): r["ratio"] for r in rows},
        ratios_vs_downdate={str(r["landmarks"]): r["ratio_vs_downdate"] for r in rows})
    payload = {"benchmark": "ekf_update", "numpy": np.__version__,
               "python": platform.python_version(), "machine": platform.machine(),
               "repeats": args.repeats, "blas_threads": args.threads or None,
               "ratio_definition": "update_s / floor_s (the target's); ratio_vs_downdate = "
                                   "update_s / downdate_s (informational, issue 20's figures)",
               "summary": summary, "results": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, payload, indent=2, trailing_newline=True)
    print(f"worst ratio {worst['ratio']:.2f} at {worst['landmarks']} landmarks "
          f"(target {timing.TARGETS['ekf']:g}); wrote {args.out}")
    plot(rows, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
