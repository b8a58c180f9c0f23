"""Precision and recall of place recognition (:mod:`graphslam.evaluation.places`) when a
figure is undefined: recall with no true pair was 0.0, read as every revisit missed."""

from __future__ import annotations

from graphslam.evaluation.places import pr_curve, score


def test_recall_is_none_without_true_pairs():
    assert score([(5, 1)], set()) == (0.0, None, 0)
    assert score([], set()) == (None, None, 0)
    assert score([], {(5, 1)}) == (None, 0.0, 0)  # a pair missed: recall 0 is right
    assert score([(5, 1)], {(5, 1)}) == (1.0, 1.0, 1)


def test_curve_without_true_pairs_has_no_recall():
    curve = pr_curve([(4, 0, 2.0), (3, 0, 1.0)], set())
    assert [(p.closures, p.precision, p.recall) for p in curve] == [(1, 0.0, None), (2, 0.0, None)]


def test_a_truth_csv_with_a_byte_order_mark_is_read(tmp_path):
    # a spreadsheet's "CSV UTF-8" export starts with one: it was refused as a file
    # without the header query,match, which it has
    from pathlib import Path

    from graphslam.evaluation.places import read_truth

    (tmp_path / "t.csv").write_text("\ufeffquery,match\n03.png,01.png\n", encoding="utf-8")
    paths = [Path(f"{k:02d}.png") for k in range(1, 4)]
    assert read_truth(tmp_path / "t.csv", paths) == {(2, 0)}


def test_a_truth_row_pairing_an_image_with_itself_is_refused_at_its_line(tmp_path):
    """Tenth hostile pass: a row ``10.png,10.png`` (a typo for another image) was dropped
    without a word, the true pair it meant never scored."""
    from pathlib import Path

    import pytest

    from graphslam.evaluation.places import read_truth, restrict_truth
    from slamcore.errors import InputError

    (tmp_path / "t.csv").write_text("query,match\n03.png,01.png\n03.png,03.png\n")
    paths = [Path(f"{k:02d}.png") for k in range(1, 4)]
    with pytest.raises(InputError, match="pairs '03.png' with itself") as e:
        read_truth(tmp_path / "t.csv", paths)
    assert e.value.line == 3
    # a selection keeps its pairs, re-indexed, and counts the others
    assert restrict_truth({(2, 0), (1, 0)}, [0, 2]) == ({(1, 0)}, 1)
