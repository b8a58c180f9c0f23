"""Lens distortion named by a sequence's calibration is removed by ``ImageSequence.load``.

A checkerboard is drawn through an ideal pinhole camera (corner positions
known exactly), then distorted with known coefficients the way a real lens
would, written to a folder with an intrinsics file that states those
coefficients, and read back with :func:`read_image_sequence`. The corners
found in the loaded image must sit where the pinhole model puts them; in the
file as stored they must not.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from graphslam.sources.spatial.images import read_image_sequence

W, H = 640, 480
FX, FY, CX, CY = 500.0, 500.0, 319.5, 239.5
K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
#: k1, k2, p1, p2 of a strongly barrel-distorting lens.
DIST = np.array([-0.3, 0.1, 0.0, 0.0])
SQUARE_PX = 40.0
INNER = (11, 8)  # inner corners (columns, rows) of a 12 x 9 board
#: Agreement of undistorted corners with the pinhole corners, pixels (sub-pixel
#: corner refinement after a bilinear distort + undistort round trip).
UNDISTORTED_TOL_PX = 0.35
#: The stored (distorted) corners must be at least this far off somewhere.
DISTORTED_MIN_ERR_PX = 5.0


def _true_corners() -> np.ndarray:
    """(M, 2) inner corners of the board in the pinhole image, row by row."""
    x0 = CX - SQUARE_PX * (INNER[0] - 1) / 2
    y0 = CY - SQUARE_PX * (INNER[1] - 1) / 2
    xs = x0 + SQUARE_PX * np.arange(INNER[0])
    ys = y0 + SQUARE_PX * np.arange(INNER[1])
    return np.array([(x, y) for y in ys for x in xs])


def _pinhole_board(ss: int = 4) -> np.ndarray:
    """(H, W) uint8 board, anti-aliased by ``ss`` x ``ss`` supersampling."""
    x0 = CX - SQUARE_PX * (INNER[0] + 1) / 2
    y0 = CY - SQUARE_PX * (INNER[1] + 1) / 2
    # sample positions in pixel coordinates (pixel centres at integers)
    u = (np.arange(W * ss) + 0.5) / ss - 0.5
    v = (np.arange(H * ss) + 0.5) / ss - 0.5
    i = np.floor((u - x0) / SQUARE_PX).astype(int)
    j = np.floor((v - y0) / SQUARE_PX).astype(int)
    inside_u = (i >= 0) & (i <= INNER[0])
    inside_v = (j >= 0) & (j <= INNER[1])
    black = ((i[None, :] + j[:, None]) % 2 == 0) & inside_u[None, :] & inside_v[:, None]
    big = np.where(black, 20.0, 235.0)
    return cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA).round().astype(np.uint8)


def _distort(pinhole: np.ndarray) -> np.ndarray:
    """What a lens with ``DIST`` records of the pinhole scene: for each stored pixel,
    sample the pinhole image where its undistorted ray lands."""
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, K, DIST, None, K, criteria=(
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-6))
    map_xy = und.reshape(H, W, 2).astype(np.float32)
    return cv2.remap(pinhole, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _corners(img: np.ndarray) -> np.ndarray:
    found, c = cv2.findChessboardCorners(img, INNER)
    assert found, "checkerboard not found"
    c = cv2.cornerSubPix(img, c, (5, 5), (-1, -1),
                         (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-4))
    c = c.reshape(-1, 2)
    if np.linalg.norm(c[0] - _true_corners()[0]) > np.linalg.norm(c[-1] - _true_corners()[0]):
        c = c[::-1]  # OpenCV may report the grid from the other end
    return c


@pytest.fixture(scope="module")
def distorted_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("distorted")
    cv2.imwrite(str(folder / "frame_000.png"), _distort(_pinhole_board()))
    (folder / "intrinsics.txt").write_text(
        f"# fx fy cx cy, then k1 k2 p1 p2\n{FX} {FY} {CX} {CY}\n"
        + " ".join(str(v) for v in DIST) + "\n")
    return folder


def test_load_removes_the_lens_distortion(distorted_folder):
    seq = read_image_sequence(distorted_folder)
    assert seq.is_distorted
    truth = _true_corners()
    undistorted = np.linalg.norm(_corners(seq.load(0)) - truth, axis=1)
    stored = np.linalg.norm(_corners(seq.load_raw(0)) - truth, axis=1)
    assert undistorted.max() < UNDISTORTED_TOL_PX, undistorted.max()
    assert stored.max() > DISTORTED_MIN_ERR_PX, stored.max()


def test_no_or_zero_distortion_leaves_the_pixels_alone(tmp_path):
    img = _pinhole_board()
    cv2.imwrite(str(tmp_path / "a.png"), img)
    (tmp_path / "intrinsics.txt").write_text(f"{FX} {FY} {CX} {CY}\n0 0 0 0\n")
    seq = read_image_sequence(tmp_path)
    assert not seq.is_distorted
    np.testing.assert_array_equal(seq.load(0), img)


def test_a_frame_selection_undistorts_at_its_own_camera(tmp_path):
    """``--frames`` with ``--intrinsics estimate``: the camera is set on the selection
    after it is made (``with_camera``); its images must be undistorted at that camera,
    not loaded as the base (read without distortion) would."""
    import dataclasses

    from graphslam.sources.spatial.frames import select_frames

    board = _distort(_pinhole_board())
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"frame_{k:03d}.png"), board)
    (tmp_path / "intrinsics.txt").write_text(f"{FX} {FY} {CX} {CY}\n")
    base = read_image_sequence(tmp_path)
    assert not base.is_distorted
    picked = dataclasses.replace(select_frames(base, slice(0, 3, 2)), distortion=DIST)
    assert picked.is_distorted
    undistorted = np.linalg.norm(_corners(picked.load(1)) - _true_corners(), axis=1)
    assert undistorted.max() < UNDISTORTED_TOL_PX, undistorted.max()
