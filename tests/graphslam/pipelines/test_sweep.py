"""``graphslam sweep``: the grid, bad sweep files, a failing run, resume, Ctrl-C, Dask = pool.

Runs are short (20 steps of the synthetic world, about a second each: most of
it is the child's Python start and imports).
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from graphslam.cli.main import main
from graphslam.pipelines.sweep import run_sweep
from graphslam.pipelines.sweep_exec import PoolExecutor
from graphslam.pipelines.sweep_spec import parse_sweep
from slamcore.errors import ConfigError
from tests.conftest import ROOT

SMALL = """\
[sweep]
dataset = ["synthetic"]
backend = ["isam2", "ekf"]
seed = [0, 1]
max_steps = 20
[sweep.set]
"ekf.association" = ["unknown"]
"""
#: columns that differ between two executions of the same run
TIMING = ("run_wall_s", "wall_s", "peak_rss_mb")


def _file(tmp_path, text, name="sweep.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _without_timing(rows):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def _csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_grid_is_the_product_and_overrides_reach_only_their_readers(tmp_path):
    spec = parse_sweep(_file(tmp_path, """\
[sweep]
dataset = ["synthetic"]
backend = ["isam2", "ekf", "fastslam1"]
seed = {from = 3, to = 5}
[sweep.set]
"fastslam.n_particles" = [10, 20]
"synthetic.sigma_r_m" = [0.1, 0.2]
"""))
    runs = spec.runs()
    # isam2 and ekf: 2 world settings; fastslam1: 2 x 2; each over 3 seeds
    assert len(runs) == (2 + 2 + 4) * 3
    assert {r.seed for r in runs} == {3, 4, 5}
    isam2 = [r for r in runs if r.backend == "isam2"]
    assert all("fastslam.n_particles" not in r.overrides for r in isam2)
    assert {r.config["synthetic"]["sigma_r_m"] for r in isam2} == {0.1, 0.2}
    assert len({(r.config_hash, r.seed) for r in runs}) == len(runs)
    again = parse_sweep(tmp_path / "sweep.toml").runs()
    assert [r.run_id for r in again] == [r.run_id for r in runs]  # hashes are stable


def test_base_config_and_overrides_make_the_run_config(tmp_path):
    _file(tmp_path, "[ekf]\nodometry_covariance_scale = 2.0\nassociation = \"known\"\n", "base.toml")
    spec = parse_sweep(_file(tmp_path, """\
