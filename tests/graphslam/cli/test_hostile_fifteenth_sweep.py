"""The fifteenth hostile pass (repeatability and provenance): each test reproduces a
finding that was silent, then checks what the toolkit does now."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from graphslam.cli.main import main
from graphslam.pipelines.sweep import folder_mismatch
from graphslam.pipelines.sweep_spec import dataset_fingerprint, parse_sweep

ROOT = Path(__file__).resolve().parents[3]


def _kitti_layout(root: Path) -> tuple[Path, Path]:
    """A KITTI download's layout: ``dataset/sequences/07`` and its truth in ``dataset/poses``."""
    seq = root / "dataset" / "sequences" / "07"
    (seq / "image_0").mkdir(parents=True)
    (seq / "image_0" / "000000.png").write_bytes(b"png")
    (seq / "calib.txt").write_text("P0: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    truth = root / "dataset" / "poses" / "07.txt"
    truth.parent.mkdir(parents=True)
    truth.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    return seq, truth


def test_a_sweep_sees_the_kitti_truth_outside_the_swept_folder(tmp_path):
    """A corrected ``dataset/poses/07.txt`` kept the sweep's old runs ("1 already done")."""
    seq, truth = _kitti_layout(tmp_path)
    before = dataset_fingerprint(str(seq))
    truth.write_text("1 0 0 0.5 0 1 0 0 0 0 1 0\n")  # the truth corrected
    assert dataset_fingerprint(str(seq)) != before


def test_a_sweep_sees_the_plaza_range_file_beside_the_log(tmp_path):
    """A new ``Plaza2_TD.txt`` beside ``Plaza2_DR.txt`` kept the sweep's old runs."""
    dr, td = tmp_path / "Plaza2_DR.txt", tmp_path / "Plaza2_TD.txt"
    dr.write_text("0.0 0.1 0.0 0\n")
    td.write_text("0.0 0 1 5.0\n")
    before = dataset_fingerprint(str(dr))
    td.write_text("0.0 0 1 6.5\n")  # ranges of a mis-calibrated radio
    assert dataset_fingerprint(str(dr)) != before


def test_a_sweep_follows_a_linked_image_folder(tmp_path):
    """``image_0`` a link repointed to other images kept the sweep's old runs: ``rglob``
    does not follow linked folders."""
    for name, size in (("a", 3), ("b", 5)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "000000.png").write_bytes(b"x" * size)
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "image_0").symlink_to("../a")
    before = dataset_fingerprint(str(ds))
    (ds / "image_0").unlink()
    (ds / "image_0").symlink_to("../b")
    assert dataset_fingerprint(str(ds)) != before


def test_a_link_back_up_the_tree_is_walked_once(tmp_path):
    from slamcore.input_files import files_below

    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "f.txt").write_text("1")
    (tmp_path / "d" / "up").symlink_to("..")
    assert files_below(tmp_path) == [tmp_path / "d" / "f.txt"]


def test_one_sweep_file_is_one_set_of_runs_from_any_working_directory(tmp_path, monkeypatch):
    """s.toml, swg/s.toml and the absolute path gave three config hashes, three run folders,
    every run made again, a false "another sweep file?" warning and three spellings."""
    swg = tmp_path / "swg"
    swg.mkdir()
    (swg / "w.g2o").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    (swg / "s.toml").write_text('[sweep]\ndataset = ["w.g2o"]\nbackend = ["isam2"]\n')
    runs = []
    for cwd, path in ((swg, "s.toml"), (tmp_path, "swg/s.toml"), (Path("/"), str(swg / "s.toml"))):
        monkeypatch.chdir(cwd)
        runs.append(parse_sweep(path).runs())
    assert [r.config_hash for (r,) in runs] == [runs[0][0].config_hash] * 3
    assert {r.entry for (r,) in runs} == {"w.g2o"}  # sweep.csv's dataset column
    assert {r.dataset for (r,) in runs} == {str(swg / "w.g2o")}  # the same command from anywhere

    # a run recorded with a relative --dataset from another folder is the same run
    (run,) = runs[0]
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n")
    from graphslam.pipelines.sweep_spec import dump_toml
    from graphslam.pipelines.provenance import code_identity

    prov = {
        "command": ["graphslam", "run", "--dataset", "w.g2o", "--backend", "isam2"],
        "cwd": str(swg),
        "config_sha256": __import__("hashlib").sha256(dump_toml(run.config).encode()).hexdigest(),
        **code_identity(),
    }
    (folder / "metrics.json").write_text(json.dumps({"provenance": prov}))
    assert folder_mismatch(run, folder) is None
    prov["cwd"] = str(tmp_path)  # w.g2o read from elsewhere: another file
    (folder / "metrics.json").write_text(json.dumps({"provenance": prov}))
    assert folder_mismatch(run, folder) == "its folder holds another run (other --dataset)"


