"""Output paths checked before a run (:mod:`slamcore.files`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from slamcore.errors import ConfigError
from slamcore.files import check_no_folder_at, check_not_inputs, check_output_dir, check_output_file


def test_an_output_folder_holding_a_folder_under_a_written_name_is_refused(tmp_path):
    """Third hostile pass: ``--out`` whose ``eval.json`` (or ``sweep.csv``...) was a folder
    passed the checks and failed with IsADirectoryError after the work."""
    (tmp_path / "o" / "eval.json").mkdir(parents=True)
    assert check_output_dir(tmp_path / "o") == tmp_path / "o"  # no names: as before
    with pytest.raises(ConfigError, match=r"--out .*/o: eval.json there is a folder"):
        check_output_dir(tmp_path / "o", files=("eval.png", "eval.json"))
    check_output_dir(tmp_path / "new", files=("eval.json",))  # a folder yet to make: fine
    with pytest.raises(ConfigError, match="--save-map"):
        check_no_folder_at(tmp_path / "o", ["eval.json"], "--save-map")


def test_an_output_folder_through_a_link_to_nothing_is_refused(tmp_path):
    """Seventh hostile pass: ``--out`` a dangling symbolic link (or a folder under one)
    passed the checks and failed in mkdir with a FileExistsError traceback."""
    (tmp_path / "link").symlink_to(tmp_path / "gone")
    for out in (tmp_path / "link", tmp_path / "link" / "sub"):
        with pytest.raises(ConfigError, match=r"link is a symbolic link to .*gone, which does not exist"):
            check_output_dir(out)
    with pytest.raises(ConfigError, match="which does not exist"):
        check_output_file(tmp_path / "link" / "loops.csv")
    (tmp_path / "gone").mkdir()  # the link leads somewhere now: fine
    assert check_output_dir(tmp_path / "link" / "sub") == tmp_path / "link" / "sub"


def test_an_output_file_named_with_a_trailing_slash_is_refused(tmp_path):
    """``--out results/`` (a folder not made yet): Path() drops the slash, and the run
    wrote a file named ``results``."""
    with pytest.raises(ConfigError, match="names a folder .it ends in a slash.; give a file name"):
        check_output_file(f"{tmp_path}/results/")
    assert check_output_file(f"{tmp_path}/results.json") == tmp_path / "results.json"


def test_an_output_that_is_an_input_is_refused(tmp_path):
    """Seventh hostile pass: a run wrote over (or removed as stale) its own input."""
    data = tmp_path / "o" / "trajectory.bag"
    data.parent.mkdir()
    data.write_bytes(b"a bag")
    (tmp_path / "alias").symlink_to(tmp_path / "o")
    outputs = [("the output (in --out)", tmp_path / "alias" / "trajectory.bag")]
    with pytest.raises(ConfigError, match=r"trajectory.bag is the input --dataset: .*would write over it"):
        check_not_inputs(outputs, {"--dataset": data, "--config": None})
    check_not_inputs(outputs, {"--dataset": tmp_path / "o", "--config": None})  # a folder: no file of it
    check_not_inputs([("--out", tmp_path / "new.csv")], {"--dataset": data})


def test_folder_name_names_dot_and_dot_dot_after_the_folder(tmp_path, monkeypatch):
    """``--dataset .`` gave the default output folder ``runs/-robot1-isam2``."""
    from slamcore.files import folder_name

    (tmp_path / "seq" / "sub").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "seq" / "sub")
    assert folder_name(".") == "sub"
    assert folder_name("..") == "seq"
    assert folder_name("../sub/.") == "sub"
    assert folder_name("x.g2o") == "x.g2o"
    assert folder_name("/") == "root"


MRCLAM = Path("/work/shared/data/mrclam6")


@pytest.mark.skipif(not MRCLAM.is_dir(), reason="MRCLAM Dataset 6 not available")
def test_a_dataset_read_as_dot_is_named_after_its_folder(monkeypatch):
    from graphslam.sources.planar.mrclam import read_mrclam

    monkeypatch.chdir(MRCLAM)
    assert read_mrclam(".").name == "mrclam6-robot1"


def test_a_write_cut_by_a_size_limit_names_its_output(tmp_path):
    """A file-size limit (or a full disk) met while writing: the system's error names no
    file, and the one line said "an output file"; it names the output now."""
    import os
    import subprocess
    import sys

    from tests.conftest import ROOT

    code = (
        "import resource, sys\n"
        "from slamcore.files import atomic_open\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.RLIM_INFINITY))\n"
        "try:\n"
        "    with atomic_open(sys.argv[1]) as f:\n"
        "        f.write('x' * 100_000)\n"
        "except OSError as e:\n"
        "    print(e.errno, e.filename)\n"
    )
    target = tmp_path / "trajectory.tum"
    done = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.stdout.split() == ["27", str(target)], done.stderr  # EFBIG
    assert not list(tmp_path.iterdir())  # no partial file left


def test_an_output_named_through_a_link_into_proc_is_refused(tmp_path, monkeypatch):
    """``convert g.g2o /dev/stdout > file``: /dev/stdout -> /proc/self/fd/1 -> a regular
    file passed the device test, and the output replaced the /dev/stdout link itself."""
    from slamcore.errors import ConfigError
    from slamcore.files import check_special_file

    link = tmp_path / "stdout"
    link.symlink_to("/proc/self/fd/1")
    with pytest.raises(ConfigError, match="a link into /proc"):
        check_special_file(link)
    with pytest.raises(ConfigError, match="writing to stdout is not supported"):
        check_output_file("-")


def test_a_link_is_written_through_and_kept(tmp_path):
    from slamcore.files import atomic_open

    target = tmp_path / "data" / "real.csv"
    target.parent.mkdir()
    link = tmp_path / "out.csv"
    link.symlink_to(target)  # dangling: the target is made, as open() would
    with atomic_open(link) as fh:
        fh.write("a\n")
    assert link.is_symlink() and target.read_text() == "a\n"
    with atomic_open(link) as fh:
        fh.write("b\n")
    assert link.is_symlink() and target.read_text() == "b\n"