[sweep]
dataset = ["synthetic"]
backend = ["ekf"]
config = "base.toml"
max_steps = 7
[sweep.set]
"ekf.association" = ["unknown"]
"""))
    (run,) = spec.runs()
    assert run.seed is None and run.max_steps == 7
    assert run.config == {"ekf": {"odometry_covariance_scale": 2.0, "association": "unknown"}}


@pytest.mark.parametrize("text, line, words", [
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseeds = [1]\n', 4, "unknown key 'seeds'"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n[sweep.set]\n"ekf.asociation" = ["unknown"]\n',
     5, "unknown key(s) ['asociation']"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n[sweep.set]\n"isam2.polish" = [true]\n',
     5, "not a section.key that these runs read"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = []\n', 3, "empty"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = {from = 5, to = 4}\n', 4, "empty"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n[sweep.set]\n"ekf.association" = []\n',
     5, "grid has no run"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n[sweep.set]\n"synthetic.sigma_r_m" = [-1.0]\n',
     5, "sigma_r_m"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf2"]\n', 3, "unknown back end"),
    # issue 34: a grid of 4 x 10^7 runs spent minutes listing them before starting any
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf", "isam2"]\nseed = {from = 0, to = 99999}\n'
     '[sweep.set]\n"ekf.association" = ["known", "unknown"]\n', 1,
     "the grid has 400000 runs, above its cap of 10000"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nmax_runs = 0\n', 4, "max_runs"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n\n[ekf]\nassociation = "unknown"\n', 5,
     "unknown table [ekf]"),
    ('[sweep]\ndataset = ["synthetic-images"]\nbackend = ["fastslam1"]\n', 3,
     "does not run on the image sequence"),
    ('[sweep]\ndataset = ["synthetic-images"]\nbackend = ["ekf"]\nnees = true\n', 4,
     "write no nees.csv"),
    ('[sweep]\ndataset = ["synthetic-images"]\nbackend = ["isam2"]\n[sweep.set]\n"ekf.association" = ["known"]\n',
     5, "not a section.key that these runs read"),
    ('[sweep]\ndataset = ["synthetic-images"]\nbackend = ["ekf"]\n[sweep.set]\n"active_search.order" = ["random"]\n',
     5, "active_search.order"),
    # third hostile pass: a value listed twice ran once, the grid smaller than written
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = [0, 1, 0]\n', 4, "seed lists 0 twice"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf", "ekf"]\n', 3, "backend lists 'ekf' twice"),
    ('[sweep]\ndataset = ["synthetic", "synthetic"]\nbackend = ["ekf"]\n', 2, "lists 'synthetic' twice"),
    ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n[sweep.set]\n"synthetic.sigma_r_m" = [0.2, 0.2]\n',
     5, "synthetic.sigma_r_m lists 0.2 twice"),
])
def test_bad_sweep_file_is_refused_with_file_and_line(tmp_path, capsys, text, line, words):
    path = _file(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        parse_sweep(path)
    assert e.value.line == line and words in str(e.value)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{path}:{line}:" in err[0]
    assert not (tmp_path / "o").exists()  # refused before any run


def test_seeds_on_a_pose_graph_solve_are_refused_before_any_run(tmp_path, capsys):
    """A pose-graph solve draws no random numbers (run refuses --seed on it): seeds in a sweep
    of one were every run's failure; a filter streaming the same file takes them."""
    (tmp_path / "g.g2o").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                                    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    path = _file(tmp_path, '[sweep]\ndataset = ["g.g2o"]\nbackend = ["isam2"]\nseed = [0, 1]\n')
    with pytest.raises(ConfigError) as e:
        parse_sweep(path)
    assert e.value.line == 4 and "isam2 on" in str(e.value) and "pose-graph solve" in str(e.value)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    streamed = _file(tmp_path, '[sweep]\ndataset = ["g.g2o"]\nbackend = ["fastslam1"]\nseed = [0, 1]\n')
    assert [r.seed for r in parse_sweep(streamed).runs()] == [0, 1]


@pytest.mark.parametrize("key", ["synthetic.seed", "fastslam.seed"])
def test_a_swept_key_that_seed_sets_is_refused_beside_sweep_seed(tmp_path, capsys, key):
    """Tenth hostile pass: with [sweep] seed every run gets --seed, which set
    synthetic.seed whatever [sweep.set] said: three runs labelled 1, 2, 3 gave one ATE."""
    text = ('[sweep]\ndataset = ["synthetic"]\nbackend = ["fastslam1"]\nseed = [0]\n'
            f'[sweep.set]\n"{key}" = [1, 2, 3]\n')
    path = _file(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        parse_sweep(path)
    assert e.value.line == 6 and f"[sweep] seed gives every run --seed, which sets {key}" in str(e.value)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    # without [sweep] seed the key is the one seed of the runs, and is swept
    alone = _file(tmp_path, text.replace("seed = [0]\n", ""))
    assert len(parse_sweep(alone).runs()) == 3


#: A dataset that exists (a sweep checks that first) and fails in its run.
BAD_GRAPH = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 oops 0 0\n"


def test_failing_run_is_recorded_and_the_sweep_goes_on(tmp_path):
    (tmp_path / "bad.g2o").write_text(BAD_GRAPH)
    spec = parse_sweep(_file(tmp_path, SMALL.replace('["synthetic"]', '["synthetic", "bad.g2o"]')
                             .replace("seed = [0, 1]\n", "")))
    outcome = run_sweep(spec, tmp_path / "o", PoolExecutor(2))
    rows = {Path(r["dataset"]).name: r for r in _csv(tmp_path / "o" / "sweep.csv")}
    assert outcome.ran == 4 and outcome.failed == 2
    assert rows["synthetic"]["status"] == "ok" and float(rows["synthetic"]["ate_rmse_m"]) > 0
    # the map's columns: the synthetic world has landmark truth, so they are filled
    ok = rows["synthetic"]
    assert int(ok["landmarks"]) > 0 and float(ok["map_rmse_m"]) > 0
    assert 0 <= int(ok["landmarks_recovered"]) <= int(ok["landmarks_true"])
    bad = rows["bad.g2o"]
    assert bad["map_rmse_m"] == "" and bad["landmarks_recovered"] == ""
    assert bad["status"] == "failed" and "bad.g2o:2:" in bad["error"]
    assert "\n" not in bad["error"]


def test_a_sweep_with_a_failed_run_exits_1(tmp_path, capsys):
    (tmp_path / "bad.g2o").write_text(BAD_GRAPH)
    # nees stated: unset, a mixed grid's default (off) is said in a line of its own
    path = _file(tmp_path, SMALL.replace('["synthetic"]', '["synthetic", "bad.g2o"]')
                 .replace("seed = [0, 1]\n", "nees = false\n"))
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "2",
                 "--quiet", "--no-plots"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["graphslam: warning: 2 of 4 runs failed; their errors are in sweep.csv"]


def test_ctrl_c_keeps_finished_runs_and_a_rerun_resumes(tmp_path):
    """Ctrl-C arrives in the main thread right after the first run finished (the
    progress callback raises it); the next invocation runs only what is missing."""
    spec = parse_sweep(_file(tmp_path, SMALL))
    out = tmp_path / "o"

    def ctrl_c(run, row):
        raise KeyboardInterrupt

    first = run_sweep(spec, out, PoolExecutor(1), on_result=ctrl_c)
    assert first.interrupted and first.ran == 1
    kept = _csv(out / "sweep.csv")
    assert len(kept) == 1 and kept[0]["status"] == "ok"

    second = run_sweep(spec, out, PoolExecutor(2))
    assert not second.interrupted and second.skipped == 1 and second.ran == 3
    rows = _csv(out / "sweep.csv")
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows)
    assert rows[0] == kept[0]  # the finished run is kept as it was, not run again

    third = run_sweep(spec, out, PoolExecutor(2))
    assert third.ran == 0 and third.skipped == 4


