"""Range-only SLAM on gtsam's Plaza logs (issue 31 item 5): the reader, range
observations, beacon initialisation from ranges, iSAM2 end to end, filters refusing."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import gtsam
import numpy as np
import pytest

from graphslam import registry
from graphslam.backends import gtsam_convert as conv
from graphslam.backends.planar.range_init import (RangeLandmarkInitialiser, principal_spread,
                                                  trilaterate)
from graphslam.cli.main import main
from graphslam.sources.planar.plaza import read_plaza
from slamcore.errors import InputError, MeasurementError
from slamcore.planar.records import Observation, ObservationKind, range_batch

#: Trilateration of noise-free ranges: exact but for rounding, metres.
EXACT_TOL_M = 1e-9
#: Range noise of the synthetic test, metres, and how far the trilaterated beacon may
#: land: 30 ranges from poses spread over ~20 m, so about sigma / sqrt(30) * a few.
NOISY_SIGMA_M = 0.5
NOISY_TOL_M = 0.5


def _plaza(name: str) -> Path:
    return Path(gtsam.findExampleDataFile(f"{name}_DR.txt"))


# --- records ------------------------------------------------------------------------


def test_range_observation_validates_and_range_bearing_still_does():
    o = Observation(3, 5, [12.5], [[4.0]], ObservationKind.RANGE)
    assert o.z.shape == (1,) and o.covariance.shape == (1, 1)
    rb = Observation(3, 5, [12.5, 0.1], np.eye(2))
    assert rb.kind is ObservationKind.RANGE_BEARING and rb.z.shape == (2,)
    for z, cov in (([-1.0], [[1.0]]), ([np.inf], [[1.0]]), ([1.0], [[0.0]]),
                   ([1.0, 0.2], [[1.0]]), ([1.0], np.eye(2))):
        with pytest.raises(MeasurementError):
            Observation(0, 1, z, cov, ObservationKind.RANGE)
    with pytest.raises(MeasurementError, match="row 1: range must be positive"):
        range_batch([0, 1], [2, 2], [3.0, 0.0], [1.0, 1.0])


def test_range_factor_is_gtsams_range_factor():
    obs = Observation(0, 7, [5.0], [[0.25]], ObservationKind.RANGE)
    factor = conv.range_factor(obs, 7)
    values = gtsam.Values()
    values.insert(gtsam.symbol_shorthand.X(0), gtsam.Pose2(1.0, 2.0, 0.3))
    values.insert(gtsam.symbol_shorthand.L(7), np.array([4.0, 6.0]))  # 5 m away: no error
    assert isinstance(factor, gtsam.RangeFactor2D)
    assert factor.error(values) == pytest.approx(0.0, abs=1e-12)
    values.update(gtsam.symbol_shorthand.L(7), np.array([4.0, 7.0]))
    d = np.hypot(3.0, 5.0) - 5.0
    assert factor.error(values) == pytest.approx(0.5 * d**2 / 0.25, rel=1e-9)
    with pytest.raises(Exception, match="range observation"):
        conv.range_factor(Observation(0, 7, [5.0, 0.1], np.eye(2)), 7)


# --- beacon initialisation ----------------------------------------------------------


def _synthetic_ranges(rng, n: int, sigma: float):
    beacon = np.array([7.3, -4.1])
    t = np.linspace(0.0, 2.5, n)
    positions = np.column_stack([10.0 * np.cos(t), 6.0 * np.sin(t)]) + rng.normal(0, 0.01, (n, 2))
    ranges = np.linalg.norm(positions - beacon, axis=1) + rng.normal(0.0, sigma, n)
    return beacon, positions, ranges


def test_trilateration_is_exact_on_noise_free_ranges():
    rng = np.random.default_rng(31)
    for _ in range(20):
        beacon, positions, ranges = _synthetic_ranges(rng, int(rng.integers(3, 40)), 0.0)
        beacon = beacon + rng.normal(0.0, 30.0, 2)
        ranges = np.linalg.norm(positions - beacon, axis=1)
        got = trilaterate(positions, ranges)
        assert np.linalg.norm(got - beacon) < EXACT_TOL_M


def test_trilateration_on_noisy_ranges_within_tolerance():
    rng = np.random.default_rng(5)
    for _ in range(10):
        beacon, positions, ranges = _synthetic_ranges(rng, 30, NOISY_SIGMA_M)
        assert np.linalg.norm(trilaterate(positions, ranges) - beacon) < NOISY_TOL_M


def test_trilateration_refuses_what_cannot_be_determined():
    line = np.column_stack([np.arange(5.0), 2.0 * np.arange(5.0)])
    assert trilaterate(line, np.full(5, 3.0)) is None  # collinear: two mirror points
    assert trilaterate(line[:2], np.full(2, 3.0)) is None


def test_initialiser_waits_for_spread_poses_then_hands_back_every_range():
    rng = np.random.default_rng(0)
    beacon = np.array([3.0, 4.0])
    init = RangeLandmarkInitialiser(min_ranges=5, min_spread_m=1.0)
    # a straight drive: ranges pile up, no position (mirror ambiguity)
    for k in range(10):
        p = np.array([0.5 * k, 0.0])
        obs = Observation(k, 9, [np.linalg.norm(p - beacon)], [[1.0]], ObservationKind.RANGE)
        init.add(9, k, p, obs)
        assert init.try_initialise(9) is None
    assert init.pending_count(9) == 10 and init.pending_landmarks() == [9]
    # then a turn: the poses spread in both directions
    got = None
    for k in range(10, 30):
        p = np.array([4.5, 0.8 * (k - 9)])
        obs = Observation(k, 9, [np.linalg.norm(p - beacon)], [[1.0]], ObservationKind.RANGE)
        init.add(9, k, p, obs)
        got = init.try_initialise(9)
        if got is not None:
            break
    assert got is not None
    position, observations = got
    assert len(observations) > 12  # not before the turn had spread the poses by 1 m
    assert np.linalg.norm(position - beacon) < EXACT_TOL_M
    assert [o.pose_id for o in observations] == list(range(len(observations)))
    assert init.pending_count() == 0
    assert principal_spread(rng.normal(size=(1, 2))) == 0.0


# --- the reader -----------------------------------------------------------------------


def test_reader_counts_on_plaza2():
    ds = read_plaza(_plaza("Plaza2"))
    assert ds.name == "plaza2" and ds.has_timestamps
    assert len(ds.frames) == 4091  # the start and one pose per DR line
    obs = [o for f in ds.frames for o in f.observations]
    assert len(obs) == 1816
    assert {o.landmark_id for o in obs} == {0, 1, 5, 6} == set(ds.landmarks_true)
    assert all(o.kind is ObservationKind.RANGE and o.z.shape == (1,) for o in obs)
    assert all(f.wTb_true is not None for f in ds.frames)
    assert np.allclose(ds.prior_wTb, [-34.208649, 45.300764, np.pi - 2.021089], atol=1e-5)
    assert any("heading turned by pi" in n for n in ds.notes)
    assert ds.frames[1].odometry.delta[1] == 0.0


def test_reader_counts_on_plaza1():
    ds = read_plaza(_plaza("Plaza1"))
    assert len(ds.frames) == 9658
    assert sum(len(f.observations) for f in ds.frames) == 3529
    assert not any("heading turned" in n for n in ds.notes)
    assert any("out of time order at 2 places" in n for n in ds.notes)


def _copy_log(tmp_path: Path, name: str = "Plaza2") -> Path:
    for suffix in ("_DR.txt", "_TD.txt", "_.mat"):
        shutil.copy(Path(gtsam.findExampleDataFile(f"{name}_DR.txt")).with_name(name + suffix),
                    tmp_path / (name + suffix))
    return tmp_path / f"{name}_DR.txt"


def test_a_gap_in_the_dead_reckoning_is_said_and_its_ranges_dropped(tmp_path):
    """600 DR lines (60 s) removed from Plaza2: no word, and the 256 ranges timed inside
    the gap were put on the two frames at its edges (twentieth hostile pass)."""
    dr = _copy_log(tmp_path)
    lines = dr.read_text().splitlines(keepends=True)
    gap_t = float(lines[2600].split()[0]) - float(lines[1998].split()[0])
    dr.write_text("".join(lines[:1999] + lines[2600:]))
    td = np.loadtxt(dr.with_name("Plaza2_TD.txt"))
    t_a, t_b = float(lines[1998].split()[0]), float(lines[2600].split()[0])
    inside = int(np.sum((td[:, 0] > t_a + 0.1) & (td[:, 0] < t_b - 0.1)))
    ds = read_plaza(dr)
    assert len(ds.warnings) == 1
    assert ds.warnings[0].startswith(f"Plaza2_DR.txt has no line for {gap_t:.1f} s before its line 2000 ")
    assert f"{inside} ranges timed inside it are dropped" in ds.warnings[0] and inside > 200
    n_ranges = sum(len(f.observations) for f in ds.frames)
    assert n_ranges == sum(len(f.observations) for f in read_plaza(_plaza("Plaza2")).frames) - inside


@pytest.mark.parametrize("name", ["Plaza1", "Plaza2"])
def test_the_shipped_logs_have_no_gap(name):
    """Their longest DR intervals are 1.2 and 3.5 medians, under DR_GAP_MEDIANS."""
    assert read_plaza(_plaza(name)).warnings == ()


@pytest.mark.parametrize("which, line, text, reason", [
    ("_DR.txt", 3, "3152.3 abc 0.1", "is not a number"),
    ("_DR.txt", 2, "3152.1 0.1", "needs 3 numbers"),
    ("_DR.txt", 4, "3000.0 0.1 0.0", "time order"),
    ("_TD.txt", 5, "3153.0 2 1 -4.0", "range -4 m"),
    ("_TD.txt", 2, "3153.0 2 1.5 4.0", "whole numbers"),
])
def test_a_bad_line_is_named_by_file_and_line(tmp_path, which, line, text, reason):
    dr = _copy_log(tmp_path)
    path = tmp_path / ("Plaza2" + which)
    lines = path.read_text().splitlines()
    lines[line - 1] = text
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        read_plaza(dr)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: ") and reason in msg and "\n" not in msg


def test_missing_range_file_and_folder_dispatch(tmp_path):
    dr = _copy_log(tmp_path)
    ds = registry.load_dataset(str(tmp_path))  # a folder holding the three files
    assert len(ds.frames) == 4091 and not registry.is_visual_dataset(str(tmp_path))
    assert registry.load_dataset(str(dr)).name == "plaza2"
    (tmp_path / "Plaza2_TD.txt").unlink()
    with pytest.raises(InputError, match="Plaza2_TD.txt: Plaza log file not found"):
        read_plaza(dr)


def test_dataset_graph_holds_range_factors():
    ds = read_plaza(_plaza("Plaza2")).truncated(400)
    graph = conv.dataset_graph(ds)
    n_ranges = sum(len(f.observations) for f in ds.frames)
    kinds = [type(graph.at(i)).__name__ for i in range(graph.size())]
    assert kinds.count("RangeFactor2D") == n_ranges > 0
    assert kinds.count("BetweenFactorPose2") == 399


# --- end to end ----------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.heavy  # 12 s of CI; benchmarks/bench_plaza.py runs the same
def test_isam2_on_plaza2_beats_dead_reckoning(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--dataset", "plaza2", "--rerun", "off", "--quiet",
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["landmarks"] == 4
    assert m["ate_rmse_m"] < m["odometry_ate_rmse_m"]


@pytest.mark.parametrize("backend", ["ekf", "fastslam2"])
def test_filters_refuse_range_only_data_in_one_line(tmp_path, capsys, backend):
    code = main(["run", "--dataset", "plaza2", "--backend", backend, "--rerun", "off",
                 "--quiet", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert err.endswith("range-bearing observations only, got range (range-only data: the isam2 back end takes it)")


@pytest.mark.parametrize("part", ["_TD.txt", "_.mat"])
@pytest.mark.parametrize("command", ["run", "compare"])
def test_another_file_of_the_log_points_to_its_dr_file(tmp_path, capsys, part, command):
    """Tenth hostile pass: the ranges file was read as a Victoria Park log ("unknown tag
    '3.1520127000072971e+003'"), the .mat as "not a text file"."""
    _copy_log(tmp_path)
    code = main([command, "--dataset", str(tmp_path / f"Plaza2{part}"), "--rerun", "off",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert f"Plaza2{part}: a file of the Plaza range-only log Plaza2_DR.txt: give --dataset Plaza2_DR.txt" in err


def test_compare_on_ranges_runs_the_back_ends_that_take_them(tmp_path, capsys):
    """Tenth hostile pass: compare's default ran the EKF and both FastSLAMs on Plaza2, each
    failing in its run (exit 1); a back end named that cannot take ranges is refused first."""
    assert main(["compare", "--dataset", "plaza2", "--max-steps", "300", "--rerun", "off",
                 "--out", str(tmp_path / "c")]) == 0
    assert "comparing the back ends that take them (isam2)" in capsys.readouterr().err
    entries = json.loads((tmp_path / "c" / "compare.json").read_text())["runs"]
    assert [e["backend"] for e in entries] == list(registry.RANGE_BACKENDS) == ["isam2"]
    assert main(["compare", "--dataset", "plaza2", "--backends", "isam2", "ekf", "--rerun", "off",
                 "--out", str(tmp_path / "d")]) == 2
    assert "which ekf cannot take (back ends that do: isam2)" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
    # narrowed to iSAM2, --seed has nothing to seed: refused in one line, as elsewhere
    assert main(["compare", "--dataset", "plaza2", "--seed", "3", "--rerun", "off",
                 "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seed has no effect here" in err[0]


@pytest.mark.parametrize("backend", registry.BACKENDS)
def test_the_table_says_which_back_ends_take_ranges(backend):
    """``ranges`` in the back-end table is what each back end does with range-only data."""
    from graphslam.pipelines import planar as pipeline
    from slamcore.errors import UnsupportedError

    ds = read_plaza(_plaza("Plaza2")).truncated(200)
    be = registry.make_backend(backend)
    if backend in registry.RANGE_BACKENDS:
        assert len(pipeline.run(ds, be).estimate.pose_ids) == 200
    else:
        with pytest.raises(UnsupportedError, match="range-bearing observations only"):
            pipeline.run(ds, be)


@pytest.mark.parametrize("with_truth", [True, False])
def test_sender_and_receiver_columns_exchanged_are_said(tmp_path, with_truth):
    """Plaza2's TD file with its sender and receiver columns exchanged: every range went to
    one "beacon" at the antenna's id 2, unsaid; the genuine file says nothing."""
    dr = _copy_log(tmp_path)
    assert read_plaza(dr).warnings == ()
    td = tmp_path / "Plaza2_TD.txt"
    rows = np.loadtxt(td)
    np.savetxt(td, rows[:, [0, 2, 1, 3]])
    if not with_truth:
        (tmp_path / "Plaza2_.mat").unlink()
    (warning,) = read_plaza(dr).warnings
    assert warning.startswith("Plaza2_TD.txt: its receivers (2) are read as the beacons, but its senders (0, 1, 5, 6)")
    assert "sender and receiver columns exchanged?" in warning
    assert ("(the truth's beacons)" in warning) is with_truth


def test_a_map_of_range_only_beacons_says_no_back_end_localises_on_it(tmp_path, capsys):
    """``--save-map`` on Plaza wrote a map in silence that every localiser then refused;
    the EKF's refusal named isam2, which refuses it too (nineteenth hostile pass)."""
    base = ["--dataset", "plaza2", "--rerun", "off", "--quiet"]
    assert main(["run", *base, "--max-steps", "800", "--save-map", str(tmp_path / "map"),
                 "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "is of range-only beacons: no back end localises against ranges alone" in err
    assert main(["run", *base, "--backend", "ekf", "--map", str(tmp_path / "map"),
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("got range (range-only data: it runs without a map)")
    assert "isam2" not in err


@pytest.mark.parametrize("extra, reason", [
    ([1.0, 100.0, 100.0], "TL row 5: beacon 1 is given a second position"),
    ([1.6, 0.0, 0.0], "TL row 5: beacon id 1.6 is not a whole number"),
])
def test_a_truth_file_giving_a_beacon_twice_or_a_fractional_id_is_refused(tmp_path, extra, reason):
    """Hostile pass 21: the last of two TL rows won (map RMSE 95.5 m against 3.09 m, blamed
    on units), and beacon 1.6 was read as beacon 1."""
    from scipy.io import loadmat, savemat

    dr = _copy_log(tmp_path)
    mat_path = tmp_path / "Plaza2_.mat"
    mat = {k: v for k, v in loadmat(str(mat_path)).items() if not k.startswith("__")}
    assert len(mat["TL"]) == 4
    mat["TL"] = np.vstack([mat["TL"], extra])
    savemat(str(mat_path), mat)
    with pytest.raises(InputError, match=reason) as err:
        read_plaza(dr)
    assert str(mat_path) in str(err.value)


def test_a_folder_of_plaza_files_that_is_no_one_log_says_why(tmp_path, capsys):
    """Hostile pass 21: two logs in one folder, or a DR file alone, were read as an image
    folder ("no images (.png, ...)")."""
    from graphslam.cli.main import main

    (tmp_path / "both").mkdir()
    _copy_log(tmp_path / "both", "Plaza1")
    _copy_log(tmp_path / "both", "Plaza2")
    assert main(["run", "--dataset", str(tmp_path / "both"), "--out", str(tmp_path / "o")]) == 2
    assert "holds 2 Plaza logs (Plaza1_DR.txt, Plaza2_DR.txt)" in capsys.readouterr().err
    (tmp_path / "both" / "Plaza1_TD.txt").unlink()
    (tmp_path / "both" / "Plaza2_DR.txt").unlink()
    assert main(["run", "--dataset", str(tmp_path / "both"), "--out", str(tmp_path / "o")]) == 2
    assert "Plaza1_DR.txt has no Plaza1_TD.txt beside it" in capsys.readouterr().err


def test_a_truth_of_another_log_is_a_warning_and_an_unlisted_beacon_a_note(tmp_path):
    """Hostile pass 21: Plaza1's .mat beside Plaza2's log gave exit 0 and ATE n/a with only
    a data note; a beacon missing from TL was mapped and not scored, unsaid."""
    from scipy.io import loadmat, savemat

    dr = _copy_log(tmp_path)
    other = Path(gtsam.findExampleDataFile("Plaza1_DR.txt")).with_name("Plaza1_.mat")
    mat = {k: v for k, v in loadmat(str(other)).items() if not k.startswith("__")}
    mat["GT"] = mat["GT"].copy()
    mat["GT"][:, 0] += 1e5  # nowhere near Plaza2's clock
    savemat(str(tmp_path / "Plaza2_.mat"), mat)
    ds = read_plaza(dr)
    assert any(w.startswith("the .mat's GT covers none of the log") for w in ds.warnings)
    shutil.copy(Path(gtsam.findExampleDataFile("Plaza2_DR.txt")).with_name("Plaza2_.mat"), tmp_path / "Plaza2_.mat")
    mat = {k: v for k, v in loadmat(str(tmp_path / "Plaza2_.mat")).items() if not k.startswith("__")}
    ranged = sorted({int(b) for b in np.loadtxt(tmp_path / "Plaza2_TD.txt")[:, 2]})
    mat["TL"] = mat["TL"][mat["TL"][:, 0] != ranged[0]]
    savemat(str(tmp_path / "Plaza2_.mat"), mat)
    ds = read_plaza(dr)
    assert f"beacon(s) {ranged[0]} ranged but not in the .mat's TL: mapped, not scored" in ds.notes
    assert not any("covers none" in w for w in ds.warnings)
