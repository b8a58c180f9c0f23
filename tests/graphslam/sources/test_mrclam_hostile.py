"""A hostile pass on the MRCLAM reader's ids, odometry and sightings: huge or fractional
subjects and barcodes, an odometry log of one time, lines written twice, a robot's own
barcode and sightings off the odometry's clock. Each folder is a 60-s cut of Dataset 6
(robot 1) built by the fifteenth pass's ``cut``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from graphslam.sources.planar.mrclam import MrclamConfig, read_mrclam
from slamcore.errors import InputError
from tests.graphslam.sources.test_mrclam_fifteenth import T0, cut

END_S = 60.0


@pytest.fixture(scope="module")
def mrclam(shared_data) -> Path:
    return shared_data / "mrclam6"


def _read(mrclam: Path, folder: Path, edits: dict):
    return read_mrclam(cut(mrclam, folder, end_s=END_S, edits=edits), MrclamConfig(robot=1))


def _set(row: int, column: int, value: str):
    """An edit putting ``value`` in ``column`` of data row ``row`` (file line ``row + 5``)."""

    def edit(rows):
        rows[row][column] = value
        return rows

    return edit


# -- 1. ids beyond what the graph's keys and int fields hold ----------------------------


@pytest.mark.parametrize(
    "name, row, column, value, said",
    [
        # barcode 90 is landmark 15's, seen 60 times by robot 1 in the cut
        ("Barcodes.dat", 14, 1, "1000000000000", "(got 15 and 1000000000000)"),
        ("Barcodes.dat", 14, 0, "1099511627776", "(got 1099511627776 and 90)"),  # 2**40
        ("Barcodes.dat", 14, 0, "1e20", "(got 1e+20 and 90)"),  # overflowed int64: a traceback
        ("Barcodes.dat", 14, 0, "3.5", "(got 3.5 and 90)"),
        ("Landmark_Groundtruth.dat", 9, 0, "99999999999", "(got 99999999999)"),
        ("Robot1_Measurement.dat", 1, 1, "99999999999", "barcode 99999999999 is not a whole number"),
        # a 301-digit barcode was printed whole in the unknown-barcode note
        ("Robot1_Measurement.dat", 1, 1, "1e300", "barcode 1e+300 is not a whole number"),
    ],
)
def test_huge_or_fractional_ids_are_refused_naming_file_and_line(
    mrclam, tmp_path, name, row, column, value, said
):
    with pytest.raises(InputError) as err:
        _read(mrclam, tmp_path / "f", {name: _set(row, column, value)})
    assert f"{name}:{row + 5}: " in str(err.value)
    assert said in str(err.value) and "below 2147483648" in str(err.value)


def test_a_huge_subject_is_one_line_on_the_command_line(mrclam, tmp_path, capsys):
    """Subject 1e20 in Barcodes.dat: OverflowError with a traceback."""
    from graphslam.cli.main import main

    folder = cut(mrclam, tmp_path / "f", end_s=END_S, edits={"Barcodes.dat": _set(14, 0, "1e20")})
    rc = main(
        [
            "run",
            "--dataset",
            str(folder),
            "--robot",
            "1",
            "--rerun",
            "off",
            "--quiet",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("graphslam: error:"), err
    assert "Barcodes.dat:19: subject and barcode must be whole numbers" in err[0]


# -- 2. odometry of one time, odometry covering a small part of the sightings -----------


@pytest.mark.parametrize(
    "keep, said", [(1, "holds one command (at "), (3, "holds 3 commands, all at one time")]
)
def test_odometry_of_one_time_is_refused(mrclam, tmp_path, keep, said):
    """One odometry line held its command over the whole log, unsaid (its gap "inf")."""

    def one_time(rows):
        return [[rows[0][0], *r[1:]] for r in rows[:keep]]

    with pytest.raises(InputError) as err:
        _read(mrclam, tmp_path / "f", {"Robot1_Odometry.dat": one_time})
    assert "Robot1_Odometry.dat:5: " + said in str(err.value)
    assert "cannot be integrated" in str(err.value)


def test_odometry_covering_a_small_part_of_the_sightings_is_warned(mrclam, tmp_path):
    """Odometry over the first 10 s of 60 s of sightings: most dropped, in a note only."""
    ds = _read(
        mrclam,
        tmp_path / "f",
        {"Robot1_Odometry.dat": lambda rows: [r for r in rows if float(r[0]) < T0 + 10]},
    )
    (warning,) = ds.warnings
    assert (
        warning.startswith("robot 1: ")
        and "sightings fall outside its odometry's span and are dropped (" in warning
    )
    assert "odometry alone" not in warning and "covering 18 % of theirs" in warning
    assert not any("sightings after its odometry ends dropped" in n for n in ds.notes)


# -- 3. a sighting written twice ---------------------------------------------------------


def _sightings(ds) -> int:
    return sum(len(f.observations) for f in ds.frames)


def test_a_repeated_sighting_line_is_dropped_and_counted(mrclam, tmp_path):
    """The same line twice (adjacent, or after another sighting of that instant) was two
    sightings."""

    def twice(rows):
        k = next(i for i in range(len(rows) - 1) if rows[i][0] == rows[i + 1][0])
        return rows[: k + 2] + [list(rows[k]), list(rows[k + 1])] + rows[k + 2 :]

    plain = _read(mrclam, tmp_path / "plain", {})
    dup = _read(mrclam, tmp_path / "dup", {"Robot1_Measurement.dat": twice})
    assert "robot 1: 2 repeated lines of Robot1_Measurement.dat dropped" in dup.notes
    assert _sightings(dup) == _sightings(plain)


def test_two_readings_of_one_barcode_at_one_time_are_both_dropped_and_warned(mrclam, tmp_path):
    """A second reading 0.5 m longer of a sighting's barcode at its time was kept beside
    it: two contradicting sightings of one landmark, each taken as evidence."""

    def clash(rows):
        r = rows[10]
        return rows[:11] + [[r[0], r[1], f"{float(r[2]) + 0.5:.3f}", r[3]]] + rows[11:]

    plain = _read(mrclam, tmp_path / "plain", {})
    ds = _read(mrclam, tmp_path / "clash", {"Robot1_Measurement.dat": clash})
    (warning,) = ds.warnings
    assert warning.startswith("robot 1: 2 sightings in Robot1_Measurement.dat share their time and barcode")
    assert "all of them dropped" in warning
    assert _sightings(ds) == _sightings(plain) - 1


# -- 4. odometry lines repeating a time with another command --------------------------------


def test_odometry_repeating_a_time_with_another_command_is_counted_and_the_later_held(mrclam, tmp_path):
    def added(rows):
        return rows[:101] + [[rows[100][0], "0.300", "0.500"]] + rows[101:]

    def replaced(rows):
        return rows[:100] + [[rows[100][0], "0.300", "0.500"]] + rows[101:]

    both = _read(mrclam, tmp_path / "both", {"Robot1_Odometry.dat": added})
    later = _read(mrclam, tmp_path / "later", {"Robot1_Odometry.dat": replaced})
    assert (
        "robot 1: 1 lines of Robot1_Odometry.dat repeat the time of the line before with another "
        "command: the later of each is held (the earlier lasts no time)"
    ) in both.notes
    steps = [np.array([f.odometry.delta for f in ds.frames[1:]]) for ds in (both, later)]
    np.testing.assert_array_equal(*steps)


# -- 5. the robot's own barcode ------------------------------------------------------------


def test_sightings_of_the_robots_own_barcode_are_counted(mrclam, tmp_path):
    def own(rows):  # robot 1 wears barcode 5
        return rows[:3] + [[rows[3][0], "5", "1.0", "0.1"]] + rows[3:]

    ds = _read(mrclam, tmp_path / "f", {"Robot1_Measurement.dat": own})
    assert "robot 1: 1 sightings of its own barcode (5) in the whole log dropped" in ds.notes


# -- 6. every sighting off the odometry's clock ----------------------------------------------


def test_all_sightings_outside_the_odometry_is_a_warning(mrclam, tmp_path):
    """Sightings 1000 s late (another clock): all dropped, said in a note only."""

    def shifted(rows):
        return [[f"{float(r[0]) + 1000:.3f}", *r[1:]] for r in rows]

    ds = _read(mrclam, tmp_path / "f", {"Robot1_Measurement.dat": shifted})
    (warning,) = ds.warnings
    assert (
        warning.startswith("robot 1: ")
        and "all 202 of its sightings fall outside its odometry's span" in warning
    )
    assert "robot 1 runs on odometry alone" in warning and "do the logs' clocks disagree" in warning
    assert _sightings(ds) == 0


# -- 5. odometry that is not the robot's, or not in the format's units ----------------


def _scale_column(column: int, factor: float):
    def edit(rows):
        for r in rows:
            r[column] = repr(float(r[column]) * factor)
        return rows

    return edit


def _robot2_odometry(mrclam: Path):
    """Robot 1's odometry replaced by robot 2's lines over the same minute."""
    rows = [line.split() for line in (mrclam / "Robot2_Odometry.dat").read_text().splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#") and float(r[0]) < T0 + END_S]
    return lambda _rows: rows


def test_genuine_odometry_fits_its_truth_without_a_word(mrclam, tmp_path):
    assert _read(mrclam, tmp_path / "f", {}).warnings == ()


@pytest.mark.parametrize(
    "edit, said",
    [
        (_scale_column(2, -1.0), "Robot1_Odometry.dat's turns run opposite to its truth's (cosine -0.9"),
        (_scale_column(2, 180.0 / np.pi), "Robot1_Odometry.dat's turns are 5"),
        (_scale_column(1, 100.0), "Robot1_Odometry.dat's forward motions are 9"),
    ],
    ids=["flipped turns", "deg/s", "cm/s"],
)
def test_odometry_with_a_flipped_sign_or_in_other_units_is_warned(mrclam, tmp_path, edit, said):
    """Each ran quietly: the sightings still fit the truth, so the truth doubt said nothing."""
    (warning,) = _read(mrclam, tmp_path / "f", {"Robot1_Odometry.dat": edit}).warnings
    assert warning.startswith("robot 1: ") and said in warning
    if "deg/s" in said or "are 5" in said:
        assert "(in deg/s?)" in warning
    if "forward" in said:
        assert "(in cm/s?)" in warning


def test_another_robots_odometry_is_warned(mrclam, tmp_path):
    (warning,) = _read(mrclam, tmp_path / "f", {"Robot1_Odometry.dat": _robot2_odometry(mrclam)}).warnings
    assert "Robot1_Odometry.dat's turns do not follow its truth's (cosine" in warning
    assert "another robot's odometry" in warning


def test_one_robots_flipped_odometry_is_warned_in_the_joint_run(mrclam, tmp_path):
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    folder = cut(
        mrclam,
        tmp_path / "f",
        robots=(1, 2),
        end_s=END_S,
        edits={"Robot2_Odometry.dat": _scale_column(2, -1.0)},
    )
    warnings = read_mrclam_all(folder, MrclamConfig()).warnings
    assert [w[:9] for w in warnings if "Odometry.dat" in w] == ["robot 2: "]


def test_a_truth_heading_in_degrees_is_refused_naming_file_and_line(mrclam, tmp_path):
    """Headings in degrees were read as radians: the truth spun, the scores were noise."""

    def degrees(rows):
        return [[t, x, y, repr(float(h) * 180.0 / np.pi)] for t, x, y, h in rows]

    with pytest.raises(InputError) as err:
        _read(mrclam, tmp_path / "f", {"Robot1_Groundtruth.dat": degrees})
    assert "Robot1_Groundtruth.dat:" in str(err.value) and "rad is not within +-2 pi (degrees?)" in str(
        err.value
    )


def test_a_hole_in_a_thinned_odometry_log_is_warned(mrclam, tmp_path):
    """Odometry thinned to about a line a second (median 1 s) with 20 s missing: the gap
    bound was 200 medians (200 s), so the command was held over the hole unsaid."""

    def thinned(rows):
        kept, last = [], -math.inf
        for r in rows:
            t = float(r[0])
            if t - last >= 1.0 and not T0 + 20 < t < T0 + 40:
                kept.append(r)
                last = t
        return kept

    ds = _read(mrclam, tmp_path / "f", {"Robot1_Odometry.dat": thinned})
    (warning,) = [w for w in ds.warnings if "has no line for" in w]
    assert "Robot1_Odometry.dat has no line for 2" in warning and "(gaps over 10" in warning
    # the genuine log keeps its bound: two seconds
    from graphslam.sources.planar.mrclam import odometry_gaps

    rows = [line.split() for line in (mrclam / "Robot1_Odometry.dat").read_text().splitlines()]
    times = np.array([float(r[0]) for r in rows if r and not r[0].startswith("#")])
    assert odometry_gaps(1, times)[0] == pytest.approx(2.0, abs=0.01)


@pytest.mark.parametrize(
    ("name", "robot_flag"),
    [("Robot2_Odometry.dat", " --robot 2"), ("Robot2_Measurement.dat", " --robot 2"), ("Barcodes.dat", "")],
)
def test_one_file_of_the_folder_as_the_dataset_names_the_folder(tmp_path, capsys, name, robot_flag):
    """One file of an MRCLAM folder given as ``--dataset`` was read as a pose graph and refused
    at "line 5: unknown tag '1248444187.156'"; it now names the folder (and robot) to give."""
    from graphslam.cli.main import main

    folder = tmp_path / "mrclam"
    folder.mkdir()
    for f in ("Barcodes.dat", "Robot2_Odometry.dat", "Robot2_Measurement.dat"):
        (folder / f).write_text("# header\n1248444187.156 0.1 0.0\n")
    assert main(["run", "--dataset", str(folder / name), "--out", str(tmp_path / "o"), "--rerun", "off"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"graphslam: error: {folder / name}: a file of the MRCLAM data set in {folder}: "
                   f"give --dataset {folder}{robot_flag}, which reads it with the others")
    assert not (tmp_path / "o").exists()


def test_a_measurement_file_without_its_folder_is_read_as_what_it_is(tmp_path, capsys):
    """A ``RobotN_Measurement.dat`` in a folder with neither Barcodes.dat nor an odometry
    log is no MRCLAM part: the reader it goes to refuses it, naming its line."""
    from graphslam.cli.main import main

    lone = tmp_path / "Robot2_Measurement.dat"
    lone.write_text("1248444187.156 0.1 0.0\n")
    assert main(["run", "--dataset", str(lone), "--out", str(tmp_path / "o"), "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert "a file of the MRCLAM data set" not in err and f"{lone}:1:" in err
