"""ORB detector: determinism, cell spreading, descriptors, camera model and KITTI readers."""

from __future__ import annotations

import numpy as np
import pytest

from slamcore.spatial.geometry import invert_pose, se3_exp
from slamcore.spatial.camera import plane_induced_affine, project, project_jacobians
from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses
from frontend.features import Detector
from frontend.orb import OrbConfig, OrbDetector
from slamcore.errors import ConfigError, InputError

#: Tolerance of analytic vs central-difference Jacobians, px per unit (relative to the entry scale).
JAC_RTOL = 1e-5


def textured_image(seed: int = 0, shape=(240, 320)) -> np.ndarray:
    """Seeded random blocks, blurred a little: many corners everywhere."""
    import cv2
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, size=(shape[0] // 8, shape[1] // 8)).astype(np.uint8)
    img = cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(img, (3, 3), 0)


def test_orb_is_a_detector_and_deterministic():
    img = textured_image()
    det = OrbDetector()
    assert isinstance(det, Detector)
    a, b = det.detect(img), OrbDetector().detect(img.copy())
    assert len(a) > 20
    assert a.descriptors.dtype == np.uint8 and a.descriptors.shape == (len(a), 32)
    assert a.response.shape == (len(a),) and a.cell.shape == (len(a),)
    for x, y in ((a.xy_px, b.xy_px), (a.response, b.response), (a.descriptors, b.descriptors), (a.cell, b.cell)):
        assert np.array_equal(x, y)


def test_orb_cells_spread_features():
    img = textured_image()
    cs = 40
    f = OrbDetector(cell_size_px=cs, per_cell=1).detect(img)
    n_cols = -(-img.shape[1] // cs)
    expect = (f.xy_px[:, 1] // cs).astype(int) * n_cols + (f.xy_px[:, 0] // cs).astype(int)
    assert np.array_equal(f.cell, expect)
    assert len(np.unique(f.cell)) == len(f)  # one per cell
    assert np.all(np.diff(f.cell) > 0)       # sorted by cell
    # without cells, ORB concentrates: with cells, more of the image's cells are covered
    raw = OrbDetector(cell_size_px=0, n_features=len(f)).detect(img)
    assert raw.cell is None
    raw_cells = np.unique((raw.xy_px[:, 1] // cs).astype(int) * n_cols + (raw.xy_px[:, 0] // cs).astype(int))
    assert len(np.unique(f.cell)) > len(raw_cells)
    # per_cell = 2 keeps at most two per cell, the best responses first
    f2 = OrbDetector(cell_size_px=cs, per_cell=2).detect(img)
    _, counts = np.unique(f2.cell, return_counts=True)
    assert counts.max() <= 2 and len(f2) > len(f)
    same = f2.cell[1:] == f2.cell[:-1]
    assert np.all(f2.response[:-1][same] >= f2.response[1:][same])


def test_orb_max_features_and_empty_image():
    img = textured_image()
    f = OrbDetector(max_features=10).detect(img)
    assert len(f) <= 10
    e = OrbDetector().detect(np.full((100, 100), 128, np.uint8))
    assert len(e) == 0 and e.descriptors.shape == (0, 32)
    with pytest.raises(InputError):
        OrbDetector().detect(np.zeros((10, 10), np.float32))
    with pytest.raises(ConfigError, match=r"orb\.cell_size_px must be >= 0"):
        OrbConfig(cell_size_px=-1)
    with pytest.raises(ConfigError, match=r"orb\.scale_factor must be > 1"):
        OrbConfig(scale_factor=1.0)
    assert OrbConfig.SECTION == "orb"


@pytest.mark.parametrize("field, value", [
    # wrong type
    ("n_features", "many"), ("n_features", 1.5), ("per_cell", True), ("scale_factor", "big"),
    ("score", 1),
    # out of range: below the minimum, above what a frame or the machine can hold
    ("n_features", 0), ("n_features", 2**24 + 1), ("cell_size_px", -1), ("cell_size_px", 4097),
    ("per_cell", 0), ("max_features", -1), ("fast_threshold", 256), ("scale_factor", 1.0),
    ("n_levels", 0), ("n_levels", 33), ("edge_threshold", 256), ("patch_size", 1),
    ("patch_size", 256),
    # unknown mode
    ("score", "orb"),
])
def test_config_refuses_a_bad_value_naming_it(field, value):
    with pytest.raises(ConfigError, match=rf"^orb\.{field}\b"):
        OrbConfig(**{field: value})
    with pytest.raises(ConfigError, match=rf"^orb\.{field}\b"):
        OrbDetector(**{field: value})  # keyword overrides are checked the same way


def test_config_normalises_and_keeps_defaults():
    c = OrbConfig(n_features=np.int64(300), scale_factor=2)
    assert type(c.n_features) is int and type(c.scale_factor) is float
    assert OrbDetector(cell_size_px=64).config == OrbConfig(cell_size_px=64)
    with pytest.raises(ConfigError, match="n_feature"):
        OrbDetector(n_feature=10)  # a typo in an override is not ignored


# ---------------------------------------------------------------- camera model


def _camera(seed=0):
    rng = np.random.default_rng(seed)
    K = np.array([[700.0, 0.0, 600.0], [0.0, 710.0, 180.0], [0.0, 0.0, 1.0]])
    cTw = se3_exp(np.r_[rng.normal(0, 0.5, 3), rng.normal(0, 0.2, 3)])
    p_c = np.column_stack([rng.uniform(-5, 5, 8), rng.uniform(-2, 2, 8), rng.uniform(4, 30, 8)])
    p_w = (p_c - cTw[:3, 3]) @ cTw[:3, :3]
    return K, cTw, p_w


def test_project_known_values():
    K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
    uv, z = project(K, np.eye(4), np.array([[1.0, -0.5, 10.0], [0.0, 0.0, 2.0]]))
    assert np.allclose(uv, [[670.0, 145.0], [600.0, 180.0]]) and np.allclose(z, [10.0, 2.0])


def test_project_jacobians_match_numerical():
    K, cTw, p_w = _camera()
    uv, z, Jx, Jp = project_jacobians(K, cTw, p_w)
    uv0, z0 = project(K, cTw, p_w)
    assert np.allclose(uv, uv0) and np.allclose(z, z0)
    eps = 1e-6
    num_x = np.zeros_like(Jx)
    for j in range(3):
        d = np.zeros(3); d[j] = eps
        num_x[:, :, j] = (project(K, cTw, p_w + d)[0] - project(K, cTw, p_w - d)[0]) / (2 * eps)
    num_p = np.zeros_like(Jp)
    for j in range(6):
        d = np.zeros(6); d[j] = eps
        num_p[:, :, j] = (project(K, se3_exp(d) @ cTw, p_w)[0] - project(K, se3_exp(-d) @ cTw, p_w)[0]) / (2 * eps)
    assert np.allclose(Jx, num_x, rtol=JAC_RTOL, atol=JAC_RTOL * np.abs(num_x).max())
    assert np.allclose(Jp, num_p, rtol=JAC_RTOL, atol=JAC_RTOL * np.abs(num_p).max())


def test_se3_exp_and_inverse():
    T = se3_exp([0.1, -0.2, 0.3, 0.4, -0.1, 0.2])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.allclose(invert_pose(T) @ T, np.eye(4), atol=1e-12)
    assert np.allclose(se3_exp(np.zeros(6)), np.eye(4))


def test_plane_induced_affine_matches_numerical():
    K, _, _ = _camera()
    c1Tc0 = se3_exp([0.05, -0.02, 0.6, 0.01, 0.02, -0.005])
    uv0 = np.array([[300.0, 100.0], [900.0, 250.0]])
    depth = np.array([8.0, 20.0])
    A = plane_induced_affine(K, c1Tc0, uv0, depth)

    def warp(uv, d):  # pixel of camera 0 on the plane z = d -> pixel in camera 1
        ray = np.linalg.solve(K, np.r_[uv, 1.0])
        p0 = ray * d / ray[2]
        return project(K, c1Tc0, p0[None])[0][0]

    for i in range(2):
        num = np.zeros((2, 2))
        for j in range(2):
            e = np.zeros(2); e[j] = 1e-3
            num[:, j] = (warp(uv0[i] + e, depth[i]) - warp(uv0[i] - e, depth[i])) / 2e-3
        assert np.allclose(A[i], num, atol=1e-6)


# ---------------------------------------------------------------- KITTI readers


def test_read_kitti_files(shared_data):
    root = shared_data / "kitti07"
    K, _ = read_kitti_calib(root / "calib.txt")
    assert np.allclose(K, [[707.0912, 0, 601.8873], [0, 707.0912, 183.1104], [0, 0, 1]])
    P = read_kitti_poses(root / "poses.txt")
    assert P.shape == (160, 4, 4)
    assert np.allclose(P[0], np.eye(4), atol=1e-9)
    assert np.allclose(P[:, 3], [0, 0, 0, 1])


def test_read_kitti_errors_name_the_line(tmp_path):
    good = " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"])
    p = tmp_path / "poses.txt"
    p.write_text(good + "\n" + good + "\n1 2 3\n")
    with pytest.raises(InputError) as e:
        read_kitti_poses(p)
    assert e.value.line == 3 and str(p) in str(e.value)
    p.write_text(good + "\n" + good.replace("0", "x", 1) + "\n")
    with pytest.raises(InputError) as e:
        read_kitti_poses(p)
    assert e.value.line == 2
    c = tmp_path / "calib.txt"
    c.write_text("P0: 1 2 3\n")
    with pytest.raises(InputError) as e:
        read_kitti_calib(c)
    assert e.value.line == 1
    c.write_text("P1: " + good + "\n")
    with pytest.raises(InputError):
        read_kitti_calib(c)  # no P0
    with pytest.raises(InputError):
        read_kitti_poses(tmp_path / "missing.txt")


def _reference_select(kps, shape, cs: int, per_cell: int) -> np.ndarray:
    """The selection spelled out: one five-key sort (cell, -response, row, column,
    octave) of every candidate, the first ``per_cell`` of each cell."""
    xy = np.array([k.pt for k in kps], np.float64)
    resp = np.array([k.response for k in kps])
    octv = np.array([k.octave for k in kps])
    n_cols = -(-shape[1] // cs)
    col = np.clip((xy[:, 0] // cs).astype(int), 0, n_cols - 1)
    row = np.clip((xy[:, 1] // cs).astype(int), 0, -(-shape[0] // cs) - 1)
    cell = row * n_cols + col
    order = np.lexsort([octv, xy[:, 0], xy[:, 1], -resp, cell])
    rank = np.zeros(len(kps), int)
    for pos in range(1, len(order)):
        same = cell[order[pos]] == cell[order[pos - 1]]
        rank[pos] = rank[pos - 1] + 1 if same else 0
    return np.sort(order[rank < per_cell])


@pytest.mark.parametrize("per_cell", [1, 2])
def test_orb_fast_selection_equals_the_full_sort_with_and_without_ties(per_cell):
    """The selection skips the five-key sort when no two keypoints of a cell share a
    response, and finds a cell's best without sorting: both must keep exactly what
    the full sort keeps, on texture (no ties) and on a tiled pattern (many ties)."""
    import cv2

    rng = np.random.default_rng(3)
    tile = rng.integers(0, 256, (16, 16)).astype(np.uint8)
    tiled = np.tile(cv2.resize(tile, (32, 32), interpolation=cv2.INTER_NEAREST), (8, 10))
    ties_seen = 0
    for img in (textured_image(1), tiled):
        det = OrbDetector(cell_size_px=40, per_cell=per_cell)
        kps = det._orb().detect(img, None)
        resp = np.array([k.response for k in kps])
        ties_seen += len(resp) - len(np.unique(resp))
        assert np.array_equal(det.select(kps, img.shape), _reference_select(kps, img.shape, 40, per_cell))
        f = det.detect(img)
        kept = [kps[i] for i in det.select(kps, img.shape)]
        assert len(f) == len(kept)  # compute() dropped none of ORB's own keypoints
        assert np.all(np.diff(f.cell) >= 0)
        same = f.cell[1:] == f.cell[:-1]
        assert np.all(f.response[:-1][same] >= f.response[1:][same])
    assert ties_seen > 0  # the tiled image does exercise the tie path
