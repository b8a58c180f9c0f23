"""``graphslam sweep``: every run of a sweep file, its table, and what the plots need.

``sweep.csv`` (in ``--out``) has one row a run: ``run_id``, ``dataset`` (as the sweep
file lists it),
``backend``, every swept ``section.key`` (empty where the run does not read
that section), ``config_hash``, ``seed``, then :data:`METRIC_COLUMNS` (a landmark
log's map: the landmarks built, ``map_rmse_m`` after the trajectory's alignment, the
true landmarks recovered within
:data:`graphslam.evaluation.planar.MAP_RECOVERY_RADIUS_M` and their number; empty
without landmark truth),
``run_wall_s``, ``wall_s``, ``peak_rss_mb`` (:data:`TAIL_COLUMNS`), ``status`` (ok, failed, interrupted),
``error`` (the failed run's one-line error) and ``warnings`` (what the run's
metrics.json says makes its estimate doubtful, joined by " | "; empty: nothing). The file is rewritten after
every finished run, so Ctrl-C keeps them all; a sweep run again into the same
folder skips the runs whose ``(config_hash, seed)`` has status ok and whose folder
still holds them (:func:`folder_mismatch`).
Each run's own files are in ``runs/<run_id>/`` (its config.toml, metrics.json,
trajectories, nees.csv, stderr.txt).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphslam.pipelines.common import active_guard
from graphslam.pipelines.sweep_spec import RunSpec, SweepSpec, run_config_file
from slamcore.errors import InputError
from slamcore.files import atomic_open

METRIC_COLUMNS = (
    "ate_rmse_m",
    "ate_alignment",
    "rpe_trans_rmse_m",
    "rpe_rot_rmse_deg",
    "nees_mean",
    "nees_in_bounds_fraction",
    "association_accuracy",
    "duplicates",
    "landmarks",
    "map_rmse_m",
    "landmarks_recovered",
    "landmarks_true",
)
#: ``run_wall_s``: the run's own time (its metrics.json's ``wall_s``: reading the data,
#: the run, its outputs); ``wall_s`` and ``peak_rss_mb``: the whole child process's,
#: with the interpreter's start, the imports (about 120 MB) and the sweep's scoring.
TAIL_COLUMNS = ("run_wall_s", "wall_s", "peak_rss_mb", "status", "error", "warnings")
#: Between two of a run's warnings in the ``warnings`` column.
WARNING_SEPARATOR = " | "


def columns(spec: SweepSpec) -> list[str]:
    return [
        "run_id",
        "dataset",
        "backend",
        *spec.set_keys,
        "config_hash",
        "seed",
        *METRIC_COLUMNS,
        *TAIL_COLUMNS,
    ]


def base_row(run: RunSpec, spec: SweepSpec) -> dict:
    row = {
        "run_id": run.run_id,
        "dataset": run.entry or run.dataset,  # as the sweep file lists it, from any folder
        "backend": run.backend,
        "config_hash": run.config_hash,
        "seed": "" if run.seed is None else run.seed,
    }
    for key in spec.set_keys:
        row[key] = run.overrides.get(key, "")
    return row


#: Columns of every ``sweep.csv``: a file without them is not a sweep's table.
KEY_COLUMNS = ("run_id", "config_hash", "seed", "status")


def read_rows(path: Path) -> list[dict]:
    """Rows of an existing ``sweep.csv`` (empty when there is none, or it is empty).

    Raises:
        InputError: the file is not a sweep's table (another file of that name, bytes
            no CSV reader takes): the sweep would write over it.
    """
    if not path.is_file():
        return []
    advice = "move it away or choose another --out"
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            rows = list(reader)
            header = reader.fieldnames or []
    except (UnicodeDecodeError, csv.Error) as e:
        raise InputError(f"not a sweep table that can be read ({e}); {advice}", path) from None
    if header and not set(KEY_COLUMNS) <= set(header):
        raise InputError(
            f"not a table of graphslam sweep (no {', '.join(KEY_COLUMNS)} columns); {advice}", path
        )
    return rows


def write_rows(path: Path, header: list[str], rows: list[dict]) -> None:
    """Write ``sweep.csv`` whole, through a temporary file (never half a table)."""
    with atomic_open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=header, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in header})


@dataclass
class SweepOutcome:
    """What a sweep did: every row of sweep.csv, and this call's counts."""

    rows: list[dict]
    csv_path: Path
    ran: int = 0
    failed: int = 0
    skipped: int = 0
    #: rows of an earlier sweep.csv whose runs are not in this grid (another sweep
    #: file into the same folder): not in the new table, their folders kept
    dropped: int = 0
    interrupted: bool = False
    runs: list[RunSpec] = field(default_factory=list)
    #: ``(run_id, why)`` of runs sweep.csv says are done whose folder does not hold them
    #: (:func:`folder_mismatch`): run again
    stale: list[tuple[str, str]] = field(default_factory=list)
    #: run ids of done rows whose figures in sweep.csv differed from their run's files
    #: (edited by hand): the files' figures are kept
    edited: list[str] = field(default_factory=list)


