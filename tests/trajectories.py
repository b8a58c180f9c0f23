"""Trajectory files for the ``graphslam eval`` tests, and evo's numbers on them.

The trajectories are closed-form (sines of the frame index, no random
generator), so the files are the same bits on every machine and numpy
version; ``evo_reference.json`` holds what evo 1.38 computed on them, so the
agreement is checked where evo is not installed (CI). Regenerate with
``python -m tests.trajectories`` (needs ``pip install evo``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

REFERENCE = Path(__file__).with_name("evo_reference.json")
N_REF, N_EST = 400, 380
#: (name, align, n_align, delta, delta unit) of every compared case.
CASES = [
    ("se3", "se3", None, 1, "frames"),
    ("sim3", "sim3", None, 10, "frames"),
    ("first", "first", None, 1, "frames"),
    ("none", "none", None, 5.0, "m"),
    ("se3-n50", "se3", 50, 1, "frames"),
    ("sim3-m", "sim3", None, 20.0, "m"),
]
FORMATS = ("tum", "kitti", "euroc")


def run_eval(tmp_path: Path, capsys, *argv) -> tuple[int, str, str]:
    """``graphslam eval ARGV --no-plot --out TMP/o`` in this process: exit status, stdout, stderr."""
    from graphslam.cli.main import main as graphslam

    code = graphslam(["eval", *map(str, argv), "--no-plot", "--out", str(tmp_path / "o")])
    out = capsys.readouterr()
    return code, out.out, out.err


def one_error(err: str, *words: str) -> None:
    """``err`` is one ``graphslam: error:`` line holding each of ``words``."""
    assert err.count("\n") == 1 and err.startswith("graphslam: error:"), err
    for w in words:
        assert w in err, err


def trajectory(n: int, estimate: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps (n,), wTc (n, 4, 4))``: an oval at 10 Hz; the estimate is scaled,
    shifted and wobbled, and its stamps jitter by up to 12 ms (some beyond evo's 10 ms)."""
    k = np.arange(n, dtype=np.float64)
    ang = 2 * np.pi * k / N_REF
    p = np.column_stack([60 * np.cos(ang), 40 * np.sin(ang), 2 * np.sin(3 * ang)])
    rv = np.column_stack([0.05 * np.sin(5 * ang), 0.03 * np.cos(7 * ang), ang + np.pi / 2])
    t = 1000.0 + 0.1 * k
    if estimate:
        p = 1.1 * p + np.column_stack([0.3 * np.sin(1.7 * k), 0.2 * np.cos(2.3 * k),
                                       0.1 * np.sin(0.7 * k)]) + [5.0, -3.0, 1.0]
        rv = rv + np.column_stack([0.01 * np.sin(1.3 * k), 0.02 * np.cos(0.9 * k),
                                   0.015 * np.sin(2.9 * k)])
        t = t + 0.012 * np.sin(3.1 * k)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_euler("xyz", rv).as_matrix()
    T[:, :3, 3] = p
    return t, T


def write(path: Path, fmt: str, stamps: np.ndarray, wTc: np.ndarray) -> Path:
    """``wTc`` as a TUM, KITTI (no stamps) or EuRoC (ns stamps) file."""
    q = Rotation.from_matrix(wTc[:, :3, :3]).as_quat()  # x y z w
    with open(path, "w", encoding="utf-8") as f:
        if fmt == "euroc":
            f.write("#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z\n")
        for t, T, (qx, qy, qz, qw) in zip(stamps, wTc, q):
            x, y, z = T[:3, 3]
            if fmt == "tum":
                f.write(f"{t:.6f} {x:.9f} {y:.9f} {z:.9f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n")
            elif fmt == "kitti":
                f.write(" ".join(f"{v:.9e}" for v in T[:3].ravel()) + "\n")
            else:
                f.write(f"{round(t * 1e9)},{x:.9f},{y:.9f},{z:.9f},{qw:.9f},{qx:.9f},{qy:.9f},{qz:.9f}\n")
    return path


