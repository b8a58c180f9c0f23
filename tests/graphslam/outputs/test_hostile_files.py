"""Hostile files and folders (issue 34): names over the file-system limit, a full
disk, a map naming files outside its folder, two outputs naming one file, a signal
just after the recorder opens. Each ends in a valid run or one line and exit 2,
and a folder never mixes two runs."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.maps.files import load_planar_map, save_planar_map
from graphslam.outputs import writers
from slamcore.errors import ConfigError, InputError
from slamcore.files import atomic_open, replacing
from tests.conftest import ROOT
from tests.graphslam.cli.test_faults import graphslam
from tests.graphslam.maps.test_maps2d import small_map

LONG = "a" * 300
#: A valid name (under 255 bytes) whose old temporary name (".NAME.part-XXXXXXXX.npz") was not.
NEAR_LIMIT = "v" * 244 + ".npz"
SMALL_RUN = ("run", "--dataset", "synthetic", "--max-steps", "15", "--rerun", "off", "--quiet")


def one_error_line(capsys, *argv, warned: str | None = None) -> str:
    """The one error line of a command that exits 2; ``warned``: the start of warnings
    the run may give beside it (a doubt of its estimate, not of the failure)."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    if warned is not None:
        err = [ln for ln in err if not ln.startswith(warned)]
    assert rc == 2 and len(err) == 1 and err[0].startswith("graphslam: error:"), err
    return err[0]


def digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir()) if p.is_file()}


# ------------------------------------------------------------------ names too long

@pytest.mark.parametrize("argv, flag", [
    (("run", "--out", "TMP/" + LONG, "--rerun", "off"), "--out"),
    (("run", "--dataset", LONG), "--dataset"),
    (("run", "--config", "TMP/" + LONG), "--config"),
    (("eval", LONG, "x.tum"), "GT"),
    (("eval", "x.tum", "TMP/" + LONG + "/y.tum"), "EST"),
    (("convert", "x.g2o", "TMP/" + LONG), "OUT"),
    (("vocab", "train", "x.png", "--out", "TMP/" + LONG), "--out"),
])
def test_a_name_over_255_bytes_is_one_line_naming_the_option(tmp_path, capsys, argv, flag):
    argv = [a.replace("TMP", str(tmp_path)) for a in argv]
    line = one_error_line(capsys, *argv)
    assert f"error: {flag}:" in line and "255" in line
    assert list(tmp_path.iterdir()) == []  # refused before any work


@pytest.mark.parametrize("write", ["replacing", "atomic_open"])
def test_a_valid_long_output_name_gets_a_short_temporary_name(tmp_path, write):
    """A 248-byte output name: the temporary name must not pass 255 bytes (``vocab
    train`` trained for minutes and then lost everything)."""
    target = tmp_path / NEAR_LIMIT
    if write == "replacing":
        with replacing(target) as tmp:
            assert len(os.fsencode(tmp.name)) < 64 and tmp.suffix == ".npz"
            np.savez(tmp, a=np.arange(3))
    else:
        with atomic_open(target, "w") as fh:
            fh.write("x")
    assert target.is_file() and [p.name for p in tmp_path.iterdir()] == [NEAR_LIMIT]


# ------------------------------------------------------------------ a full disk

def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device", "landmarks.csv")


def test_a_full_disk_is_one_line_and_leaves_no_earlier_run_beside_the_new(tmp_path, capsys,
                                                                          monkeypatch):
    out = tmp_path / "run"
    assert main([*SMALL_RUN, "--out", str(out)]) == 0
    capsys.readouterr()
    old = {p.name: p.stat().st_ino for p in out.iterdir()}
    assert {"trajectory.tum", "metrics.json", "landmarks.csv"} <= set(old)
    monkeypatch.setattr(writers, "write_landmarks_csv", _disk_full)
    line = one_error_line(capsys, *SMALL_RUN, "--out", out)
    assert "no space left on device writing landmarks.csv" in line
    now = {p.name: p.stat().st_ino for p in out.iterdir()}
    # what the new run wrote stays (new files: new inodes); nothing of the earlier run
    assert "trajectory.tum" in now and all(now[n] != old.get(n) for n in now), (old, now)
    # the files after the refused one are still tried (fifteenth hostile pass)
    assert "landmarks.csv" not in now and not any(n.startswith(".") for n in now)
    assert "metrics.json" in now and line.endswith("holds trajectory.tum, ground_truth.tum, metrics.json")


