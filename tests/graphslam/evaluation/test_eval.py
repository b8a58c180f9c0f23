"""``graphslam eval``: readers, association, alignment, agreement with evo, KITTI drift, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.evaluation.trajectory import EvalOptions, associate, evaluate, kitti_drift
from graphslam.pipelines.trajectory_eval import evaluate_files
from slamcore.errors import ConfigError
from tests import trajectories as tr

#: agreement with evo, relative: the issue asks 1e-6; the same formulas agree to
#: rounding (~1e-14), and 1e-9 catches a different formula (a general matrix
#: inverse instead of evo's rigid one parts at ~3e-8 on KITTI 07)
EVO_REL_TOL = 1e-9
#: metric values compared with evo's
EVO_KEYS = ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m", "ate_rot_rmse_deg",
            "rpe_trans_rmse_m", "rpe_rot_rmse_deg")
#: exact-geometry cases: errors at rounding level, metres / degrees
EXACT_M = 1e-9
EXACT_DEG = 1e-7


def _ours(tmp_path, fmt, align, n_align, delta, unit) -> dict:
    gt, est = tr.write_pair(tmp_path, fmt)
    options = EvalOptions(align=align, n_align=n_align, delta=delta, delta_unit=unit)
    return evaluate_files(gt, [est], options)[0].result.summary()


def _assert_agrees(ours: dict, evo: dict) -> None:
    assert ours["matched_poses"] == evo["matched_poses"]
    for key in EVO_KEYS:
        assert ours[key] == pytest.approx(evo[key], rel=EVO_REL_TOL), key


@pytest.mark.parametrize("fmt", tr.FORMATS)
@pytest.mark.parametrize("case", tr.CASES, ids=[c[0] for c in tr.CASES])
def test_agrees_with_evo_recorded_numbers(tmp_path, fmt, case):
    reference = json.loads(tr.REFERENCE.read_text())
    _assert_agrees(_ours(tmp_path, fmt, *case[1:]), reference[f"{fmt}/{case[0]}"])


@pytest.mark.parametrize("fmt", tr.FORMATS)
def test_agrees_with_evo_itself(tmp_path, fmt):
    pytest.importorskip("evo")
    gt, est = tr.write_pair(tmp_path, fmt)
    for name, *case in tr.CASES:
        _assert_agrees(_ours(tmp_path, fmt, *case), tr.evo_numbers(gt, est, fmt, *case))


@pytest.mark.parametrize("case", tr.CASES, ids=[c[0] for c in tr.CASES])
def test_agrees_with_evo_on_kitti07_ground_truth(tmp_path, shared_data, case):
    """Real KITTI poses: rotations orthonormal to ~1e-7 only, where a general matrix
    inverse and evo's rigid inverse part at 1e-8 of a frame-to-frame RPE."""
    gt, est = tr.kitti07_pair(tmp_path, shared_data / "kitti07" / "poses.txt")
    options = EvalOptions(align=case[1], n_align=case[2], delta=case[3], delta_unit=case[4])
    ours = evaluate_files(gt, [est], options)[0].result.summary()
    _assert_agrees(ours, json.loads(tr.REFERENCE.read_text())[f"kitti07/{case[0]}"])


def test_partial_association_drops_far_stamps(tmp_path):
    """12 ms jitter against a 10 ms window: some estimate poses are left out."""
    s = _ours(tmp_path, "tum", "se3", None, 1, "frames")
    assert 0 < s["matched_poses"] < tr.N_EST


def test_association_nearest_within_max_diff_ties_to_earlier():
    ref_t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    est_t = np.array([0.5, 2.004, 5.7])  # 0.5: tie between 0 and 1; 5.7 too far
    i_ref, i_est = associate(ref_t, est_t, max_diff=0.5)
    assert i_ref.tolist() == [0, 2] and i_est.tolist() == [0, 1]
    est_t = np.array([0.5, 2.004, 3.2])  # shifted by -0.2 s, only 3.2 is within 10 ms
    i_ref, i_est = associate(ref_t, est_t, max_diff=0.01, offset=-0.2)
    assert i_ref.tolist() == [3] and i_est.tolist() == [2]


