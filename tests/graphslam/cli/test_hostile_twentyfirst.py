"""The twenty-first hostile pass (run management: sweeps, the working folder): each test
reproduces a finding, then checks what the toolkit does now."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.pipelines.sweep import folder_mismatch, nees_series
from graphslam.pipelines.sweep_spec import parse_sweep, run_config_file

SWEEP = '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nseed = [0]\nmax_steps = 20\nnees = false\n'


def test_a_deleted_working_folder_is_one_line(tmp_path, monkeypatch, capsys):
    """Every command ended in chained tracebacks (FileNotFoundError of os.getcwd)."""
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    for argv in (["run", "--dataset", "synthetic", "--max-steps", "5", "--rerun", "off"], ["eval", "a", "b"]):
        assert main(argv) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line == "graphslam: error: the working folder was deleted (a shell still in it): cd to a folder that exists"


def test_a_yaml_null_and_an_out_folder_named_with_a_dash_run(tmp_path, monkeypatch, capsys):
    """A YAML base config's null was written into each run's config.toml, which no run could
    read (every run failed); a relative --out=-o reached each run as '--config -o/runs/...',
    read as a flag (every run failed). Both as run takes them now."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "base.yaml").write_text("ekf:\n  known_gate_chi2_prob: null\n")
    (tmp_path / "sw.toml").write_text(SWEEP + 'config = "base.yaml"\n')
    assert main(["sweep", "sw.toml", "--out=-o", "--workers", "1", "--quiet", "--no-plots"]) == 0
    (row,) = [ln for ln in (tmp_path / "-o" / "sweep.csv").read_text().splitlines()[1:]]
    assert ",ok," in row
    (run_dir,) = (tmp_path / "-o" / "runs").iterdir()
    assert (run_dir / "config.yaml").read_text() == "ekf:\n  known_gate_chi2_prob: null\n"
    assert main(["sweep", "sw.toml", "--out=-o", "--workers", "1", "--quiet", "--no-plots"]) == 0
    assert "1 already done" in capsys.readouterr().out  # resumed: the YAML's digest is the run's


def test_run_config_file_is_toml_unless_a_setting_is_null():
    assert run_config_file({"ekf": {"gate": 0.5}}) == ("config.toml", "[ekf]\ngate = 0.5\n")
    name, text = run_config_file({"ekf": {"gate": None, "k": [1, 2]}})
    assert name == "config.yaml" and "gate: null" in text


def _done_run(tmp_path: Path):
    """A run folder a resumed sweep takes as done (provenance, metrics, trajectory)."""
    import hashlib

    from graphslam.pipelines.provenance import code_identity
    from graphslam.pipelines.sweep_exec import run_command

    (tmp_path / "s.toml").write_text(SWEEP.replace("nees = false", "nees = true"))
    (run,) = parse_sweep(tmp_path / "s.toml").runs()
    folder = tmp_path / "run"
    folder.mkdir()
    prov = {
        "command": ["graphslam", *run_command(run, folder)[3:]],
        "config_sha256": hashlib.sha256(run_config_file(run.config)[1].encode()).hexdigest(),
        **code_identity(),
    }
    for name in ("trajectory.tum", "nees.csv"):
        (folder / name).write_text("x\n")
    return run, folder, prov


def test_a_resumed_sweep_runs_again_a_stopped_run_or_one_whose_files_are_gone(tmp_path):
    """A run stopped at 643 of 769 steps (interrupted: true), or whose trajectory.tum was
    deleted, was taken as done: its row kept 'ok' with the cut run's ATE, or with its RPE
    emptied."""
    run, folder, prov = _done_run(tmp_path)

    def mismatch(**metrics):
        (folder / "metrics.json").write_text(json.dumps({"provenance": prov, "nees_mean": 3.0, **metrics}))
        return folder_mismatch(run, folder)

    assert mismatch() is None
    assert mismatch(interrupted=True) == "its run was stopped before the end"
    (folder / "nees.csv").unlink()
    assert mismatch() == "its nees.csv is gone"
    (folder / "trajectory.tum").unlink()
    assert mismatch() == "its trajectory.tum and nees.csv is gone"


