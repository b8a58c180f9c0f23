"""OutputWrites: every output tried, the refused ones named once (fifteenth hostile pass)."""

from __future__ import annotations

import errno

import pytest

from graphslam.outputs.writers import OutputWrites
from slamcore.errors import GraphSlamError


def _refused(code: int):
    def writer(path, *args):
        raise OSError(code, "refused", str(path))

    return writer


def _text(path, text):
    path.write_text(text)


def test_a_refused_file_is_noted_the_next_written_and_the_earlier_file_removed(tmp_path):
    (tmp_path / "a.tum").write_text("an earlier run's")
    writes, paths = OutputWrites(tmp_path), {}
    assert not writes(paths, "a", tmp_path / "a.tum", _refused(errno.ENOSPC))
    assert writes(paths, "b", tmp_path / "b.csv", _text, "b")
    assert not writes(paths, "c", tmp_path / "c.json", _refused(errno.EFBIG))
    assert paths == {"b": tmp_path / "b.csv"} and not (tmp_path / "a.tum").exists()
    with pytest.raises(GraphSlamError) as e:
        writes.check(paths.values())
    assert str(e.value) == (
        f"no space left on device writing {tmp_path / 'a.tum'}: refused; not written either: c.json; "
        f"{tmp_path}/ holds b.csv"
    )


def test_an_error_that_is_not_the_file_systems_refusal_is_raised_at_once(tmp_path):
    writes = OutputWrites(tmp_path)
    # (EACCES and EPERM are a refusal since hostile pass 22: an output the user may not replace)
    with pytest.raises(OSError) as err:
        writes({}, "a", tmp_path / "a.tum", _refused(errno.EBADF))
    assert err.value.errno == errno.EBADF
    writes.check([])  # nothing refused: no error


def test_a_folder_elsewhere_is_named_by_its_path(tmp_path):
    writes = OutputWrites(tmp_path / "out")
    assert not writes.attempt(tmp_path / "map", _refused(errno.EDQUOT), tmp_path / "map")
    assert writes.names() == [str(tmp_path / "map")]
    with pytest.raises(GraphSlamError, match="disk quota exceeded .* holds none of this command's outputs"):
        writes.check([])


def test_a_folder_moved_while_the_outputs_are_written_is_one_line(tmp_path):
    """The folder moved between two outputs (after the command last found it): the
    next file has nowhere to go, a FileNotFoundError that was a traceback."""
    out = tmp_path / "out"
    out.mkdir()
    writes, paths = OutputWrites(out), {}
    assert writes(paths, "a", out / "a.json", _text, "a")
    out.rename(tmp_path / "moved")
    assert not writes(paths, "b", out / "b.png", _text, "b")
    assert not writes(paths, "c", out / "c.csv", _text, "c")
    with pytest.raises(GraphSlamError) as e:
        writes.check(paths.values())
    assert str(e.value) == (
        f"{out} was moved or deleted while this command wrote its outputs into it; not written either: "
        "c.csv; written before it went: a.json"
    )
    assert (tmp_path / "moved" / "a.json").read_text() == "a"


def test_a_missing_file_in_a_folder_still_there_is_not_taken_for_a_moved_folder(tmp_path):
    def reads_a_missing_input(path):
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(tmp_path / "gone" / "input"))

    with pytest.raises(FileNotFoundError):
        OutputWrites(tmp_path)({}, "a", tmp_path / "a.json", reads_a_missing_input)
