"""The whole ``graphslam run`` command against a bare script doing the same work (issue 20 item 2).

Three subprocesses per data set, alternated repeat by repeat by
``timing.alternate`` (median of the repeats, no best-of):

- ``bare``: ``python benchmarks/bare_run.py NAME DIR``, the floor, what a user
  would otherwise run: read the file (``gtsam.load2D``; a plain line loop for
  city10000), one ``gtsam.ISAM2`` update per new pose with the settings the
  default run uses, the same Levenberg-Marquardt polish, ``trajectory.tum``
  written in the same format; gtsam and numpy only;
- ``off``: ``python -m graphslam run --dataset NAME --out DIR --rerun off --quiet``;
- ``save``: the same with ``--rerun save`` (the default: ``run.rrd``).

Whole command / bare (``off`` / ``bare``, target 1.1) and the cost of the
recording (``save`` / ``off``, target 1.05) are two ratios, each a summary
row. Each process is timed from its start to its exit: interpreter start,
imports, reading, solving, scoring, writing. The JSON also holds both runs'
final graph error and the largest position difference between the two
trajectories (same factors, same settings: equal up to iSAM2's key order), and
each command's CPU seconds (``*_cpu_s``, ``command_cpu_ratio``,
``rerun_cpu_ratio``: user + system time of the process and of the recording
process it waits for, from ``RUSAGE_CHILDREN``), which a loaded machine shifts
less than wall time.

    python benchmarks/bench_command.py [--datasets victoria-park w10000 city10000]
        [--repeats 3] [--max-steps N] [--quick] [--out FILE.json]

``--max-steps N``: the first N poses of each data set (both sides). ``--quick``:
Victoria Park's first 300 poses, 1 repeat (a smoke run of the code path).
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import timing  # beside this script
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

ROOT = Path(__file__).resolve().parent.parent
BARE = Path(__file__).resolve().parent / "bare_run.py"
DATASETS = ("victoria-park", "w10000", "city10000")
#: Whole command / bare script, and --rerun save / --rerun off: the issue's targets.
TARGET_COMMAND = 1.1
TARGET_RERUN = 1.05


def commands(name: str, work: Path, max_steps: int | None) -> dict[str, list[str]]:
    """The three command lines of one data set (outputs under ``work``)."""
    cut = [] if max_steps is None else ["--max-steps", str(max_steps)]
    run = [sys.executable, "-m", "graphslam", "run", "--dataset", name, "--quiet", *cut]
    return {
        "bare": [sys.executable, str(BARE), name, str(work / "bare"),
                 *([] if max_steps is None else ["--max-poses", str(max_steps)])],
        "off": [*run, "--out", str(work / "off"), "--rerun", "off"],
        "save": [*run, "--out", str(work / "save"), "--rerun", "save"],
    }


def children_cpu_s() -> float:
    """User + system CPU seconds of this process's finished (waited-for) descendants: the
    command and, through its own wait, the recording process of ``--rerun save``."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def call(cmd: list[str], cpu: list[float] | None = None) -> str:
    """Run one command from the repository root; its stdout; RuntimeError on failure.
    ``cpu``: the command's CPU seconds (:func:`children_cpu_s`) are appended to it."""
    before = children_cpu_s()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if cpu is not None:
        cpu.append(children_cpu_s() - before)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr[-2000:]}")
    return done.stdout


def agreement(work: Path) -> dict:
    """Largest position difference between the bare and our trajectories, and both errors."""
    bare = np.loadtxt(work / "bare" / "trajectory.tum", ndmin=2)
    ours = np.loadtxt(work / "off" / "trajectory.tum", ndmin=2)
    same_ids = len(bare) == len(ours) and np.array_equal(bare[:, 0], ours[:, 0])
    diff = float(np.max(np.linalg.norm(bare[:, 1:3] - ours[:, 1:3], axis=1))) if same_ids else None
    metrics = json.loads((work / "off" / "metrics.json").read_text())
    return {"poses": int(len(ours)), "same_pose_ids": bool(same_ids), "max_position_diff_m": diff,
            "error_ours": metrics["final_error"]}