def test_an_unreadable_nees_file_is_left_out_of_the_plot(tmp_path):
    """An emptied or edited nees.csv of a done run raised IndexError / ValueError in the
    plotting, after every run was done."""
    rows = []
    for k, text in enumerate(("step,pose_id,nees\n0,0,1.0\n1,1,2.0\n", "", "step,pose_id,nees\n0,0,oops\n")):
        folder = tmp_path / "runs" / f"r{k}"
        folder.mkdir(parents=True)
        (folder / "nees.csv").write_text(text)
        rows.append({"run_id": f"r{k}", "status": "ok", "label": "ekf"})
    series, unreadable = nees_series(tmp_path, rows)
    assert unreadable == ["r1", "r2"]
    assert np.array_equal(series["ekf"], [[1.0, 2.0]])


def test_the_runs_get_an_absolute_root_whatever_the_out_given(tmp_path, monkeypatch):
    """A relative --out with --cluster ADDRESS put the runs in the worker's working folder
    (the sweep said 6 ok, its runs/ empty)."""
    from graphslam.pipelines.sweep import run_sweep

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SWEEP)
    roots = []

    class Recorder:
        notes: list[str] = []

        def map_unordered(self, runs, root):
            roots.append(root)
            yield from ()

    run_sweep(parse_sweep(tmp_path / "s.toml"), Path("rel"), Recorder())
    assert roots == [tmp_path / "rel"] and roots[0].is_absolute()


def test_a_scheduler_without_workers_is_said(tmp_path):
    """The sweep waited with no word for a worker that never came."""
    pytest.importorskip("dask.distributed")
    from dask.distributed import LocalCluster

    from graphslam.pipelines.sweep_exec import DaskExecutor

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        executor = DaskExecutor(cluster.scheduler_address, 1)
        try:
            assert executor.notes == [
                f"--cluster {cluster.scheduler_address}: the scheduler has no worker yet; the runs wait "
                f"until one joins (dask worker {cluster.scheduler_address})"
            ]
        finally:
            executor.close()
    assert os.getcwd()


def test_a_nested_tables_error_names_the_table_as_written(tmp_path, capsys, shared_data):
    """[loops.orb] scale_factor = 0.5 was refused as 'orb.scale_factor', the name of
    another table ([orb], the tracker's)."""
    (tmp_path / "c.toml").write_text("[loops.orb]\nscale_factor = 0.5\n")
    folder = shared_data / "slambook2_desk" / "images"
    assert main(["loops", str(folder), "--config", str(tmp_path / "c.toml"), "--out", str(tmp_path / "l.csv")]) == 2
    err = capsys.readouterr().err
    assert "c.toml:2: loops.orb.scale_factor must be > 1.0" in err