def _key(run: RunSpec) -> tuple[str, str]:
    """``(config_hash, seed)`` as sweep.csv spells them."""
    return run.config_hash, "" if run.seed is None else str(run.seed)


def _flag_value(command: list, flag: str) -> str | None:
    """The value given to ``flag`` in a recorded command line, None when absent."""
    return str(command[command.index(flag) + 1]) if flag in command[:-1] else None


def _same_dataset(recorded: str | None, run: RunSpec, cwd) -> bool:
    """Whether a recorded ``--dataset`` is the run's: the same built-in name, or a path
    (a relative one read from the run's recorded working directory, else this one) that
    resolves to the same file or folder."""
    from graphslam.registry import is_builtin_dataset

    if recorded is None or is_builtin_dataset(recorded) or is_builtin_dataset(run.dataset):
        return recorded == run.dataset
    where = os.path.join(cwd if isinstance(cwd, str) else os.getcwd(), recorded)
    return os.path.realpath(where) == os.path.realpath(run.dataset)


def _other_code(prov: dict) -> str | None:
    """How the code that made a run differs from this one's, or None when it is the same
    (:func:`graphslam.pipelines.provenance.code_identity`): a sweep re-run after an upgrade kept the
    old version's results (fifteenth hostile pass)."""
    from graphslam.pipelines.provenance import code_identity

    now = code_identity()
    then = {"versions": prov.get("versions"), "code_sha256": prov.get("code_sha256")}
    if then == now:
        return None
    if not isinstance(then["versions"], dict) or then["code_sha256"] is None:
        return "made by other code (its metrics.json names no code version)"
    differ = [
        f"{name} {then['versions'].get(name)} -> {version}"
        for name, version in now["versions"].items()
        if then["versions"].get(name) != version
    ]
    if then["code_sha256"] != now["code_sha256"]:
        differ.append(f"graphslam source {str(then['code_sha256'])[:12]} -> {now['code_sha256'][:12]}")
    return f"made by other code ({', '.join(differ)})"


def folder_mismatch(run: RunSpec, folder: Path) -> str | None:
    """Why ``folder`` does not hold ``run`` finished, or None when it does: its metrics.json
    is there and records the run's dataset, back end, seed, steps, NEES flag and config
    file bytes (provenance), and this code (:func:`_other_code`). A folder deleted, or
    written over by another run, still counted as done, and the plots were redrawn from
    its files (hostile pass)."""
    try:
        metrics = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        return "no metrics.json in its folder"
    except (OSError, ValueError):
        return "its metrics.json cannot be read"
    prov = metrics.get("provenance") if isinstance(metrics, dict) else None
    if not isinstance(prov, dict) or not isinstance(prov.get("command"), list):
        return "its metrics.json does not say how it was run"
    command = prov["command"]
    want = {
        "--backend": run.backend,
        "--seed": None if run.seed is None else str(run.seed),
        "--max-steps": None if run.max_steps is None else str(run.max_steps),
    }
    differ = [flag for flag, value in want.items() if _flag_value(command, flag) != value]
    if not _same_dataset(_flag_value(command, "--dataset"), run, prov.get("cwd")):
        differ.insert(0, "--dataset")
    if ("--nees" in command) != run.nees:
        differ.append("--nees")
    if (
        prov.get("config_sha256")
        != hashlib.sha256(run_config_file(run.config)[1].encode("utf-8")).hexdigest()
    ):
        differ.append("config")
    if differ:
        return f"its folder holds another run (other {', '.join(differ)})"
    if metrics.get("interrupted"):  # a stop kept its estimate so far: no finished run
        return "its run was stopped before the end"
    # the table's RPE and the NEES plot are read from these: a run without them is not done
    needed = ["trajectory.tum"] + (["nees.csv"] if run.nees and metrics.get("nees_mean") is not None else [])
    missing = [name for name in needed if not (folder / name).is_file()]
    if missing:
        return f"its {' and '.join(missing)} is gone"
    return _other_code(prov)


