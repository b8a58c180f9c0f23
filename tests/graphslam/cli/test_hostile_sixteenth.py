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
import time
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


@pytest.mark.slow
def test_eval_stopped_among_several_estimates_keeps_those_scored(tmp_path):
    """``eval GT E1 E2 E3`` and Ctrl-C while E2 was scored: exit 130 and no output folder;
    E1's scores (seconds of work on 600 000 poses) were lost."""
    n = 300_000
    _tum(tmp_path / "gt.tum", n, 0.0)
    for i in (1, 2, 3):
        _tum(tmp_path / f"e{i}.tum", n, 0.01 * i)
    # how long loading and one estimate take here, so that the signal lands in the second
    t0 = time.monotonic()
    one = _cli(["eval", "gt.tum", "e1.tum", "--out", "one", "--no-plot"], tmp_path)
    assert one.returncode == 0, one.stderr
    whole = time.monotonic() - t0
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "graphslam",
            "eval",
            "gt.tum",
            "e1.tum",
            "e2.tum",
            "e3.tum",
            "--out",
            "o",
            "--no-plot",
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    # loading four files takes about twice loading two; then e1 is scored
    time.sleep(1.6 * whole)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    data = json.loads((tmp_path / "o" / "eval.json").read_text())
    assert data["interrupted"] is True
    scored = [Path(e["estimate"]).name for e in data["estimates"]]
    assert scored and scored == ["e1.tum", "e2.tum", "e3.tum"][: len(scored)] and len(scored) < 3
    assert [Path(u).name for u in data["unscored"]] == ["e1.tum", "e2.tum", "e3.tum"][len(scored) :]
    assert f"{len(scored)} of 3 estimates scored and written" in err and "Traceback" not in err


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
    assert "a symbolic link to nothing" in capsys.readouterr().err