def test_a_pose_graph_run_on_a_full_disk_leaves_no_earlier_run_beside_the_new(
        tmp_path, capsys, monkeypatch):
    import gtsam

    from graphslam.pipelines import posegraph as pipeline

    w100 = gtsam.findExampleDataFile("w100.graph")
    out = tmp_path / "run"
    argv = ("run", "--dataset", w100, "--rerun", "off", "--quiet", "--out", out)
    assert main([str(a) for a in argv]) == 0
    capsys.readouterr()
    old = {p.name: p.stat().st_ino for p in out.iterdir()}
    assert {"trajectory.tum", "metrics.json", "closures.csv"} <= set(old)

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", "closures.csv")

    monkeypatch.setattr(pipeline, "write_closures_csv", full)
    # w100 states its noise 23x larger than its residuals, and its runs say so
    line = one_error_line(capsys, *argv, warned="graphslam: warning: 2 x cost over kept edges")
    assert "no space left on device writing closures.csv" in line
    now = {p.name: p.stat().st_ino for p in out.iterdir()}
    assert "trajectory.tum" in now and all(now[n] != old.get(n) for n in now), (old, now)
    assert "metrics.json" in now and "closures.csv" not in now  # every other file still tried


def test_a_map_saved_over_another_on_a_full_disk_leaves_the_old_map_whole(tmp_path,
                                                                          monkeypatch):
    folder = tmp_path / "map"
    save_planar_map(small_map(seed=0), folder)
    before = digest(folder)

    def full(*args):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError):
        save_planar_map(small_map(seed=1), folder)
    monkeypatch.undo()
    assert digest(folder) == before  # no temporary left, the old map untouched
    assert load_planar_map(folder).n_landmarks == small_map(seed=0).n_landmarks
    save_planar_map(small_map(seed=1), folder)  # and a later save replaces it whole
    assert digest(folder) != before and load_planar_map(folder).n_landmarks


# ------------------------------------------------------------------ a map naming outside files

@pytest.mark.parametrize("where", ["parent", "absolute"])
def test_a_map_naming_a_file_outside_its_folder_is_refused(tmp_path, where):
    folder = tmp_path / "map"
    save_planar_map(small_map(), folder)
    # a byte-identical copy outside: only the place is wrong, the checksum is right
    outside = shutil.copy(folder / "map.npz", tmp_path / "x.npz")
    doc = json.loads((folder / "map.json").read_text())
    doc["arrays"]["file"] = "../x.npz" if where == "parent" else str(outside)
    (folder / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="outside the map folder"):
        load_planar_map(folder)


# ------------------------------------------------------------------ two outputs, one file

def test_loops_out_and_log_naming_one_file_is_one_line(tmp_path, capsys):
    (tmp_path / "images").mkdir()
    line = one_error_line(capsys, "loops", tmp_path / "images", "--out", tmp_path / "x.csv",
                          "--log", tmp_path / "." / "x.csv")
    assert "--out and --log name the same file" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images"]


# ------------------------------------------------------------------ a signal after the recorder opens

@pytest.mark.parametrize("steps", ["30", "700", "1000"])
def test_a_signal_after_the_recorder_opens_keeps_the_earlier_run_whole(tmp_path, steps):
    """1000 steps record in a second process: before, the command cut there never
    ended (multiprocessing's exit hook waited for a recording process that ignored
    its SIGTERM)."""
    (tmp_path / "long.toml").write_text("[synthetic]\nlaps = 2\n")  # 1538 frames
    run = ("run", "--dataset", "synthetic", "--max-steps", steps, "--rerun", "save",
           "--quiet", "--out", "out", "--config", "long.toml")
    done = graphslam(tmp_path, *run)
    assert done.returncode == 0, done.stderr
    before = digest(tmp_path / "out")
    assert "run.rrd" in before
    cut = graphslam(tmp_path, *run, "--seed", "3", at="recorder")
    assert cut.returncode == 130, cut.stderr
    assert digest(tmp_path / "out") == before  # the earlier run whole, nothing of the new
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(before)


def test_a_recording_process_left_without_close_deletes_its_recording(tmp_path):
    """Runs of 1000 steps and more record in a second process: when the run dies
    before closing it, the earlier run's recording stays whole and no stub is left."""
    old = tmp_path / "run.rrd"
    old.write_bytes(b"an earlier run's recording")
    # the run: starts the recording process, waits until it records, dies without close
    code = ("import os, sys, time; from pathlib import Path; "
            "from graphslam.visualisation.background import BackgroundLog; "
            "from graphslam.visualisation.planar import PlanarLog; "
            "p = Path(sys.argv[1]); BackgroundLog(PlanarLog, 'save', p, None)\n"
            "for _ in range(1200):\n"
            "    if any(q.name.startswith('.gs-') for q in p.parent.iterdir()): os._exit(0)\n"
            "    time.sleep(0.1)\n"
            "os._exit(1)")
    subprocess.run([sys.executable, "-c", code, str(old)], check=True, timeout=180,
                   cwd=ROOT)
    for _ in range(1200):  # hang guard only: the recording process sees the end of its pipe
        if not any(p.name.startswith(".gs-") for p in tmp_path.iterdir()):
            break
        time.sleep(0.1)
    assert old.read_bytes() == b"an earlier run's recording"
    assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]



# ------------------------------------------------------------------ a folder under an output's name
# (third hostile pass: the final rename onto it failed with IsADirectoryError, a traceback
# after the work, in every command)