def run_sweep(
    spec: SweepSpec,
    out: Path,
    executor,
    *,
    on_result: Callable[[RunSpec, dict], None] | None = None,
    check_out: Callable[[], None] | None = None,
    score_finished: Callable[[Path], dict | None] | None = None,
) -> SweepOutcome:
    """Run every run of ``spec`` not already done in ``out`` on ``executor``.

    ``on_result(run, row)`` is called after each finished run (the progress
    bar). A KeyboardInterrupt (Ctrl-C) stops the sweep: runs in flight are
    stopped and left out, finished ones stay in sweep.csv, and the outcome
    says ``interrupted``. ``check_out()`` is called before each write of sweep.csv
    (as each run finishes, and at the end): an error it raises (the folder moved away, and
    the table would be written into a new folder at the old path) stops the runs
    in flight and is raised. ``score_finished(run folder)``: the row of a run found
    finished whole after a stop (:func:`graphslam.pipelines.sweep_exec.score_finished`),
    or None; without it such runs are left out.
    """
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "sweep.csv"
    header = columns(spec)
    runs = spec.runs()
    earlier = read_rows(csv_path)
    done = {(r.get("config_hash"), r.get("seed")): r for r in earlier if r.get("status") == "ok"}
    stale = []
    for run in runs:
        why = folder_mismatch(run, out / "runs" / run.run_id) if _key(run) in done else None
        if why is not None:  # sweep.csv's word alone is not the run's files
            stale.append((run.run_id, why))
            del done[_key(run)]
    # a done row in this sweep's spelling (its dataset as the sweep file lists it)
    rows = {run.run_id: {**done[_key(run)], **base_row(run, spec)} for run in runs if _key(run) in done}
    edited = _rescore(rows, out, score_finished) if score_finished is not None else []
    todo = [run for run in runs if _key(run) not in done]
    ours = {_key(run) for run in runs}
    outcome = SweepOutcome([], csv_path, skipped=len(runs) - len(todo), runs=runs, stale=stale, edited=edited)
    outcome.dropped = sum((r.get("config_hash"), r.get("seed")) not in ours for r in earlier)
    order = {run.run_id: i for i, run in enumerate(runs)}

    def flush():
        if check_out is not None:  # before every write of the table, the last one too
            check_out()
        outcome.rows = sorted(rows.values(), key=lambda r: order.get(r["run_id"], len(order)))
        write_rows(csv_path, header, outcome.rows)

    flush()
    started = time.time()
    # an absolute root: a cluster's worker starts elsewhere (a relative --out put the runs
    # in its working folder, the sweep none the wiser), and a child's "--out -o/runs/x"
    # was read as a flag (hostile pass 21)
    results = executor.map_unordered(todo, Path(os.path.abspath(out)))
    try:
        for run, result in results:
            row = {**base_row(run, spec), **result}
            outcome.ran += 1
            outcome.failed += row["status"] == "failed"  # a stopped run is no failure
            if row["status"] != "interrupted":
                rows[run.run_id] = row
            flush()
            if on_result is not None:
                on_result(run, row)
    except KeyboardInterrupt:
        outcome.interrupted = True
        guard = active_guard()
        if guard is not None:
            # the rest is the save: a second signal (a batch system's SIGTERM after the
            # user's Ctrl-C) is recorded, not raised, or it cut the harvest of runs that
            # finished as the first one came and they were left out of sweep.csv
            guard.begin_save()
    finally:
        results.close()  # stops the runs still in flight
    if outcome.interrupted and score_finished is not None:
        _harvest(todo, rows, out, spec, started, score_finished)
    flush()
    return outcome


#: Columns only sweep.csv holds (the sweep measured them around the run): kept on resume.
SWEEP_ONLY_COLUMNS = ("wall_s", "peak_rss_mb")


