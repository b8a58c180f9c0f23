"""Image-sequence readers: KITTI odometry, TUM RGB-D, EuRoC MAV, a plain folder.

Every reader returns an :class:`ImageSequence` (numpy + OpenCV only, no gtsam):
ordered image paths, timestamps, intrinsics ``K`` (3, 3), distortion, optional
ground truth ``wTc_true`` (N, 4, 4, camera-to-world: ``p_w = wTc @ p_c``,
camera looking along +z) and the image size ``(W, H)``. Images are read lazily
by :meth:`ImageSequence.load` as (H, W) uint8 greyscale.

Bad input raises :class:`~slamcore.errors.InputError` naming the file and, for
a malformed line, its 1-based line number; a missing file or a count mismatch
gives a one-line message.

Formats accepted
----------------
KITTI odometry (:func:`read_kitti`), folder with ``image_<c>/*.png``,
``calib.txt`` (lines ``P<c>: 12 numbers``, row-major 3x4; ``K`` is its left
3x3 block), ``times.txt`` (one time in s per line, optional) and ``poses.txt``
(optional; 12 numbers per line: row-major 3x4 pose of camera 0 at frame k in
camera 0 at frame 0). For ``camera != 0`` the pose is composed with the
rectified offset ``c0Tck`` taken from ``P<c>`` (``t = K^-1 P[:, 3]``).

TUM RGB-D (:func:`read_tum_rgbd`): ``rgb.txt`` (``timestamp filename``, ``#``
comments), ``groundtruth.txt`` optional (``timestamp tx ty tz qx qy qz qw``,
the colour camera's optical centre in the world). Each image takes the ground
truth with the nearest timestamp if it is within ``max_dt_s`` (0.02 s);
**images without such a match are dropped** when ground truth exists (TUM's
ground truth often starts after the first images). Intrinsics, first match
wins: the ``intrinsics`` argument (``(fx, fy, cx, cy)``, a (3, 3) K, a path to
an intrinsics file, or a preset ``"fr1"``/``"fr2"``/``"fr3"``/``"ros"``); an
intrinsics file in the folder (see :data:`INTRINSICS_FILE_NAMES`); the preset
named by ``freiburg1/2/3`` in the folder's name (TUM's own naming); otherwise
an InputError (TUM folders carry no calibration).

EuRoC MAV (:func:`read_euroc`): ``mav0/cam0/data.csv`` (``#timestamp [ns],
filename``, images in ``mav0/cam0/data/``), ``mav0/cam0/sensor.yaml``
(``intrinsics: [fu, fv, cu, cv]``, ``distortion_coefficients``, ``T_BS`` as
``{rows, cols, data}``, ``resolution``), and optionally
``mav0/state_groundtruth_estimate0/data.csv`` (``timestamp [ns], px, py, pz,
qw, qx, qy, qz, ...``, the body pose ``wTb``). Camera ground truth is
``wTc = wTb @ T_BS`` with nearest-timestamp association (``max_dt_s``, 0.02 s);
unmatched images are dropped, as for TUM.

Plain folder (:func:`read_image_folder`): files ending in ``.png .jpg .jpeg
.bmp .tif .tiff`` (any case) in natural file-name order (``img2`` before
``img10``); no timestamps, no ground truth. Intrinsics from a file:

* text (any name not ending in ``.yaml``/``.yml``), ``#`` comments, numbers
  separated by spaces or commas, either ``fx fy cx cy`` on one line, or the
  three rows of ``K`` on three lines; optionally one more line with the OpenCV
  distortion coefficients ``k1 k2 p1 p2 [k3 ...]``;
* YAML: ``fx, fy, cx, cy`` keys, or ``K``/``camera_matrix`` (3x3 nested list,
  9-list or OpenCV ``{rows, cols, data}``), or EuRoC's ``intrinsics: [fu, fv,
  cu, cv]``; optional ``distortion`` / ``distortion_coefficients`` /
  ``dist_coeffs`` (list or ``{data}``). ``%YAML`` directives are ignored.

Without ``intrinsics_file`` the folder is searched for
:data:`INTRINSICS_FILE_NAMES`; if none is found an InputError says so.

:func:`read_image_sequence` picks the reader from the folder layout.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from slamcore.errors import InputError

__all__ = [
    "ImageSequence", "read_kitti", "read_tum_rgbd", "read_euroc", "read_image_folder",
    "read_image_sequence", "read_intrinsics_file", "intrinsics_matrix", "TUM_INTRINSICS",
    "INTRINSICS_FILE_NAMES", "IMAGE_EXTENSIONS", "ASSOCIATION_MAX_DT_S",
]

#: Extensions :func:`read_image_folder` accepts (compared lower-case).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: Intrinsics files looked for in a folder, in this order.
INTRINSICS_FILE_NAMES = ("intrinsics.txt", "camera.txt", "intrinsics.yaml", "intrinsics.yml",
                         "camera.yaml", "camera.yml", "calibration.txt")

#: Nearest-timestamp association tolerance (s) for TUM and EuRoC ground truth.
ASSOCIATION_MAX_DT_S = 0.02

#: TUM RGB-D colour-camera calibrations (fx, fy, cx, cy) and distortion
#: (k1, k2, p1, p2, k3), from the dataset's "file formats" page. "ros" is the
#: ROS default used for the uncalibrated/undistorted case.
TUM_INTRINSICS = {
    "fr1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": ((535.4, 539.2, 320.1, 247.6), None),
    "ros": ((525.0, 525.0, 319.5, 239.5), None),
}


@dataclass(frozen=True, eq=False)
class ImageSequence:
    """An ordered image sequence with its calibration and optional ground truth.

    Attributes:
        name: short name for reports ("kitti", "tum-rgbd", "euroc", "folder", ...).
        image_paths: (N,) image file paths in time order.
        stamps_s: (N,) timestamps in seconds, or ``None``.
        K: (3, 3) intrinsic matrix (pixels; pixel centres at integer coordinates).
        distortion: OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3...])`` or ``None``.
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

    def __len__(self) -> int:
        return len(self.image_paths)

    @property
    def has_ground_truth(self) -> bool:
        return self.wTc_true is not None

    def load(self, i: int) -> np.ndarray:
        """Image ``i`` as (H, W) uint8 greyscale; an unreadable file raises InputError."""
        path = self.image_paths[i]
        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError("cannot read image (missing or not an image)", path)
        return img


