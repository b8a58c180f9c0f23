"""``graphslam eval`` says what makes a score doubtful (fourth hostile pass: silent
wrong answers of trajectory evaluation). Each case scored a plausible number, exit
0, without a word: a unit, convention or clock mix-up. Now a ``graphslam: warning:``
line, kept in eval.json; the honest pairs stay free of warnings, and the numbers
are checked against evo's definitions computed here in numpy."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphslam.evaluation.trajectory import EvalOptions, evaluate
from graphslam.evaluation.trajectory_doubts import clock_doubts
from tests import trajectories as tr
from tests.conftest import SHARED_DATA

#: ATE of a rigidly moved copy after SE(3) alignment: float64 residue only, metres.
SHIFTED_ATE_TOL_M = 1e-9


def _tum(path, stamps, wTc, order="xyzw"):
    """``wTc`` as TUM lines; ``order="wxyz"`` writes the quaternion w first (the mix-up)."""
    q = Rotation.from_matrix(wTc[:, :3, :3]).as_quat()
    if order == "wxyz":
        q = np.roll(q, 1, axis=1)
    path.write_text("".join(
        f"{t:.6f} {T[0, 3]:.9f} {T[1, 3]:.9f} {T[2, 3]:.9f} " + " ".join(f"{v:.9f}" for v in qq) + "\n"
        for t, T, qq in zip(stamps, wTc, q)))
    return path


def _kitti07():
    gt = np.loadtxt(SHARED_DATA / "kitti07" / "poses.txt")
    T = np.tile(np.eye(4), (len(gt), 1, 1))
    T[:, :3] = gt.reshape(-1, 3, 4)
    return T


def _scored(tmp_path, capsys, *argv):
    code, out, err = tr.run_eval(tmp_path, capsys, *argv)
    assert code == 0, err
    return json.loads((tmp_path / "o" / "eval.json").read_text())["estimates"][0], err


def _warned(err: str, *words: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.startswith("graphslam: warning:")]
    assert any(all(w in ln for w in words) for ln in lines), err


# numbers: evo's definitions, computed independently

def _umeyama_se3(src, dst):
    mu_s, mu_d = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ S @ Vt
    return R, mu_d - R @ mu_s


def test_ate_and_rpe_match_evos_definitions_in_numpy():
    t, ref = tr.trajectory(400, False)
    _, est = tr.trajectory(400, True)
    s = evaluate(t, ref, t, est, EvalOptions()).summary()
    R, p = _umeyama_se3(est[:, :3, 3], ref[:, :3, 3])
    aligned = est[:, :3, 3] @ R.T + p
    assert s["ate_rmse_m"] == pytest.approx(np.sqrt(np.mean(np.sum((aligned - ref[:, :3, 3]) ** 2, 1))), rel=1e-9)
    # RPE, delta 1 frame: translation of inv(inv(Q_i) Q_j) inv(P_i) P_j (alignment-free)
    rel = lambda T: np.linalg.inv(T[:-1]) @ T[1:]  # noqa: E731
    err = np.linalg.inv(rel(ref)) @ rel(est)
    assert s["rpe_trans_rmse_m"] == pytest.approx(np.sqrt(np.mean(np.sum(err[:, :3, 3] ** 2, 1))), rel=1e-6)


@pytest.mark.parametrize("align", ["se3", "sim3", "first", "none"])
def test_estimate_identical_to_the_truth_scores_exactly_zero(tmp_path, capsys, align):
    t, wTc = tr.trajectory(400, False)
    gt = _tum(tmp_path / "gt.txt", t, wTc)  # the estimate a copy: the file itself is said
    s, err = _scored(tmp_path, capsys, gt, _tum(tmp_path / "est.txt", t, wTc), "--align", align)
    assert s["ate_rmse_m"] == 0.0 and s["ate_max_m"] == 0.0
    assert "warning" not in err


def test_estimate_shifted_by_a_constant_scores_zero_after_se3(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    moved = wTc.copy()
    moved[:, :3, 3] += [100.0, -50.0, 7.0]
    s, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t, wTc), _tum(tmp_path / "e.txt", t, moved))
    assert s["ate_rmse_m"] < SHIFTED_ATE_TOL_M and "warning" not in err


# the mix-ups: said

def test_quaternion_written_w_first_is_said(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    te, est = tr.trajectory(380, True)
    s, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t, wTc),
                     _tum(tmp_path / "e.txt", te, est, order="wxyz"))
    assert s["ate_rot_rmse_deg"] > 90  # the number stays what it is: the warning says why
    _warned(err, "e.txt", "quaternions read as w x y z")
    assert any("w x y z" in w for w in s["warnings"])


def test_inverted_kitti_poses_are_said(tmp_path, capsys):
    T = _kitti07()
    gt = tr.write(tmp_path / "gt.txt", "kitti", np.zeros(len(T)), T)
    est = tr.write(tmp_path / "inv.txt", "kitti", np.zeros(len(T)), np.linalg.inv(T))
    _, err = _scored(tmp_path, capsys, gt, est)
    _warned(err, "inv.txt", "hardly follows", "poses inverted", "world-to-camera")


@pytest.mark.parametrize("align,words", [("se3", ("spreads 1e+03 times", "millimetres")),
                                         ("sim3", ("scales the estimate by 0.001", "millimetres"))])
def test_millimetres_against_metres_is_said(tmp_path, capsys, align, words):
    T = _kitti07()
    mm = T.copy()
    mm[:, :3, 3] *= 1000.0
    gt = tr.write(tmp_path / "gt.txt", "kitti", np.zeros(len(T)), T)
    est = tr.write(tmp_path / "mm.txt", "kitti", np.zeros(len(T)), mm)
    _, err = _scored(tmp_path, capsys, gt, est, "--align", align)
    _warned(err, "mm.txt", *words)


def test_kitti_files_of_different_lengths_paired_by_line_are_said(tmp_path, capsys):
    T = _kitti07()
    gt = tr.write(tmp_path / "gt.txt", "kitti", np.zeros(len(T)), T)
    est = tr.write(tmp_path / "key.txt", "kitti", np.zeros(80), T[::2])  # every other frame
    _, err = _scored(tmp_path, capsys, gt, est)
    _warned(err, "key.txt", "KITTI files pair by line", "80 poses", "160")


def test_frame_indices_against_seconds_are_said(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    _, est = tr.trajectory(40, True)
    _, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t - 1000.0, wTc),
                     _tum(tmp_path / "e.txt", np.arange(40.0), est))
    _warned(err, "e.txt", "frame indices", "frame k took the pose at k s")


def test_nanosecond_tum_stamps_are_said(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    _, est = tr.trajectory(400, True)
    ns = np.round(t * 1e9) + 1.4e18
    _, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", ns, wTc), _tum(tmp_path / "e.txt", ns, est))
    _warned(err, "times reach 1.4e+18", "not seconds")


def test_no_overlap_names_both_spans_and_the_nanoseconds(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    gt = _tum(tmp_path / "gt.txt", t * 1e9, wTc)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, _tum(tmp_path / "e.txt", t, wTc))
    assert code == 2
    tr.one_error(err, "reference's stamps run from 1e+12", "estimate's from 1000 to 1039.9", "nanoseconds")


def test_a_wide_max_diff_pairing_poses_twice_is_said(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    _, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t, wTc),
                     _tum(tmp_path / "e.txt", t + 20.0, wTc), "--max-diff", "1000")
    _warned(err, "200 of 400 matched pairs reuse a pose", "--max-diff 1000")


def test_a_clock_19_s_off_with_half_the_poses_paired_is_said(tmp_path, capsys):
    # the hostile pass's case: 52 % paired, above the coverage line's 50 %, and silent
    t, wTc = tr.trajectory(400, False)
    _, est = tr.trajectory(400, True)
    got, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t, wTc), _tum(tmp_path / "e.txt", t + 19.0, est))
    assert got["matched_share"] == pytest.approx(210 / 400)
    _warned(err, "e.txt", "clocks may differ", "by -19 s pairs 400 of its 400 poses", "against 210")


def test_a_reference_over_part_of_the_estimate_is_no_clock_doubt(tmp_path, capsys):
    # a shift cannot pair more than the reference covers: only the coverage line
    t, wTc = tr.trajectory(400, False)
    _, est = tr.trajectory(400, True)
    _, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t[:150], wTc[:150]),
                     _tum(tmp_path / "e.txt", t, est))
    assert "clocks" not in err
    _warned(err, "only 150 of 400 poses")


def test_milliseconds_from_the_start_against_seconds_are_named(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    gt = _tum(tmp_path / "gt.txt", t - t[0], wTc)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, _tum(tmp_path / "e.txt", (t - t[0]) * 1e3, wTc))
    assert code == 2
    tr.one_error(err, "estimate's stamps span 3.99e+04, 1000 times the other file's 39.9", "milliseconds?")


def test_clock_doubts_name_a_span_in_microseconds_before_any_shift():
    t = np.arange(0.0, 10.0, 0.1)
    said = clock_doubts(t * 1e6, t, EvalOptions(), paired=0)
    assert len(said) == 1 and "reference's stamps span" in said[0] and "microseconds?" in said[0]
    assert clock_doubts(t, t + 0.004, EvalOptions(), paired=len(t)) == []  # within --max-diff: one clock


@pytest.mark.parametrize("align", ["none", "first"])
def test_an_estimate_that_never_moves_is_said_without_a_fit(tmp_path, capsys, align):
    t, wTc = tr.trajectory(400, False)
    still = wTc.copy()
    still[:, :3, 3] = [1.0, 2.0, 3.0]
    _, err = _scored(tmp_path, capsys, _tum(tmp_path / "gt.txt", t, wTc),
                     _tum(tmp_path / "e.txt", t, still), "--align", align)
    _warned(err, "does not move")
    assert "inverted" not in err


# honest data: no warning

@pytest.mark.parametrize("fmt", tr.FORMATS)
@pytest.mark.parametrize("align", ["se3", "sim3", "first"])
def test_the_honest_pairs_say_nothing_new(tmp_path, capsys, fmt, align):
    gt, est = tr.write_pair(tmp_path, fmt)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est, "--align", align)
    assert code == 0
    assert not [ln for ln in err.splitlines() if "only" not in ln], err  # the coverage line alone


def test_kitti07_against_itself_and_a_drifted_copy_say_nothing(tmp_path, capsys, shared_data):
    poses, times = shared_data / "kitti07" / "poses.txt", shared_data / "kitti07" / "times.txt"
    copy = tmp_path / "poses_copy.txt"  # the file itself is said ("0 by construction")
    copy.write_bytes(poses.read_bytes())
    code, _, err = tr.run_eval(tmp_path, capsys, poses, copy, "--format", "kitti", "--times", times)
    assert code == 0 and err == ""
    _, drifted = tr.kitti07_pair(tmp_path, poses)
    for align in ("se3", "sim3"):
        code, _, err = tr.run_eval(tmp_path, capsys, poses, drifted, "--align", align)
        assert code == 0 and err == ""


def test_an_absurd_ate_from_a_few_pose_alignment_blames_n_align(tmp_path, capsys):
    """KITTI 07's truth with 5 cm of noise on its first three positions,
    aligned on the first 3 (--n-align 3): the fit carried along the route gave an ATE of
    three times the route's spread (88 m), and the warning blamed another sequence, clock or units."""
    T = _kitti07()
    est = T.copy()
    rng = np.random.default_rng(0)
    for k in range(3):
        est[k, :3, 3] += rng.normal(0.0, 0.05, 3)
    gt = tr.write(tmp_path / "gt.txt", "kitti", np.zeros(len(T)), T)
    e = tr.write(tmp_path / "e.txt", "kitti", np.zeros(len(T)), est)
    _, err = _scored(tmp_path, capsys, gt, e, "--n-align", "3")
    _warned(err, "e.txt", "aligned on its first 3 matched poses only", "a larger --n-align")
    assert "another sequence" not in err