def measure(name: str, repeats: int, max_steps: int | None) -> dict:
    """Median seconds of the three commands on one data set, alternated."""
    with tempfile.TemporaryDirectory(prefix="bench_command_") as tmp:
        work = Path(tmp)
        warm = commands(name, work, 10)  # page cache and bytecode, for all three alike
        for cmd in warm.values():
            call(cmd)
        cmds = commands(name, work, max_steps)
        out: dict[str, str] = {}
        cpu: dict[str, list[float]] = {k: [] for k in cmds}
        timed = timing.alternate({k: (lambda k=k: out.__setitem__(k, call(cmds[k], cpu[k])))
                                  for k in cmds}, repeats, warmup=0)
        row = {"dataset": name, "max_steps": max_steps, "repeats": repeats,
               **{f"{k}_s": t.median_s for k, t in timed.items()},
               # CPU time shifts less than wall time with the machine's load
               **{f"{k}_cpu_s": float(np.median(c)) for k, c in cpu.items()},
               "cpu_samples_s": cpu,
               "timings": {k: timing.timing_dict(t) for k, t in timed.items()},
               **agreement(work)}
        row["error_bare"] = float(out["bare"].split()[1])
    row["command_ratio"] = row["off_s"] / row["bare_s"]
    row["rerun_ratio"] = row["save_s"] / row["off_s"]
    row["command_cpu_ratio"] = row["off_cpu_s"] / row["bare_cpu_s"]
    row["rerun_cpu_ratio"] = row["save_cpu_s"] / row["off_cpu_s"]  # both processes of save
    return row


def summaries(rows: list[dict], command: str) -> list[dict]:
    out = []
    for r in rows:
        steps = "all poses" if r["max_steps"] is None else f"first {r['max_steps']} poses"
        out.append(timing.summary(
            f"graphslam run, {r['dataset']} ({steps})", r["off_s"], r["bare_s"],
            target=TARGET_COMMAND, command=command, dataset=r["dataset"],
            floor="benchmarks/bare_run.py: gtsam.load2D (city10000: a line loop), one ISAM2 "
                  "update per pose with the run's settings, the same LM polish, trajectory.tum; "
                  "a subprocess like ours (--rerun off)"))
        out.append(timing.summary(
            f"--rerun save cost, {r['dataset']} ({steps})", r["save_s"], r["off_s"],
            target=TARGET_RERUN, command=command, dataset=r["dataset"],
            floor="the same graphslam run with --rerun off"))
    return out


def plot(rows: list[dict], out) -> object:
    """Seconds of the three commands per data set, and both ratios against their targets."""
    from plotting import Panel, save_figure  # beside this script

    names = [r["dataset"] if r["max_steps"] is None else f"{r['dataset']} ({r['max_steps']})"
             for r in rows]
    return save_figure(out, "graphslam run end to end against a bare gtsam script", [
        Panel("whole command, subprocess start to exit (median)", "data set", "wall time [s]",
              {"bare script": (names, [r["bare_s"] for r in rows]),
               "graphslam run --rerun off": (names, [r["off_s"] for r in rows]),
               "graphslam run --rerun save": (names, [r["save_s"] for r in rows])}, kind="bar"),
        Panel("ratios", "data set", "ratio",
              {"run (off) / bare": (names, [r["command_ratio"] for r in rows]),
               "save / off": (names, [r["rerun_ratio"] for r in rows])}, kind="bar",
              targets={f"target {TARGET_COMMAND}": TARGET_COMMAND,
                       f"target {TARGET_RERUN}": TARGET_RERUN, "parity": 1.0})])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=DATASETS)
    ap.add_argument("--repeats", type=entry.count, default=3)
    ap.add_argument("--max-steps", type=entry.count, default=None, help="first N poses only")
    ap.add_argument("--quick", action="store_true", help="Victoria Park, 300 poses, 1 repeat (a smoke run)")
    ap.add_argument("--out", type=entry.output_file, default="benchmarks/results/bench_command.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, datasets=["victoria-park"], max_steps=300, repeats=1)
    command = "python benchmarks/bench_command.py " + " ".join(argv if argv is not None
                                                               else sys.argv[1:])
    rows = []
    for name in args.datasets:
        row = measure(name, args.repeats, args.max_steps)
        rows.append(row)
        print(f"{name:14s} bare={row['bare_s']:7.2f}s  off={row['off_s']:7.2f}s  "
              f"save={row['save_s']:7.2f}s  run/bare={row['command_ratio']:.3f} "
              f"(target {TARGET_COMMAND})  save/off={row['rerun_ratio']:.3f} "
              f"(target {TARGET_RERUN})  max |dp|={row['max_position_diff_m']} m", flush=True)
        print(f"{'':14s} CPU: bare={row['bare_cpu_s']:7.2f}s  off={row['off_cpu_s']:7.2f}s  "
              f"save={row['save_cpu_s']:7.2f}s  run/bare={row['command_cpu_ratio']:.3f}  "
              f"save/off={row['rerun_cpu_ratio']:.3f}", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {"benchmark": "command_overhead", "rows": rows,
                                "summaries": summaries(rows, command.strip())}, indent=2)
    print(f"wrote {args.out}")
    plot(rows, args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
