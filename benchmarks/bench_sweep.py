"""The sweep engines: parallel efficiency and per-run dispatch overhead.

For the local pool and a Dask ``LocalCluster``, the same small sweep (the
synthetic world, ``--runs`` EKF runs of ``--steps`` steps, distinct seeds) is
run with one worker and with ``--workers`` workers:

- parallel efficiency = runs/s with k workers / (k x runs/s with one);
- dispatch overhead per run = engine wall time per run with one worker minus
  the mean wall time of the run's own process (``wall_s`` of its row): what
  the engine adds per run (config file, process start bookkeeping, scoring
  the run's files, handing the row back);
- this process's CPU time per run (load-independent): the pool's threads
  and scoring; with Dask, the client and the LocalCluster's scheduler (the
  scoring runs in the workers);
- Dask round trip: submit-to-result of an empty task on the running cluster,
  the scheduler's own share of that overhead.

Every measurement is taken in this process, one after the other, so the
machine's load is shared alike; on a loaded machine the efficiency measures
the cores actually free, not the engine. Writes JSON.

    python benchmarks/bench_sweep.py [--runs 8] [--steps 200] [--workers 2] [--quick] [--out FILE.json]

The PNG beside the JSON shows runs per second with one and k workers, and the
per-run costs, for each engine. ``--quick``: 2 runs of 20 steps.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from graphslam.pipelines.sweep import run_sweep
from graphslam.pipelines.sweep_exec import DaskExecutor, PoolExecutor
from graphslam.pipelines.sweep_spec import parse_sweep
import entry  # noqa: E402  (beside this script: its argparse types)

#: Empty Dask tasks timed for the round trip.
ROUND_TRIPS = 50


def sweep_file(folder: Path, runs: int, steps: int) -> Path:
    path = folder / "bench.toml"
    path.write_text(f'[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n'
                    f'seed = {{from = 0, to = {runs - 1}}}\nmax_steps = {steps}\n')
    return path


def timed_sweep(spec, executor, folder: Path) -> dict:
    """Wall time of the whole sweep and the mean wall time of its runs' processes."""
    shutil.rmtree(folder, ignore_errors=True)
    t0, cpu0 = time.perf_counter(), time.process_time()
    outcome = run_sweep(spec, folder, executor)
    if outcome.interrupted:  # a cut sweep's throughput is no measurement
        raise KeyboardInterrupt
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    if any(r["status"] != "ok" for r in outcome.rows):
        raise SystemExit(f"a benchmark run failed: {[r['error'] for r in outcome.rows]}")
    child = statistics.mean(float(r["wall_s"]) for r in outcome.rows)
    return {"wall_s": wall, "runs_per_s": len(outcome.rows) / wall, "child_wall_s": child,
            "overhead_per_run_ms": 1e3 * (wall / len(outcome.rows) - child),
            "this_process_cpu_per_run_ms": 1e3 * cpu / len(outcome.rows)}


def _noop() -> None:
    return None


def warm_imports() -> None:
    """Import what scoring a run needs (once per process, not a per-run cost)."""
    import graphslam.pipelines.trajectory_eval  # noqa: F401
    from scipy.spatial.transform import Rotation  # noqa: F401


def dask_round_trip_ms(executor: DaskExecutor) -> float:
    client = executor.client
    client.submit(_noop, pure=False).result()  # warm: the function is shipped once
    t0 = time.perf_counter()
    for _ in range(ROUND_TRIPS):
        client.submit(_noop, pure=False).result()
    return 1e3 * (time.perf_counter() - t0) / ROUND_TRIPS


def make_dask(k: int) -> DaskExecutor:
    executor = DaskExecutor("local", k)
    executor.client.run(warm_imports)  # in every worker process, before the clock
    return executor


def engine(name: str, make, spec, k: int, folder: Path) -> dict:
    one_exec = make(1)
    try:
        one = timed_sweep(spec, one_exec, folder / f"{name}-1")
        trip = dask_round_trip_ms(one_exec) if name == "dask" else None
    finally:
        one_exec.close()
    many_exec = make(k)
    try:
        many = timed_sweep(spec, many_exec, folder / f"{name}-{k}")
    finally:
        many_exec.close()
    return {"one_worker": one, f"{k}_workers": many, "round_trip_ms": trip,
            "efficiency": many["runs_per_s"] / (k * one["runs_per_s"])}


def plot(results: dict, out: Path) -> Path:
    """Runs per second with one and k workers, and what each engine adds per run."""
    from plotting import Panel, save_figure  # beside this script

    k = results["workers"]
    names = [n for n in ("pool", "dask") if n in results]
    r = {n: results[n] for n in names}
    costs = {"dispatch overhead per run": (names, [r[n]["one_worker"]["overhead_per_run_ms"] for n in names]),
             "this process's CPU per run": (names, [r[n]["one_worker"]["this_process_cpu_per_run_ms"]
                                                    for n in names])}
    if "dask" in r:
        costs["Dask round trip (empty task)"] = (["dask"], [r["dask"]["round_trip_ms"]])
    return save_figure(out, f"Sweep engines: {results['runs']} EKF runs of {results['steps']} steps", [
        Panel("throughput (efficiency " + ", ".join(f"{n} {r[n]['efficiency']:.2f}" for n in names) + ")",
              "engine", "runs per second", {
                  "1 worker": (names, [r[n]["one_worker"]["runs_per_s"] for n in names]),
                  f"{k} workers": (names, [r[n][f"{k}_workers"]["runs_per_s"] for n in names])}, kind="bar"),
        Panel("per-run costs (one worker)", "engine", "time per run [ms]", costs, kind="bar")])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=entry.count, default=8)
    ap.add_argument("--steps", type=entry.count, default=200)
    ap.add_argument("--workers", type=entry.count, default=2)
    ap.add_argument("--quick", action="store_true", help="2 runs of 20 steps")
    ap.add_argument("--out", type=entry.output_file, default=Path("benchmarks/results/bench_sweep.json"),
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, runs=2, steps=20)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        spec = parse_sweep(sweep_file(folder, args.runs, args.steps))
        # one-time imports (the config classes, the scoring) are not per-run costs
        spec.runs()
        warm_imports()
        results = {"runs": args.runs, "steps": args.steps, "workers": args.workers,
                   "pool": engine("pool", PoolExecutor, spec, args.workers, folder)}
        try:
            import distributed  # noqa: F401
        except ImportError:
            print("dask distributed not installed: cluster engine skipped", file=sys.stderr)
        else:
            results["dask"] = engine("dask", make_dask, spec, args.workers, folder)
    print(f"{'engine':<6} {'1 worker runs/s':>15} {f'{args.workers} workers runs/s':>17} "
          f"{'efficiency':>10} {'overhead/run ms':>15} {'CPU/run ms':>10} {'round trip ms':>13}")
    for name in ("pool", "dask"):
        if name in results:
            r = results[name]
            trip = "" if r["round_trip_ms"] is None else f"{r['round_trip_ms']:.1f}"
            print(f"{name:<6} {r['one_worker']['runs_per_s']:>15.3f} "
                  f"{r[f'{args.workers}_workers']['runs_per_s']:>17.3f} {r['efficiency']:>10.2f} "
                  f"{r['one_worker']['overhead_per_run_ms']:>15.1f} "
                  f"{r['one_worker']['this_process_cpu_per_run_ms']:>10.1f} {trip:>13}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, results, indent=1, trailing_newline=True)
    print(f"wrote {args.out}")
    plot(results, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
