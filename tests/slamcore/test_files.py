"""Output paths checked before a run (:mod:`slamcore.files`)."""

from __future__ import annotations

import pytest

from slamcore.errors import ConfigError
from slamcore.files import check_no_folder_at, check_output_dir


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
