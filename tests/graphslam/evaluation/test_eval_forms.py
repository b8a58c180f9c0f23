"""``graphslam eval`` with a file not of its format's form (hostile pass): a TUM file
forced as EuRoC read its seconds as nanoseconds and its columns shifted (100/100
matched, 109 degrees, exit 0); now one ``graphslam: error:`` line naming file and
line. And a --times file out of order names its stamps as plain numbers."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from graphslam.sources.ground_truth import read_trajectory
from slamcore.errors import InputError
from tests import trajectories as tr


def _circles(tmp_path):
    """The finding's two TUM files (space-separated, seconds), the second shifted 0.5 s."""
    paths = []
    for name, o in (("circ.tum", 0), ("circ_shift.tum", 0.5)):
        path = tmp_path / name
        path.write_text("".join(
            f"{1305031102.175304 + 0.033 * k + o:.6f} {math.cos(k / 10) + (0.05 * math.sin(k) if o else 0)} "
            f"{math.sin(k / 10)} 0.1 0 0 {math.sin(k / 20)} {math.cos(k / 20)}\n" for k in range(100)))
        paths.append(path)
    return paths


def test_tum_forced_as_euroc_is_refused_with_file_and_line(tmp_path, capsys):
    a, b = _circles(tmp_path)
    assert tr.run_eval(tmp_path, capsys, a, b)[0] == 0  # told from the content: TUM, scored
    code, out, err = tr.run_eval(tmp_path, capsys, a, b, "--format", "euroc")
    assert code == 2 and "circ_shift" not in out
    tr.one_error(err, "circ.tum:1", "comma-separated")


def test_tum_named_csv_is_refused_not_read_as_euroc(tmp_path, capsys):
    a, b = _circles(tmp_path)
    shutil.copy(a, tmp_path / "circ.csv")  # the .csv extension says EuRoC
    code, _, err = tr.run_eval(tmp_path, capsys, tmp_path / "circ.csv", b)
    assert code == 2
    tr.one_error(err, "circ.csv:1", "comma-separated")


def test_euroc_with_seconds_is_refused(tmp_path, capsys):
    a, b = _circles(tmp_path)
    commas = tmp_path / "commas.csv"
    commas.write_text(a.read_text().replace(" ", ","))  # commas, but TUM's seconds
    code, _, err = tr.run_eval(tmp_path, capsys, commas, b)
    assert code == 2
    tr.one_error(err, "commas.csv:1", "integer nanoseconds", "1305031102.175304")


def test_a_negative_euroc_time_is_named_not_blamed_on_tum(tmp_path, capsys):
    """A minus sign on an integer EuRoC stamp was told "(seconds: a TUM file?)"."""
    gt, est = tr.write_pair(tmp_path, "euroc")
    lines = est.read_text().splitlines(keepends=True)
    k = next(i for i, t in enumerate(lines) if not t.startswith("#"))
    lines[k] = "-" + lines[k]
    est.write_text("".join(lines))
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est)
    assert code == 2
    tr.one_error(err, f"{est.name}:{k + 1}", "never negative")
    assert "TUM" not in err


def test_comma_in_a_forced_tum_or_kitti_line_is_refused(tmp_path):
    gt, _ = tr.write_pair(tmp_path, "euroc")
    for fmt in ("tum", "kitti"):
        with pytest.raises(InputError, match=f"a comma in a {fmt.upper()} line") as e:
            read_trajectory(gt, fmt)
        assert e.value.line == 2  # line 1 is the header comment


def test_euroc_empty_or_space_separated_field_is_refused(tmp_path):
    gt, _ = tr.write_pair(tmp_path, "euroc")
    good = read_trajectory(gt, "euroc")
    lines = gt.read_text().splitlines()
    for k, bad in ((3, lines[3].replace(",", ",,", 1)), (4, lines[4].replace(",", " ", 2))):
        edited = list(lines)
        edited[k] = bad
        gt.write_text("\n".join(edited) + "\n")
        with pytest.raises(InputError, match="empty field or one of two numbers") as e:
            read_trajectory(gt, "euroc")
        assert e.value.line == k + 1
    gt.write_text("\n".join(lines) + "\n")
    again = read_trajectory(gt)  # the honest file still reads, told or given
    assert again.format == "euroc" and np.array_equal(again.stamps_s, good.stamps_s)


def test_times_out_of_order_names_plain_numbers(tmp_path, capsys, shared_data):
    kitti = shared_data / "kitti07"
    lines = (kitti / "times.txt").read_text().splitlines()
    lines[49], lines[50] = lines[50], lines[49]
    times = tmp_path / "times.txt"
    times.write_text("\n".join(lines) + "\n")
    poses = kitti / "poses.txt"
    code, _, err = tr.run_eval(tmp_path, capsys, poses, poses, "--format", "kitti", "--times", times)
    assert code == 2
    tr.one_error(err, "times.txt:51", f"{float(lines[50])} is not after {float(lines[49])} of line 50")
    assert "np." not in err


def test_a_times_file_no_kitti_file_takes_is_refused(tmp_path, capsys):
    """Third hostile pass: --times with TUM files was read by nobody (exit 0, no word)."""
    gt, est = tr.write_pair(tmp_path, "tum")
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{k}\n" for k in range(len(gt.read_text().splitlines()))))
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est, "--times", times)
    assert code == 2
    tr.one_error(err, str(times), "--times gives KITTI files their stamps; none of these files is KITTI")


@pytest.mark.parametrize("rows, fmt", [
    ("# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n", "tum"),
    ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n", "kitti"),
])
def test_a_byte_order_mark_is_no_number(tmp_path, rows, fmt):
    # an editor's byte-order mark before the first line: the TUM header was read as
    # data ("1 numbers a line"), a KITTI first row refused as malformed
    (tmp_path / "t.txt").write_text("\ufeff" + rows, encoding="utf-8")
    traj = read_trajectory(tmp_path / "t.txt")
    assert traj.format == fmt and len(traj.wTc) == 2
