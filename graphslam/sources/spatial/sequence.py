"""Image sequences: the :class:`ImageSequence` record every image reader returns,
and the small parsing helpers the readers share (numpy + OpenCV, no gtsam).

Readers: :mod:`.kitti`, :mod:`.images` (TUM RGB-D, EuRoC, plain folders, and
the layout detection), :mod:`.calibration` (intrinsics files), and the
rendered :mod:`.synthetic_images`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from frontend.image import load_gray
from graphslam.sources.tokens import NUMBER_TOKEN
from slamcore.errors import InputError, quote
from slamcore.input_files import check_input_path

#: Extensions :func:`read_image_folder` accepts (compared lower-case).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")

#: Nearest-timestamp association tolerance (s) for TUM and EuRoC ground truth.
ASSOCIATION_MAX_DT_S = 0.02
#: Focal lengths read, pixels (f over the pixel pitch). Below 1 px one pixel
#: spans more than 45 degrees: no camera; a phone is ~500-3000 px, a long
#: telephoto on a small pixel ~1e5, so 1e6 is beyond any lens. Outside this a
#: typo (1e-300, 1e300) made every bearing 0 or inf and left every pose at
#: the identity without a word.
FOCAL_MIN_PX, FOCAL_MAX_PX = 1.0, 1e6
#: Largest |principal point| and |skew| read, pixels: a few widths of the
#: largest sensors (~2e4 px); a crop moves the principal point by at most
#: about an image size.
PRINCIPAL_POINT_MAX_PX = 1e5


@dataclass(frozen=True, eq=False)
class ImageSequence:
    """An ordered image sequence with its calibration and optional ground truth.

    Attributes:
        name: short name for reports ("kitti", "tum-rgbd", "euroc", "folder", ...).
        image_paths: (N,) image file paths in time order.
        stamps_s: (N,) timestamps in seconds, or ``None``.
        K: (3, 3) intrinsic matrix (pixels; pixel centres at integer coordinates)
            of the images :meth:`load` returns: a pinhole model, distortion removed.
        distortion: OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3...])``
            of the files on disk, or ``None``; :meth:`load` undoes them.
        wTc_true: (N, 4, 4) camera-to-world ground truth, or ``None``.
        image_size: ``(W, H)`` in pixels.
        source_path: the folder the sequence came from, if any.
    """

    name: str
    image_paths: list[str]
    stamps_s: np.ndarray | None
    K: np.ndarray
    distortion: np.ndarray | None
    wTc_true: np.ndarray | None
    image_size: tuple[int, int]
    source_path: str | None = None
    #: (map_xy, map_interp) of :func:`cv2.initUndistortRectifyMap`, built on the
    #: first :meth:`load` of a distorted sequence; ``False`` once found unneeded.
    _undistort_maps: tuple | bool | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.image_paths)

    @property
    def has_ground_truth(self) -> bool:
        return self.wTc_true is not None

    @property
    def nearest_depth_m(self) -> float | None:
        """Nearest depth of the scene's points, metres, when the sequence knows it
        (a rendered scene), else None. The monocular EKF's inverse-depth prior is
        set from it (:func:`graphslam.pipelines.spatial.backend_overrides`)."""
        return None

    @property
    def is_distorted(self) -> bool:
        """Whether the files carry lens distortion (a non-zero coefficient)."""
        return self.distortion is not None and bool(np.any(np.asarray(self.distortion) != 0))

    def load_raw(self, i: int) -> np.ndarray:
        """Image ``i`` as stored, (H, W) uint8 greyscale; an unreadable file raises InputError."""
        img = load_gray(self.image_paths[i])
        if (img.shape[1], img.shape[0]) != tuple(self.image_size):
            # the intrinsics are the first image's: another size is another camera
            raise InputError(
                f"image is {img.shape[1]}x{img.shape[0]} px, the sequence's "
                f"are {self.image_size[0]}x{self.image_size[1]}",
                self.image_paths[i],
            )
        return img

    def load(self, i: int) -> np.ndarray:
        """Image ``i`` as (H, W) uint8 greyscale, undistorted: a pinhole image with ``K``.

        Why the images and not the points: everything after the reader, the
        corner detectors, active search around the back ends' predictions,
        ORB matching for loops, the Rerun overlays, works in pixels of a
        pinhole camera. Removing the distortion from the image once, here,
        keeps all of them right without each having to undistort detections
        and distort predictions. ``K`` stays the camera matrix of the output
        (``newCameraMatrix = K``), so no consumer sees a different model; the
        remap maps are built once per sequence and cost one ``cv2.remap`` per
        frame. Pixels that fall outside the stored image repeat the border
        (``BORDER_REPLICATE``) so no artificial black edge gives the
        detectors corners that do not exist.
        """
        img = self.load_raw(i)
        maps = self._maps(img.shape)
        if not maps:
            return img
        if maps[0].shape[:2] != img.shape[:2]:
            raise InputError(
                f"image is {img.shape[1]}x{img.shape[0]}, the sequence's first "
                f"is {maps[0].shape[1]}x{maps[0].shape[0]}",
                self.image_paths[i],
            )
        return cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _maps(self, shape_hw: tuple[int, ...]):
        """The undistortion maps for (H, W) images, or ``False`` when there is no distortion."""
        if self._undistort_maps is None:
            maps: tuple | bool = False
            if self.is_distorted:
                size_wh = (int(shape_hw[1]), int(shape_hw[0]))
                K = np.asarray(self.K, dtype=np.float64)
                maps = cv2.initUndistortRectifyMap(
                    K,
                    np.asarray(self.distortion, dtype=np.float64).reshape(-1),
                    None,
                    K,
                    size_wh,
                    cv2.CV_16SC2,
                )
            # frozen record: the cache is the one field written after construction
            object.__setattr__(self, "_undistort_maps", maps)
        return self._undistort_maps


def read_lines(path: Path, what: str) -> list[tuple[int, str]]:
    """(line_no, stripped text) of non-empty, non-comment lines; missing file -> InputError."""
    check_input_path(path, what)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise InputError(f"cannot read {what}: {e.strerror}", path) from None
    out = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if s:
            out.append((k, s))
    return out


def parse_floats(
    text: str, path: Path, line: int, count: int | None = None, what: str = "numbers"
) -> np.ndarray:
    parts = [p for p in re.split(r"[\s,]+", text.strip()) if p]
    try:
        if not all(NUMBER_TOKEN.match(p) for p in parts):  # float() takes 1_000, full-width
            raise ValueError
        vals = np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise InputError(f"malformed line, expected {what}: {quote(text)}", path, line) from None
    if count is not None and vals.size != count:
        raise InputError(f"expected {count} {what}, got {vals.size}", path, line)
    if not np.all(np.isfinite(vals)):
        raise InputError(f"non-finite value in {quote(text)}", path, line)
    return vals


#: An EuRoC time stamp: integer nanoseconds (``1403636579758555392``).
_EUROC_STAMP = re.compile(r"[0-9]+")


def parse_euroc_line(text: str, path: Path, line: int, what: str) -> np.ndarray:
    """The numbers of one line of an EuRoC CSV (``timestamp [ns],v1,v2,...``).

    InputError when the line is not one, rather than misread: no comma (a
    space-separated TUM or KITTI line), an empty field or one holding two
    numbers (the columns after it would shift), or a time that is not integer
    nanoseconds (seconds, as TUM writes them, would be read as 1e-9 times less).
    """
    fields = [f.strip() for f in text.split(",")]
    if len(fields) < 2:
        raise InputError(f"no comma: EuRoC lines are comma-separated ({what}): {quote(text)}", path, line)
    if not all(f and len(f.split()) == 1 for f in fields):
        raise InputError(
            f"an empty field or one of two numbers: EuRoC lines are comma-separated ({what}): {quote(text)}",
            path,
            line,
        )
    if not _EUROC_STAMP.fullmatch(fields[0]):
        raise InputError(
            f"EuRoC times are integer nanoseconds, got {quote(fields[0])} (seconds: a TUM file?)", path, line
        )
    return parse_floats(",".join(fields), path, line, what=what)


def quat_to_rotation(
    qw: float, qx: float, qy: float, qz: float, path: str | Path | None, line: int | None
) -> np.ndarray:
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if not 0.9 < n < 1.1:
        raise InputError(f"quaternion norm {n:.4f} is not 1", path, line)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


#: Largest ``|R^T R - I|`` entry and ``|det R - 1|`` of a rotation read from a file.
#: Poses printed with 6 significant digits (the KITTI poses' ``%e``) are orthonormal
#: to ~1e-6, with 4 digits to ~1e-4; 1e-3 keeps every honest file and refuses a
#: scaled, sheared or reflected block, whose rotation error would be meaningless.
ROTATION_TOL = 1e-3


def check_rotation(R: np.ndarray, path: str | Path | None, line: int | None) -> np.ndarray:
    """``R`` when it is a rotation to :data:`ROTATION_TOL`, else InputError at ``line``."""
    off = float(np.max(np.abs(R.T @ R - np.eye(3))))
    det = float(np.linalg.det(R))
    if off > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise InputError(
            f"the 3x3 block is not a rotation (|R^T R - I| = {off:.2g}, det R = "
            f"{det:.4g}; tolerance {ROTATION_TOL:g})",
            path,
            line,
        )
    return R


def check_increasing(stamps, line_numbers, path: Path, what: str = "timestamps") -> None:
    """InputError at the first stamp not after the one before it: a repeated or
    decreasing time pairs two frames with one truth pose (or none)."""
    stamps = np.asarray(stamps, dtype=np.float64)
    bad = np.nonzero(np.diff(stamps) <= 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"{what} must increase strictly: {float(stamps[k])} is not after "
            f"{float(stamps[k - 1])} of line {line_numbers[k - 1]}",
            path,
            line_numbers[k],
        )


def check_K(K: np.ndarray, path, line=None) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise InputError("intrinsics must be a finite 3x3 matrix", path, line)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise InputError(
            "intrinsics must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", path, line
        )
    fx, fy = K[0, 0], K[1, 1]
    if not (FOCAL_MIN_PX <= min(fx, fy) and max(fx, fy) <= FOCAL_MAX_PX):
        raise InputError(
            f"focal lengths fx = {fx:.6g}, fy = {fy:.6g} px are outside "
            f"{FOCAL_MIN_PX:g} to {FOCAL_MAX_PX:.0e} px: no camera's",
            path,
            line,
        )
    if np.max(np.abs([K[0, 1], K[0, 2], K[1, 2]])) > PRINCIPAL_POINT_MAX_PX:
        raise InputError(
            f"principal point ({K[0, 2]:.6g}, {K[1, 2]:.6g}) or skew {K[0, 1]:.6g} "
            f"beyond {PRINCIPAL_POINT_MAX_PX:.0e} px: no camera's",
            path,
            line,
        )
    return K


def image_size(path: str) -> tuple[int, int]:
    img = load_gray(path)
    return int(img.shape[1]), int(img.shape[0])


def check_exist(paths: Sequence[str], where: Path) -> None:
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        raise InputError(
            f"{len(missing)} of {len(paths)} listed images are missing (first: {missing[0]})", where
        )


#: Runs of ASCII digits only: ``\d`` and ``str.isdigit`` also take ``²`` or
#: ``١``, which ``int`` refuses or which no file-name order means as a number.
_ASCII_DIGITS = re.compile(r"([0-9]+)")


def natural_key(name: str):
    """Sort key of a file name: ``img2`` before ``img10`` (ASCII digit runs as numbers)."""
    parts = _ASCII_DIGITS.split(name)
    # split with a group alternates text and digit runs: odd places are digits
    return [int(t) if i % 2 else t.lower() for i, t in enumerate(parts)]


def associate(img_t: np.ndarray, gt_t: np.ndarray, max_dt_s: float) -> np.ndarray:
    """Index into ``gt_t`` (sorted) of the nearest stamp per image, -1 if > max_dt_s."""
    if gt_t.size == 0:
        return np.full(img_t.shape, -1)
    j = np.clip(np.searchsorted(gt_t, img_t), 1, max(gt_t.size - 1, 1))
    j0 = np.clip(j - 1, 0, gt_t.size - 1)
    j1 = np.clip(j, 0, gt_t.size - 1)
    pick = np.where(np.abs(gt_t[j0] - img_t) <= np.abs(gt_t[j1] - img_t), j0, j1)
    return np.where(np.abs(gt_t[pick] - img_t) <= max_dt_s, pick, -1)


def list_images(folder: Path) -> list[str]:
    """Image files of ``folder`` (:data:`IMAGE_EXTENSIONS`) in natural file-name order.

    A symbolic link with an image's name that leads to no file is refused
    (InputError naming it), as a corrupt image is when read: skipped, it made
    the folder one image shorter without a word.
    """
    found, dangling = [], []
    for p in Path(folder).iterdir():
        if p.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        if p.is_file():
            found.append(str(p))
        elif p.is_symlink() and not p.exists():
            dangling.append(p)
    if dangling:
        first = min(dangling, key=lambda q: natural_key(q.name))
        more = f" ({len(dangling) - 1} more such links in the folder)" if len(dangling) > 1 else ""
        raise InputError(
            f"image file not found: a symbolic link to {quote(os.readlink(first))}, which leads to no file"
            + more,
            first,
        )
    return sorted(found, key=lambda s: natural_key(Path(s).name))


def folder_images(folder: Path) -> list[Path]:
    """:func:`list_images` as paths; InputError when the folder is missing or has none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("image folder not found", folder)
    paths = [Path(p) for p in list_images(folder)]
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in folder", folder)
    return paths


def expand_images(items: list[str | Path]) -> list[Path]:
    """Image files and folders (each in natural order) as one list of paths."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            out.extend(folder_images(p))
        elif p.is_file():
            out.append(p)
        else:
            raise InputError("no such image file or folder", p)
    return out