def test_a_run_folder_made_by_other_code_is_run_again(tmp_path):
    """A sweep re-run after an upgrade kept the old version's results: the run identity
    had no code version."""
    from graphslam.pipelines.sweep_spec import dump_toml
    from graphslam.pipelines.provenance import code_identity

    (tmp_path / "s.toml").write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0]\n')
    (run,) = parse_sweep(tmp_path / "s.toml").runs()
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n")
    from graphslam.pipelines.sweep_exec import run_command

    prov = {
        "command": ["graphslam", *run_command(run, folder)[3:]],
        "config_sha256": __import__("hashlib").sha256(dump_toml(run.config).encode()).hexdigest(),
        **code_identity(),
    }

    def mismatch(**change):
        (folder / "metrics.json").write_text(json.dumps({"provenance": {**prov, **change}}))
        return folder_mismatch(run, folder)

    assert mismatch() is None
    assert mismatch(code_sha256="0" * 64) == (
        f"made by other code (graphslam source 000000000000 -> {prov['code_sha256'][:12]})"
    )
    versions = {**prov["versions"], "gtsam": "4.2"}
    assert mismatch(versions=versions) == f"made by other code (gtsam 4.2 -> {prov['versions']['gtsam']})"
    assert mismatch(versions=None, code_sha256=None) == "made by other code (its metrics.json names no code version)"


def test_the_code_digest_changes_with_any_source_file(tmp_path, monkeypatch):
    from graphslam.pipelines import provenance

    pkg = tmp_path / "fifteenth_pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "m.py").write_text("X = 0.2\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(provenance, "PACKAGES", ("fifteenth_pkg",))
    provenance.code_sha256.cache_clear()
    try:
        before = provenance.code_sha256()
        provenance.code_sha256.cache_clear()
        (pkg / "sub" / "m.py").write_text("X = 0.5\n")  # the synthetic range noise, say
        assert provenance.code_sha256() != before
    finally:
        provenance.code_sha256.cache_clear()


def test_a_session_joined_twice_is_said_however_it_is_spelled(tmp_path, monkeypatch):
    """The same frames via a relative path, a linked folder, ``0:40:1`` or ``:40`` gave no
    warning, and the joined map held them twice."""
    from graphslam.maps.merge import repeated_session

    data = tmp_path / "data" / "kitti07"
    data.mkdir(parents=True)
    (tmp_path / "link").symlink_to(data)
    # a map saved before the fix: the source and --frames as typed
    old = SimpleNamespace(meta={"dataset": "kitti-kitti07", "source": str(data), "frames": "0:40", "n_frames": 40})
    monkeypatch.chdir(tmp_path / "data")

    def again(source: str, frames: str | None, ran: list[int]) -> int | None:
        meta = {"dataset": "kitti-x", "source": source, "source_path": os.path.realpath(source),
                "frames": frames, "frame_range": ran, "n_frames": ran[1] - ran[0] + 1}
        return repeated_session(old, meta, 160)

    assert again("kitti07", "0:40", [0, 39, 1]) == 0
    assert again(str(tmp_path / "link"), "0:40", [0, 39, 1]) == 0
    assert again(str(data), "0:40:1", [0, 39, 1]) == 0
    assert again(str(data), ":40", [0, 39, 1]) == 0
    assert again(str(data), "0:20", [0, 19, 1]) is None
    assert again(str(data), "0:40:2", [0, 38, 2]) is None
    # an old map's own relative spelling is read from here
    old.meta["source"] = "kitti07"
    assert again(str(tmp_path / "link"), ":40", [0, 39, 1]) == 0


