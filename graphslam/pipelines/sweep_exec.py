"""Running a sweep's runs: one ``graphslam run`` process each, on a local pool or Dask.

:func:`execute_run` is the unit of work: it writes the run's config file,
starts ``python -m graphslam.cli.main run ...`` (``--nees`` when the sweep
scores NEES) in the run's folder,
waits for it (``os.wait4``: the child's own peak memory), then reads its
``metrics.json`` and scores ``trajectory.tum`` against ``ground_truth.tum``
for the RPE. It returns one row of ``sweep.csv`` and never raises for a
failed run: the row says ``failed`` and carries the run's one-line error.

Executors (same rows whichever runs them: every run is seeded and shares
nothing with the others):

- :class:`PoolExecutor`: ``workers`` runs at a time from threads of this
  process (the work is in the child processes; a thread only waits);
- :class:`DaskExecutor`: Dask distributed, ``local`` (a ``LocalCluster`` of
  ``workers`` single-threaded worker processes) or the address of a running
  scheduler, whose workers must see the same ``--out`` folder.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path

from graphslam.pipelines.common import EXIT_STATUS_OF_SIGNAL, PARENT_PID_ENV
from graphslam.pipelines.sweep import WARNING_SEPARATOR
from graphslam.pipelines.sweep_spec import RunSpec, run_config_file
from slamcore.errors import ConfigError, GraphSlamError

#: Runs in flight in this process (Ctrl-C stops them), and the flag that keeps
#: a thread that was about to start one from starting it after the stop.
_LIVE: set[subprocess.Popen] = set()
_LIVE_LOCK = threading.Lock()
_STOPPING = threading.Event()


def run_command(run: RunSpec, out_dir: Path) -> list[str]:
    """The ``graphslam run`` command line of ``run``."""
    cmd = [
        sys.executable,
        "-m",
        "graphslam.cli.main",
        "run",
        "--dataset",
        run.dataset,
        "--backend",
        run.backend,
        "--config",
        str(out_dir / run_config_file(run.config)[0]),
        "--out",
        str(out_dir),
        "--rerun",
        "off",
        "--quiet",
    ]
    if run.nees:
        cmd.append("--nees")
    if run.seed is not None:
        cmd += ["--seed", str(run.seed)]
    if run.max_steps is not None:
        cmd += ["--max-steps", str(run.max_steps)]
    return cmd


def _last_error_line(text: str) -> str:
    """The run's one-line error (its last stderr line, without the program prefix)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    return last.removeprefix("graphslam: error: ")


def _spawn_and_wait(cmd: list[str], out_dir: Path) -> tuple[int, float, float]:
    """``(exit status, wall s, peak RSS MB of the child)``; stderr goes to stderr.txt.
    Once :func:`stop_live_runs` has been called, nothing starts (status 130)."""
    t0 = time.perf_counter()
    with open(out_dir / "stderr.txt", "wb") as err, _LIVE_LOCK:
        if _STOPPING.is_set():
            return 130, 0.0, 0.0
        # the child holds its own copy of the stderr file once started
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.DEVNULL,
            stderr=err,
            cwd=os.getcwd(),
            # the run ends (SIGTERM: its outputs so far written) when the sweep dies, even
            # by SIGKILL: orphans went on writing folders a re-run sweep then refused
            env={**os.environ, "PYTHONPATH": _pythonpath(), PARENT_PID_ENV: str(os.getpid())},
        )
        _LIVE.add(proc)
    try:
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    finally:
        with _LIVE_LOCK:
            _LIVE.discard(proc)
    return proc.returncode, time.perf_counter() - t0, usage.ru_maxrss / 1024.0


def _pythonpath() -> str:
    """This package's root first, so the child runs the same code as the sweep."""
    root = str(Path(__file__).resolve().parents[2])
    rest = os.environ.get("PYTHONPATH")
    return root if not rest else f"{root}{os.pathsep}{rest}"


