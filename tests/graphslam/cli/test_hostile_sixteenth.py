"""The sixteenth hostile pass (2026-12-04): standard streams closed or unable to spell a
path, distortion coefficients that are not the camera's, a setting that changed no run,
``eval`` stopped among several estimates, a pose graph whose edges agree exactly. Each
test reproduces a finding, then checks what the command does now."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main

REPO = Path(__file__).resolve().parents[3]


def _cli(args: list[str], cwd: Path, env: dict | None = None, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "graphslam", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})},
        **kw,
    )


def test_a_closed_stdout_is_no_traceback_and_the_run_writes_its_files(tmp_path):
    """``graphslam run ... >&-``: AttributeError 'NoneType' object has no attribute 'write'
    at the summary's print (also --help and --version), exit 1."""
    out = tmp_path / "o"
    closed = _cli(
        ["run", "--max-steps", "10", "--rerun", "off", "--out", str(out)],
        tmp_path,
        stdout=None,
        preexec_fn=lambda: os.close(1),
    )
    assert closed.returncode == 0, closed.stderr
    assert "Traceback" not in closed.stderr
    assert (out / "trajectory.tum").is_file() and (out / "metrics.json").is_file()
    for flag in ("--help", "--version"):
        done = _cli([flag], tmp_path, stdout=None, preexec_fn=lambda: os.close(1))
        assert done.returncode == 0 and "Traceback" not in done.stderr, (flag, done.stderr)


def test_a_path_the_output_encoding_cannot_spell_is_escaped_not_a_traceback(tmp_path):
    """PYTHONIOENCODING=ascii and a dataset named café.g2o: UnicodeEncodeError, exit 1."""
    import gtsam

    graph = tmp_path / "café.g2o"
    graph.write_bytes(Path(gtsam.findExampleDataFile("noisyToyGraph.txt")).read_bytes())
    done = _cli(
        ["run", "--dataset", str(graph), "--rerun", "off", "--out", str(tmp_path / "o_café")],
        tmp_path,
        env={"PYTHONIOENCODING": "ascii"},
    )
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and "caf\\xe9" in done.stdout
    assert (tmp_path / "o_café" / "trajectory.tum").is_file()


def _folder(tmp_path: Path, distortion: str) -> tuple[Path, Path]:
    import cv2

    folder = tmp_path / "imgs"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:02d}.png"), rng.integers(0, 255, (120, 160), dtype=np.uint8))
    k = tmp_path / "k.txt"
    k.write_text(f"125 125 79.5 59.5\n{distortion}\n")
    return folder, k


