"""KITTI 07 from ../shared/data for the tests that verify image pairs on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses


def kitti07(shared_data: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """``(folder, K (3, 3), wTc (N, 4, 4))`` of KITTI 07; the test skips without the data."""
    root = shared_data / "kitti07"
    if not (root / "poses.txt").is_file():
        pytest.skip("KITTI 07 data missing")
    K, _ = read_kitti_calib(root / "calib.txt")
    return root, K, read_kitti_poses(root / "poses.txt")
