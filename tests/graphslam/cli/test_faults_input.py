"""Bad input is one line on stderr and exit status 2, refused before any work where it can be.

The attacks of issue 14 on output paths, images, vocabulary files and
Victoria Park ids; each ran into a traceback, a hang or a silent acceptance
before. Run in process through :func:`graphslam.cli.main.main` (the one place
that turns errors into lines and statuses) where a command is involved.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from graphslam.cli.main import main
from slamcore.errors import ConfigError, InputError

#: Hang guard on a refusal, seconds: minutes above the worst case (a refusal reads at
#: most a header; a run on these inputs would not end at all). Not a timing check.
REFUSE_S = 300.0


def refused(capsys, argv: list[str], match: str) -> str:
    """``graphslam ARGV`` exits 2 with one ``graphslam: error:`` line matching ``match``."""
    t0 = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - t0 < REFUSE_S
    stderr = capsys.readouterr().err
    assert "Traceback" not in stderr
    # progress lines aside ("training a vocabulary ..."), one line says what is wrong
    err = [ln for ln in stderr.splitlines() if ln.startswith("graphslam:")]
    assert len(err) == 1 and err[0].startswith("graphslam: error: "), stderr
    assert match in err[0], err[0]
    return err[0]


# ------------------------------------------------------------------------------ --out

@pytest.mark.parametrize("command", [
    ["run", "--quiet"], ["compare", "--rerun", "off"], ["eval", "T", "T"],
    ["sweep", "SWEEP"], ["localize", "--map", "MAP", "--dataset", "synthetic-images"],
])
def test_out_that_is_a_file_is_refused_before_the_run(tmp_path, capsys, command):
    target = tmp_path / "taken"
    target.write_text("mine")
    (tmp_path / "t.tum").write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    (tmp_path / "s.toml").write_text('[sweep]\ndataset = ["synthetic"]\nbackend = ["ekf"]\n')
    stand_in = {"T": tmp_path / "t.tum", "SWEEP": tmp_path / "s.toml", "MAP": tmp_path / "nomap"}
    command = [str(stand_in.get(a, a)) for a in command]  # --out is checked before any of them
    refused(capsys, [*command, "--out", str(target)], "is an existing file, not a folder")
    refused(capsys, [*command, "--out", str(target / "sub")], "is a file, not a folder")
    assert target.read_text() == "mine"


@pytest.mark.parametrize("command", [["loops", "IMAGES"], ["vocab", "train", "IMAGES"]])
def test_out_file_that_is_a_folder_is_refused(tmp_path, capsys, command):
    images = tmp_path / "images"
    images.mkdir()
    argv = [str(images) if a == "IMAGES" else a for a in command]
    refused(capsys, [*argv, "--out", str(tmp_path)], "is a folder; give a file name")


def test_unwritable_out_folder_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):  # root writes anyway: nothing to refuse
            pytest.skip("this user can write into a read-only folder")
        refused(capsys, ["run", "--quiet", "--out", str(locked / "o")], "cannot")
    finally:
        locked.chmod(0o700)


# ------------------------------------------------------------------------------ images

@pytest.fixture(scope="module")
def frames():
    from graphslam.sources.spatial.synthetic_images import (
        SyntheticImagesConfig, make_synthetic_images,
    )

    seq = make_synthetic_images(SyntheticImagesConfig(width=160, height=120, fx=125, fy=125,
                                                      cx=79.5, cy=59.5, n_frames=4))
    return [seq.load(i) for i in range(len(seq))]


EKF = ("--backend", "ekf", "--odometry", "none")  # a folder has no odometry of its own


def image_folder(root: Path, frames, ext: str = ".png") -> Path:
    root.mkdir()
    for i, im in enumerate(frames):
        cv2.imwrite(str(root / f"f{i}{ext}"), im)
    (root / "intrinsics.txt").write_text("125 125 79.5 59.5\n")
    return root


def test_whole_png_with_trailing_bytes_is_read():
    """A PNG written to its IEND chunk is whole, whatever a tool appended after it."""
    from frontend.image import decode_gray

    ok, buf = cv2.imencode(".png", np.full((20, 30), 7, np.uint8))
    image = decode_gray(buf.tobytes() + bytes(1000), "x.png")
    assert image.shape == (20, 30) and np.all(image == 7)


@pytest.mark.parametrize("ext, what", [(".jpg", "truncated JPEG"), (".png", "truncated PNG")])
def test_truncated_image_is_refused_with_its_name(tmp_path, capsys, frames, ext, what):
    folder = image_folder(tmp_path / "seq", frames, ext)
    cut = folder / f"f2{ext}"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    line = refused(capsys, ["run", "--dataset", str(folder), *EKF, "--quiet", "--rerun", "off",
                            "--out", str(tmp_path / "o")], what)
    assert f"f2{ext}" in line
    refused(capsys, ["vocab", "train", str(folder), "--out", str(tmp_path / "v.voc"),
                     "--quiet"], what)


def test_image_of_another_size_is_refused(tmp_path, capsys, frames):
    folder = image_folder(tmp_path / "seq", frames)
    cv2.imwrite(str(folder / "f3.png"), cv2.resize(frames[3], (80, 60)))
    line = refused(capsys, ["run", "--dataset", str(folder), *EKF, "--quiet", "--rerun", "off",
                            "--out", str(tmp_path / "o")], "is 80x60 px")
    assert "f3.png" in line and "160x120" in line


def test_one_pixel_images_do_not_crash_orb(tmp_path, capsys):
    from frontend.orb import OrbDetector

    for shape in [(1, 1), (1, 300), (300, 1), (2, 2)]:
        assert len(OrbDetector().detect(np.full(shape, 128, np.uint8)).xy_px) == 0
        index, _ = OrbDetector().describe(np.full(shape, 128, np.uint8), np.zeros((1, 2)))
        assert len(index) == 0
    folder = image_folder(tmp_path / "tiny", [np.full((1, 1), v, np.uint8) for v in (0, 255)])
    # training a vocabulary on them is refused in one line ...
    refused(capsys, ["loops", str(folder), "--words", "5", "--out", str(tmp_path / "l.csv"),
                     "--quiet"], "no ORB features")
    # ... and with the shipped vocabulary the run is refused as well: no image can close a
    # loop (it used to be a silent empty run, "0 closures accepted")
    refused(capsys, ["loops", str(folder), "--out", str(tmp_path / "l.csv"), "--quiet"],
            "no ORB features found in the images (2 of 2")


# ------------------------------------------------------------------------------ vocabulary

def test_vocabulary_tree_with_a_cycle_is_refused_on_load(tmp_path):
    from loopclosure.vocabulary import VocabularyTree, load_vocabulary

    rng = np.random.default_rng(0)
    x = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    tree = VocabularyTree(branching=4, depth=2, seed=0).fit([x])
    good = tmp_path / "good.voc"
    tree.save(good)
    assert load_vocabulary(good).n_words_ == tree.n_words_
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    for name, link in [("to_root", 0), ("to_itself", 1), ("to_parent", 0)]:
        children = arrays["children"].copy()
        node = 1 if name != "to_root" else 2
        children[node, 0] = link if name != "to_itself" else node
        bad = tmp_path / f"{name}.voc"
        with open(bad, "wb") as fh:
            np.savez(fh, **{**arrays, "children": children})
        with pytest.raises(InputError, match="inconsistent"):
            load_vocabulary(bad)


# ------------------------------------------------------------------------------ Victoria Park

VP_HEAD = "ODOMETRY 0 1 1.0 0.0 0.0 1e-4 0 0 1e-4 0 1e-5\n"


@pytest.mark.parametrize("line, match", [
    ("ODOMETRY 1 2.0 1 0 0 1e-4 0 0 1e-4 0 1e-5", "'2.0' is not an integer"),
    ("ODOMETRY 1 1e3 1 0 0 1e-4 0 0 1e-4 0 1e-5", "'1e3' is not an integer"),
    ("ODOMETRY 1 -2 1 0 0 1e-4 0 0 1e-4 0 1e-5", "out of range"),
    (f"ODOMETRY 1 {2**56} 1 0 0 1e-4 0 0 1e-4 0 1e-5", "out of range"),
    ("LANDMARK 1 3.5 1.0 2.0 0.01 0 0.01", "landmark id '3.5' is not an integer"),
    (f"LANDMARK 1 {2**60} 1.0 2.0 0.01 0 0.01", "out of range"),
])
def test_victoria_park_ids_are_integers_in_range(tmp_path, line, match):
    from graphslam.sources.planar.victoria_park import read_victoria_park

    path = tmp_path / "vp.txt"
    path.write_text(VP_HEAD + line + "\n")
    with pytest.raises(InputError, match=match) as e:
        read_victoria_park(path)
    assert e.value.line == 2


def test_covariance_overflowing_its_factor_is_refused(tmp_path):
    """Found by the fuzzer: a covariance with entries near the float limit made
    Cholesky overflow to inf instead of failing, and passed as positive definite."""
    from graphslam.sources.planar.victoria_park import read_victoria_park

    path = tmp_path / "vp.txt"
    path.write_text(VP_HEAD + "ODOMETRY 1 2 1 0 0 1e-4 0 1e308 4e-6 0 4e-6\n")
    with pytest.raises(InputError, match="not positive definite"):
        read_victoria_park(path)


@pytest.mark.parametrize("line, match", [
    ("ODOMETRY 1 2 1 0 0 1e-4 0 0 1e-4 0 1e308", "heading variance 1e+308 is outside"),
    ("ODOMETRY 1 2 1 0 0 1e-4 0 0 1e-4 0 1e-320", "heading variance 9.99989e-321 is outside"),
    ("ODOMETRY 1 2 1e300 0 0 1e-4 0 0 1e-4 0 1e-5", "offset 1e+300 m is beyond"),
    ("LANDMARK 1 3 1.0 9223372036854775807 0.4 0 0.4", "is beyond 1e+06 m"),
    ("LANDMARK 1 3 1.0 2.0 1e30 0 0.4", "range variance 1e+30 is outside"),
])
def test_victoria_park_values_a_solver_can_weigh(tmp_path, line, match):
    """Found by the fuzzer: a heading variance of 1e308 or a tree 9e18 m away read
    fine and then broke iSAM2 (indeterminate system) and the EKF (math domain)."""
    from graphslam.sources.planar.victoria_park import read_victoria_park

    path = tmp_path / "vp.txt"
    path.write_text(VP_HEAD + line + "\n")
    with pytest.raises(InputError, match=re.escape(match)) as e:
        read_victoria_park(path)
    assert e.value.line == 2


def test_victoria_park_ids_past_2_53_stay_exact(tmp_path):
    from graphslam.sources.planar.victoria_park import read_victoria_park

    big = 2**53 + 1  # a float would make it 2**53
    path = tmp_path / "vp.txt"
    path.write_text(VP_HEAD + f"ODOMETRY 1 {big} 1 0 0 1e-4 0 0 1e-4 0 1e-5\n")
    assert [f.pose_id for f in read_victoria_park(path).frames] == [0, 1, big]


# ------------------------------------------------------------------------------ seeds

def test_image_run_seeds(tmp_path, capsys):
    for seed in ("-1", str(2**63 - 1)):  # the parser's one line (tests/graphslam/cli/test_error_wording.py)
        with pytest.raises(SystemExit) as stop:
            main(["run", "--dataset", "synthetic-images", "--seed", seed, "--quiet",
                  "--out", str(tmp_path / "a")])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and err.count("\n") == 1 and "from 0 to 2**62" in err
    assert main(["run", "--dataset", "synthetic-images", "--seed", str(2**32 - 1),
                 "--max-steps", "2", "--quiet", "--rerun", "off",
                 "--out", str(tmp_path / "c")]) == 0


def test_output_checks_raise_config_errors(tmp_path):
    from slamcore.files import check_output_dir, check_output_file

    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError):
        check_output_dir(tmp_path / "f")
    with pytest.raises(ConfigError):
        check_output_file(tmp_path)
    assert check_output_file(tmp_path / "new" / "x.csv") == tmp_path / "new" / "x.csv"
    assert not (tmp_path / "new").exists()  # checking creates nothing


def test_a_folder_that_refuses_files_is_refused(tmp_path, monkeypatch, capsys):
    """What a read-only folder (or mount) does to the write probe, for users (root in
    CI) whom permissions do not stop: the run is refused before it starts."""
    import errno
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    refused(capsys, ["run", "--quiet", "--out", str(tmp_path / "o")],
            f"cannot write in {tmp_path} (Permission denied)")
    assert not (tmp_path / "o").exists()


def test_victoria_park_with_a_byte_order_mark_reads_the_same(tmp_path):
    from graphslam.sources.planar.victoria_park import read_victoria_park

    plain, bom = tmp_path / "plain.txt", tmp_path / "bom.txt"
    plain.write_text(VP_HEAD + "LANDMARK 1 3 1.0 2.0 0.4 0 0.4\n")
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read_victoria_park(plain), read_victoria_park(bom)
    assert [f.pose_id for f in a.frames] == [f.pose_id for f in b.frames] == [0, 1]
    assert len(b.frames[1].observations) == 1