def _scores(out_dir: Path) -> dict:
    """Metrics of a finished run: metrics.json, with its RPE where it has one (image runs:
    a monocular run's at the scale of its Sim(3) fit; scored from the files, unscaled, it
    was 4.5x the run's own, thirteenth hostile pass), else the frame-delta RPE of its files."""
    from graphslam.evaluation.trajectory import EvalOptions
    from graphslam.pipelines.trajectory_eval import evaluate_files

    m = json.loads((out_dir / "metrics.json").read_text())
    assoc = m.get("association") or {}
    row = {
        "ate_rmse_m": m.get("ate_rmse_m"),
        # image runs say theirs (a monocular one's is Sim(3)); 2-D runs align in SE(2)
        "ate_alignment": m.get("alignment")
        or ("se2" if "steps" in m and m.get("ate_rmse_m") is not None else ""),
        "run_wall_s": m.get("wall_s"),
        "nees_mean": m.get("nees_mean"),
        "nees_in_bounds_fraction": m.get("nees_in_bounds_fraction"),
        "association_accuracy": assoc.get("accuracy"),
        "duplicates": assoc.get("duplicates"),
        # a landmark log's map (MRCLAM seeds of FastSLAM are the sweep users run most)
        **{k: m.get(k) for k in ("landmarks", "map_rmse_m", "landmarks_recovered", "landmarks_true")},
        "warnings": WARNING_SEPARATOR.join(m.get("warnings") or []),
    }
    own = m.get("rpe")
    if isinstance(own, dict):  # an image run's own RPE: a monocular one's at its Sim(3) scale
        return {
            **row,
            "rpe_trans_rmse_m": own.get("trans_rmse_m"),
            "rpe_rot_rmse_deg": own.get("rot_rmse_deg"),
        }
    gt = out_dir / "ground_truth.tum"
    if gt.is_file():
        # time column = pose id on both sides: exact association; SE(2) poses as z = 0
        try:
            s = evaluate_files(gt, [out_dir / "trajectory.tum"], EvalOptions(max_diff_s=0.0))[0]
        except GraphSlamError:  # fewer than two poses: RPE null, as the run's own ATE
            return {**row, "rpe_trans_rmse_m": None, "rpe_rot_rmse_deg": None}
        summary = s.result.summary()
        row["rpe_trans_rmse_m"] = summary["rpe_trans_rmse_m"]
        row["rpe_rot_rmse_deg"] = summary["rpe_rot_rmse_deg"]
    return row


def execute_run(run: RunSpec, root: str) -> dict:
    """Run one sweep run in ``root/runs/<run_id>`` (module doc); its ``sweep.csv`` row."""
    out_dir = Path(root) / "runs" / run.run_id
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        name, text = run_config_file(run.config)
        (out_dir / name).write_text(text, encoding="utf-8")
        rc, wall, peak = _spawn_and_wait(run_command(run, out_dir), out_dir)
    except OSError as e:  # runs/<run id> or its stderr.txt not a file, a full disk, no fork:
        # this run fails, the sweep goes on
        why = f"{e.strerror}: {e.filename}" if e.strerror else str(e)
        return {
            "run_id": run.run_id,
            "wall_s": 0.0,
            "peak_rss_mb": None,
            "status": "failed",
            "error": f"cannot write the run's folder or start it ({why})",
        }
    row = {"run_id": run.run_id, "wall_s": wall, "peak_rss_mb": peak}
    if rc != 0:
        try:
            err = _last_error_line((out_dir / "stderr.txt").read_text(errors="replace"))
        except OSError:  # the sweep's folder moved away while the run went on (the sweep says so)
            err = f"{out_dir / 'stderr.txt'} cannot be read: its folder was moved or deleted during the run"
        # stopped by SIGINT or SIGTERM (ours via stop_live_runs, or a batch system's)
        stopped = {*EXIT_STATUS_OF_SIGNAL.values(), *(-s for s in EXIT_STATUS_OF_SIGNAL)}
        status = "interrupted" if rc in stopped else "failed"
        return {**row, "status": status, "error": err or f"exit status {rc}"}
    try:
        row.update(_scores(out_dir))
    except Exception as e:  # a run whose files cannot be scored is a failed run, not a crash
        return {**row, "status": "failed", "error": f"scoring: {e}"}
    return {**row, "status": "ok", "error": ""}


def score_finished(out_dir: Path) -> dict | None:
    """The ``sweep.csv`` row of a run found finished in ``out_dir`` after a stop (its
    wall time and peak memory unknown: null), or None when its files cannot be scored."""
    try:
        scores = _scores(out_dir)
    except Exception:  # noqa: BLE001 (as execute_run: unscorable files are no row here)
        return None
    return {"wall_s": None, "peak_rss_mb": None, **scores, "status": "ok", "error": ""}


def stop_live_runs(signum: int = signal.SIGTERM) -> None:
    """Stop every run this process started and is still waiting for (``signum``: SIGTERM,
    which lets a run save; SIGKILL, which does not), and start no more until
    :func:`allow_runs`."""
    with _LIVE_LOCK:
        _STOPPING.set()
        for proc in _LIVE:
            # os.kill, not proc.terminate(): terminate() polls, which could reap the
            # child under the thread blocked in os.wait4 on it
            try:
                os.kill(proc.pid, signum)
            except ProcessLookupError:
                pass