@pytest.mark.slow
def test_ctrl_c_to_a_local_dask_sweep_is_one_line(tmp_path):
    """Tenth hostile pass: Ctrl-C in a terminal (SIGINT to the whole process group) during
    a ``--cluster local`` sweep printed the Dask worker processes' two tracebacks and
    Dask's WARNING lines before the sweep's own line. The rows were and are kept."""
    pytest.importorskip("distributed")
    out = tmp_path / "o"
    proc = subprocess.Popen(
        [sys.executable, "-m", "graphslam.cli.main", "sweep", str(_file(tmp_path, SMALL)),
         "--out", str(out), "--cluster", "local", "--workers", "1", "--quiet", "--no-plots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    deadline = time.monotonic() + 120  # s: generous on a loaded machine
    while not ((out / "sweep.csv").is_file() and _csv(out / "sweep.csv")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("graphslam: interrupted; sweep.csv keeps every finished run"), err
    assert all(r["status"] == "ok" for r in _csv(out / "sweep.csv"))


def test_sigint_to_the_sweep_process_keeps_finished_runs(tmp_path):
    """The real signal: SIGINT to a ``graphslam sweep`` process once its first run is
    in sweep.csv; it stops the run in flight and exits 130 with the finished rows."""
    out = tmp_path / "o"
    proc = subprocess.Popen(
        [sys.executable, "-m", "graphslam.cli.main", "sweep", str(_file(tmp_path, SMALL)),
         "--out", str(out), "--workers", "1", "--quiet", "--no-plots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    deadline = time.monotonic() + 120  # s: generous on a loaded machine
    while not ((out / "sweep.csv").is_file() and _csv(out / "sweep.csv")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.02)  # polling for the first row, not waiting a guessed time
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    rows = _csv(out / "sweep.csv")
    assert 1 <= len(rows) < 4 and all(r["status"] == "ok" for r in rows)
    # the summary names the runs left (it said only that the finished ones were kept)
    done = {r["run_id"] for r in rows}
    left = [r.run_id for r in parse_sweep(out.parent / "sweep.toml").runs() if r.run_id not in done]  # grid order
    assert f"; {len(left)} not run to the end ({', '.join(left)}): the same command runs them" in err, err


def test_cli_sweep_writes_table_and_plots(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["sweep", str(_file(tmp_path, SMALL.replace("[0, 1]", "{from = 0, to = 1}"))),
                 "--out", str(out), "--workers", "2", "--quiet"]) == 0
    rows = _csv(out / "sweep.csv")
    assert len(rows) == 4 and {r["backend"] for r in rows} == {"isam2", "ekf"}
    assert {r["ekf.association"] for r in rows if r["backend"] == "ekf"} == {"unknown"}
    assert all(r["nees_mean"] and r["rpe_trans_rmse_m"] and float(r["peak_rss_mb"]) > 0
               for r in rows)
    for name in ("sweep_nees.png", "sweep_ate.png"):
        assert (out / name).stat().st_size > 0
    assert "4 runs" in capsys.readouterr().out


def test_image_sequence_grid_reads_the_visual_sections(tmp_path):
    spec = parse_sweep(_file(tmp_path, """\
[sweep]
dataset = ["synthetic-images"]
backend = ["isam2", "ekf"]
[sweep.set]
"active_search.order" = ["batch", "sequential"]
"mono_ekf.landmark_param" = ["idp", "ahp"]
"synthetic_images.n_frames" = [40]
"""))
    assert not spec.nees  # image-sequence runs write no nees.csv
    runs = spec.runs()
    # iSAM2 does not read [mono_ekf]: 2 runs for it, 4 for the EKF
    assert sorted(r.backend for r in runs) == ["ekf"] * 4 + ["isam2"] * 2
    assert all(r.config["synthetic_images"] == {"n_frames": 40} for r in runs)
    assert all(("mono_ekf" in r.config) == (r.backend == "ekf") for r in runs)


@pytest.mark.slow
def test_cli_sweep_over_an_image_sequence(tmp_path, capsys):
    # two back ends on 12 frames of the synthetic image sequence, each run a real
    # `graphslam run` in its own process: ATE and RPE scored from its files
    out = tmp_path / "o"
    path = _file(tmp_path, """\
[sweep]
dataset = ["synthetic-images"]
backend = ["isam2", "ekf"]
max_steps = 12
[sweep.set]
"synthetic_images.n_frames" = [12]
""")
    assert main(["sweep", str(path), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    rows = _csv(out / "sweep.csv")
    assert sorted(r["backend"] for r in rows) == ["ekf", "isam2"]
    assert all(r["status"] == "ok" and float(r["ate_rmse_m"]) >= 0.0 and r["rpe_trans_rmse_m"]
               and not r["nees_mean"] for r in rows), rows
    assert (out / "sweep_ate.png").stat().st_size > 0
    assert "2 runs" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--workers", "0"],
                                  ["--workers", "2", "--cluster", "tcp://127.0.0.1:1"]])
def test_workers_refused_where_they_do_nothing(tmp_path, capsys, argv):
    assert main(["sweep", str(_file(tmp_path, SMALL)), "--out", str(tmp_path / "o"), *argv]) == 2
    assert "--workers" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
# "not a url" (issue 34) was a ValueError traceback
@pytest.mark.parametrize("address", ["tcp://127.0.0.1:1", "not a url"])
def test_a_cluster_that_cannot_be_reached_is_one_line(tmp_path, capsys, address):
    pytest.importorskip("distributed")
    assert main(["sweep", str(_file(tmp_path, SMALL)), "--out", str(tmp_path / "o"),
                 "--cluster", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--cluster {address}: cannot connect" in err[0]


def test_max_runs_raises_the_cap(tmp_path):
    text = ('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = {from = 0, to = 10000}\n'
            'max_runs = 10001\n')
    assert len(parse_sweep(_file(tmp_path, text)).runs()) == 10001


def test_the_pool_queues_two_runs_a_worker_not_the_grid(tmp_path, monkeypatch):
    """A stop leaves nothing queued behind it: at most 2 x workers runs submitted."""
    import graphslam.pipelines.sweep_exec as sweep_exec

    started = []
    monkeypatch.setattr(sweep_exec, "execute_run",
                        lambda run, root: started.append(run) or {"status": "ok"})
    runs = parse_sweep(_file(tmp_path, '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n'
                                       'seed = {from = 0, to = 99}\n')).runs()
    results = PoolExecutor(2).map_unordered(runs, tmp_path)
    next(results)
    assert len(started) <= 4
    results.close()
    assert len(started) <= 4


@pytest.mark.slow
def test_local_dask_cluster_gives_the_pool_results(tmp_path):
    """A real LocalCluster with two worker processes against the local pool: same
    rows (timings aside) and the same trajectories, to the byte."""
    pytest.importorskip("distributed")
    from graphslam.pipelines.sweep_exec import DaskExecutor

    spec = parse_sweep(_file(tmp_path, SMALL))
    dask = DaskExecutor("local", 2)
    try:
        run_sweep(spec, tmp_path / "dask", dask)
    finally:
        dask.close()
    run_sweep(spec, tmp_path / "pool", PoolExecutor(2))
    a, b = _csv(tmp_path / "dask" / "sweep.csv"), _csv(tmp_path / "pool" / "sweep.csv")
    assert len(a) == 4 and all(r["status"] == "ok" for r in a)
    assert _without_timing(a) == _without_timing(b)
    for r in a:
        for name in ("trajectory.tum", "nees.csv"):
            assert ((tmp_path / "dask" / "runs" / r["run_id"] / name).read_bytes()
                    == (tmp_path / "pool" / "runs" / r["run_id"] / name).read_bytes())


def test_run_config_file_reads_back_as_written():
    import tomllib

    from graphslam.pipelines.sweep_spec import dump_toml

    config = {"ekf": {"association": "unknown", "odometry_covariance_scale": 1e-05,
                      "flag": True, "n": 3},
              "loops": {"top_k": 5, "orb": {"n_features": 500, "sizes": [1.5, 2]}}}
    assert tomllib.loads(dump_toml(config)) == config


def test_nees_defaults_to_the_synthetic_world_only(tmp_path):
    def spec(datasets, extra=""):
        return parse_sweep(_file(tmp_path, f'[sweep]\ndataset = {datasets}\nbackend = ["ekf"]\n{extra}'))

    assert spec('["synthetic"]').nees and not spec('["victoria-park"]').nees
    assert not spec('["synthetic"]', "nees = false\n").nees
    with pytest.raises(ConfigError):
        spec('["synthetic"]', 'nees = "yes"\n')
    on, off = spec('["synthetic"]').runs()[0], spec('["synthetic"]', "nees = false\n").runs()[0]
    assert on.config_hash != off.config_hash  # a resumed sweep never mixes the two


def test_progress_bar_counts_runs_and_failures(tmp_path, monkeypatch, capsys):
    import io

    class Tty(io.StringIO):
        def isatty(self):  # tqdm draws only on a terminal
            return True

    fake = Tty()
    monkeypatch.setattr("sys.stderr", fake)
    (tmp_path / "bad.g2o").write_text("not a pose graph\n")  # exists, so the run starts and fails
    path = _file(tmp_path, '[sweep]\ndataset = ["bad.g2o"]\nbackend = ["ekf"]\n')
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1"]) == 1
    bar = fake.getvalue()
    assert "1/1" in bar and "failed=1" in bar


def test_the_documented_visual_sweep_examples_run_clean(tmp_path, capsys):
    """The visual sweep examples of the README and the docs exit 0 with every run ok (the search-order example
    failed 2 of its 8 runs by design and exited 1); frames cut to 5 to keep it short."""
    import re
    from pathlib import Path

    pages = [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]
    text = "".join(p.read_text(encoding="utf-8") for p in pages)
    examples = sorted(set(re.findall(r"graphslam sweep (benchmarks/sweep_visual\S*\.toml)", text)))
    assert examples, "the docs name no visual sweep example"
    for name in examples:
        text = (ROOT / name).read_text(encoding="utf-8")
        short = tmp_path / Path(name).name
        short.write_text(re.sub(r"(?m)^max_steps = \d+", "max_steps = 5", text))
        out = tmp_path / Path(name).stem
        assert main(["sweep", str(short), "--out", str(out), "--quiet"]) == 0, \
            capsys.readouterr().err
        with open(out / "sweep.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert rows and all(r["status"] == "ok" for r in rows)


def test_a_dataset_path_is_read_beside_the_sweep_file_and_checked_first(tmp_path, monkeypatch):
    """Like ``config``, a dataset path is the sweep file's (the hostile pass ran one from
    another folder: every row failed "no such dataset"); a missing one is refused with the
    file and line before any run."""
    from graphslam.pipelines.sweep_spec import parse_sweep

    (tmp_path / "in").mkdir()
    (tmp_path / "g.g2o").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    sweep = tmp_path / "in" / "s.toml"
    sweep.write_text('[sweep]\ndataset = ["../g.g2o", "synthetic"]\nbackend = ["ekf"]\n')
    monkeypatch.chdir(tmp_path / "in")
    assert parse_sweep(sweep).datasets == (str(tmp_path / "in" / ".." / "g.g2o"), "synthetic")
    sweep.write_text('[sweep]\ndataset = ["g.g2o"]\nbackend = ["ekf"]\n')
    monkeypatch.chdir(tmp_path)  # g.g2o is here, not beside the sweep file
    with pytest.raises(ConfigError, match=r"s.toml:2: \[sweep\] no such dataset or file 'g.g2o'"):
        parse_sweep(sweep)


def test_a_runs_warnings_reach_its_row(tmp_path):
    # an ok row can hold a doubtful estimate: metrics.json's warnings go in the table
    from graphslam.pipelines.sweep_exec import _scores

    (tmp_path / "metrics.json").write_text('{"ate_rmse_m": 9.0, "warnings": ["ATE absurd", "half scored"]}')
    assert _scores(tmp_path)["warnings"] == "ATE absurd | half scored"
    (tmp_path / "metrics.json").write_text('{"ate_rmse_m": 0.1, "warnings": null}')
    assert _scores(tmp_path)["warnings"] == ""


def test_a_sweep_says_how_many_finished_runs_carry_warnings(tmp_path, monkeypatch, capsys):
    from graphslam.pipelines import sweep_exec

    def fake(run, root):  # the first run's estimate is doubtful, the second's is not
        said = "ATE 40 m is more than 10x the odometry's" if run.seed == 0 else ""
        return {"run_id": run.run_id, "status": "ok", "error": "", "warnings": said}

    monkeypatch.setattr(sweep_exec, "execute_run", fake)
    path = _file(tmp_path, '[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0, 1]\n')
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1",
                 "--quiet", "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert "graphslam: warning: 1 of 2 finished runs carry warnings" in err
    rows = _csv(tmp_path / "o" / "sweep.csv")
    assert sorted(r["warnings"] for r in rows) == ["", "ATE 40 m is more than 10x the odometry's"]


def _server(reply: bytes | None):
    """A TCP server on a free local port that accepts and sends ``reply`` (None: says
    nothing, holds the connection); ``(address, stop)``."""
    import socket
    import threading

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    held = []

    def serve():
        while True:
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            if reply is None:
                held.append(conn)
            else:
                conn.sendall(reply)
                conn.close()

    threading.Thread(target=serve, daemon=True).start()
    return f"tcp://127.0.0.1:{sock.getsockname()[1]}", sock.close


@pytest.mark.parametrize("reply, words", [
    (b"SSH-2.0-OpenSSH_9.6\r\n" * 4, "cannot connect (MemoryError"),
    (None, "cannot connect (no answer in 2 s: not a Dask scheduler?)"),
])
def test_a_server_that_is_no_scheduler_is_one_line(tmp_path, capsys, monkeypatch, reply, words):
    """Tenth hostile pass: a server answering SSH's banner ended --cluster in a 3 EiB
    MemoryError traceback; an HTTP server (never answering Dask's handshake) hung it."""
    pytest.importorskip("distributed")
    from graphslam.pipelines import sweep_exec

    monkeypatch.setattr(sweep_exec, "CONNECT_TIMEOUT_S", 2.0)
    address, stop = _server(reply)
    try:
        assert main(["sweep", str(_file(tmp_path, SMALL)), "--out", str(tmp_path / "o"),
                     "--cluster", address]) == 2
    finally:
        stop()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--cluster {address}: {words}" in err[0], err


def test_workers_beyond_the_runs_are_not_started(tmp_path, monkeypatch):
    """Tenth hostile pass: ``--workers 1000000 --cluster local`` started a LocalCluster of a
    million workers (memory grew, no run began); the pool already capped them at the runs."""
    from graphslam.pipelines import sweep_exec

    asked = []

    class Fake:
        def __init__(self, address, workers):
            asked.append(workers)
            raise ConfigError("stop here")

    monkeypatch.setattr(sweep_exec, "DaskExecutor", Fake)
    path = _file(tmp_path, SMALL)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1000000",
                 "--cluster", "local"]) == 2
    assert asked == [len(parse_sweep(path).runs())] == [4]


def test_an_image_runs_row_takes_its_own_rpe_and_alignment(tmp_path):
    """A monocular run's RPE scored from its files ignored its Sim(3) scale: 0.2155 in
    sweep.csv against the run's own 0.0475 (thirteenth hostile pass)."""
    import json

    from graphslam.pipelines.sweep_exec import _scores

    (tmp_path / "metrics.json").write_text(json.dumps({
        "ate_rmse_m": 0.0773, "alignment": "sim3", "wall_s": 1.5,
        "rpe": {"trans_rmse_m": 0.0475, "rot_rmse_deg": 0.12, "delta_frames": 1}}))
    (tmp_path / "ground_truth.tum").write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    (tmp_path / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n1 5 0 0 0 0 0 1\n")
    row = _scores(tmp_path)
    assert (row["rpe_trans_rmse_m"], row["rpe_rot_rmse_deg"]) == (0.0475, 0.12)
    assert (row["ate_alignment"], row["run_wall_s"]) == ("sim3", 1.5)


def test_plot_groups_keep_datasets_and_back_ends_apart():
    """One "ekf" box averaged a synthetic run with a real robot's, and a swept value's
    box pooled iSAM2 with the EKF (thirteenth hostile pass)."""
    from graphslam.pipelines.sweep import with_labels
    from graphslam.visualisation.plots import _setting_group

    rows = [{"backend": "ekf", "dataset": "synthetic", "x.k": 1},
            {"backend": "ekf", "dataset": "/data/mrclam6", "x.k": 1}]
    labels = [r["label"] for r in with_labels(rows, ["x.k"])]
    assert labels == ["ekf k=1 synthetic", "ekf k=1 mrclam6"]
    assert with_labels(rows[:1], ["x.k"])[0]["label"] == "ekf k=1"
    assert _setting_group({**rows[0], "backend": "isam2"}, "x.k", False) != _setting_group(rows[0], "x.k", False)


def test_a_local_cluster_without_file_descriptors_is_one_line(tmp_path):
    """``ulimit -n 20``: Dask's LocalCluster cannot start; its event loop's some 170
    lines of tracebacks became one line naming the limit."""
    pytest.importorskip("distributed")
    import resource

    def low_limit():
        resource.setrlimit(resource.RLIMIT_NOFILE, (20, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    done = subprocess.run(
        [sys.executable, "-m", "graphslam.cli.main", "sweep", str(_file(tmp_path, SMALL)),
         "--out", str(tmp_path / "o"), "--cluster", "local", "--workers", "2", "--quiet"],
        capture_output=True, text=True, timeout=120, preexec_fn=low_limit,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "graphslam: error: --cluster local: cannot start the local cluster "
        "(too many open files; ulimit -n is 20)"
    ], done.stderr


def test_a_done_run_whose_folder_is_gone_or_foreign_is_run_again(tmp_path):
    """sweep.csv's word is not the run's files: a run folder deleted, or written over by
    another run (another seed), was skipped as done and its files plotted."""
    import json
    import shutil

    from graphslam.pipelines.sweep import folder_mismatch

    spec = parse_sweep(_file(tmp_path, SMALL))
    out = tmp_path / "o"
    run_sweep(spec, out, PoolExecutor(2))
    gone, foreign, *kept = spec.runs()
    shutil.rmtree(out / "runs" / gone.run_id)
    metrics_path = out / "runs" / foreign.run_id / "metrics.json"
    metrics = json.loads(metrics_path.read_text())
    command = metrics["provenance"]["command"]
    command[command.index("--seed") + 1] = "9"
    metrics_path.write_text(json.dumps(metrics))

    again = run_sweep(spec, out, PoolExecutor(2))
    assert again.ran == 2 and again.skipped == 2
    assert dict(again.stale) == {
        gone.run_id: "no metrics.json in its folder",
        foreign.run_id: "its folder holds another run (other --seed)",
    }
    assert all(folder_mismatch(run, out / "runs" / run.run_id) is None for run in spec.runs())


def test_a_sweep_whose_folder_is_moved_stops_in_one_line_and_resumes_there(tmp_path, monkeypatch, capsys):
    """The folder moved while the sweep ran: the next runs and sweep.csv went into a new
    folder at the old path, the sweep split in two without a word."""
    from graphslam.pipelines import sweep_exec

    out, moved = tmp_path / "o", tmp_path / "moved"

    def fake(run, root):  # the user moves the folder as the first run ends
        (Path(root) / "runs" / run.run_id).mkdir(parents=True, exist_ok=True)
        if run.seed == 0:
            out.rename(moved)
        return {"run_id": run.run_id, "status": "ok", "error": ""}

    monkeypatch.setattr(sweep_exec, "execute_run", fake)
    path = _file(tmp_path, '[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0, 1, 2]\n')
    argv = ["sweep", str(path), "--workers", "1", "--quiet", "--no-plots"]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"was moved to {moved} while the sweep ran" in err[0]
    assert f"run the sweep again with --out {moved}" in err[0]
    assert not (out / "sweep.csv").exists()  # nothing of the table at the old path
    monkeypatch.setattr(sweep_exec, "execute_run",
                        lambda run, root: {"run_id": run.run_id, "status": "ok", "error": ""})
    assert main([*argv, "--out", str(moved)]) == 0
    assert len(_csv(moved / "sweep.csv")) == 3


@pytest.mark.parametrize(("dataset", "key", "hint"), [
    ("synthetic", "sigma_r_m", '"synthetic.sigma_r_m" = [...]'),
    ("synthetic", "association", '"isam2.association" = [...]'),
    ("synthetic", "frobnicate", None),
])
def test_a_sections_setting_in_sweep_points_to_sweep_set(tmp_path, dataset, key, hint):
    """``robot = [1, 2]`` or ``sigma_r_m = [...]`` in [sweep] was refused naming the sweep's own
    keys only; a setting of a section these runs read is named as [sweep.set] takes it."""
    path = tmp_path / "s.toml"
    path.write_text(f'[sweep]\ndataset = ["{dataset}"]\nbackend = ["isam2"]\n{key} = [1]\n')
    with pytest.raises(ConfigError) as info:
        parse_sweep(path)
    words = str(info.value)
    assert f"unknown key '{key}' in [sweep]" in words
    if hint is None:
        assert "[sweep.set]:" not in words
    else:
        assert words.endswith(f"a section's setting is swept under [sweep.set]: {hint}")


def test_a_local_cluster_starts_after_a_malformed_address_and_beside_port_8787(tmp_path, capsys):
    """After ``--cluster "not a url"`` in a process, its next LocalCluster never started
    (Dask's loop left behind: AssertionError after 10 s; CI met it when xdist ran the two
    tests in one worker); and a second local cluster of the machine warned "Port 8787 is
    already in use" (the scheduler's HTTP server on Dask's default port) into a sweep's stderr."""
    pytest.importorskip("distributed")
    import socket
    import warnings

    from graphslam.pipelines.sweep_exec import DaskExecutor, _connect

    assert main(["sweep", str(_file(tmp_path, SMALL)), "--out", str(tmp_path / "o"),
                 "--cluster", "not a url"]) == 2
    assert "--cluster not a url: cannot connect (ValueError: missing port number" in capsys.readouterr().err
    # the mechanism: a malformed address never reaches a Client (whose failed start in a
    # thread is what left the loop behind; the order that showed it is xdist's to choose)
    made = []
    with pytest.raises(ConfigError, match="missing port number"):
        _connect(lambda *a, **k: made.append(a), "tcp://host")
    assert made == []
    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            taken.bind(("127.0.0.1", 8787))
            taken.listen()
        except OSError:
            pass  # another process holds it: the case itself
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            dask = DaskExecutor("local", 1)
            dask.close()
    assert not [w for w in seen if "8787" in str(w.message)], [str(w.message) for w in seen]


def test_a_figure_edited_in_sweep_csv_is_read_again_from_the_runs_files(tmp_path):
    """A resumed sweep trusted sweep.csv's rows: an ATE edited by hand was carried forward
    as the run's (nineteenth hostile pass). The files' figures are kept and the rows named."""
    from graphslam.pipelines.sweep import write_rows
    from graphslam.pipelines.sweep_exec import score_finished

    spec = parse_sweep(_file(tmp_path, SMALL))
    out = tmp_path / "o"
    run_sweep(spec, out, PoolExecutor(2), score_finished=score_finished)
    rows = _csv(out / "sweep.csv")
    true_ate = rows[1]["ate_rmse_m"]
    rows[1]["ate_rmse_m"] = "0.000001"
    rows[2]["wall_s"] = "123.0"  # the sweep's own measure: no file holds it, kept
    write_rows(out / "sweep.csv", list(rows[0]), rows)
    again = run_sweep(spec, out, PoolExecutor(2), score_finished=score_finished)
    assert again.ran == 0 and again.edited == [rows[1]["run_id"]]
    now = _csv(out / "sweep.csv")
    assert now[1]["ate_rmse_m"] == true_ate and now[2]["wall_s"] == "123.0"
    assert run_sweep(spec, out, PoolExecutor(2), score_finished=score_finished).edited == []
