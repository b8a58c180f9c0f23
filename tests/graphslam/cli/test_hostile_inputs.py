"""Hostile inputs of issue 34: each ends in one ``graphslam: error:`` line and exit 2."""

from __future__ import annotations

import io
import os
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.sources.spatial.sequence import natural_key
from slamcore.errors import QUOTE_CHARS, quote

DESK = Path("/work/shared/data/slambook2_desk/images")
#: Longest error line a hostile token may cause: the message, a path and a short quote.
SHORT_ERROR_CHARS = 600


def one_error_line(capsys, argv) -> str:
    """Run ``argv``; assert exit 2 and one short error line; return it."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("graphslam: error:")]
    assert len(lines) == 1, err[:2000]
    assert "Traceback" not in err
    return lines[0]


def test_quote_shortens_huge_token():
    text = quote("\0" * 10**6)
    assert len(text) < 10 * QUOTE_CHARS and "1000000 characters" in text
    assert quote("abc") == "'abc'"
    assert "bits" in quote(10**5000)  # repr would raise past 4300 digits


@pytest.mark.parametrize("name", ["nul.g2o", "nul.graph", "nul.txt"])
def test_megabyte_of_nul_bytes_is_quoted_short(tmp_path, capsys, name):
    path = tmp_path / name
    path.write_bytes(b"\0" * 10**6)
    line = one_error_line(capsys, ["run", "--dataset", path, "--out", tmp_path / "o",
                                   "--rerun", "off"])
    assert len(line) < SHORT_ERROR_CHARS


def test_natural_key_takes_only_ascii_digits():
    names = ["img10.png", "²1.png", "img2.png", "١.png"]
    assert sorted(names, key=natural_key)[:2] == ["img2.png", "img10.png"]


@pytest.mark.skipif(not DESK.is_dir(), reason="desk photos not available")
def test_superscript_image_name_trains_a_vocabulary(tmp_path, capsys):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for src in sorted(DESK.glob("*.png"))[:3]:
        shutil.copy(src, folder / src.name)
    shutil.copy(folder / "01.png", folder / "²1.png")
    assert main(["vocab", "train", str(folder), "--words", "10", "--out",
                 str(tmp_path / "v.npz"), "--quiet"]) == 0


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("flag", ["--dataset", "--config"])
def test_fifo_is_refused(tmp_path, capsys, flag):
    fifo = tmp_path / "pipe.g2o"
    os.mkfifo(fifo)
    line = one_error_line(capsys, ["run", flag, fifo, "--out", tmp_path / "o", "--rerun", "off"])
    assert "FIFO" in line


def test_device_is_refused(tmp_path, capsys):
    line = one_error_line(capsys, ["run", "--dataset", "/dev/zero", "--out", tmp_path / "o",
                                   "--rerun", "off"])
    assert "device" in line
    line = one_error_line(capsys, ["convert", "/dev/zero", tmp_path / "x.g2o"])
    assert "device" in line


def test_non_utf8_truth_names_the_file(tmp_path):
    from graphslam.evaluation.places import read_truth
    from slamcore.errors import InputError

    truth = tmp_path / "truth.csv"
    truth.write_bytes(b"query,match\n\xff\xfe,a\n")
    with pytest.raises(InputError, match="truth.csv: not a UTF-8"):
        read_truth(truth, [tmp_path / "a.png"])


def billion_laughs() -> str:
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, name in zip("abcdefgh", "bcdefghi"):
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("text, expected", [
    (billion_laughs(), "anchors and aliases"),
    ("synthetic:\n  seed: 1\n  seed: 2\n", "cfg.yaml:3: duplicate key 'seed'"),
])
def test_yaml_aliases_and_duplicate_keys_are_refused(tmp_path, capsys, text, expected):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text)
    line = one_error_line(capsys, ["run", "--config", cfg, "--out", tmp_path / "o",
                                   "--rerun", "off"])
    assert expected in line


@pytest.mark.parametrize("token", ["1_000", "１２"])
@pytest.mark.parametrize("backend", ["isam2", "ekf"])
def test_numbers_g2o_would_not_read_are_refused(tmp_path, capsys, token, backend):
    path = tmp_path / "g.g2o"
    path.write_text(f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 {token} 0 0\n"
                    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", encoding="utf-8")
    line = one_error_line(capsys, ["run", "--dataset", path, "--backend", backend,
                                   "--out", tmp_path / "o", "--rerun", "off"])
    assert "g.g2o:2:" in line and "not a number" in line


def npz_declaring(shape) -> bytes:
    """A vocabulary-like .npz whose ``centres`` header declares ``shape`` of float64
    but holds 8 bytes of data."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, arr in (("format_version", np.int64(1)), ("kind", np.str_("tree"))):
            member = io.BytesIO()
            np.save(member, arr)
            zf.writestr(name + ".npy", member.getvalue())
        member = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            member, {"descr": "<f8", "fortran_order": False, "shape": shape})
        zf.writestr("centres.npy", member.getvalue() + b"\0" * 8)
    return buf.getvalue()