def _wait_for_runs(pool: ThreadPoolExecutor) -> None:
    """Wait for the pool's runs, stopped by :func:`stop_live_runs`, to end. A second
    Ctrl-C (0.1 s after the first) raised out of the wait and the sweep exited with a run
    still going, which wrote its files into ``--out`` after the sweep had reported: a
    further signal now tells the runs again and the wait goes on (a stopped run saves and
    ends within seconds); one more kills them, for a run stuck in C code never runs its
    SIGTERM handler and the wait would have no end."""
    further = 0
    while True:
        try:
            pool.shutdown(wait=True)
            return
        except KeyboardInterrupt:
            further += 1
            stop_live_runs(signal.SIGTERM if further == 1 else signal.SIGKILL)


def allow_runs() -> None:
    """Let runs start again (after :func:`stop_live_runs`)."""
    _STOPPING.clear()


class PoolExecutor:
    """``workers`` runs at a time on this machine."""

    name = "pool"

    def __init__(self, workers: int):
        self.workers = workers
        self.notes: list[str] = []  # what the command says before the runs (none here)

    def map_unordered(self, runs: list[RunSpec], root: Path):
        """Yield ``(run, row)`` as runs finish; on KeyboardInterrupt stop everything.

        At most two runs a worker are queued at a time: submitting the whole grid
        first took minutes on a large one, and a signal in that loop left the
        pool's threads starting runs with nothing to stop them (an orphan)."""
        pool = ThreadPoolExecutor(max_workers=self.workers)
        queue = iter(runs)
        futures: dict[Future, RunSpec] = {}
        try:
            while True:
                while len(futures) < 2 * self.workers:
                    run = next(queue, None)
                    if run is None:
                        break
                    futures[pool.submit(execute_run, run, str(root))] = run
                if not futures:
                    break
                # short timeout: the main thread stays responsive to Ctrl-C
                done, _ = wait(set(futures), timeout=0.2, return_when=FIRST_COMPLETED)
                for f in done:
                    yield futures.pop(f), f.result()
        finally:
            for f in futures:
                f.cancel()
            stop_live_runs()
            _wait_for_runs(pool)
            allow_runs()

    def close(self) -> None:
        pass


#: Longest wait for a scheduler's answer, s: Dask's own ``timeout`` covers the
#: connection, not a server that accepts it and never speaks Dask (an HTTP server).
CONNECT_TIMEOUT_S = 20.0


def _cannot_connect(address: str, e: BaseException) -> ConfigError:
    """The one line of a failed connection to ``address``: the error's type and words."""
    return ConfigError(
        f"--cluster {address}: cannot connect ({type(e).__name__}: {' '.join(str(e).split())[:200]})"
    )


def _connect(Client, address: str):
    """A Dask ``Client`` of the scheduler at ``address``, or one ConfigError: no answer
    within :data:`CONNECT_TIMEOUT_S`, or any failure of the handshake (a server that is
    no scheduler answered 'SSH-2.0...' and Dask read it as a 3 EiB frame: MemoryError)."""
    try:  # a malformed address is refused before a Client exists: its failed start in
        # a thread left Dask's loop registry so that the next LocalCluster of this process
        # never started (AssertionError after 10 s: a notebook's next sweep, or CI's tests)
        from distributed.comm import parse_address
        from distributed.comm.addressing import parse_host_port

        scheme, where = parse_address(address)
        if scheme in ("tcp", "tls", "ws", "wss"):
            parse_host_port(where)
    except ValueError as bad:
        raise _cannot_connect(address, bad) from None
    box: dict = {}

    def connect() -> None:
        try:
            box["client"] = Client(address, timeout="10s")
        except Exception as e:  # noqa: BLE001 - every failure is the address's: one line
            box["error"] = e

    # a thread of its own: a handshake that never ends must not hold the command
    worker = threading.Thread(target=connect, name="dask-connect", daemon=True)
    worker.start()
    worker.join(CONNECT_TIMEOUT_S)
    if worker.is_alive():
        raise ConfigError(
            f"--cluster {address}: cannot connect (no answer in {CONNECT_TIMEOUT_S:g} s: "
            "not a Dask scheduler?)"
        )
    if "error" in box:
        raise _cannot_connect(address, box["error"])
    return box["client"]