def test_stale_output_removal_refuses_a_folder_under_a_name_the_run_writes(tmp_path):
    (tmp_path / "metrics.json").mkdir()
    (tmp_path / "run.rrd").mkdir()  # not written by this run: left alone, as before
    with pytest.raises(ConfigError, match="metrics.json there is a folder"):
        writers.remove_stale_outputs(tmp_path, {"metrics.json", "trajectory.tum"})
    assert writers.remove_stale_outputs(tmp_path, {"trajectory.tum"}) == []
    assert (tmp_path / "run.rrd").is_dir()


TUM2 = "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n"


@pytest.mark.parametrize("argv, folder, name", [
    ((*SMALL_RUN, "--out", "TMP/o"), "o", "trajectory.tum"),
    (("run", "--dataset", "synthetic", "--max-steps", "5", "--quiet", "--out", "TMP/o"), "o", "run.rrd"),
    ((*SMALL_RUN, "--out", "TMP/o", "--save-map", "TMP/m"), "m", "map.json"),
    (("eval", "TMP/a.tum", "TMP/a.tum", "--out", "TMP/o"), "o", "eval.png"),
    (("eval", "TMP/a.tum", "TMP/a.tum", "--out", "TMP/o", "--no-plot"), "o", "eval.json"),
    (("compare", "--max-steps", "5", "--backends", "isam2", "--rerun", "off", "--in-process",
      "--out", "TMP/o"), "o", "compare.json"),
    (("sweep", "TMP/s.toml", "--out", "TMP/o", "--quiet"), "o", "sweep.csv"),
])
def test_a_folder_under_an_output_name_is_one_line_before_the_work(tmp_path, capsys, argv, folder,
                                                                   name):
    (tmp_path / folder / name).mkdir(parents=True)
    (tmp_path / "a.tum").write_text(TUM2)
    (tmp_path / "s.toml").write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\n'
                                     'max_steps = 3\n')
    line = one_error_line(capsys, *[a.replace("TMP", str(tmp_path)) for a in argv])
    assert f"{name} there is a folder" in line
    assert [p.name for p in (tmp_path / folder).iterdir()] == [name]  # nothing written beside it


def test_a_folder_met_while_writing_is_one_line_naming_the_output(tmp_path, capsys, monkeypatch):
    """The net under the checks: EISDIR from a rename names its target, not the temporary."""
    target = tmp_path / "o" / "landmarks.csv"

    def rename_onto_a_folder(*args, **kwargs):
        raise IsADirectoryError(errno.EISDIR, "Is a directory", str(tmp_path / "o" / ".gs-x.part.csv"),
                                None, str(target))
    monkeypatch.setattr(writers, "write_landmarks_csv", rename_onto_a_folder)
    line = one_error_line(capsys, *SMALL_RUN, "--out", tmp_path / "o")
    assert line == (
        f"graphslam: error: {target} is a folder; an output file of that name cannot be written; "
        f"{tmp_path / 'o'}/ holds trajectory.tum, ground_truth.tum, metrics.json"
    )


# ------------------------------------------------------------------ stdout on a full disk

@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full here")
@pytest.mark.parametrize("argv, writes", [
    (["--version"], False),
    (["run", "--help"], False),  # over the stream's buffer: argparse swallowed the error
    (["run", "--max-steps", "3", "--rerun", "off", "--quiet", "--out", "o"], True),
])
def test_stdout_on_a_full_disk_is_named_and_the_outputs_kept(tmp_path, argv, writes):
    """--help and --version into /dev/full exited 0 with nothing said; a run's summary
    was blamed on "an output file"."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "graphslam.cli.main", *argv], cwd=tmp_path,
                              env=env, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == ("graphslam: error: no space left on device writing standard output: "
                           "No space left on device\n")
    if writes:
        assert {p.name for p in (tmp_path / "o").iterdir()} >= {"trajectory.tum", "metrics.json"}


# ------------------------------------------------------------------ two commands, one folder

HOLD_FOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDONLY)
fcntl.flock(fd, fcntl.LOCK_EX)
print("held", flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("argv", [
    ["run", "--max-steps", "3", "--rerun", "off", "--quiet"],
    ["compare", "--max-steps", "3", "--rerun", "off", "--backends", "isam2"],
])
def test_a_folder_another_command_is_writing_is_refused(tmp_path, capsys, argv):
    """Two runs into one --out at once left a mix of both runs' files, each whole."""
    from tests.graphslam.cli.test_hostile_inputs import one_error_line

    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", HOLD_FOLDER, str(out)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        line = one_error_line(capsys, [*argv, "--out", out])
        assert "another graphslam command is writing this folder now" in line
        assert not any(out.iterdir())
    finally:
        holder.kill()
        holder.wait()
    assert main([*argv, "--out", str(out)]) == 0  # the lock went with the process
    assert main([*argv, "--out", str(out)]) == 0  # and a command's own lock with its return