def _line(n, step=1.0):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = step * np.arange(n)
    return T


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_sim3_and_se3_recover_a_known_transform():
    _, ref = tr.trajectory(100, False)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rz(0.7), [3.0, -2.0, 0.5]
    moved = T @ ref
    scaled = moved.copy()
    scaled[:, :3, 3] *= 0.25
    for est, align in ((moved, "se3"), (scaled, "sim3"), (moved, "first")):
        s = evaluate(None, ref, None, est, EvalOptions(align=align)).summary()
        assert s["ate_max_m"] < EXACT_M and s["ate_rot_rmse_deg"] < EXACT_DEG, align
    assert evaluate(None, ref, None, scaled, EvalOptions(align="sim3")).scale == pytest.approx(4.0)


def test_kitti_drift_hand_case_scale_error():
    """Straight 200 m at 1 m a frame, the estimate 1 % long: a 100 m segment ends at
    the first frame beyond 100 m, 101 m on, so its error is 1.01 m / 100 m; no 200 m
    segment fits; start frames 0, 10, .., 90."""
    pct, deg = kitti_drift(_line(201), _line(201, 1.01))
    assert pct == pytest.approx(1.01, abs=1e-9)
    assert deg == pytest.approx(0.0, abs=1e-6)


def test_kitti_drift_hand_case_heading_error():
    """Same line, the estimate's heading turning 1 mrad a frame at the true positions:
    each 101-frame segment is off by 0.101 rad in rotation, and from start frame f its
    translation is the truth's rotated by -f mrad: error 2 * 101 * sin(f mrad / 2)."""
    a = 1e-3
    est = _line(201)
    est[:, :3, :3] = np.array([_rz(a * k) for k in range(201)])
    pct, deg = kitti_drift(_line(201), est)
    starts = np.arange(0, 100, 10)
    assert deg == pytest.approx(np.degrees(a * 101 / 100) * 100, rel=1e-9)
    assert pct == pytest.approx(100 * np.mean(2 * 101 * np.sin(a * starts / 2) / 100), rel=1e-9)


def test_kitti_drift_is_none_under_100_m():
    assert kitti_drift(_line(50), _line(50)) == (None, None)


@pytest.mark.parametrize("bad", [dict(align="umeyama"), dict(max_diff_s=-1.0),
                                 dict(delta=0), dict(delta=1.5), dict(delta_unit="s"),
                                 dict(align="first", n_align=10)])
def test_options_are_checked(bad):
    with pytest.raises(ConfigError):
        EvalOptions(**bad)


# --------------------------------------------------------------------------- CLI

JSON_KEYS = {"ate_rmse_m", "ate_mean_m", "ate_max_m", "ate_rot_rmse_deg", "rpe_trans_rmse_m",
             "rpe_rot_rmse_deg", "kitti_drift_pct", "kitti_drift_deg_per_100m", "matched_poses",
             "options"}


def test_cli_writes_eval_json_one_entry_per_estimate(tmp_path, capsys):
    gt, est = tr.write_pair(tmp_path, "tum")
    t, wTc = tr.trajectory(tr.N_REF, False)
    same = tr.write(tmp_path / "same.txt", "tum", t, wTc)
    out = tmp_path / "out"
    assert main(["eval", str(gt), str(est), str(same), "--align", "sim3", "--delta", "10",
                 "--out", str(out)]) == 0
    doc = json.loads((out / "eval.json").read_text())
    rows = doc["estimates"]
    assert [r["estimate"] for r in rows] == [str(est), str(same)]
    for r in rows:
        assert JSON_KEYS <= set(r)
        assert r["options"]["align"] == "sim3" and r["options"]["delta"] == 10
    assert rows[1]["ate_max_m"] < 1e-6  # itself, to the file's 9 digits
    assert rows[0]["kitti_drift_pct"] is not None  # the oval is ~320 m long
    assert (out / "eval.png").stat().st_size > 0
    assert "est_tum.txt" in capsys.readouterr().out


