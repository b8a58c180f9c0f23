"""Image sequences: the :class:`ImageSequence` record every image reader returns,
and the small parsing helpers the readers share (numpy + OpenCV, no gtsam).

Readers: :mod:`.kitti`, :mod:`.images` (TUM RGB-D, EuRoC, plain folders, and
the layout detection), :mod:`.calibration` (intrinsics files), and the
rendered :mod:`.synthetic_images`.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from frontend.image import load_gray, quiet_opencv
from graphslam.sources.tokens import NUMBER_TOKEN
from slamcore.errors import InputError, quote
from slamcore.input_files import check_input_path, check_plain_text

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
        camera_warnings: the reader's reasons to doubt the camera (intrinsics that do
            not fit the images), one line each; :attr:`warnings` adds the frames.
        frame_warnings: what was done to the frames after reading (frames left out
            for want of ground truth), one line each.
    """

    name: str
    image_paths: list[str]
    stamps_s: np.ndarray | None
    K: np.ndarray
    distortion: np.ndarray | None
    wTc_true: np.ndarray | None
    image_size: tuple[int, int]
    source_path: str | None = None
    #: reasons to doubt the camera that the reader found (intrinsics that do not fit
    #: the images), one line each
    camera_warnings: tuple[str, ...] = ()
    frame_warnings: tuple[str, ...] = ()
    #: (map_xy, map_interp) of :func:`cv2.initUndistortRectifyMap`, built on the
    #: first :meth:`load` of a distorted sequence; ``False`` once found unneeded.
    _undistort_maps: tuple | bool | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.image_paths)

    @cached_property
    def warnings(self) -> tuple[str, ...]:
        """Reasons to doubt a run on these frames, one line each: the camera's, then
        frames stored twice among these (:func:`repeated_frames`, so a selection of
        frames is judged on its own). The run says them as ``graphslam: warning:``
        lines and keeps them in metrics.json ``warnings``."""
        return (*self.camera_warnings, *self.frame_warnings, *repeated_frames(self.image_paths))

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
            turned = (img.shape[0], img.shape[1]) == tuple(self.image_size)
            raise InputError(
                f"image is {img.shape[1]}x{img.shape[0]} px, the sequence's "
                f"are {self.image_size[0]}x{self.image_size[1]}"
                + (" (turned by 90 degrees: a photo with another EXIF orientation?)" if turned else ""),
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

    def __post_init__(self) -> None:
        if self.is_distorted:  # refused as the files are read, before any output is made
            self._check_coverage()

    def _check_coverage(self) -> None:
        """InputError when the distortion sends most of the pinhole image outside the
        stored one: no lens does that to its own camera (a strong barrel lens pulls the
        corners in, a pincushion pushes the outer rim out), so the coefficients are not
        this camera's, e.g. a second camera's line read as ``k1 k2 p1 p2``. The run would
        otherwise see a smeared border, find no corner, and blame the rest.

        The share is that of :meth:`_maps`' undistortion map (identity rotation, ``K`` kept),
        on a grid of about 64 x 48 of its pixels: the lens model at each, by OpenCV."""
        W, H = (int(v) for v in self.image_size)
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
        u, v = np.meshgrid(np.linspace(0, W - 1, 64), np.linspace(0, H - 1, 48))
        rays = np.linalg.solve(K, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
        uv, _ = cv2.projectPoints(rays.T.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
        uv = uv.reshape(-1, 2)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        coverage = float(np.count_nonzero(inside)) / float(len(uv))
        if coverage < MIN_UNDISTORTED_COVERAGE:
            coeffs = " ".join(f"{c:g}" for c in dist)
            raise InputError(
                f"distortion coefficients {coeffs} take {100.0 * coverage:.1f} % of the "
                f"undistorted image's pixels from inside the {W}x{H} images (a lens gives "
                f"most of them): not this camera's distortion",
                self.source_path,
            )


def read_lines(path: Path, what: str) -> list[tuple[int, str]]:
    """(line_no, stripped text) of non-empty, non-comment lines; missing file -> InputError."""
    check_input_path(path, what)
    check_plain_text(path)
    try:
        text = path.read_text(encoding="utf-8-sig", errors="replace")  # a byte-order mark is no number
    except OSError as e:
        raise InputError(f"cannot read {what}: {e.strerror}", path) from None
    out = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if s:
            out.append((k, s))
    return out


def parse_floats(
    text: str, path: Path, line: int | None, count: int | None = None, what: str = "numbers"
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
    if re.match(r"[A-Za-z_]", fields[0]) and fields[0].lower() not in ("nan", "inf", "infinity"):
        # pandas' to_csv writes its header without EuRoC's '#' (it was blamed on the time)
        raise InputError(f"a header line ({quote(text)}): start it with '#', as EuRoC's files do", path, line)
    if len(fields) < 2:
        raise InputError(f"no comma: EuRoC lines are comma-separated ({what}): {quote(text)}", path, line)
    if not all(f and len(f.split()) == 1 for f in fields):
        raise InputError(
            f"an empty field or one of two numbers: EuRoC lines are comma-separated ({what}): {quote(text)}",
            path,
            line,
        )
    if re.fullmatch(r"-[0-9]+", fields[0]):
        raise InputError(
            f"EuRoC times are nanoseconds since an epoch, never negative: {quote(fields[0])}", path, line
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
    return np.array(rotation_entries(qw / n, qx / n, qy / n, qz / n))


def rotation_entries(w, x, y, z) -> tuple:
    """The 3 x 3 entries (rows of tuples) of the rotation of the unit quaternion
    ``w + xi + yj + zk``; numbers or arrays alike, so a file read line by line and one
    read as a whole array give the same bits."""
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
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


#: Coefficient counts OpenCV's distortion model takes (``cv2.initUndistortRectifyMap``
#: asserts on any other, a traceback naming no file).
DISTORTION_COUNTS = (4, 5, 8, 12, 14)


#: Least share of the undistorted (pinhole) image whose pixels come from inside the
#: stored image (:meth:`ImageSequence._check_coverage`). Real lenses, undistorted at
#: their own camera matrix, give nearly all of them (EuRoC's radtan 100 %, a pincushion
#: of k1 = 0.3 at a 90 deg field 68 %, of k1 = 1 47 %); a camera's focal length read as k1 gives
#: almost none.
MIN_UNDISTORTED_COVERAGE = 0.5


def check_distortion(dist: np.ndarray, path, line=None, what: str = "") -> np.ndarray | None:
    """``dist`` as a flat float64 array, None when empty; InputError naming ``path`` (and
    ``what``, the key or topic holding it) for a count OpenCV does not take or a
    non-finite coefficient. Every calibration reader (files, bags) checks here."""
    dist = np.asarray(dist, dtype=np.float64).reshape(-1)
    if dist.size == 0:
        return None
    where = f"{what}: " if what else ""
    if dist.size not in DISTORTION_COUNTS:
        raise InputError(
            f"{where}expected {', '.join(map(str, DISTORTION_COUNTS[:-1]))} or {DISTORTION_COUNTS[-1]} "
            f"distortion coefficients, got {dist.size}",
            path,
            line,
        )
    if not np.all(np.isfinite(dist)):
        raise InputError(f"{where}non-finite distortion coefficient", path, line)
    return dist


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


#: Farthest a pinhole ``K`` may put an image edge from the optical axis, degrees.
#: The widest rectilinear lenses made see about 120-130 degrees across (60-65
#: from the axis); past 80 degrees a pixel at the edge covers over 30 times the
#: angle of one at the centre (``1 / cos^2``). Beyond it the numbers are not a
#: pinhole camera's: a fisheye, or intrinsics divided by the image size.
MAX_HALF_VIEW_DEG = 80.0
#: How far from the image centre the principal point may be before a run is
#: doubted, as a share of the way to the edge (an ellipse through the middles of
#: the half-widths). A lens is centred on its sensor to a few percent, and
#: rectification or a crop moves the point by a few percent more (KITTI: 2 %,
#: EuRoC: 4 %, TUM fr1: 6 %); intrinsics of another resolution or of the image
#: turned by 90 degrees put it 50 % or more away (at a corner: 100 %).
PRINCIPAL_POINT_DOUBT = 0.5


def _offset(cx: float, cy: float, w: int, h: int) -> float:
    """Distance of ``(cx, cy)`` from the centre of a ``w`` x ``h`` image, 1 at an edge's middle."""
    return math.hypot((cx - (w - 1) / 2) / (w / 2), (cy - (h - 1) / 2) / (h / 2))


#: fx / fy beyond which the pixels are doubted not square. Sensors have square pixels (the
#: calibrations at hand: KITTI 1.000, the Lund door's COLMAP 1.000, TUM's fr1 1.002); an
#: anamorphic lens squeezes 1.33-2x, and a 5 % difference is already far outside what any
#: calibration of square pixels gives (pass 23: fy = fx / 2 ran without a word).
PIXEL_ASPECT_DOUBT = 0.05


def _aspect_doubt(fx: float, fy: float, where) -> list[str]:
    ratio = fx / fy
    if abs(ratio - 1.0) <= PIXEL_ASPECT_DOUBT:
        return []
    return [
        f"{where}: fx = {fx:.6g} and fy = {fy:.6g} px differ by {100 * abs(ratio - 1):.0f} % (square "
        "pixels: within a few tenths of a %): a camera of non-square pixels, or fx and fy of two "
        "calibrations? the estimate is doubtful"
    ]


def camera_doubts(K: np.ndarray, size: tuple[int, int], where, first_image: str | None = None) -> list[str]:
    """Check that ``K`` is a camera of ``size`` ``(W, H)`` images; InputError (naming
    ``where``) when it cannot be, else the reasons to doubt it (warning lines).

    Refused: a principal point outside the image (intrinsics of another resolution,
    or ``cx cy`` in another place of the line) and a focal length that puts an image
    edge more than :data:`MAX_HALF_VIEW_DEG` off the axis (normalised intrinsics).
    Doubted: a principal point more than :data:`PRINCIPAL_POINT_DOUBT` of the way to
    the edge, or half that when ``first_image`` is turned by its EXIF orientation
    (OpenCV reads it turned) and ``K`` fits the image as stored better (the line
    says so).
    """
    K = np.asarray(K, dtype=np.float64)
    w, h = int(size[0]), int(size[1])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
        raise InputError(
            f"principal point (cx, cy) = ({cx:.6g}, {cy:.6g}) px is outside the {w}x{h} px "
            "images: "
            + (
                _exif_turned(cx, cy, w, h, first_image)
                or "intrinsics of another resolution, or the numbers in another order "
                "(expected 'fx fy cx cy')"
            ),
            where,
        )
    half_x = math.degrees(math.atan(max(cx + 0.5, w - 0.5 - cx) / fx))
    half_y = math.degrees(math.atan(max(cy + 0.5, h - 0.5 - cy) / fy))
    if max(half_x, half_y) > MAX_HALF_VIEW_DEG:
        raise InputError(
            f"fx = {fx:.6g}, fy = {fy:.6g} px put the edge of the {w}x{h} px images "
            f"{max(half_x, half_y):.1f} degrees off the axis (a pinhole camera sees at most "
            f"{MAX_HALF_VIEW_DEG:g}): intrinsics divided by the image size? they are in pixels",
            where,
        )
    aspect = _aspect_doubt(fx, fy, where)
    off = _offset(cx, cy, w, h)
    # half the doubt when the photos are turned on reading and K fits them as stored:
    # a 4:3 photo's landscape K on the portrait image is 42 % off, beyond any lens too
    exif = _exif_turned(cx, cy, w, h, first_image) if off > PRINCIPAL_POINT_DOUBT / 2 else ""
    if off <= PRINCIPAL_POINT_DOUBT and not exif:
        return aspect
    why = exif or "intrinsics of another resolution or orientation?"
    return aspect + [
        f"{where}: principal point ({cx:.6g}, {cy:.6g}) px is {100 * off:.0f} % of the way from "
        f"the centre of the {w}x{h} px images to their edge (a lens: a few %): {why}; "
        "the estimate is doubtful"
    ]


def _exif_turned(cx: float, cy: float, w: int, h: int, first_image: str | None) -> str:
    """What to say when ``first_image`` is stored ``h`` x ``w`` and turned by its EXIF
    orientation when read, and ``(cx, cy)`` fit the stored pixels; else ``""``."""
    if first_image is None or w == h or _offset(cx, cy, h, w) >= _offset(cx, cy, w, h):
        return ""
    if stored_size(first_image) != (h, w):
        return ""
    return (
        f"the photos are stored {h}x{w} px and turned by their EXIF orientation when read, "
        "and these intrinsics fit the stored pixels: give those of the turned images"
    )


def image_doubts(
    K: np.ndarray, paths: Sequence[str], camera_from, stated: tuple[int, int] | None = None
) -> tuple[tuple[int, int], tuple[str, ...]]:
    """``(image size (W, H), warnings)`` of a sequence read from ``paths`` with ``K``:
    :func:`camera_doubts` (InputError naming ``camera_from``, the file the camera came
    from). ``stated``: the size the camera file gives its
    images, if it does; another size than the images' is refused."""
    size = image_size(paths[0])
    if stated is not None and tuple(stated) != size:
        raise InputError(
            f"the camera is calibrated for {stated[0]}x{stated[1]} px images (the size the file "
            f"states), these are {size[0]}x{size[1]} px ({Path(paths[0]).name})",
            camera_from,
        )
    return size, tuple(camera_doubts(K, size, camera_from, paths[0]))


def stored_size(path: str) -> tuple[int, int] | None:
    """``(W, H)`` of an image as stored, its EXIF orientation ignored (None: unreadable)."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    with quiet_opencv():
        img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    return None if img is None else (int(img.shape[1]), int(img.shape[0]))


def repeated_frames(paths: Sequence[str]) -> list[str]:
    """A warning line when consecutive frames are one file or byte-identical files, else [].

    A camera's two exposures always differ (sensor noise, at least), so two equal
    files in a row are one frame stored twice: the run takes them as two instants,
    between which the camera did not move whatever its odometry or truth says.
    Only files of the size of a neighbour are read, each once (a BLAKE2b
    digest compared, not the bytes).
    """
    sizes = []
    for p in paths:
        try:
            sizes.append(os.stat(p).st_size)
        except OSError:
            sizes.append(-1)
    digests: dict[int, bytes | None] = {}  # each file read once (an uncompressed
    # sequence has every file of one size)

    def digest(k: int) -> bytes | None:
        if k not in digests:
            try:
                digests[k] = hashlib.blake2b(Path(paths[k]).read_bytes()).digest()
            except OSError:
                digests[k] = None
        return digests[k]

    pairs = []
    for k in range(1, len(paths)):
        a, b = paths[k - 1], paths[k]
        if sizes[k] < 0 or sizes[k] != sizes[k - 1]:
            continue
        if a == b or (digest(k - 1) is not None and digest(k - 1) == digest(k)):
            pairs.append((a, b))
    if not pairs:
        return []
    a, b = pairs[0]
    return [
        f"{len(pairs)} of {len(paths) - 1} consecutive frames are the same image twice "
        f"(first: {Path(a).name}, {Path(b).name}): two exposures of a camera always differ, "
        "so these are frames stored twice, or blank (a covered lens, no signal), taken as "
        "instants at which the camera did not move"
    ]


def image_size(path: str) -> tuple[int, int]:
    img = load_gray(path)
    return int(img.shape[1]), int(img.shape[0])


def check_exist(paths: Sequence[str], where: Path) -> None:
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        raise InputError(
            f"{len(missing)} of {len(paths)} listed images are missing (first: {missing[0]})", where
        )


#: Numbers in a file name: runs of ASCII digits (``\d`` and ``str.isdigit`` also take
#: ``²`` or ``١``, which ``int`` refuses or which no file-name order means as a number),
#: with a fraction where a point joins two runs: a time stamp (``1.25.png``,
#: ``cam_0.30000000000000004.png``, ``1305031102.175304.png``) is ordered by its value
#: (``0.3`` after ``0.25`` and before ``1.0``), not as two digit runs (``5`` before
#: ``25``), which read a folder of ``f"cam_{t}.png"`` names out of time order.
_NUMBER = re.compile(r"([0-9]+(?:\.[0-9]+)?)")


def natural_key(name: str):
    """Sort key of a file name: ``img2`` before ``img10`` (digit runs as numbers),
    ``cam_1.25.png`` before ``cam_1.5.png`` (a decimal number by its value)."""
    parts = _NUMBER.split(name)
    # split with a group alternates text and numbers: odd places are numbers, as
    # (integer part, fraction digits): fractions compare as text ("25" < "5")
    return [_number_key(t) if i % 2 else t.lower() for i, t in enumerate(parts)]


def _number_key(text: str) -> tuple[int, str]:
    whole, _, fraction = text.partition(".")
    return int(whole), fraction.rstrip("0")


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
    the folder one image shorter without a word. Hidden files (a name starting with
    ``.``: macOS's ``._0001.png`` AppleDouble companions on a copied drive) are no
    frames and are passed over, as ``ls`` does.
    """
    found, dangling = [], []
    for p in Path(folder).iterdir():
        if p.suffix.lower() not in IMAGE_EXTENSIONS or p.name.startswith("."):
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
    ordered = sorted(found, key=lambda s: natural_key(Path(s).name))
    _check_one_place_each(ordered)
    return ordered


def _check_one_place_each(paths: list[str]) -> None:
    """InputError when two files take one place in the order: the same number under two
    spellings (``frame_1.png``, ``frame_01.png``: their order would be the file
    system's) or one frame stored twice (``000003.png`` and ``000003.jpg``)."""
    keys = [natural_key(Path(p).stem) for p in paths]
    seen: dict[str, str] = {}
    for p, k in zip(paths, keys, strict=True):
        first = seen.setdefault(repr(k), p)
        if first != p:
            raise InputError(
                f"{Path(first).name} and {Path(p).name} name the same frame: which comes first "
                "is not known; keep one of them (or number them apart)",
                Path(p).parent,
            )


def images_below(folder: Path) -> str:
    """``"; its folder X/ holds N: pass that folder"`` for the first subfolder holding
    images (a data set whose images sit one level down), else ``""``. A TUM RGB-D
    folder without its ``rgb.txt`` (ORB-SLAM's ``associations.txt`` in its place) is
    said as that: its ``depth/`` sorts first and was offered as the images."""
    if (
        (folder / "rgb").is_dir()
        and not (folder / "rgb.txt").is_file()
        and ((folder / "groundtruth.txt").is_file() or (folder / "associations.txt").is_file())
    ):
        return (
            "; a TUM RGB-D folder without its rgb.txt (the list 'timestamp rgb/file.png' that "
            "graphslam reads; associations.txt is ORB-SLAM's): add rgb.txt"
        )
    try:
        below = sorted((p for p in folder.iterdir() if p.is_dir()), key=lambda p: (p.name == "depth", p.name))
    except OSError:
        return ""
    for sub in below:
        try:
            n = len(list_images(sub))
        except (OSError, InputError):  # an unreadable folder, a dangling link: not the one to name
            continue
        if n:
            return f"; its folder {sub.name}/ holds {n}: pass that folder"
    return ""


def folder_images(folder: Path) -> list[Path]:
    """:func:`list_images` as paths; InputError when the folder is missing or has none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("image folder not found", folder)
    paths = [Path(p) for p in list_images(folder)]
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in folder{images_below(folder)}", folder)
    return paths


def check_utf8_names(paths: Sequence[str | Path], why: str) -> None:
    """InputError naming the first file whose name is not UTF-8 (a Latin-1 name from an
    old archive reads as undecodable bytes), for outputs that name images by file name
    in UTF-8 text (``why``: which)."""
    for p in paths:
        name = Path(p).name
        try:
            name.encode("utf-8")
        except UnicodeEncodeError:
            raise InputError(
                f"file name {os.fsencode(name)!r} is not UTF-8: {why}; rename the file "
                "(e.g. convmv -f latin1 -t utf8)",
                Path(p).parent,
            ) from None


def expand_images(items: list[str | Path]) -> tuple[list[Path], int]:
    """Image files and folders (each in natural order) as one list of paths, each file
    once (the first time it comes: a file and its folder, a file given twice, a link to
    it), and how many repeats were left out."""
    out: list[Path] = []
    seen: set[str] = set()
    repeats = 0
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = folder_images(p)
        elif p.is_file():
            found = [p]
        else:
            raise InputError("no such image file or folder", p)
        for q in found:
            key = os.path.realpath(q)
            if key in seen:
                repeats += 1
                continue
            seen.add(key)
            out.append(q)
    return out, repeats