def test_a_run_records_where_and_with_what_it_ran(tmp_path):
    """metrics.json said ``graphslam`` for ``python -m graphslam``, and neither the working
    directory its relative paths are read from nor any version."""
    (tmp_path / "c.toml").write_text("[isam2]\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run(
        [sys.executable, "-m", "graphslam", "run", "--max-steps", "5", "--config", "c.toml", "--rerun", "off",
         "--quiet", "--out", "o", "--save-map", "m"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    prov = json.loads((tmp_path / "o" / "metrics.json").read_text())["provenance"]
    assert prov["command"][:4] == [Path(sys.executable).name, "-m", "graphslam", "run"]
    assert prov["cwd"] == os.path.realpath(tmp_path)
    assert prov["config_file"] == "c.toml" and prov["config_file_resolved"] == os.path.realpath(tmp_path / "c.toml")
    assert set(prov["versions"]) == {"graphslam", "gtsam", "numpy", "opencv", "python"}
    assert prov["versions"]["gtsam"] and len(prov["code_sha256"]) == 64
    saved = json.loads((tmp_path / "m" / "map.json").read_text())["meta"]["provenance"]
    assert saved["cwd"] == prov["cwd"] and saved["code_sha256"] == prov["code_sha256"]


def test_eval_json_records_where_and_with_what_it_ran(tmp_path, monkeypatch, capsys):
    for name in ("gt.tum", "est.tum"):
        (tmp_path / name).write_text("".join(f"{t} {t} 0 0 0 0 0 1\n" for t in range(5)))
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "gt.tum", "est.tum", "--out", "e", "--no-plot"]) == 0
    prov = json.loads((tmp_path / "e" / "eval.json").read_text())["provenance"]
    assert prov["command"][:2] == ["graphslam", "eval"] and prov["cwd"] == os.path.realpath(tmp_path)
    assert prov["versions"]["numpy"]


@pytest.mark.parametrize("argv0", ["graphslam"])
def test_main_called_from_python_stands_for_the_command(argv0):
    from graphslam.pipelines.provenance import invoked_as

    assert invoked_as() == [argv0]  # pytest's __main__ is no graphslam module


def test_anchored_landmarks_give_the_same_bits_on_any_blas_thread_count(tmp_path, shared_data):
    """The monocular EKF with anchored landmarks on KITTI 07 ended with other bits under
    OPENBLAS_NUM_THREADS=2 than =1 (ATE 0.04334820268821955 against ...546): the
    correction's multi-threaded solve. Its BLAS is pinned to one thread now."""
    (tmp_path / "ahp.toml").write_text('[mono_ekf]\nlandmark_param = "ahp"\n')
    outs = []
    for threads in ("1", "2"):
        out = tmp_path / f"t{threads}"
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "PYTHONPATH": str(Path(__file__).resolve().parents[3])}
        done = subprocess.run(
            [sys.executable, "-m", "graphslam.cli.main", "run", "--dataset", str(shared_data / "kitti07"),
             "--frames", "0:25", "--odometry", "none", "--backend", "ekf", "--config", str(tmp_path / "ahp.toml"),
             "--rerun", "off", "--quiet", "--out", str(out)],
            capture_output=True, text=True, env=env, timeout=300,
        )
        assert done.returncode == 0, done.stderr
        outs.append(out)
    a, b = (json.loads((o / "metrics.json").read_text()) for o in outs)
    assert a["ate_rmse_m"] == b["ate_rmse_m"]
    assert (outs[0] / "trajectory.tum").read_bytes() == (outs[1] / "trajectory.tum").read_bytes()