def _rescore(rows: dict, out: Path, score_finished: Callable[[Path], dict | None]) -> list[str]:
    """Each done row's figures read again from its run's files, which hold them; ids of
    the rows whose table disagreed. A number edited in sweep.csv was carried forward on
    resume as the run's (nineteenth hostile pass). A folder :func:`folder_mismatch` passed
    but that cannot be scored keeps its row."""
    edited = []
    for run_id, row in rows.items():
        fresh = score_finished(out / "runs" / run_id)
        if fresh is None:
            continue
        fresh = {k: v for k, v in fresh.items() if k not in SWEEP_ONLY_COLUMNS}
        if any(_cell(v) != _cell(row.get(k)) for k, v in fresh.items()):
            edited.append(run_id)
        row.update(fresh)
    return edited


def _cell(value) -> str:
    """``value`` as csv.DictWriter writes it (None: empty), to compare a read row."""
    return "" if value is None else str(value)


def _harvest(
    todo: list[RunSpec],
    rows: dict,
    out: Path,
    spec: SweepSpec,
    started: float,
    score_finished: Callable[[Path], dict | None],
) -> None:
    """After a stop: the rows of runs that finished whole in this sweep but were not
    yet reported (a worker's result not collected, or a run that got the signal as it
    ended and said its outputs are complete): their metrics.json, written since the sweep
    started, says ``interrupted: false``. A stopped sweep listed 2 of 4 finished runs, and
    its next start ran the other two again (sixteenth hostile pass)."""
    for run in todo:
        if run.run_id in rows:
            continue
        metrics = out / "runs" / run.run_id / "metrics.json"
        try:
            if metrics.stat().st_mtime < started or json.loads(metrics.read_text()).get("interrupted", True):
                continue
        except (OSError, ValueError):
            continue
        row = score_finished(out / "runs" / run.run_id)
        if row is not None:
            rows[run.run_id] = {**base_row(run, spec), "run_id": run.run_id, **row}


#: Names of the sweep's plots: ``sweep_nees.png``, ``sweep_ate.png`` and one
#: ``sweep_<section.key>.png`` per swept setting.
PLOT_NAME = re.compile(r"sweep_(nees|ate|[A-Za-z0-9_]+\.[A-Za-z0-9_.]+)\.png")


def plot_files(out: Path) -> tuple[str, ...]:
    """Names of the sweep plots in ``out`` (this sweep's or an earlier one's)."""
    return tuple(sorted(p.name for p in out.glob("sweep_*.png") if PLOT_NAME.fullmatch(p.name)))


def sweep_output_names(out: Path) -> tuple[str, ...]:
    """What a sweep wrote at the top of ``out``: ``sweep.csv`` and its plots."""
    return ("sweep.csv", *plot_files(out))


def with_labels(rows: list[dict], set_keys) -> list[dict]:
    """Rows with a ``label``: the back end and the swept values it ran with, and its
    dataset when the sweep has several (the group a plot puts it in; seeds are the
    Monte Carlo runs of a group: a synthetic run and a real robot's pooled as two
    repeats of one "ekf", thirteenth hostile pass)."""
    several = len({r.get("dataset") for r in rows}) > 1
    out = []
    for r in rows:
        parts = [f"{k.split('.', 1)[1]}={r[k]}" for k in set_keys if r.get(k) not in (None, "")]
        where = [Path(str(r.get("dataset"))).name or str(r.get("dataset"))] if several else []
        out.append({**r, "label": " ".join([r["backend"], *parts, *where])})
    return out


def nees_series(out: Path, rows: list[dict]) -> tuple[dict[str, np.ndarray], list[str]]:
    """Per ``label`` (:func:`with_labels`), the (runs, steps) pose NEES of its ok runs
    (``nees.csv`` of each), cut to the shortest run; and the run ids whose ``nees.csv``
    could not be read (left out of the plot: an emptied or edited file raised in the
    plotting after every run was done, hostile pass 21)."""
    by_backend: dict[str, list[np.ndarray]] = {}
    unreadable: list[str] = []
    for r in rows:
        path = out / "runs" / r["run_id"] / "nees.csv"
        if r.get("status") == "ok" and path.is_file():
            try:
                with warnings.catch_warnings():  # "input contained no data": counted below
                    warnings.simplefilter("ignore", UserWarning)
                    values = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)[:, 2]
            except (OSError, ValueError, IndexError):
                unreadable.append(r["run_id"])
                continue
            if not len(values):
                unreadable.append(r["run_id"])
                continue
            by_backend.setdefault(r["label"], []).append(values)
    series = {b: np.array([v[: min(len(x) for x in vs)] for v in vs]) for b, vs in by_backend.items()}
    return series, unreadable
