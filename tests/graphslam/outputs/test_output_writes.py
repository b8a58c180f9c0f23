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
    with pytest.raises(PermissionError):
        writes({}, "a", tmp_path / "a.tum", _refused(errno.EACCES))
    writes.check([])  # nothing refused: no error


def test_a_folder_elsewhere_is_named_by_its_path(tmp_path):
    writes = OutputWrites(tmp_path / "out")
    assert not writes.attempt(tmp_path / "map", _refused(errno.EDQUOT), tmp_path / "map")
    assert writes.names() == [str(tmp_path / "map")]
    with pytest.raises(GraphSlamError, match="disk quota exceeded .* holds none of this command's outputs"):
        writes.check([])