def write_pair(folder: Path, fmt: str) -> tuple[Path, Path]:
    """Reference and estimate files of ``fmt`` in ``folder`` (KITTI: equal lengths,
    paired by line, as evo requires)."""
    ext = {"tum": "txt", "kitti": "txt", "euroc": "csv"}[fmt]
    n_est = N_REF if fmt == "kitti" else N_EST
    gt = write(folder / f"gt_{fmt}.{ext}", fmt, *trajectory(N_REF, False))
    est = write(folder / f"est_{fmt}.{ext}", fmt, *trajectory(n_est, True))
    return gt, est


def drifted(wTc: np.ndarray) -> np.ndarray:
    """Odometry-like drift of a real trajectory: each relative motion 1 % long and
    turned by a slowly varying 0.1-0.3 mrad about the camera's y axis."""
    out = [wTc[0]]
    for i in range(1, len(wTc)):
        rel = np.linalg.inv(wTc[i - 1]) @ wTc[i]
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_rotvec([0.0, 2e-4 * np.sin(0.01 * i) + 1e-4, 0.0]).as_matrix()
        rel = rel @ turn
        rel[:3, 3] *= 1.01
        out.append(out[-1] @ rel)
    return np.array(out)


def kitti07_pair(folder: Path, poses: Path) -> tuple[Path, Path]:
    """KITTI 07's own ground truth (rotations rounded to 7 digits in the file, so not
    exactly orthonormal) and a drifted copy of it."""
    gt = np.loadtxt(poses).reshape(-1, 3, 4)
    T = np.tile(np.eye(4), (len(gt), 1, 1))
    T[:, :3, :] = gt
    return poses, write(folder / "est_kitti07.txt", "kitti", np.zeros(len(T)), drifted(T))


def evo_numbers(gt: Path, est: Path, fmt: str, align: str, n_align, delta, unit) -> dict:
    """evo's APE and RPE on the two files (evo's API, as ``evo_ape``/``evo_rpe`` run it)."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    read = {"tum": file_interface.read_tum_trajectory_file,
            "kitti": file_interface.read_kitti_poses_file,
            "euroc": file_interface.read_euroc_csv_trajectory}[fmt]
    ref, e = read(str(gt)), read(str(est))
    if fmt != "kitti":
        ref, e = sync.associate_trajectories(ref, e, max_diff=0.01, offset_2=0.0)
    if align == "first":
        e.align_origin(ref)
    elif align != "none":
        e.align(ref, correct_scale=align == "sim3", n=-1 if n_align is None else n_align)
    rel = metrics.PoseRelation
    u = metrics.Unit.frames if unit == "frames" else metrics.Unit.meters
    out = {"matched_poses": ref.num_poses}
    for key, metric, stat in (
            ("ate_rmse_m", metrics.APE(rel.translation_part), "rmse"),
            ("ate_mean_m", metrics.APE(rel.translation_part), "mean"),
            ("ate_median_m", metrics.APE(rel.translation_part), "median"),
            ("ate_max_m", metrics.APE(rel.translation_part), "max"),
            ("ate_rot_rmse_deg", metrics.APE(rel.rotation_angle_deg), "rmse"),
            ("rpe_trans_rmse_m", metrics.RPE(rel.translation_part, delta, u), "rmse"),
            ("rpe_rot_rmse_deg", metrics.RPE(rel.rotation_angle_deg, delta, u), "rmse")):
        metric.process_data((ref, e))
        out[key] = float(metric.get_statistic(metrics.StatisticsType(stat)))
    return out


def main(folder: Path) -> None:
    """Write ``evo_reference.json``: evo's numbers for every format and case."""
    folder.mkdir(parents=True, exist_ok=True)
    table = {}
    for fmt in FORMATS:
        gt, est = write_pair(folder, fmt)
        for name, *case in CASES:
            table[f"{fmt}/{name}"] = evo_numbers(gt, est, fmt, *case)
    from tests.conftest import SHARED_DATA

    gt, est = kitti07_pair(folder, SHARED_DATA / "kitti07" / "poses.txt")
    for name, *case in CASES:
        table[f"kitti07/{name}"] = evo_numbers(gt, est, "kitti", *case)
    REFERENCE.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":  # pragma: no cover
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        main(Path(d))
