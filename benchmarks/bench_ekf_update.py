"""EKF-SLAM update cost versus the bare O(n^2) covariance downdate.

For n landmarks (state size N = 3 + 2n) this builds a filter with a random
SPD covariance, times one full :meth:`filters.ekf_slam.EkfSlam.update` with a
single range-bearing observation of one landmark (median of repeats), and, in
the same process, the bare in-place downdate ``P -= K S K^T`` on an N x N
array. Two honest numpy forms of the bare operation are timed and the faster
is the reference:

- ``gemm``: ``np.subtract(P, (K @ S) @ K.T, out=P)``;
- ``syrk``: ``np.subtract(P, M @ M.T, out=P)`` with ``M = K L`` (``S = L L^T``),
  which numpy sends to BLAS syrk.

Usage: ``python benchmarks/bench_ekf_update.py [--out FILE.json] [--repeats R]
[--sizes 100 200 ...] [--quick]``; default output
``benchmarks/results/ekf_update.json`` and its PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from slamcore.planar import geometry as models  # noqa: E402
from filters.ekf_slam import EkfSlam  # noqa: E402
from filters.ekf_slam_config import EkfSlamConfig  # noqa: E402
from slamcore.planar.records import Observation  # noqa: E402

SIZES = (100, 200, 500, 1000, 2000)


def _random_state(rng: np.random.Generator, n_lm: int) -> tuple[np.ndarray, np.ndarray]:
    N = 3 + 2 * n_lm
    x = np.r_[0.0, 0.0, 0.1, rng.uniform(-20, 20, size=2 * n_lm)]
    # SPD in O(N^2 k): low rank plus a diagonal (a dense A A^T would be O(N^3))
    B = rng.normal(size=(N, 8)) * 0.05
    P = B @ B.T
    P[np.diag_indices(N)] += 0.01
    return x, P


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def bench(n_lm: int, repeats: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    x, P = _random_state(rng, n_lm)
    ekf = EkfSlam(EkfSlamConfig(initial_capacity=n_lm))
    ekf.load_state(0, x, P)
    slot = n_lm // 2
    i = 3 + 2 * slot
    R = np.diag([0.04, 0.003])
    z = models.observe(x[:3], x[i:i + 2]) + np.array([0.05, 0.01])
    obs = [Observation(0, slot, z, R)]
    t_ours = _median_time(lambda: ekf.update(obs), repeats)

    # Bare downdate on a fresh contiguous array of the same size.
    N = x.size
    Pb = P.copy()
    K = rng.normal(size=(N, 2)) * 1e-4
    S = np.array([[0.05, 0.001], [0.001, 0.004]])
    M = K @ np.linalg.cholesky(S)
    Mt = np.ascontiguousarray(M.T)
    t_gemm = _median_time(lambda: np.subtract(Pb, (K @ S) @ K.T, out=Pb), repeats)
    t_syrk = _median_time(lambda: np.subtract(Pb, Mt.T @ Mt, out=Pb), repeats)
    t_bare = min(t_gemm, t_syrk)
    return {"landmarks": n_lm, "state_size": N, "update_s": t_ours, "bare_gemm_s": t_gemm,
            "bare_syrk_s": t_syrk, "bare_s": t_bare, "ratio": t_ours / t_bare}


def plot(rows: list[dict], out: Path) -> Path:
    """Update time and the two bare downdates against the map size (log-log)."""
    from plotting import Panel, save_figure  # beside this script

    n = [r["landmarks"] for r in rows]
    series = {"EkfSlam.update (one observation)": (n, [1e3 * r["update_s"] for r in rows]),
              "bare P -= K S K^T (gemm)": (n, [1e3 * r["bare_gemm_s"] for r in rows]),
              "bare P -= M M^T (syrk)": (n, [1e3 * r["bare_syrk_s"] for r in rows])}
    return save_figure(out, "EKF-SLAM update against the bare O(n^2) covariance downdate", [
        Panel("median time per update", "landmarks", "time [ms]", series, logx=True, logy=True),
        Panel("overhead", "landmarks", "update / min(gemm, syrk)",
              {"ratio": (n, [r["ratio"] for r in rows])}, logx=True)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the results as JSON here (and its PNG beside it)",
                    default=Path(__file__).resolve().parent / "results" / "ekf_update.json")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    ap.add_argument("--quick", action="store_true", help="sizes 100 and 200, 3 repeats")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.repeats = [100, 200], 3
    rows = []
    print(f"{'landmarks':>9} {'state':>6} {'update ms':>10} {'gemm ms':>9} {'syrk ms':>9} "
          f"{'ratio':>6}")
    for n in args.sizes:
        r = bench(n, args.repeats)
        rows.append(r)
        print(f"{r['landmarks']:>9d} {r['state_size']:>6d} {1e3 * r['update_s']:>10.3f} "
              f"{1e3 * r['bare_gemm_s']:>9.3f} {1e3 * r['bare_syrk_s']:>9.3f} {r['ratio']:>6.2f}",
              flush=True)
    payload = {"benchmark": "ekf_update", "numpy": np.__version__,
               "python": platform.python_version(), "machine": platform.machine(),
               "repeats": args.repeats,
               "ratio_definition": "update_s / min(bare_gemm_s, bare_syrk_s)",
               "results": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}")
    plot(rows, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