#: Dask's setting of the ``distributed`` loggers' level, read from the environment.
_DASK_LOG_ENV = "DASK_LOGGING__DISTRIBUTED"


#: Loggers of the event loop a local cluster starts on (a failed accept is an ERROR there).
_START_LOGGERS = ("asyncio", "tornado", "distributed")


def _start_failure(e: BaseException) -> str:
    """Why a local cluster did not start, in words: too few file descriptors (somewhere
    in the chain of causes), with the limit to raise; else the last error, on one line."""
    seen: BaseException | None = e
    visited: set[int] = set()  # a chain of causes may loop back on itself
    while seen is not None and id(seen) not in visited:
        visited.add(id(seen))
        if isinstance(seen, OSError) and seen.errno == errno.EMFILE:
            import resource  # POSIX: where EMFILE is

            soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
            return f"too many open files; ulimit -n is {soft}"
        seen = seen.__cause__ or seen.__context__
    return f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"


class DaskExecutor:
    """Runs on Dask distributed: ``address`` ``"local"`` starts a LocalCluster."""

    name = "dask"

    def __init__(self, address: str, workers: int):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError("--cluster needs Dask: pip install 'graphslam-toolkit[cluster]'") from None
        self.cluster = None
        self._log_level: int | None = None  # the distributed loggers' level before (local)
        if address == "local":
            # Ctrl-C in a terminal reaches the whole process group: the worker processes
            # died of it with tracebacks of their own, while this process already stops
            # the runs in flight (stop_live_runs). They are started ignoring SIGINT (a
            # disposition a spawned process keeps; a run they start sets its own).
            # Dask's WARNING lines of a cancelled run or a removed worker are its own
            # bookkeeping, said as noise on the command's stderr: errors only, here and
            # in the workers (which read the level from their environment at start)
            self._log_level = logging.getLogger("distributed").level
            logging.getLogger("distributed").setLevel(logging.ERROR)
            old = signal.signal(signal.SIGINT, signal.SIG_IGN)
            env = os.environ.get(_DASK_LOG_ENV)
            os.environ[_DASK_LOG_ENV] = "error"
            # a cluster that fails to start (too few file descriptors) printed some 170
            # lines of its event loop's tracebacks before its own: the one line below says it
            quiet = {name: logging.getLogger(name).level for name in _START_LOGGERS}
            for name in _START_LOGGERS:
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            try:
                # one thread a worker: a run is a process of its own, a worker only waits.
                # No dashboard, but the scheduler's HTTP server still binds: on Dask's 8787 by
                # default, where a second sweep of the machine printed "Port 8787 is already
                # in use" (three lines and a traceback line); any free port on the loopback
                self.cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                )
            except Exception as e:  # noqa: BLE001 - every failure to start is said in one line
                raise ConfigError(
                    f"--cluster local: cannot start the local cluster ({_start_failure(e)})"
                ) from None
            finally:
                for name, level in quiet.items():
                    logging.getLogger(name).setLevel(level)
                signal.signal(signal.SIGINT, old)
                if env is None:
                    os.environ.pop(_DASK_LOG_ENV, None)
                else:
                    os.environ[_DASK_LOG_ENV] = env
            self.client = Client(self.cluster)
        else:
            self.client = _connect(Client, address)
        #: what the command should say before the runs (a scheduler without a worker)
        self.notes: list[str] = []
        if self.cluster is None and not self.client.scheduler_info().get("workers"):
            # the runs wait for a worker to join; they waited with no word (hostile pass 21)
            self.notes.append(
                f"--cluster {address}: the scheduler has no worker yet; the runs wait until one "
                f"joins (dask worker {address})"
            )
        self.client.run(allow_runs)  # a Ctrl-C'd sweep before this one left them stopped

    def map_unordered(self, runs: list[RunSpec], root: Path):
        from dask.distributed import as_completed

        futures = {self.client.submit(execute_run, r, str(root), pure=False): r for r in runs}
        finished = False
        try:
            for f in as_completed(list(futures)):
                row = f.result()
                # released once collected: a worker lost later (killed) made the scheduler
                # compute a result it still held again, the run rewritten in its folder
                # after its row was in the table (hostile pass 21)
                run = futures.pop(f)
                f.release()
                yield run, row
            finished = True
        finally:
            for f in futures:
                f.cancel()
            if not finished:
                # cancelling a task does not stop the process it started: the
                # workers stop their runs in flight themselves
                self.client.run(stop_live_runs)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        if self._log_level is not None:  # after the shutdown, whose warnings were noise too
            logging.getLogger("distributed").setLevel(self._log_level)