# --------------------------------------------------------------------------- helpers

def _read_lines(path: Path, what: str) -> list[tuple[int, str]]:
    """(line_no, stripped text) of non-empty, non-comment lines; missing file -> InputError."""
    if not path.is_file():
        raise InputError(f"{what} not found", path)
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


def _floats(text: str, path: Path, line: int, count: int | None = None,
            what: str = "numbers") -> np.ndarray:
    parts = [p for p in re.split(r"[\s,]+", text.strip()) if p]
    try:
        vals = np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise InputError(f"malformed line, expected {what}: {text[:80]!r}", path, line) from None
    if count is not None and vals.size != count:
        raise InputError(f"expected {count} {what}, got {vals.size}", path, line)
    if not np.all(np.isfinite(vals)):
        raise InputError(f"non-finite value in {text[:80]!r}", path, line)
    return vals


def _quat_to_R(qw: float, qx: float, qy: float, qz: float, path: Path, line: int) -> np.ndarray:
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if not 0.9 < n < 1.1:
        raise InputError(f"quaternion norm {n:.4f} is not 1", path, line)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) ``K`` from focal lengths and principal point (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _check_K(K: np.ndarray, path, line=None) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise InputError("intrinsics must be a finite 3x3 matrix", path, line)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise InputError("intrinsics must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0",
                         path, line)
    return K


def _image_size(path: str) -> tuple[int, int]:
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError("cannot read image (missing or not an image)", path)
    return int(img.shape[1]), int(img.shape[0])


def _check_exist(paths: Sequence[str], where: Path) -> None:
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        raise InputError(f"{len(missing)} of {len(paths)} listed images are missing "
                         f"(first: {missing[0]})", where)


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _associate(img_t: np.ndarray, gt_t: np.ndarray, max_dt_s: float) -> np.ndarray:
    """Index into ``gt_t`` (sorted) of the nearest stamp per image, -1 if > max_dt_s."""
    if gt_t.size == 0:
        return np.full(img_t.shape, -1)
    j = np.clip(np.searchsorted(gt_t, img_t), 1, max(gt_t.size - 1, 1))
    j0 = np.clip(j - 1, 0, gt_t.size - 1)
    j1 = np.clip(j, 0, gt_t.size - 1)
    pick = np.where(np.abs(gt_t[j0] - img_t) <= np.abs(gt_t[j1] - img_t), j0, j1)
    return np.where(np.abs(gt_t[pick] - img_t) <= max_dt_s, pick, -1)


# --------------------------------------------------------------------------- intrinsics

def _fs_to_python(node):
    """An OpenCV FileNode as plain Python (dict / list / float / str / None)."""
    if node.isMap():
        return {k: _fs_to_python(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_fs_to_python(node.at(i)) for i in range(node.size())]
    if node.isInt() or node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def _load_yaml(path: Path):
    """Parse a small YAML file (PyYAML if installed, else OpenCV's YAML reader).

    ``%YAML`` directives and OpenCV's ``!!opencv-matrix`` tags are ignored, so
    OpenCV/Kalibr/EuRoC files read the same way as plain YAML.
    """
    text = path.read_text(encoding="utf-8", errors="replace")
    text = "\n".join("" if ln.lstrip().startswith("%") else ln for ln in text.splitlines())
    text = text.replace("!!opencv-matrix", "")
    try:
        import yaml
    except ImportError:
        yaml = None
    if yaml is not None:
        try:
            return yaml.safe_load(text)
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)
            line = None if mark is None else mark.line + 1
            raise InputError(f"malformed YAML: {getattr(e, 'problem', e)}", path, line) from None
    try:
        fs = cv2.FileStorage("%YAML:1.0\n" + text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        return _fs_to_python(fs.root())
    except (cv2.error, SystemError) as e:  # OpenCV 5 wraps parse errors in SystemError
        msg = " ".join(str(e.__cause__ or e).split())
        m = re.search(r"\((\d+)\)", msg)
        line = int(m.group(1)) - 1 if m else None  # OpenCV counts the added header line
        raise InputError(f"malformed YAML: {msg[-120:]}", path, line) from None


def _yaml_matrix(value, path: Path, key: str) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        arr = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{key}: expected a list of numbers", path) from None
    return arr


def read_intrinsics_file(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """``(K (3, 3), distortion or None)`` from a text or YAML file (formats in the module doc)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("intrinsics file not found", path)
    if path.suffix.lower() in (".yaml", ".yml"):
        data = _load_yaml(path)
        if not isinstance(data, dict):
            raise InputError("intrinsics YAML must be a mapping", path)
        if all(k in data for k in ("fx", "fy", "cx", "cy")):
            try:
                K = intrinsics_matrix(*(float(data[k]) for k in ("fx", "fy", "cx", "cy")))
            except (TypeError, ValueError):
                raise InputError("fx, fy, cx, cy must be numbers", path) from None
        elif "K" in data or "camera_matrix" in data:
            key = "K" if "K" in data else "camera_matrix"
            arr = _yaml_matrix(data[key], path, key)
            if arr.size != 9:
                raise InputError(f"{key}: expected 9 numbers, got {arr.size}", path)
            K = arr.reshape(3, 3)
        elif "intrinsics" in data:
            arr = _yaml_matrix(data["intrinsics"], path, "intrinsics")
            if arr.size != 4:
                raise InputError(f"intrinsics: expected [fu, fv, cu, cv], got {arr.size} numbers", path)
            K = intrinsics_matrix(*arr)
        else:
            raise InputError("no intrinsics found: expected fx/fy/cx/cy, K, camera_matrix "
                             "or intrinsics", path)
        dist = None
        for key in ("distortion", "distortion_coefficients", "dist_coeffs"):
            if key in data and data[key] is not None:
                dist = _yaml_matrix(data[key], path, key)
                break
        return _check_K(K, path), dist
    lines = _read_lines(path, "intrinsics file")
    if not lines:
        raise InputError("intrinsics file is empty", path)
    first_no, first = lines[0]
    v = _floats(first, path, first_no, what="intrinsics numbers")
    if v.size == 4:
        K, rest = intrinsics_matrix(*v), lines[1:]
    elif v.size == 3:
        if len(lines) < 3:
            raise InputError("a 3x3 K needs three lines of 3 numbers", path, first_no)
        rows = [v] + [_floats(t, path, n, 3, "numbers (row of K)") for n, t in lines[1:3]]
        K, rest = np.array(rows), lines[3:]
    else:
        raise InputError(f"expected 'fx fy cx cy' (4 numbers) or a row of K (3), got {v.size}",
                         path, first_no)
    K = _check_K(K, path, first_no)
    dist = None
    if rest:
        n, t = rest[0]
        dist = _floats(t, path, n, what="distortion coefficients")
        if dist.size not in (4, 5, 8, 12, 14):
            raise InputError(f"expected 4, 5, 8, 12 or 14 distortion coefficients, got {dist.size}",
                             path, n)
        if len(rest) > 1:
            raise InputError("unexpected extra line after the distortion coefficients", path, rest[1][0])
    return K, dist


def _resolve_intrinsics(intrinsics, folder: Path, presets: dict | None = None):
    """Explicit value -> (K, dist). ``intrinsics`` may be a tuple, a K, a path or a preset name."""
    if isinstance(intrinsics, str) and presets and intrinsics.lower() in presets:
        f, d = presets[intrinsics.lower()]
        return intrinsics_matrix(*f), None if d is None else np.array(d, dtype=np.float64)
    if isinstance(intrinsics, (str, Path)):
        p = Path(intrinsics)
        if not p.is_absolute() and not p.exists():
            p = folder / p
        return read_intrinsics_file(p)
    arr = np.asarray(intrinsics, dtype=np.float64)
    if arr.shape == (4,):
        return _check_K(intrinsics_matrix(*arr), "intrinsics argument"), None
    if arr.shape == (3, 3):
        return _check_K(arr, "intrinsics argument"), None
    raise InputError(f"intrinsics must be (fx, fy, cx, cy), a 3x3 K, a file or a preset, "
                     f"got shape {arr.shape}", "intrinsics argument")


def _find_intrinsics_file(folder: Path) -> Path | None:
    for name in INTRINSICS_FILE_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


# --------------------------------------------------------------------------- KITTI

def _read_kitti_calib(path: Path, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, c0Tck) of camera ``camera`` from a KITTI ``calib.txt``."""
    found = {}
    for n, text in _read_lines(path, "KITTI calib.txt"):
        if ":" not in text:
            raise InputError(f"malformed line, expected 'NAME: numbers': {text[:80]!r}", path, n)
        key, rest = text.split(":", 1)
        vals = _floats(rest, path, n, what="numbers")
        found[key.strip()] = (vals, n)
    key = f"P{camera}"
    if key not in found:
        raise InputError(f"no {key} line (cameras present: {sorted(found)})", path)
    vals, n = found[key]
    if vals.size != 12:
        raise InputError(f"{key}: expected 12 numbers, got {vals.size}", path, n)
    P = vals.reshape(3, 4)
    K = _check_K(P[:, :3], path, n)
    ckTc0 = np.eye(4)
    ckTc0[:3, 3] = np.linalg.solve(K, P[:, 3])
    c0Tck = np.eye(4)
    c0Tck[:3, 3] = -ckTc0[:3, 3]
    return K, c0Tck


def read_kitti(folder: str | Path, camera: int = 0) -> ImageSequence:
    """A KITTI odometry sequence folder (``image_<camera>/``, ``calib.txt``, ...)."""
    folder = Path(folder)
    img_dir = folder / f"image_{camera}"
    if not img_dir.is_dir():
        raise InputError(f"KITTI image folder image_{camera}/ not found", folder)
    paths = sorted(str(p) for p in img_dir.glob("*.png"))
    if not paths:
        raise InputError("no .png images", img_dir)
    K, c0Tck = _read_kitti_calib(folder / "calib.txt", camera)
    stamps = None
    tpath = folder / "times.txt"
    if tpath.is_file():
        lines = _read_lines(tpath, "KITTI times.txt")
        stamps = np.array([_floats(t, tpath, n, 1, "time in seconds")[0] for n, t in lines])
        if stamps.size != len(paths):
            raise InputError(f"{stamps.size} timestamps but {len(paths)} images in {img_dir}", tpath)
    wTc = None
    ppath = folder / "poses.txt"
    if ppath.is_file():
        lines = _read_lines(ppath, "KITTI poses.txt")
        wTc = np.tile(np.eye(4), (len(lines), 1, 1))
        for k, (n, t) in enumerate(lines):
            wTc[k, :3, :] = _floats(t, ppath, n, 12, "numbers (row-major 3x4 pose)").reshape(3, 4)
        if len(lines) != len(paths):
            raise InputError(f"{len(lines)} poses but {len(paths)} images in {img_dir}", ppath)
        if camera != 0:
            wTc = wTc @ c0Tck
    return ImageSequence(f"kitti-{folder.name}", paths, stamps, K, None, wTc,
                         _image_size(paths[0]), str(folder))


# --------------------------------------------------------------------------- TUM RGB-D

def read_tum_rgbd(folder: str | Path, intrinsics=None,
                  max_dt_s: float = ASSOCIATION_MAX_DT_S) -> ImageSequence:
    """A TUM RGB-D sequence folder (``rgb.txt``, ``rgb/``, ``groundtruth.txt``).

    ``intrinsics``: ``(fx, fy, cx, cy)``, a (3, 3) K, an intrinsics file path,
    or a preset of :data:`TUM_INTRINSICS`; see the module doc for the fallbacks.
    """
    folder = Path(folder)
    rgb = folder / "rgb.txt"
    stamps, paths = [], []
    for n, t in _read_lines(rgb, "TUM rgb.txt"):
        parts = t.split()
        if len(parts) != 2:
            raise InputError(f"expected 'timestamp filename', got {t[:80]!r}", rgb, n)
        try:
            stamps.append(float(parts[0]))
        except ValueError:
            raise InputError(f"bad timestamp {parts[0]!r}", rgb, n) from None
        paths.append(str(folder / parts[1]))
    if not paths:
        raise InputError("no images listed", rgb)
    stamps = np.array(stamps)
    if np.any(np.diff(stamps) < 0):
        raise InputError("timestamps are not in increasing order", rgb)
    _check_exist(paths, rgb)

    if intrinsics is not None:
        K, dist = _resolve_intrinsics(intrinsics, folder, TUM_INTRINSICS)
    elif (f := _find_intrinsics_file(folder)) is not None:
        K, dist = read_intrinsics_file(f)
    else:
        m = re.search(r"freiburg([123])", folder.resolve().name)
        if m is None:
            raise InputError("no intrinsics: pass intrinsics=(fx, fy, cx, cy) or 'fr1'/'fr2'/'fr3', "
                             f"or add one of {', '.join(INTRINSICS_FILE_NAMES)}", folder)
        f, d = TUM_INTRINSICS["fr" + m.group(1)]
        K, dist = intrinsics_matrix(*f), None if d is None else np.array(d)

    wTc = None
    gpath = folder / "groundtruth.txt"
    if gpath.is_file():
        gt_t, gt_T = [], []
        for n, t in _read_lines(gpath, "TUM groundtruth.txt"):
            v = _floats(t, gpath, n, 8, "numbers (timestamp tx ty tz qx qy qz qw)")
            T = np.eye(4)
            T[:3, :3] = _quat_to_R(v[7], v[4], v[5], v[6], gpath, n)
            T[:3, 3] = v[1:4]
            gt_t.append(v[0])
            gt_T.append(T)
        gt_t = np.array(gt_t)
        order = np.argsort(gt_t, kind="stable")
        idx = _associate(stamps, gt_t[order], max_dt_s)
        keep = idx >= 0
        if not np.any(keep):
            raise InputError(f"no image has ground truth within {max_dt_s} s", gpath)
        paths = [p for p, k in zip(paths, keep) if k]
        stamps = stamps[keep]
        wTc = np.array(gt_T)[order][idx[keep]]
    return ImageSequence(f"tum-{folder.name}", paths, stamps, K, dist, wTc,
                         _image_size(paths[0]), str(folder))


# --------------------------------------------------------------------------- EuRoC

def read_euroc(folder: str | Path, camera: str = "cam0",
               max_dt_s: float = ASSOCIATION_MAX_DT_S) -> ImageSequence:
    """A EuRoC MAV sequence folder (the one holding ``mav0/``, or ``mav0`` itself)."""
    folder = Path(folder)
    mav = folder if (folder / camera).is_dir() and not (folder / "mav0").is_dir() else folder / "mav0"
    cam = mav / camera
    csv = cam / "data.csv"
    stamps, paths = [], []
    for n, t in _read_lines(csv, f"EuRoC {camera}/data.csv"):
        parts = [p.strip() for p in t.split(",")]
        if len(parts) != 2 or not parts[1]:
            raise InputError(f"expected 'timestamp_ns,filename', got {t[:80]!r}", csv, n)
        try:
            stamps.append(int(parts[0]) * 1e-9)
        except ValueError:
            raise InputError(f"bad timestamp {parts[0]!r}", csv, n) from None
        paths.append(str(cam / "data" / parts[1]))
    if not paths:
        raise InputError("no images listed", csv)
    stamps = np.array(stamps)
    if np.any(np.diff(stamps) < 0):
        raise InputError("timestamps are not in increasing order", csv)
    _check_exist(paths, csv)

    ypath = cam / "sensor.yaml"
    if not ypath.is_file():
        raise InputError("EuRoC sensor.yaml not found", ypath)
    data = _load_yaml(ypath)
    if not isinstance(data, dict) or "intrinsics" not in data:
        raise InputError("no 'intrinsics: [fu, fv, cu, cv]' entry", ypath)
    intr = _yaml_matrix(data["intrinsics"], ypath, "intrinsics")
    if intr.size != 4:
        raise InputError(f"intrinsics: expected 4 numbers, got {intr.size}", ypath)
    K = _check_K(intrinsics_matrix(*intr), ypath)
    dist = None
    if data.get("distortion_coefficients") is not None:
        dist = _yaml_matrix(data["distortion_coefficients"], ypath, "distortion_coefficients")
    T_BS = np.eye(4)
    if data.get("T_BS") is not None:
        arr = _yaml_matrix(data["T_BS"], ypath, "T_BS")
        if arr.size != 16:
            raise InputError(f"T_BS: expected 16 numbers, got {arr.size}", ypath)
        T_BS = arr.reshape(4, 4)

    wTc = None
    gpath = mav / "state_groundtruth_estimate0" / "data.csv"
    if gpath.is_file():
        gt_t, gt_T = [], []
        for n, t in _read_lines(gpath, "EuRoC ground truth"):
            v = _floats(t, gpath, n, what="numbers (timestamp, p xyz, q wxyz, ...)")
            if v.size < 8:
                raise InputError(f"expected at least 8 numbers, got {v.size}", gpath, n)
            T = np.eye(4)
            T[:3, :3] = _quat_to_R(v[4], v[5], v[6], v[7], gpath, n)
            T[:3, 3] = v[1:4]
            gt_t.append(v[0] * 1e-9)
            gt_T.append(T @ T_BS)
        gt_t = np.array(gt_t)
        order = np.argsort(gt_t, kind="stable")
        idx = _associate(stamps, gt_t[order], max_dt_s)
        keep = idx >= 0
        if not np.any(keep):
            raise InputError(f"no image has ground truth within {max_dt_s} s", gpath)
        paths = [p for p, k in zip(paths, keep) if k]
        stamps = stamps[keep]
        wTc = np.array(gt_T)[order][idx[keep]]
    return ImageSequence(f"euroc-{folder.name}", paths, stamps, K, dist, wTc,
                         _image_size(paths[0]), str(folder))


# --------------------------------------------------------------------------- plain folder

def _list_images(folder: Path) -> list[str]:
    return sorted((str(p) for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                  key=lambda s: _natural_key(Path(s).name))


def read_image_folder(folder: str | Path, intrinsics_file: str | Path | None = None,
                      intrinsics=None) -> ImageSequence:
    """Images of a folder in natural file-name order, intrinsics from a file (or ``intrinsics``)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("image folder not found", folder)
    paths = _list_images(folder)
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)})", folder)
    if intrinsics is not None:
        K, dist = _resolve_intrinsics(intrinsics, folder)
    elif intrinsics_file is not None:
        K, dist = read_intrinsics_file(intrinsics_file)
    elif (f := _find_intrinsics_file(folder)) is not None:
        K, dist = read_intrinsics_file(f)
    else:
        raise InputError(f"no intrinsics: pass intrinsics_file or add one of "
                         f"{', '.join(INTRINSICS_FILE_NAMES)}", folder)
    return ImageSequence(f"folder-{folder.name}", paths, None, K, dist, None,
                         _image_size(paths[0]), str(folder))


# --------------------------------------------------------------------------- detection

def read_image_sequence(path: str | Path, **kw) -> ImageSequence:
    """Detect the layout of ``path`` and read it.

    EuRoC if ``mav0/cam0/data.csv`` (or ``cam0/data.csv``) exists; TUM if
    ``rgb.txt``; KITTI if ``calib.txt`` and an ``image_<c>/`` folder; otherwise
    a plain image folder. ``kw`` goes to the chosen reader.
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError("image sequence folder not found", path)
    if (path / "mav0" / "cam0" / "data.csv").is_file() or (path / "cam0" / "data.csv").is_file():
        return read_euroc(path, **kw)
    if (path / "rgb.txt").is_file():
        return read_tum_rgbd(path, **kw)
    if (path / "calib.txt").is_file() and any(path.glob("image_[0-9]")):
        return read_kitti(path, **kw)
    return read_image_folder(path, **kw)
