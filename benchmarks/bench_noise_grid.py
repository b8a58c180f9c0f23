"""Noise grid: every back end must run the synthetic world to the end at any plausible noise.

Issue 14 item 1. The synthetic world's four noise values (``[synthetic]``
``sigma_v_mps``, ``sigma_w_degps``, ``sigma_r_m``, ``sigma_phi_deg``; the
course's demo values are the defaults) are scaled by each of :data:`SCALES`,
each alone and all together, over world seeds 0-9, and each cell is run on
every back end. A cell passes when the run reaches the last frame with a
finite estimate (trajectory and landmarks); a raised exception or a NaN
pose is a failure, printed with its exception and where it was raised.
Numerical recoveries the back end made on the way (counted, reported by the
filters as ``recoveries``) are printed per cell, so a pass that needed them
is visible.

    python benchmarks/bench_noise_grid.py [--backends ekf fastslam1 fastslam2 isam2]
        [--seeds 0 1 ...] [--scales 0.1 0.3 1 3 10] [--quick] [--out FILE.json]

JSON (default ``benchmarks/results/noise_grid.json``) and its PNG beside it.

Exit status 1 when any cell fails. FastSLAM runs with 100 particles (the
default) and the world seed as its own seed.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
import time
import traceback
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout, not an installed copy

from graphslam import registry  # noqa: E402
from graphslam.pipelines import planar as pipeline  # noqa: E402
from graphslam.pipelines.common import whole  # noqa: E402
from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

#: The synthetic world's noise fields (all four of its noise values).
NOISE_FIELDS = ("sigma_v_mps", "sigma_w_degps", "sigma_r_m", "sigma_phi_deg")
#: Factors on the course's values: one tenth to ten times (issue 14).
SCALES = (0.1, 0.3, 1.0, 3.0, 10.0)
SEEDS = tuple(range(10))
BACKENDS = ("ekf", "fastslam1", "fastslam2", "isam2")
#: The "all together" column's name.
ALL = "all"


def noise_cells(scales=SCALES) -> list[tuple[str, float]]:
    """``(field or "all", scale)`` cells: each noise alone, then all together.

    Scale 1 of every single field is the same world, so it appears once
    (as ``("all", 1.0)``).
    """
    cells = [(f, s) for f in NOISE_FIELDS for s in scales if s != 1.0]
    return cells + [(ALL, s) for s in scales]


def world_config(field: str, scale: float, seed: int) -> SyntheticConfig:
    """The synthetic world of one cell: ``field`` (or all four) scaled by ``scale``."""
    base = SyntheticConfig(seed=seed)
    fields = NOISE_FIELDS if field == ALL else (field,)
    return base.replace(**{f: getattr(base, f) * scale for f in fields})


def run_cell(backend: str, field: str, scale: float, seed: int) -> dict:
    """Run one cell; a dict with ``ok``, ``error`` (one line or None), ``recoveries``, ``wall_s``."""
    dataset = make_synthetic(world_config(field, scale, seed))
    t0 = time.perf_counter()
    row = {"backend": backend, "field": field, "scale": scale, "seed": seed,
           "ok": False, "error": None, "recoveries": None}
    try:
        be = registry.make_backend(backend, overrides=registry.seed_override(backend, seed))
        result = whole(pipeline.run(dataset, be))  # a cut run is no failure of the back end
        est = result.estimate
        finite = bool(np.all(np.isfinite(est.wTb)) and np.all(np.isfinite(est.landmarks_w)))
        done = result.steps == len(dataset.frames)
        row["ok"] = finite and done
        if not row["ok"]:
            row["error"] = "non-finite estimate" if not finite else f"stopped at {result.steps}"
        row["recoveries"] = result.recoveries
    except Exception as exc:  # noqa: BLE001 - a failure is what the grid records
        where = traceback.extract_tb(exc.__traceback__)[-1]
        text = str(exc).strip().splitlines()
        # gtsam's IndeterminateSystem reaches Python as a RuntimeError with no message
        row["error"] = (f"{type(exc).__name__}: {text[0] if text else '(no message)'} "
                        f"({Path(where.filename).name}:{where.lineno})")
    row["wall_s"] = time.perf_counter() - t0
    return row


def plot(rows: list[dict], backends: list[str], scales: list[float], out: Path) -> Path:
    """Per back end and noise scale: share of cells run to the end, share that needed recoveries."""
    from plotting import Panel, save_figure  # beside this script

    def share(backend, scale, test):
        cells = [r for r in rows if r["backend"] == backend and r["scale"] == scale]
        return 100.0 * sum(map(test, cells)) / max(len(cells), 1)

    def recovered(r):
        return bool(r["recoveries"]) and any(r["recoveries"].values())

    names = [f"x{s:g}" for s in scales]
    ran = {b: (names, [share(b, s, lambda r: r["ok"]) for s in scales]) for b in backends}
    rec = {b: (names, [share(b, s, recovered) for s in scales]) for b in backends}
    seeds = sorted({r["seed"] for r in rows})
    seeds_txt = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]}"
    return save_figure(out, f"Noise grid: synthetic world, noise x scale (each alone and all), "
                            f"{seeds_txt}", [
        Panel("runs that reached the last frame", "noise scale (x the course's values)",
              "cells run to the end [%]", ran, kind="bar", ylim=(0, 105)),
        Panel("runs that needed numerical recoveries", "noise scale (x the course's values)",
              "cells with recoveries [%]", rec, kind="bar", ylim=(0, 105))])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="+", default=list(BACKENDS), choices=BACKENDS)
    ap.add_argument("--seeds", type=entry.seed, nargs="+", default=list(SEEDS))
    ap.add_argument("--scales", type=entry.positive, nargs="+", default=list(SCALES))
    ap.add_argument("--quick", action="store_true", help="seed 0, scale 10 (each noise alone and all)")
    ap.add_argument("--out", type=entry.output_file,
                    default=Path(__file__).resolve().parent / "results" / "noise_grid.json",
                    help="write every cell's row as JSON to this file (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, seeds=[0], scales=[10.0])
    rows = []
    for backend in args.backends:
        fails = 0
        for field, scale in noise_cells(args.scales):
            for seed in args.seeds:
                row = run_cell(backend, field, scale, seed)
                rows.append(row)
                rec = row["recoveries"]
                if not row["ok"]:
                    fails += 1
                    print(f"FAIL {backend} {field} x{scale:g} seed {seed}: {row['error']}",
                          flush=True)
                elif rec and any(rec.values()):
                    print(f"  ok {backend} {field} x{scale:g} seed {seed} with recoveries {rec}",
                          flush=True)
        n = len(noise_cells(args.scales)) * len(args.seeds)
        print(f"{backend}: {n - fails}/{n} cells ran to the end", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, rows, indent=1)
    plot(rows, args.backends, args.scales, args.out)
    return 1 if any(not r["ok"] for r in rows) else 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
