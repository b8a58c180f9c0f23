"""``graphslam sweep SWEEP.toml``: a grid of runs (2-D, pose graphs or image sequences),
one process each, one table."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from graphslam.cli.common import add_command, add_out_dir_option, add_quiet_option, path_arg
from graphslam.cli.out_folder import claim_out_dir, moved_to
from slamcore.errors import ConfigError, GraphSlamError, InputError

EPILOG = """\
sweep file (TOML):
  [sweep]
  dataset = ["synthetic"]             # names, or paths read beside the sweep file
  backend = ["isam2", "ekf", "fastslam1", "fastslam2"]
  seed = {from = 0, to = 49}          # or a list; absent: no --seed
  max_steps = 200                     # optional
  nees = true                         # optional; default: true on the synthetic world
                                      # (image sequences: false, they write no nees.csv)
  config = "base.toml"                # optional base config, beside the sweep file
  [sweep.set]                         # config overrides, the grid is their product
  "ekf.association" = ["unknown"]

every run is `graphslam run ... [--nees]` in its own process, outputs in
OUT/runs/<backend>-<config hash>-s<seed>/. Re-running a sweep into the same
--out skips the runs already done (same config hash and seed, and their folder's
metrics.json says so: a folder deleted or overwritten is run again); Ctrl-C keeps
every finished run (exit 130); a failed run is a row with its error (exit 1).

outputs (in --out): sweep.csv, sweep_nees.png (average pose NEES over the runs
  against its 95 % chi-square bounds, per back end), sweep_ate.png (ATE per
  back end), sweep_<section.key>.png (ATE against each swept value)