def test_npz_declaring_a_huge_array_is_refused_before_allocating(tmp_path):
    from loopclosure.vocabulary_file import read_npz
    from slamcore.errors import InputError

    path = tmp_path / "v.npz"
    path.write_bytes(npz_declaring((10**9,)))
    with pytest.raises(InputError, match="declares shape"):
        read_npz(path)


# ---- a second hostile pass (2026-11-29): flags that did nothing, errors that
# blamed the wrong option or came as a usage block

GOOD_G2O = ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
            "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\nEDGE_SE2 1 2 1 0 0 100 0 0 100 0 1000\n")


@pytest.mark.parametrize("flags, says", [
    (["--frames", "0:2"], "--frames applies to image sequences only"),
    (["--nees"], "--nees applies to streamed 2-D runs"),
    (["--relocalise"], "--relocalise applies to image sequences only"),  # was ignored, exit 0
])
def test_pose_graph_solve_refuses_flags_it_would_ignore(tmp_path, capsys, flags, says):
    graph = tmp_path / "g.g2o"
    graph.write_text(GOOD_G2O)
    line = one_error_line(capsys, ["run", "--dataset", graph, *flags, "--out", tmp_path / "o",
                                   "--rerun", "off", "--quiet"])
    assert says in line and not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["run", "compare"])
def test_a_missing_dataset_is_named_before_seed_is_blamed(tmp_path, capsys, command):
    line = one_error_line(capsys, [command, "--dataset", tmp_path / "nosuch", "--seed", "0",
                                   "--out", tmp_path / "o", "--rerun", "off"])
    assert "no such dataset or file" in line and "--seed" not in line


@pytest.mark.parametrize("argv, says", [
    (["run", "--seed", "1.5"], "run: argument --seed: expected a whole number"),
    (["compare", "--backends", "isam2", "foo"], "compare: argument --backends: invalid choice"),
    (["run", "--robot", "99"], "run: argument --robot"),
    (["run", "--out", ""], "run: argument --out: an empty path"),
    (["frobnicate"], "argument COMMAND: invalid choice"),
])
def test_parser_errors_are_one_line(capsys, argv, says):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("graphslam: error: ") and "usage:" not in err
    assert says in err


def test_a_slice_starting_with_minus_is_read_as_frames(tmp_path, capsys):
    assert main(["run", "--dataset", "synthetic-images", "--frames", "-3:", "--max-steps", "2",
                 "--rerun", "off", "--quiet", "--out", str(tmp_path / "o")]) == 0
    assert "frames                       2" in capsys.readouterr().out


def test_a_path_over_the_system_limit_is_one_short_line(tmp_path, capsys):
    deep = "/".join(["y" * 200] * 25)  # 5024 bytes, every name within NAME_MAX
    line = one_error_line(capsys, ["run", "--dataset", "synthetic", "--max-steps", "3",
                                   "--rerun", "off", "--out", deep])
    assert "the path is 5024 bytes" in line and len(line) < SHORT_ERROR_CHARS


def test_convert_says_which_self_edges_it_left_out(tmp_path, capsys):
    src = tmp_path / "s.g2o"
    src.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
                   "EDGE_SE2 1 1 0.5 0 0 1 0 0 1 0 1\n")
    assert main(["convert", str(src), str(tmp_path / "s.graph")]) == 0
    assert "1 edges from a pose to itself left out (lines 4)" in capsys.readouterr().err


MRCLAM = Path("/work/shared/data/mrclam6")


@pytest.mark.skipif(not MRCLAM.is_dir(), reason="MRCLAM Dataset 6 not available")
def test_compare_every_robot_runs_every_back_end(tmp_path, capsys):
    """Every 2-D back end holds every robot's latest pose now: compare runs all four."""
    assert main(["compare", "--dataset", str(MRCLAM), "--robot", "all", "--max-steps", "5",
                 "--rerun", "off", "--out", str(tmp_path / "d")]) == 0
    err = capsys.readouterr().err
    assert all(f"running {name} ..." in err for name in ("isam2", "ekf", "fastslam1", "fastslam2"))


# ------------------------------------------------------------------ third hostile pass