@pytest.mark.parametrize("distortion", ["125 125 79.5 59.5", "1e5 -1e5 0 0"])
def test_distortion_that_is_no_lens_is_refused_in_one_line(tmp_path, capsys, distortion):
    """The camera line typed twice: its second copy was read as k1 k2 p1 p2 = 125 125 ...,
    the undistorted images were the border smeared, and the run ended with exit 0 and no
    landmark, its warnings blaming the ground truth."""
    folder, k = _folder(tmp_path, distortion)
    argv = [
        "run",
        "--dataset",
        str(folder),
        "--intrinsics",
        str(k),
        "--odometry",
        "none",
        "--rerun",
        "off",
        "--quiet",
        "--out",
        str(tmp_path / "o"),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not this camera's distortion" in err, err
    assert "% of the undistorted image's pixels" in err


def test_a_lens_distortion_is_still_undistorted(tmp_path):
    """The coverage check leaves a real lens alone: EuRoC cam0's radtan at its camera."""
    from graphslam.sources.spatial.sequence import ImageSequence

    K = np.array([[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]])
    dist = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    seq = ImageSequence("euroc", [], None, K, dist, None, (752, 480))
    maps = seq._maps((480, 752))
    assert maps and maps[0].shape[:2] == (480, 752)


def test_mono_ekf_default_sigma_px_is_gone_and_refused_by_name(tmp_path, capsys):
    """[mono_ekf] default_sigma_px = 1e-6 or 1e3 gave byte-identical runs: the map is empty
    until the first update brings the frame's pixel sigma, so it was never used."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[mono_ekf]\ndefault_sigma_px = 2.0\n")
    assert (
        main(
            [
                "run",
                "--dataset",
                "synthetic-images",
                "--backend",
                "ekf",
                "--max-steps",
                "3",
                "--config",
                str(cfg),
                "--rerun",
                "off",
                "--quiet",
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "unknown key(s) ['default_sigma_px'] in [mono_ekf]" in err


def _tum(path: Path, n: int, offset: float) -> None:
    t = np.arange(n) * 0.01
    xyz = np.cumsum(np.random.default_rng(0).normal(size=(n, 3)) * 0.01, axis=0) + offset
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    np.savetxt(path, np.hstack([t[:, None], xyz, q]), fmt="%.6f")


def test_eval_stopped_among_several_estimates_keeps_those_scored(tmp_path, capsys, monkeypatch):
    """``eval GT E1 E2 E3`` and Ctrl-C while E2 was scored: exit 130 and no output folder;
    E1's scores (seconds of work on 600 000 poses) were lost. The signal is sent from inside
    the second scoring, so the test does not depend on the machine's speed."""
    import graphslam.pipelines.trajectory_eval as te

    _tum(tmp_path / "gt.tum", 200, 0.0)
    for i in (1, 2, 3):
        _tum(tmp_path / f"e{i}.tum", 200, 0.01 * i)
    calls = []
    real = te.evaluate

    def evaluate(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)  # held: this estimate ends, the next is not begun
        return real(*a, **kw)

    monkeypatch.setattr(te, "evaluate", evaluate)
    out = tmp_path / "o"
    estimates = [str(tmp_path / f"e{i}.tum") for i in (1, 2, 3)]
    assert main(["eval", str(tmp_path / "gt.tum"), *estimates, "--out", str(out), "--no-plot"]) == 130
    err = capsys.readouterr().err
    data = json.loads((out / "eval.json").read_text())
    assert data["interrupted"] is True and len(calls) == 2
    assert [Path(e["estimate"]).name for e in data["estimates"]] == ["e1.tum", "e2.tum"]
    assert [Path(u).name for u in data["unscored"]] == ["e3.tum"]
    assert "2 of 3 estimates scored and written, not" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "text",
    [
        # three 3-D poses whose edges are their exact relative poses, one of them a closure
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\nVERTEX_SE3:QUAT 2 2 0 0 0 0 0 1\n"
        + "".join(
            f"EDGE_SE3:QUAT {a} {b} {b - a} 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n"
            for a, b in ((0, 1), (1, 2), (0, 2))
        )
    ],
)
def test_a_graph_whose_edges_agree_exactly_is_said_so_not_infx(tmp_path, capsys, text):
    """Edges equal to the poses' relative poses: 'the noise is stated about infx larger in
    sigma than the residuals show' (1.16e+154x in 2-D)."""
    graph = tmp_path / "exact.g2o"
    graph.write_text(text)
    assert main(["run", "--dataset", str(graph), "--rerun", "off", "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "infx" not in err and "e+" not in err
    assert "the edges agree to round-off" in err


def test_saving_an_empty_2d_map_warns(tmp_path, capsys):
    """``run --max-steps 5 --save-map M``: 'map in M/: 0 landmarks', exit 0, no word; a
    run with ``--map M`` then placed nothing. Image maps already said so."""
    assert main(["run", "--max-steps", "5", "--save-map", str(tmp_path / "m"), "--rerun", "off",
                 "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert f"the map in {tmp_path / 'm'} has no landmark" in err


@pytest.mark.parametrize("unit, words, fits", [("frames", "longer than 30 matched poses", "5"),
                                               ("m", "m of path", "0.1")])
def test_eval_delta_longer_than_the_trajectory_says_why_the_rpe_is_na(tmp_path, capsys, unit, words, fits):
    """``eval --delta 1000`` on 30 poses: the RPE columns read n/a, nothing said."""
    _tum(tmp_path / "gt.tum", 30, 0.0)
    _tum(tmp_path / "est.tum", 30, 0.01)
    argv = ["eval", str(tmp_path / "gt.tum"), str(tmp_path / "est.tum"), "--delta", "1000", "--delta-unit", unit,
            "--no-plot", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert words in err and "RPE is n/a; lower --delta" in err
    capsys.readouterr()
    assert main([*argv[:4], fits, *argv[5:]]) == 0  # a delta that fits is silent
    assert "RPE is n/a" not in capsys.readouterr().err


def _noise_images(tmp_path: Path) -> Path:
    import cv2

    folder = tmp_path / "imgs"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        img = cv2.GaussianBlur(rng.integers(0, 255, (240, 320), dtype=np.uint8), (0, 0), 1.5)
        cv2.imwrite(str(folder / f"{i:02d}.png"), img)
    return folder


def test_loops_words_beyond_the_descriptors_warns_as_vocab_train_does(tmp_path, capsys):
    """``loops --words 99999999``: 'vocabulary tree k=10 L=8, 1531 words', exit 0, nothing
    said; ``vocab train`` warned in the same case."""
    folder = _noise_images(tmp_path)
    assert main(["loops", str(folder), "--words", "99999999", "--out", str(tmp_path / "l.csv"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "--words 99999999: the tree has" in err and "too few descriptors" in err


def test_vocab_train_flat_with_more_words_than_descriptors_is_one_line(tmp_path, capsys):
    """A warning that the flat k-means would take minutes, then the error refusing it."""
    folder = _noise_images(tmp_path)
    assert main(["vocab", "train", str(folder), "--out", str(tmp_path / "v.voc"), "--words",
                 "999999999999999", "--flat", "--quiet"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("graphslam:")]
    assert len(err) == 1 and "descriptors for 999999999999999 words" in err[0], err


@pytest.mark.parametrize("flag", ["--loops", "--relocalise"])
def test_a_flag_the_ekf_cannot_serve_names_it_as_the_user_did(tmp_path, capsys, flag):
    """``--backend ekf --loops``: "back end 'mono_ekf' cannot use ...", a name the user never typed."""
    assert main(["run", "--dataset", "synthetic-images", "--backend", "ekf", flag, "--max-steps", "3",
                 "--rerun", "off", "--quiet", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{flag}: back end 'ekf' cannot use relative-pose loop closures" in err and "mono_ekf" not in err


def test_a_dataset_that_is_a_broken_symlink_is_said_so(tmp_path, capsys):
    """A symlink loop as --dataset: 'no such dataset or file', of a name that is there."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.symlink_to(b)
    b.symlink_to(a)
    assert main(["run", "--dataset", str(a), "--rerun", "off", "--out", str(tmp_path / "o")]) == 2
    assert "a symbolic link that resolves to nothing" in capsys.readouterr().err


def _sweep_file(tmp_path: Path) -> Path:
    spec = tmp_path / "w.toml"
    spec.write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0, 1]\nmax_steps = 20\n')
    return spec


def test_a_sweep_whose_runs_folder_is_a_file_is_one_line(tmp_path, capsys):
    """OUT/runs a file: NotADirectoryError at each run's mkdir, a traceback (a broken
    symlink: FileExistsError)."""
    out = tmp_path / "s"
    out.mkdir()
    (out / "runs").write_text("")
    assert main(["sweep", str(_sweep_file(tmp_path)), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"graphslam: error: {out / 'runs'}: is not a folder: the sweep keeps each run in runs/<run id>"


@pytest.mark.parametrize("blocker", ["folder", "stderr"])
def test_a_sweep_run_whose_folder_cannot_be_made_is_a_failed_row(tmp_path, capsys, blocker):
    """OUT/runs/<run id> a file: FileExistsError, a traceback; its stderr.txt a folder: the
    whole sweep ended in one line, its other runs not run. Now that run fails, the others run."""
    from graphslam.pipelines.sweep_spec import parse_sweep

    spec = _sweep_file(tmp_path)
    out = tmp_path / "s"
    first = parse_sweep(spec).runs()[0].run_id
    (out / "runs").mkdir(parents=True)
    if blocker == "folder":
        (out / "runs" / first).write_text("")
    else:
        (out / "runs" / first / "stderr.txt").mkdir(parents=True)
    assert main(["sweep", str(spec), "--out", str(out), "--quiet"]) == 1
    rows = (out / "sweep.csv").read_text().splitlines()
    failed = [r for r in rows if r.startswith(first)]
    assert len(rows) == 3 and failed and ",failed," in failed[0]
    assert "cannot write the run's folder or start it" in failed[0]
    assert sum(",ok," in r for r in rows) == 1


def test_mrclam_subject_with_two_barcodes_is_refused(tmp_path, capsys, shared_data):
    """Subject 13's line turned into a second line of subject 14: two landmarks merged into
    one, ATE 0.08 -> 0.65 m, exit 0, nothing said."""
    import shutil

    folder = tmp_path / "m"
    shutil.copytree(shared_data / "mrclam6", folder)
    text = (folder / "Barcodes.dat").read_text().splitlines()
    k = next(i for i, ln in enumerate(text) if ln.split()[:1] == ["13"])
    text[k] = text[k].replace("13", "14", 1)
    (folder / "Barcodes.dat").write_text("\n".join(text) + "\n")
    assert main(["run", "--dataset", str(folder), "--robot", "1", "--rerun", "off", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    second = next(i for i, ln in enumerate(text) if ln.split()[:1] == ["14"] and i != k)  # the later line
    assert err == f"graphslam: error: {folder / 'Barcodes.dat'}:{second + 1}: subject 14 is given two barcodes (54 and 61)"


def test_localize_that_places_no_frame_says_so(tmp_path, capsys):
    """A map of one synthetic world, frames of another: 'localised 0.0 %', a trajectory of
    its header, exit 0 and nothing said."""
    assert main(["run", "--dataset", "synthetic-images", "--max-steps", "30", "--save-map", str(tmp_path / "m"),
                 "--rerun", "off", "--quiet", "--out", str(tmp_path / "r")]) == 0
    other = tmp_path / "w.toml"
    other.write_text("[synthetic_images]\nseed = 7\n")
    capsys.readouterr()
    assert main(["localize", "--map", str(tmp_path / "m"), "--dataset", "synthetic-images", "--config", str(other),
                 "--frames", "40:50", "--rerun", "off", "--quiet", "--out", str(tmp_path / "l")]) == 0
    err = capsys.readouterr().err
    assert "no frame of 10 was placed in the map" in err
    warnings = json.loads((tmp_path / "l" / "metrics.json").read_text())["warnings"]
    assert any("no frame of 10 was placed" in w for w in warnings)


class _StoppedAfterOne:
    """An executor whose runs all finish, but whose stream of results is stopped (Ctrl-C)
    after it reported the first: the others' rows were dropped from sweep.csv, and the
    next start of the sweep ran them again."""

    def map_unordered(self, runs, root):
        from graphslam.pipelines.sweep_exec import execute_run

        done = [(run, execute_run(run, str(root))) for run in runs]
        yield done[0]
        raise KeyboardInterrupt


def test_a_stopped_sweep_keeps_runs_that_finished_but_were_not_reported(tmp_path):
    from graphslam.pipelines.sweep import read_rows, run_sweep
    from graphslam.pipelines.sweep_spec import parse_sweep

    spec = parse_sweep(_sweep_file(tmp_path))
    out = tmp_path / "s"
    from graphslam.pipelines.sweep_exec import score_finished

    outcome = run_sweep(spec, out, _StoppedAfterOne(), score_finished=score_finished)
    assert outcome.interrupted
    rows = read_rows(out / "sweep.csv")
    assert [r["run_id"] for r in rows] == [run.run_id for run in spec.runs()]
    assert all(r["status"] == "ok" and r["ate_rmse_m"] not in ("", None) for r in rows)


def test_sweep_set_true_and_1_are_not_a_repeat(tmp_path, capsys):
    """``[sweep.set] "isam2.polish" = [true, 1]``: 'lists 1 twice' (Python's true == 1); the
    1 is what is wrong, and a real repeat is spelt as the file spells it."""
    head = '[sweep]\ndataset = ["synthetic"]\nbackend = ["isam2"]\nseed = [0]\nmax_steps = 10\n[sweep.set]\n'
    for values, words in (("[true, 1]", "isam2.polish: expected true/false, got 1"),
                          ("[true, true]", "isam2.polish lists true twice")):
        spec = tmp_path / "s.toml"
        spec.write_text(head + f'"isam2.polish" = {values}\n')
        assert main(["sweep", str(spec), "--out", str(tmp_path / "o"), "--quiet"]) == 2
        assert words in capsys.readouterr().err


def test_a_bag_folder_whose_metadata_is_no_mapping_names_the_file(tmp_path, capsys):
    """metadata.yaml holding ``x``: 'Invalid bag metadata: string indices must be integers'."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x\n")
    (bag / "bag_0.db3").write_bytes(b"")
    assert main(["info", str(bag)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"graphslam: error: {bag / 'metadata.yaml'}: not a ROS 2 bag's metadata "
                   "(no rosbag2_bagfile_information mapping)")