def test_a_sweep_whose_runs_would_pass_the_path_limit_is_refused_first(tmp_path, capsys):
    """An --out near the 4 kB limit started the sweep, and every run failed with a cut-off
    'cannot write' line."""
    (tmp_path / "sw.toml").write_text(SWEEP)
    room = 4070 - len(str(tmp_path))
    out = tmp_path.joinpath(*(["d" * 200] * (room // 201)), "e" * max(room % 201 - 1, 1))
    assert main(["sweep", str(tmp_path / "sw.toml"), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "for the runs' files under it: runs/ekf-" in err
    assert not (tmp_path / ("d" * 200)).exists()


def test_an_output_the_user_may_not_replace_is_one_line(tmp_path, monkeypatch, capsys):
    """Hostile pass 22: an immutable run.rrd (or another user's file in a shared folder)
    ended in PermissionError's traceback out of os.replace."""
    import errno

    from slamcore import files
    from slamcore.files import write_error_line

    e = PermissionError(errno.EPERM, "Operation not permitted", str(tmp_path / ".gs-x.part.rrd"), None,
                        str(tmp_path / "run.rrd"))
    assert write_error_line(e) == (f"{tmp_path / 'run.rrd'} cannot be written or replaced "
                                   "(Operation not permitted: another user's, or read-only)")
    real = files.os.replace

    def refuse(src, dst):
        if str(dst).endswith("metrics.json"):
            raise PermissionError(errno.EACCES, "Permission denied", str(src), None, str(dst))
        return real(src, dst)

    monkeypatch.setattr(files.os, "replace", refuse)
    assert main(["run", "--max-steps", "20", "--rerun", "off", "--out", str(tmp_path / "o")]) == 2
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("graphslam: error:")]
    assert "metrics.json cannot be written or replaced (Permission denied" in line
    assert (tmp_path / "o" / "trajectory.tum").is_file()  # the files it could write are kept


@pytest.mark.parametrize("text, line", [("synthetic:\n  1: 2\n  foo: 3\n", 2), ("1: {}\nsynthetic: {}\n", 1)])
def test_a_yaml_key_that_is_no_word_is_refused_with_its_line(tmp_path, text, line):
    """Hostile pass 22: a section mixing 1: with names raised TypeError (sorting its keys);
    alone it was refused without a line."""
    from slamcore.config import ConfigFile
    from slamcore.errors import ConfigError

    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(ConfigError, match=rf"c.yaml:{line}: key 1 in \[.*\] is not a name"):
        ConfigFile.read(tmp_path / "c.yaml")


def test_a_sweeps_base_config_is_checked_with_its_swept_values_before_any_run(tmp_path):
    """Hostile pass 22: a bad value in the base config failed every run, each naming its
    generated config.toml; swept values were checked against the defaults, not the base's,
    so a grid right with the base was refused and one wrong with it failed at run time."""
    from slamcore.errors import ConfigError

    head = '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nmax_steps = 50\nconfig = "base.toml"\n'
    (tmp_path / "base.toml").write_text('[synthetic]\n\nseed = "x"\n')
    (tmp_path / "s.toml").write_text(head)
    with pytest.raises(ConfigError, match=r"base.toml:3: synthetic.seed: expected a number"):
        parse_sweep(tmp_path / "s.toml")
    (tmp_path / "base.toml").write_text("[ekf]\ngate_chi2_prob = 0.9\n")
    (tmp_path / "s.toml").write_text(head + '[sweep.set]\n"ekf.new_landmark_chi2_prob" = [0.95, 0.99]\n')
    assert parse_sweep(tmp_path / "s.toml").set_values == ((0.95, 0.99),)
    (tmp_path / "base.toml").write_text("[synthetic]\nroute_width_m = 15.0\n")
    (tmp_path / "s.toml").write_text(head + '[sweep.set]\n"synthetic.corner_radius_m" = [5.0, 9.0]\n')
    with pytest.raises(ConfigError, match=r"s.toml:7: \[sweep.set\] synthetic.corner_radius_m = 9.0"):
        parse_sweep(tmp_path / "s.toml")


@pytest.mark.parametrize("value, read", [("1:30.0", "90.0"), ("1_0.5", "10.5"), ("0b11", "3")])
def test_yaml_1_1_numbers_are_refused_as_floats_and_binary_too(tmp_path, value, read):
    """Hostile pass 22: the refusal of YAML 1.1 readings held for decimal integers only:
    1:30.0 ran as 90.0, 1_0.5 as 10.5, 0b11 as 3."""
    from slamcore.config import ConfigFile
    from slamcore.errors import ConfigError

    (tmp_path / "c.yaml").write_text(f"synthetic:\n  sensor_range_m: {value}\n")
    with pytest.raises(ConfigError, match=rf"c.yaml:2: '{value}' is not a plain .*reads it as {read}\)"):
        ConfigFile.read(tmp_path / "c.yaml")
    (tmp_path / "c.yaml").write_text("synthetic:\n  sensor_range_m: 12.5\n  dt_s: 1e-1\n")
    assert ConfigFile.read(tmp_path / "c.yaml").data["synthetic"] == {"sensor_range_m": 12.5, "dt_s": 0.1}


def test_a_removed_recording_is_not_said_to_be_one_this_command_never_writes(tmp_path, capsys):
    """Hostile pass 22: '--rerun connect' said an earlier run.rrd was removed as 'this one
    writes no such file', then wrote one when the viewer was never reached."""
    assert main(["run", "--max-steps", "10", "--rerun", "save", "--out", str(tmp_path / "o")]) == 0
    capsys.readouterr()
    assert main(["run", "--max-steps", "10", "--rerun", "off", "--out", str(tmp_path / "o")]) == 0
    said = capsys.readouterr().out
    assert "an earlier command's run.rrd" in said and "a recording only if a viewer it streams to" in said


def test_pose_graph_compare_warms_every_solver_up_before_timing_any(tmp_path, monkeypatch):
    """Hostile pass 22: the first solver named paid the process's one-time costs, and the
    table ranked the solvers by the order they were named."""
    from graphslam.pipelines import compare_posegraph
    from graphslam.sources.posegraph_files import read_pose_graph_file

    g = tmp_path / "chain.g2o"
    g.write_text("".join(f"VERTEX_SE2 {k} {k} 0 0\n" for k in range(10))
                 + "".join(f"EDGE_SE2 {k} {k + 1} 1 0 0 100 0 0 100 0 1000\n" for k in range(9)))
    calls = []
    real = compare_posegraph.run
    monkeypatch.setattr(compare_posegraph, "run", lambda graph, name, config: calls.append(
        (graph.n_poses, name)) or real(graph, name, config))
    compare_posegraph.compare(read_pose_graph_file(g), ["batch", "isam2", "batch"])
    assert calls[:2] == [(4, "batch"), (4, "isam2")]  # each solver once, on the start
    assert calls[2:] == [(10, "batch"), (10, "isam2"), (10, "batch")]


def test_loops_says_when_its_model_leaves_the_camera_unused(tmp_path, capsys, shared_data):
    """Hostile pass 22: --intrinsics under model = "fundamental" ran identical to a run
    without it, unsaid; "essential" without one failed naming neither file nor line."""
    desk = shared_data / "slambook2_desk" / "images"
    (tmp_path / "K.txt").write_text("520 520 319.5 239.5\n")
    (tmp_path / "f.toml").write_text('[loop_verify]\nmodel = "fundamental"\n')
    assert main(["loops", str(desk), "--config", str(tmp_path / "f.toml"), "--intrinsics", str(tmp_path / "K.txt"),
                 "--quiet", "--out", str(tmp_path / "f.csv")]) == 0
    assert 'model = "fundamental" (--config line 2) checks pairs without the camera' in capsys.readouterr().err
    (tmp_path / "e.toml").write_text('[loop_verify]\nmodel = "essential"\n')
    assert main(["loops", str(desk), "--config", str(tmp_path / "e.toml"), "--quiet",
                 "--out", str(tmp_path / "e.csv")]) == 2
    assert 'e.toml:2: [loop_verify] model = "essential" needs the camera' in capsys.readouterr().err


def test_compare_refuses_a_setting_an_entrys_name_replaces(tmp_path, capsys):
    """Hostile pass 22: [mono_ekf] landmark_param = "ahp" under --backends ekf-idp ran idp."""
    (tmp_path / "c.toml").write_text('[mono_ekf]\nlandmark_param = "ahp"\n')
    assert main(["compare", "--dataset", "synthetic-images", "--max-steps", "5", "--rerun", "off", "--config",
                 str(tmp_path / "c.toml"), "--backends", "ekf-idp", "--out", str(tmp_path / "o")]) == 2
    assert "c.toml:2: [mono_ekf] landmark_param = 'ahp' contradicts the compared entry ekf-idp" in capsys.readouterr().err


def test_an_unquoted_dotted_key_in_a_sweeps_set_table_is_the_quoted_one(tmp_path):
    """Hostile pass 22: TOML reads ekf.association = [...] as a table ekf, refused as
    "'ekf': not a section.key" with no line."""
    from slamcore.errors import ConfigError

    head = '[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\nmax_steps = 50\n[sweep.set]\n'
    (tmp_path / "s.toml").write_text(head + 'ekf.association = ["known", "unknown"]\n')
    spec = parse_sweep(tmp_path / "s.toml")
    assert spec.set_keys == ("ekf.association",) and spec.set_values == (("known", "unknown"),)
    (tmp_path / "s.toml").write_text(head + 'ekf.association = ["known", "bogus"]\n')
    with pytest.raises(ConfigError, match=r"s.toml:6: \[sweep.set\] ekf.association = 'bogus'"):
        parse_sweep(tmp_path / "s.toml")