@pytest.mark.parametrize("backends", [["isam2", "isam2"], ["isam2", "ekf", "isam2"]])
def test_compare_refuses_a_back_end_named_twice(tmp_path, capsys, backends):
    """It ran the same back end twice, two identical rows under one name."""
    line = one_error_line(capsys, ["compare", "--max-steps", "5", "--rerun", "off",
                                   "--out", tmp_path / "o", "--backends", *backends])
    assert "--backends names isam2 more than once" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(not DESK.is_dir(), reason="desk photos not available")
def test_vocab_branching_beyond_its_bound_names_the_option(tmp_path, capsys):
    """--branching 10^9 was refused as "max_node_samples must be ... >= 1000000000", an
    option the command does not have."""
    line = one_error_line(capsys, ["vocab", "train", DESK / "01.png", "--out", tmp_path / "v.npz",
                                   "--branching", str(10**9), "--quiet"])
    assert "--branching must be at least 2 and at most 1000" in line


@pytest.mark.skipif(not DESK.is_dir(), reason="desk photos not available")
def test_vocab_tree_with_fewer_words_than_asked_warns(tmp_path, capsys):
    """A flat vocabulary refuses more words than descriptors; a tree gave 253 of 10^12 with
    the number in the summary only. A tree a little short of its words (928 of 1000 on
    3000 descriptors) is no warning."""
    assert main(["vocab", "train", str(DESK / "01.png"), "--out", str(tmp_path / "v.npz"),
                 "--words", str(10**12), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "graphslam: warning: --words 1000000000000: only 300 descriptors, the tree has" in err
    assert main(["vocab", "train", str(DESK / "01.png"), "--out", str(tmp_path / "w.npz"),
                 "--words", "20", "--quiet"]) == 0
    # (one photo: every word in every training image, which is said; the size is not)
    assert "the tree has" not in capsys.readouterr().err


@pytest.mark.parametrize("seed", ["5000000000", "-1"])
def test_vocab_seed_outside_kmeans_range_is_the_flags_error(tmp_path, capsys, seed):
    """--flat --seed 5000000000 was a scikit-learn traceback after the image pass
    (random_state takes 0 to 2**32 - 1); -1 was refused after it, as 'seed'."""
    with pytest.raises(SystemExit) as e:
        main(["vocab", "train", str(tmp_path), "--flat", "--seed", seed, "--out", str(tmp_path / "v.npz")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "argument --seed: expected a whole number from 0 to 2**32 - 1" in err and "Traceback" not in err


# ------------------------------------------------------------------ ninth hostile pass

HUGE = "x" * 5000


@pytest.mark.parametrize("argv", [
    ["run", "--backend", HUGE],  # argparse: invalid choice 'x...'
    ["run", "--max-steps", HUGE],  # argparse: invalid int value 'x...'
    [HUGE],  # argument COMMAND: invalid choice
    ["run", "--rerun", "off", HUGE],  # unrecognized arguments
    ["run", "--" + HUGE],
])
def test_a_huge_option_value_is_quoted_short(capsys, argv):
    """argparse quoted the whole value: a 5000-character value gave a 5 kB error line."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < SHORT_ERROR_CHARS, err[:300]
    assert "(5000 characters)" in err or "(5002 characters)" in err


def test_a_huge_viewer_url_is_quoted_short(tmp_path, capsys):
    line = one_error_line(capsys, ["run", "--rerun", "connect", "--rerun-url", HUGE,
                                   "--out", tmp_path / "o", "--max-steps", "2"])
    assert "Rerun viewer URL" in line and len(line) < SHORT_ERROR_CHARS


@pytest.mark.skipif(not DESK.is_dir(), reason="desk photos not available")
def test_vocab_an_image_given_twice_is_trained_on_once_and_said(tmp_path, capsys):
    """Tenth hostile pass: ``vocab train a.png a.png`` trained on "2 images", the one image's
    descriptors counted twice in the k-means and the IDF, without a word."""
    assert main(["vocab", "train", str(DESK / "01.png"), str(DESK / "01.png"), "--out",
                 str(tmp_path / "twice.npz"), "--words", "20", "--quiet"]) == 0
    assert "1 image(s) given more than once" in capsys.readouterr().err
    assert main(["vocab", "train", str(DESK / "01.png"), "--out", str(tmp_path / "once.npz"),
                 "--words", "20", "--quiet"]) == 0
    with np.load(tmp_path / "twice.npz") as a, np.load(tmp_path / "once.npz") as b:
        assert a.files == b.files
        assert all(np.array_equal(a[k], b[k]) for k in a.files)  # the same vocabulary