def test_two_files_of_one_name_are_told_apart_by_their_folders(tmp_path, capsys):
    gt, est = tr.write_pair(tmp_path, "tum")
    for run in ("run_a", "run_b"):
        (tmp_path / run).mkdir()
        (tmp_path / run / "trajectory.tum").write_bytes(est.read_bytes())
    out = tmp_path / "out"
    assert main(["eval", str(gt), str(tmp_path / "run_a" / "trajectory.tum"),
                 str(tmp_path / "run_b" / "trajectory.tum"), "--no-plot", "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "run_a/trajectory.tum" in table and "run_b/trajectory.tum" in table
    rows = json.loads((out / "eval.json").read_text())["estimates"]
    assert [r["label"] for r in rows] == ["run_a/trajectory.tum", "run_b/trajectory.tum"]


def test_cli_kitti_needs_times_against_tum(tmp_path, capsys):
    gt, _ = tr.write_pair(tmp_path, "tum")
    _, kitti = tr.write_pair(tmp_path, "kitti")
    assert main(["eval", str(gt), str(kitti), "--out", str(tmp_path / "o")]) == 2
    assert "--times" in capsys.readouterr().err
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{t:.6f}\n" for t in tr.trajectory(tr.N_REF, True)[0]))
    assert main(["eval", str(gt), str(kitti), "--times", str(times), "--no-plot",
                 "--out", str(tmp_path / "o")]) == 0


@pytest.mark.parametrize("argv,message", [
    (["--max-diff", "-1"], "--max-diff"),
    (["--n-align", "10", "--align", "none"], "--n-align"),
])
def test_cli_bad_options_exit_2(tmp_path, capsys, argv, message):
    gt, est = tr.write_pair(tmp_path, "tum")
    assert main(["eval", str(gt), str(est), *argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_cli_bad_file_exit_2_with_line(tmp_path, capsys):
    gt, _ = tr.write_pair(tmp_path, "tum")
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3 4 0 0 0 1\n2 2 3 x 0 0 0 1\n")
    assert main(["eval", str(gt), str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "bad.txt:2" in capsys.readouterr().err


def _devkit_drift(ref, est):
    """The KITTI devkit's calcSequenceErrors written as it reads (a scan per segment)."""
    from graphslam.evaluation.trajectory import KITTI_LENGTHS_M, KITTI_STEP_FRAMES

    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1))])
    t_err, r_err = [], []
    for first in range(0, len(ref), KITTI_STEP_FRAMES):
        for length in KITTI_LENGTHS_M:
            beyond = np.nonzero(dist[first:] > dist[first] + length)[0]
            if beyond.size:
                last = first + int(beyond[0])
                inv = np.linalg.inv
                e = inv(inv(est[first]) @ est[last]) @ (inv(ref[first]) @ ref[last])
                d = 0.5 * (e[0, 0] + e[1, 1] + e[2, 2] - 1.0)
                r_err.append(np.arccos(max(min(d, 1.0), -1.0)) / length)
                t_err.append(np.linalg.norm(e[:3, 3]) / length)
    return 100.0 * float(np.mean(t_err)), float(np.degrees(np.mean(r_err)) * 100.0)


def test_kitti_drift_is_the_devkits_to_the_bit():
    """The segment ends found by binary search (a scan per segment took hours on a
    million-pose file, thirteenth hostile pass) are the devkit's, with its numbers."""
    from slamcore.spatial.geometry import se3_exp

    rng = np.random.default_rng(1)
    ref = [np.eye(4)]
    for _ in range(1999):  # 1 km, turning, with stops (repeated distances)
        step = 0.0 if rng.random() < 0.05 else 0.5
        ref.append(ref[-1] @ se3_exp(np.r_[step, 0, 0, 0, 0, rng.normal(0, 0.02)]))
    ref = np.array(ref)
    est = np.array([p @ se3_exp(rng.normal(0, 0.01, 6)) for p in ref])
    assert kitti_drift(ref, est) == _devkit_drift(ref, est)
