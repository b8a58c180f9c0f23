"""Trajectory evaluation never answers a wrong figure without a word (issue 34,
"Silent answers"): each case ends in a right answer, one ``graphslam: error:``
line (exit 2) or a stated warning."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.evaluation.spatial import align_umeyama
from graphslam.evaluation.trajectory import EvalOptions, evaluate
from graphslam.sources.ground_truth import read_trajectory
from graphslam.sources.spatial.images import read_tum_rgbd
from graphslam.sources.spatial.kitti import read_kitti, read_kitti_poses
from slamcore.errors import GraphSlamError, InputError
from tests import trajectories as tr


def _tum(path, stamps, wTc):
    return tr.write(path, "tum", np.asarray(stamps, dtype=np.float64), wTc)


# 1. duplicated / unsorted timestamps


def test_duplicated_timestamp_is_refused_with_file_and_lines(tmp_path, capsys):
    gt, est = tr.write_pair(tmp_path, "tum")
    lines = est.read_text().splitlines()
    stamp = lines[9].split()[0]
    lines[10] = " ".join([stamp, *lines[10].split()[1:]])
    est.write_text("\n".join(lines) + "\n")
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est)
    assert code == 2
    tr.one_error(err, "est_tum.txt:11", "line 10", "duplicated")


def test_unsorted_timestamps_are_sorted_same_answer(tmp_path, capsys):
    gt, est = tr.write_pair(tmp_path, "tum")
    assert tr.run_eval(tmp_path, capsys, gt, est)[0] == 0
    before = json.loads((tmp_path / "o" / "eval.json").read_text())["estimates"][0]
    lines = est.read_text().splitlines()
    lines[5], lines[200] = lines[200], lines[5]
    est.write_text("\n".join(lines) + "\n")
    traj = read_trajectory(est)
    assert np.all(np.diff(traj.stamps_s) > 0)
    assert tr.run_eval(tmp_path, capsys, gt, est)[0] == 0
    after = json.loads((tmp_path / "o" / "eval.json").read_text())["estimates"][0]
    assert after["ate_rmse_m"] == pytest.approx(before["ate_rmse_m"], rel=1e-12)


# 2. two poses: positions leave the rotation about their line free; the orientations fix it

#: Rotation error of a file scored against itself, degrees (rounding of its printed digits).
SELF_ROT_TOL_DEG = 1e-3


def test_two_poses_se3_scores_a_file_against_itself_at_zero_not_180_degrees(tmp_path, capsys):
    t, wTc = tr.trajectory(2, False)
    gt = _tum(tmp_path / "gt.txt", t, wTc)
    code, _, _ = tr.run_eval(tmp_path, capsys, gt, gt)
    assert code == 0
    s = json.loads((tmp_path / "o" / "eval.json").read_text())["estimates"][0]
    assert s["ate_rot_rmse_deg"] < SELF_ROT_TOL_DEG


def test_straight_line_fits_the_rotation_about_the_line_on_the_orientations():
    """A straight drive, the estimate rolled 150 deg about the line and moved: SE(3)
    fitted on positions alone leaves that roll free; with the orientations the
    rotation error after alignment is 0 (and the positions match)."""
    from scipy.spatial.transform import Rotation

    n = 20
    wTc = np.tile(np.eye(4), (n, 1, 1))
    wTc[:, 0, 3] = np.arange(n)
    wTc[:, :3, :3] = Rotation.from_euler("z", np.linspace(0, 0.3, n)[:, None]).as_matrix()
    roll = np.eye(4)
    roll[:3, :3] = Rotation.from_euler("x", 150, degrees=True).as_matrix()
    roll[:3, 3] = [3.0, -2.0, 5.0]
    t = np.arange(n, dtype=np.float64)
    result = evaluate(t, wTc, t, roll @ wTc, EvalOptions(align="se3"))
    summary = result.summary()
    assert summary["ate_rot_rmse_deg"] < SELF_ROT_TOL_DEG
    assert summary["ate_rmse_m"] < 1e-9


def test_positions_that_never_move_are_refused():
    n = 20
    wTc = np.tile(np.eye(4), (n, 1, 1))
    t = np.arange(n, dtype=np.float64)
    with pytest.raises(GraphSlamError, match="does not move"):
        evaluate(t, wTc, t, wTc, EvalOptions(align="se3"))


# 3. a rotation block that is not a rotation


@pytest.mark.parametrize("block", [2 * np.eye(3), np.diag([1.0, 1.0, -1.0])])
def test_kitti_non_rotation_refused_with_line(tmp_path, capsys, block):
    t, wTc = tr.trajectory(5, False)
    path = tr.write(tmp_path / "k.txt", "kitti", t, wTc)
    lines = path.read_text().splitlines()
    T = np.zeros((3, 4))
    T[:, :3] = block
    lines[2] = " ".join(f"{v:.9e}" for v in T.ravel())
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="not a rotation") as e:
        read_trajectory(path)
    assert "k.txt:3" in str(e.value)
    with pytest.raises(InputError, match="not a rotation"):
        read_kitti_poses(path)
    code, _, err = tr.run_eval(tmp_path, capsys, path, path)
    assert code == 2
    tr.one_error(err, "k.txt:3")


# 4. a times file that does not increase


def test_times_all_zero_refused_with_line(tmp_path, capsys):
    t, wTc = tr.trajectory(50, False)
    kitti = tr.write(tmp_path / "k.txt", "kitti", t, wTc)
    times = tmp_path / "times.txt"
    times.write_text("0.0\n" * 50)
    code, _, err = tr.run_eval(tmp_path, capsys, kitti, kitti, "--times", times)
    assert code == 2
    tr.one_error(err, "times.txt:2", "increase")


# 5. a reference (or estimate) that never moves


@pytest.mark.parametrize("align", ["sim3", "se3"])
def test_static_reference_refused(tmp_path, capsys, align):
    t, wTc = tr.trajectory(50, False)
    still = wTc.copy()
    still[:, :3, 3] = [1.0, 2.0, 3.0]
    gt = _tum(tmp_path / "gt.txt", t, still)
    est = _tum(tmp_path / "est.txt", t, wTc)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est, "--align", align)
    assert code == 2
    tr.one_error(err, "reference", "does not move")


def test_sim3_on_two_matched_poses_is_refused(tmp_path, capsys):
    """Third hostile pass: a Sim(3) fit of 2 positions is exact, so any estimate of two
    poses scored an ATE of 0.0000 (exit 0, no word)."""
    t, wTc = tr.trajectory(2, estimate=False)
    far = wTc.copy()
    far[:, :3, 3] *= 100.0  # 100 times the reference's path: still "0" before
    gt = _tum(tmp_path / "gt.txt", t, wTc)
    est = _tum(tmp_path / "est.txt", t, far)
    code, _, err = tr.run_eval(tmp_path, capsys, gt, est, "--align", "sim3")
    assert code == 2
    tr.one_error(err, "--align sim3 on 2 matched poses", "at least 3")
    assert tr.run_eval(tmp_path, capsys, gt, est, "--align", "se3")[0] == 0  # se3 keeps the distance


def test_umeyama_sim3_onto_a_point_refused():
    src = np.random.default_rng(0).normal(size=(10, 3))
    with pytest.raises(GraphSlamError, match="does not move"):
        align_umeyama(src, np.ones((10, 3)), with_scale=True)


# 6. matched poses: counted, shared and warned about


def test_partial_truth_counts_and_warns(tmp_path, capsys):
    t, wTc = tr.trajectory(400, False)
    est = _tum(tmp_path / "est.txt", t, wTc)
    gt = _tum(tmp_path / "gt.txt", t[:50], wTc[:50])
    code, out, err = tr.run_eval(tmp_path, capsys, gt, est)
    assert code == 0
    s = json.loads((tmp_path / "o" / "eval.json").read_text())["estimates"][0]
    assert s["matched_poses"] == 50 and s["estimate_poses"] == 400
    assert s["matched_share"] == pytest.approx(0.125)
    assert "50/400" in out
    assert err.startswith("graphslam: warning:") and "50 of 400" in err


# 7. sequence folders whose stamps do not increase


def _kitti_folder(tmp_path, times: str):
    folder = tmp_path / "07"
    (folder / "image_0").mkdir(parents=True)
    for k in range(3):
        (folder / "image_0" / f"{k:06d}.png").write_bytes(b"")
    (folder / "calib.txt").write_text("P0: 700 0 600 0 0 700 180 0 0 0 1 0\n")
    (folder / "times.txt").write_text(times)
    return folder


def test_kitti_folder_times_all_zero_refused(tmp_path):
    with pytest.raises(InputError, match="increase") as e:
        read_kitti(_kitti_folder(tmp_path, "0.0\n0.0\n0.0\n"))
    assert "times.txt:2" in str(e.value)


def test_tum_folder_stamps_all_zero_refused(tmp_path):
    (tmp_path / "rgb.txt").write_text("# rgb\n0.0 rgb/a.png\n0.0 rgb/b.png\n")
    with pytest.raises(InputError, match="increase") as e:
        read_tum_rgbd(tmp_path)
    assert "rgb.txt:3" in str(e.value)


def test_a_run_scored_on_under_half_its_poses_says_so(tmp_path, capsys):
    """A 2-D run given truth for 49 of its 400 poses reports the count and a WARNING
    (metrics.json ``warnings``); truth for every pose adds none."""
    from graphslam.cli.main import main

    full = tmp_path / "full"
    assert main(["run", "--max-steps", "400", "--rerun", "off", "--quiet", "--out", str(full)]) == 0
    assert json.loads((full / "metrics.json").read_text()).get("warnings") is None
    lines = (full / "ground_truth.tum").read_text().splitlines()
    part = tmp_path / "part.tum"
    part.write_text("\n".join(lines[:50]) + "\n")
    out = tmp_path / "o"
    assert (
        main(["run", "--max-steps", "400", "--rerun", "off", "--ground-truth", str(part), "--out", str(out)])
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    assert m["ate_poses"] < 0.5 * 400
    assert any("under half the run" in w for w in m["warnings"])
    assert "graphslam: warning: the ATE covers 49 of 400" in capsys.readouterr().err


def test_an_estimate_that_pairs_too_few_poses_is_named(tmp_path, capsys):
    """Tenth hostile pass: "only 1 matched pose(s)" named no file, with several estimates
    on the command line."""
    gt, est = tr.write_pair(tmp_path, "tum")
    one = tmp_path / "one.tum"
    one.write_text(est.read_text().splitlines()[0] + "\n")
    code, _, err = tr.run_eval(tmp_path, capsys, gt, one)
    assert code == 2
    tr.one_error(err, f"{one}:", "only 1 matched pose(s)", f"scored against {gt}")


def _line_of_poses(n: int) -> np.ndarray:
    """(n, 4, 4) rigid poses along a wavy line (an se3 fit is determined)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3], T[:, 1, 3] = np.arange(n), np.sin(np.arange(n))
    return T


def _not_scored(ref_t, ref, est_t, est, options=None):
    with pytest.raises(GraphSlamError):
        evaluate(ref_t, ref, est_t, est, options or EvalOptions())


def test_evaluate_refuses_what_is_no_trajectory_instead_of_scoring_it():
    ref, t = _line_of_poses(20), np.arange(20) * 0.1
    nan = ref.copy()
    nan[3, 0, 3] = np.nan  # raw LinAlgError (SVD did not converge) before
    _not_scored(t, ref, t, nan)
    _not_scored(t, ref, t, nan, EvalOptions(align="none"))
    _not_scored(t[:10], ref, t, ref)  # 10 stamps for 20 poses: 10 were scored
    scaled = ref.copy()
    scaled[:, :3, :3] *= 2.0  # no rotation: scored as one
    _not_scored(t, ref, t, scaled)
    assert evaluate(t, ref, t, ref, EvalOptions()).summary()["matched_poses"] == 20


def test_n_align_must_be_a_whole_number():
    with pytest.raises(GraphSlamError, match="n-align"):
        EvalOptions(n_align=3.5)
    assert EvalOptions(n_align=np.int64(4)).n_align == 4