engines: a local pool of --workers runs at a time (default); --cluster local
  starts a Dask LocalCluster of --workers processes, --cluster ADDRESS uses a
  running Dask scheduler (tcp://host:8786; workers must see --out);
  pip install 'graphslam-toolkit[cluster]'

examples:
  graphslam sweep benchmarks/sweep_unknown_association.toml --out runs/sweep-ua
  graphslam sweep my.toml --out runs/s --workers 4 --cluster local
  image sequences: dataset = ["synthetic-images"], backend = ["isam2", "ekf"],
  [sweep.set] "active_search.order" = ["batch", "sequential"]
"""


def register(sub) -> None:
    """Add the ``sweep`` sub-command to the ``graphslam`` parser."""
    p = add_command(
        sub,
        "sweep",
        cmd_sweep,
        help="run a grid of datasets x back ends x settings x seeds",
        description="Monte Carlo and parameter sweeps: every run of the grid as its own "
        "'graphslam run', one table (sweep.csv) and plots.",
        epilog=EPILOG,
    )
    p.add_argument("sweep_file", type=path_arg, metavar="SWEEP.toml", help="the sweep file")
    add_out_dir_option(p, required=True)
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="runs at a time (default: the number of CPU cores)",
    )
    p.add_argument(
        "--cluster",
        default=None,
        metavar="local|ADDRESS",
        help="run on Dask distributed: a local cluster, or a scheduler address",
    )
    p.add_argument("--no-plots", action="store_true", help="write sweep.csv only")
    add_quiet_option(p)


def _check_run_paths(out: Path, runs) -> None:
    """Refuse, before any run, an ``--out`` under which the runs' files would pass the
    system's path limit (each run failed with its own cut-off 'cannot write' line)."""
    from slamcore.files import check_name_lengths

    if not runs:
        return
    longest = max((r.run_id for r in runs), key=len)
    # the longest name a run writes: a joint MRCLAM run's per-robot trajectory
    deepest = Path(os.path.abspath(out)) / "runs" / longest / "trajectory_robot5.tum"
    try:
        check_name_lengths(deepest, "--out")
    except ConfigError as e:
        raise ConfigError(f"{e.reason} (for the runs' files under it: runs/{longest}/...)") from None


def make_executor(workers: int, cluster: str | None):
    """The local pool, or Dask when ``cluster`` is given."""
    from graphslam.pipelines.sweep_exec import DaskExecutor, PoolExecutor

    if cluster is None:
        return PoolExecutor(workers)
    return DaskExecutor(cluster, workers)


def _progress(total: int, quiet: bool):
    """``(callback, bar)``: progress of the runs (a bar, or lines in a log) with done /
    failed counts and time left."""
    if quiet or total == 0:
        return None, None
    from graphslam.pipelines.progress import progress

    bar = progress(total=total, desc="sweep", unit="run")
    counts = {"failed": 0}

    def update(run, row):
        counts["failed"] += row["status"] != "ok"
        bar.set_postfix(failed=counts["failed"], last=run.run_id, refresh=False)
        bar.update(1)

    return update, bar


#: The start of a run's warning about its config file (:func:`warn_unread_sections`).
_CONFIG_WARNING = "graphslam: warning: --config "


def _config_warnings(out: Path, rows: list[dict]) -> dict[str, int]:
    """Each distinct warning the runs said about their config file (a section no run
    reads, a setting its mode leaves unread), with how many runs said it: they were in
    each run's stderr.txt only (thirteenth hostile pass). The run's own folder is
    dropped from the line, so one setting is one line."""
    counts: dict[str, int] = {}
    for r in rows:
        path = out / "runs" / str(r.get("run_id")) / "stderr.txt"
        try:
            text = path.read_text(errors="replace")
        except OSError:
            continue
        for line in dict.fromkeys(text.splitlines()):
            if line.startswith(_CONFIG_WARNING):
                said = line[len(_CONFIG_WARNING) :]
                # the runs get an absolute root (sweep.run_sweep); a relative --out as typed too
                for folder in (Path(os.path.abspath(out)), out):
                    said = said.replace(str(folder / "runs" / str(r.get("run_id"))) + "/", "")
                counts[said] = counts.get(said, 0) + 1
    return counts


def _still_there(out: Path) -> None:
    """Refuse to go on when ``--out`` no longer names the folder the sweep locked: the
    next runs and sweep.csv would go into a new folder at the old path, the sweep split
    in two without a word. The finished runs are where the folder went, and a sweep
    resumes from its table."""
    where = moved_to(out)
    if where is not None:
        # a run started after the move made its folder anew at the old path
        stray = f"; the new {out}/ holds only what runs started after the move wrote" if out.exists() else ""
        raise GraphSlamError(
            f"--out {out} was moved to {where} while the sweep ran; its finished runs and sweep.csv "
            f"are there: run the sweep again with --out {where} to finish it (the done runs are kept)" + stray
        )


def _capped_workers(workers: int, n_runs: int, cluster: str | None) -> int:
    """``workers`` capped at the runs (more would only wait: a local cluster of a million
    never starts), said when more than the cores (each a process with its own memory)."""
    from graphslam.cli.common import warn

    workers = min(workers, max(n_runs, 1))
    cores = os.cpu_count() or 1
    if cluster in (None, "local") and workers > cores:
        warn(
            f"--workers {workers} on {cores} cores: the runs share them, each slower, and each "
            "worker holds its own memory; fewer workers finish as soon"
        )
    return workers


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run the sweep, write the table and plots; the exit status."""
    from graphslam.cli.common import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, warn
    from graphslam.outputs.writers import OutputWrites, remove_stale_outputs
    from graphslam.pipelines.sweep import plot_files, read_rows, run_sweep
    from graphslam.pipelines.sweep_exec import score_finished
    from graphslam.pipelines.sweep_spec import parse_sweep

    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    if workers < 1:
        raise ConfigError("--workers must be at least 1")
    if args.workers is not None and args.cluster not in (None, "local"):
        raise ConfigError(
            "--workers sets the local pool or --cluster local; a running "
            "cluster has the workers it was started with"
        )
    from slamcore.files import check_output_dir

    check_output_dir(args.out, files=("sweep.csv",))  # refused now, not as each run's error
    runs_dir = args.out / "runs"
    if (runs_dir.exists() or runs_dir.is_symlink()) and not runs_dir.is_dir():  # a file, a dead link
        # each run's mkdir raised NotADirectoryError / FileExistsError: a traceback
        raise InputError("is not a folder: the sweep keeps each run in runs/<run id>", runs_dir)
    from graphslam.cli.out_folder import refuse_other_outputs
    from graphslam.outputs.writers import EVAL_OUTPUT_NAMES, FOLDER_OUTPUT_NAMES

    # an eval beside the table reads the sweep's runs, as one beside a run's files reads them
    theirs = [name for name in FOLDER_OUTPUT_NAMES if name not in EVAL_OUTPUT_NAMES]
    refuse_other_outputs(args.out, theirs, "another graphslam command (run, compare or localize)")
    spec = parse_sweep(args.sweep_file)
    for note in spec.notes:
        warn(note)
    runs = spec.runs()  # once here: each call fingerprints every dataset's files again
    _check_run_paths(args.out, runs)
    read_rows(args.out / "sweep.csv")  # a file there that is no sweep table: refused before any run
    n_runs = len(runs)
    claim_out_dir(args.out)
    executor = make_executor(_capped_workers(workers, n_runs, args.cluster), args.cluster)
    for note in executor.notes:
        warn(note)
    try:
        update, bar = _progress(n_runs, args.quiet)
        try:
            outcome = run_sweep(
                spec,
                args.out,
                executor,
                on_result=update,
                check_out=lambda: _still_there(args.out),
                score_finished=score_finished,
            )
        finally:
            if bar is not None:
                bar.close()
    finally:
        executor.close()
    written = [outcome.csv_path]
    writes = OutputWrites(args.out)  # a plot the disk refuses costs no other: each is tried
    # an earlier sweep's plots go first: a stop while these are drawn left them beside
    # this sweep.csv, looking current (hostile pass 21); those drawn are kept
    remove_stale_outputs(args.out, set(), plot_files(args.out))
    if not args.no_plots and outcome.rows:
        from graphslam.pipelines.sweep import nees_series, with_labels
        from graphslam.visualisation.plots import plot_sweep

        rows = with_labels(outcome.rows, spec.set_keys)
        series, unreadable = nees_series(args.out, rows)
        if unreadable:
            warn(
                f"the NEES plot leaves out {len(unreadable)} run(s) whose nees.csv cannot be read "
                f"({', '.join(unreadable[:3])}{', ...' if len(unreadable) > 3 else ''}); delete their "
                "folders under runs/ and the same command runs them again"
            )
        written += plot_sweep(rows, series, spec.set_keys, args.out, writes)
    # an earlier sweep's plots (other settings swept, or --no-plots now) would disagree
    # with this sweep.csv
    remove_stale_outputs(args.out, {p.name for p in written}, plot_files(args.out))
    if outcome.stale:
        warn(
            f"{len(outcome.stale)} runs sweep.csv listed as done were run again: "
            + "; ".join(f"{run_id}: {why}" for run_id, why in outcome.stale)
        )
    if outcome.edited:
        warn(
            f"{len(outcome.edited)} rows of sweep.csv differed from their runs' metrics.json "
            f"({_names(outcome.edited)}): the files' figures are kept"
        )
    if outcome.dropped:
        warn(
            f"{args.out / 'sweep.csv'} held {outcome.dropped} rows of runs that are not in this "
            "sweep (another sweep file, or data its runs read changed since); sweep.csv now lists "
            f"this sweep's runs only (their folders stay in {args.out / 'runs'})"
        )
    ok = sum(r.get("status") == "ok" for r in outcome.rows)
    print(
        f"sweep: {n_runs} runs, {outcome.skipped} already done, {outcome.ran} run now "
        f"({outcome.failed} failed); {ok} ok in {outcome.csv_path}"
    )
    print(writes.outputs_line(written))
    if outcome.interrupted:
        finished = {r["run_id"] for r in outcome.rows}
        left = [run.run_id for run in outcome.runs if run.run_id not in finished]
        print(
            "graphslam: interrupted; sweep.csv keeps every finished run"
            + (
                f"; {len(left)} not run to the end ({_names(left)}): the same command runs them"
                if left
                else ""
            ),
            file=sys.stderr,
        )
        writes.check(written)
        return EXIT_INTERRUPTED
    for line, count in _config_warnings(args.out, outcome.rows).items():
        warn(f"{count} of {len(outcome.rows)} runs, in their runs/*/{line}")
    doubtful = sum(r.get("status") == "ok" and bool(r.get("warnings")) for r in outcome.rows)
    if doubtful:  # an ok row can still hold an absurd estimate; say so where it is seen
        warn(f"{doubtful} of {ok} finished runs carry warnings (the warnings column of sweep.csv)")
    writes.check(written)
    failed = len(outcome.rows) - ok
    if failed:  # the table is whole, but a script must not take the sweep for a clean one
        warn(f"{failed} of {len(outcome.rows)} runs failed; their errors are in sweep.csv")
        return EXIT_FAILED
    return EXIT_OK


def _names(run_ids: list[str], most: int = 5) -> str:
    """The first ``most`` run ids, and how many more."""
    more = f" and {len(run_ids) - most} more" if len(run_ids) > most else ""
    return ", ".join(run_ids[:most]) + more
