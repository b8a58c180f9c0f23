"""``graphslam sweep`` (seventh hostile pass): values each run would refuse are refused
before any run, and an output folder that holds something else than this sweep (an
earlier sweep's rows and plots, a file of our name that is no sweep table) is said,
cleaned or refused, never mixed silently into the new table.

Runs are faked (``execute_run``): the folder's handling is under test, not the runs.
"""

from __future__ import annotations

import csv

import pytest

from graphslam.cli.main import main
from graphslam.pipelines.sweep_spec import parse_sweep
from slamcore.errors import ConfigError

BASE = '[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nmax_steps = 5\n'


def _file(tmp_path, text, name="sweep.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture
def fake_runs(monkeypatch):
    """Every run "ok" at once, without a process; its folder holds the metrics.json a run
    writes, as much of it as says which run it was (a re-run sweep checks it)."""
    import hashlib
    import json
    from pathlib import Path

    from graphslam.pipelines import sweep_exec
    from graphslam.pipelines.sweep_spec import dump_toml
    from graphslam.pipelines.provenance import code_identity

    def fake(run, root):
        folder = Path(root) / "runs" / run.run_id
        folder.mkdir(parents=True, exist_ok=True)
        provenance = {
            "command": ["graphslam", *sweep_exec.run_command(run, folder)[3:]],
            "config_sha256": hashlib.sha256(dump_toml(run.config).encode("utf-8")).hexdigest(),
            **code_identity(),  # the code that made it, as a run records it
        }
        # the figures the row says too: a resumed sweep reads them again from the files
        (folder / "metrics.json").write_text(json.dumps({"provenance": provenance, "ate_rmse_m": 0.1}))
        (folder / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n")  # a run without it is not done
        return {"run_id": run.run_id, "status": "ok", "error": "", "warnings": "", "ate_rmse_m": 0.1}

    monkeypatch.setattr(sweep_exec, "execute_run", fake)


def _sweep(path, out, *extra):
    return main(["sweep", str(path), "--out", str(out), "--workers", "1", "--quiet", *extra])


@pytest.mark.parametrize(
    ("line", "words"),
    [
        ("max_steps = true", "max_steps must be a whole number"),
        ("seed = [0, -1]", "seed -1 is outside 0 to 2**62"),
        ("seed = [9223372036854775807]", "seed 9223372036854775807 is outside"),
        ("seed = {from = -3, to = 2}", "seed -3 is outside"),
    ],
)
def test_values_every_run_would_refuse_are_refused_with_file_and_line(tmp_path, line, words):
    text = '[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\n' + line + "\n"
    with pytest.raises(ConfigError) as e:
        parse_sweep(_file(tmp_path, text))
    assert words in str(e.value) and "sweep.toml:4" in str(e.value)


def test_one_dataset_file_spelt_twice_is_refused(tmp_path):
    (tmp_path / "g.g2o").write_text("VERTEX_SE2 0 0 0 0\n")
    text = '[sweep]\ndataset = ["g.g2o", "./g.g2o"]\nbackend = ["isam2"]\n'
    with pytest.raises(ConfigError, match="g.g2o' twice"):
        parse_sweep(_file(tmp_path, text))


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"\xff\xfe\x00junk\n", "not a sweep table that can be read"),
        (b"run_id,status\n" + b"x" * 200_000 + b",ok\n", "field larger than field limit"),
        (b"name,score\nalice,3\n", "not a table of graphslam sweep"),
    ],
)
def test_a_sweep_csv_that_is_no_sweep_table_is_refused_untouched(tmp_path, capsys, fake_runs, content, words):
    out = tmp_path / "o"
    out.mkdir()
    (out / "sweep.csv").write_bytes(content)
    assert _sweep(_file(tmp_path, BASE), out) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("graphslam: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert words in lines[0] and "sweep.csv" in lines[0]
    assert (out / "sweep.csv").read_bytes() == content and not (out / "runs").exists()


def test_an_empty_sweep_csv_is_no_earlier_run(tmp_path, fake_runs):
    out = tmp_path / "o"
    out.mkdir()
    (out / "sweep.csv").write_text("")
    assert _sweep(_file(tmp_path, BASE), out, "--no-plots") == 0


def test_another_sweep_into_the_folder_says_what_left_the_table(tmp_path, capsys, fake_runs):
    out = tmp_path / "o"
    first = _file(tmp_path, BASE + "seed = [0, 1]\n", "first.toml")
    assert _sweep(first, out, "--no-plots") == 0
    capsys.readouterr()
    assert _sweep(first, out, "--no-plots") == 0  # the same sweep again: resumed, nothing said
    assert "warning" not in capsys.readouterr().err
    second = _file(tmp_path, BASE + "seed = [1, 2]\n", "second.toml")
    assert _sweep(second, out, "--no-plots") == 0
    err = capsys.readouterr().err
    assert "held 1 rows of runs that are not in this sweep" in err
    with open(out / "sweep.csv", newline="") as f:
        assert sorted(r["seed"] for r in csv.DictReader(f)) == ["1", "2"]


def test_an_earlier_sweeps_plots_do_not_outlive_it(tmp_path, fake_runs):
    out = tmp_path / "o"
    swept = BASE.replace('["isam2"]', '["ekf"]') + '[sweep.set]\n"ekf.association" = ["known", "unknown"]\n'
    assert _sweep(_file(tmp_path, swept, "a.toml"), out) == 0
    assert {"sweep_ate.png", "sweep_ekf.association.png"} <= {p.name for p in out.iterdir()}
    (out / "sweep_notes.png").write_bytes(b"the user's")  # not a name of ours: kept
    assert _sweep(_file(tmp_path, BASE, "b.toml"), out) == 0
    names = {p.name for p in out.iterdir()}
    assert "sweep_ekf.association.png" not in names and "sweep_ate.png" in names
    assert _sweep(_file(tmp_path, BASE, "b.toml"), out, "--no-plots") == 0
    assert not {n for n in (p.name for p in out.iterdir()) if n != "sweep_notes.png" and n.endswith(".png")}
    assert (out / "sweep_notes.png").read_bytes() == b"the user's"


def test_a_cluster_start_failure_whose_causes_loop_is_still_one_line():
    """The chain of causes is walked for EMFILE; a chain that loops back ends the walk."""
    from graphslam.pipelines.sweep_exec import _start_failure

    first, second = RuntimeError("first"), RuntimeError("second")
    first.__context__, second.__context__ = second, first
    assert _start_failure(first) == "RuntimeError: first"
    caught = RuntimeError("wrapped")
    caught.__cause__ = OSError(24, "Too many open files")
    assert _start_failure(caught).startswith("too many open files; ulimit -n is ")
