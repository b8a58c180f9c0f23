"""Camera intrinsics files (text or YAML) and the TUM RGB-D presets.

Text files: ``#`` comments, numbers separated by spaces or commas, either
``fx fy cx cy`` on one line or the three rows of ``K`` on three lines;
optionally one more line with the OpenCV distortion coefficients ``k1 k2 p1 p2
[k3 ...]``. YAML: ``fx, fy, cx, cy`` keys, or ``K``/``camera_matrix`` (3x3
nested list, 9-list or OpenCV ``{rows, cols, data}``), or EuRoC's
``intrinsics: [fu, fv, cu, cv]``; optional ``distortion`` /
``distortion_coefficients`` / ``dist_coeffs``. ``%YAML`` directives are ignored.
COLMAP's ``cameras.txt`` (``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``, text model
export) or ``cameras.bin`` (:mod:`.colmap_binary`) is read for its pinhole models with
radial-tangential distortion, its pixel centres moved to OpenCV's (:func:`colmap_camera`).
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from graphslam.sources.spatial.colmap_binary import camera_lines, is_colmap_binary
from graphslam.sources.spatial.sequence import (
    check_distortion,
    check_K,
    image_doubts,
    parse_floats,
    read_lines,
)
from slamcore.errors import InputError, quote
from slamcore.spatial.camera import intrinsics_matrix

#: Intrinsics files looked for in a folder, in this order.
INTRINSICS_FILE_NAMES = (
    "intrinsics.txt",
    "camera.txt",
    "intrinsics.yaml",
    "intrinsics.yml",
    "camera.yaml",
    "camera.yml",
    "calibration.txt",
)

#: ``--intrinsics estimate``: the camera of a plain image folder is estimated from its
#: images (:mod:`graphslam.pipelines.self_calibration`). A word, not a path: the option's
#: parser gives it as this ``str`` (a file named so is passed as ``./estimate``, a Path).
ESTIMATE = "estimate"

#: The estimate's start: a focal length of this times the image's longer side, the
#: principal point at the image centre. COLMAP's default for a camera whose photos state
#: no focal length (``ImageReaderOptions.default_focal_length_factor = 1.2``, a field of
#: view of about 45 deg across the longer side).
START_FOCAL_PER_LONG_SIDE = 1.2


def is_estimate(intrinsics) -> bool:
    """True for ``--intrinsics estimate`` (:data:`ESTIMATE`, never a Path)."""
    return isinstance(intrinsics, str) and intrinsics == ESTIMATE


def start_camera(size: tuple[int, int], f_px: float | None = None) -> np.ndarray:
    """(3, 3) ``K`` of images ``size`` ``(W, H)`` px: focal length ``f_px`` (None: the
    start, :data:`START_FOCAL_PER_LONG_SIDE` times the longer side) and the principal
    point at the centre (OpenCV's pixel centres: ``((W - 1) / 2, (H - 1) / 2)``)."""
    w, h = size
    f = START_FOCAL_PER_LONG_SIDE * max(w, h) if f_px is None else float(f_px)
    return intrinsics_matrix(f, f, (w - 1) / 2.0, (h - 1) / 2.0)


#: TUM RGB-D colour-camera calibrations (fx, fy, cx, cy) and distortion
#: (k1, k2, p1, p2, k3), from the dataset's "file formats" page. "ros" is the
#: ROS default used for the uncalibrated/undistorted case.
TUM_INTRINSICS = {
    "fr1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": ((535.4, 539.2, 320.1, 247.6), None),
    "ros": ((525.0, 525.0, 319.5, 239.5), None),
}


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


def load_yaml(path: Path):
    """Parse a small YAML file (PyYAML if installed, else OpenCV's YAML reader).

    ``%YAML`` directives and OpenCV's ``!!opencv-matrix`` tags are ignored, so
    OpenCV/Kalibr/EuRoC files read the same way as plain YAML.
    """
    text = path.read_text(encoding="utf-8-sig", errors="replace")
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


def yaml_key_line(path: Path, *keys: str) -> int | None:
    """1-based line of the first top-level ``key:`` of ``keys`` in the YAML file
    ``path``, or None: the parsed mapping has no lines, and an error about a value
    (a principal point no camera has) should name the line the user edits."""
    try:
        lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    except OSError:
        return None
    for key in keys:
        pattern = re.compile(rf"^\s*[\"']?{re.escape(key)}[\"']?\s*:")
        for n, text in enumerate(lines, start=1):
            if pattern.match(text):
                return n
    return None


def yaml_matrix(value, path: Path, key: str) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        arr = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{key}: expected a list of numbers", path) from None
    return arr


#: Lens models whose coefficients are OpenCV's radial-tangential (``k1 k2 p1 p2 [k3 ...]``),
#: as calibration files name them (ROS camera_info, Kalibr and EuRoC sensor.yaml). Any
#: other (Kalibr's ``equidistant``, OpenCV's ``fisheye``, ``omni``, Kannala-Brandt,
#: double sphere) maps pixels otherwise: read as these, a corner moved by thousands of
#: pixels, silent (thirteenth hostile pass).
RADTAN_MODELS = ("plumb_bob", "rational_polynomial", "radtan", "radial-tangential", "radial_tangential", "")


def yaml_distortion(data: dict, path: Path, keys=("distortion", "distortion_coefficients", "dist_coeffs")):
    """The distortion coefficients of a calibration YAML mapping ``data`` (the first of
    ``keys`` present), None without; InputError naming ``path`` for a lens model that is
    not OpenCV's radial-tangential, a count OpenCV does not take (an OpenCV traceback
    before), or a non-finite coefficient."""
    for key, allowed in (("camera_model", ("pinhole",)), ("distortion_model", RADTAN_MODELS)):
        model = data.get(key)
        if model is not None and str(model).strip().lower() not in allowed:
            raise InputError(
                f"{key} {quote(str(model))} is not supported: the camera must be a pinhole with "
                "radial-tangential distortion (plumb_bob, radtan); undistort the images first",
                path,
            )
    found = next((k for k in keys if data.get(k) is not None), None)
    if found is None:
        return None
    key = found
    return check_distortion(yaml_matrix(data[key], path, key), path, what=key)


#: COLMAP camera models read as a pinhole with OpenCV distortion -> their parameter count
#: (``colmap/src/colmap/sensor/models.h``). The fisheye and FOV models map pixels
#: otherwise and are refused (as a YAML file's fisheye model is).
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "FULL_OPENCV": 12,
}


def is_colmap_camera_line(text: str) -> bool:
    """Whether a text line is one of COLMAP's ``cameras.txt`` (an id, then a model name)."""
    tokens = text.split()
    return len(tokens) >= 4 and tokens[0].isdigit() and re.fullmatch(r"[A-Z][A-Z_]*", tokens[1]) is not None


def colmap_camera(text: str, path: Path, line: int) -> tuple[np.ndarray, np.ndarray | None, tuple[int, int]]:
    """``(K, distortion or None, (W, H))`` of one ``cameras.txt`` line. COLMAP puts the
    centre of the top-left pixel at (0.5, 0.5), OpenCV at (0, 0) (COLMAP's "Cameras"
    documentation): the principal point moves by half a pixel."""
    tokens = text.split()
    model = tokens[1]
    if model not in COLMAP_MODELS:
        raise InputError(
            f"COLMAP camera model {model} is not supported: the camera must be a pinhole with "
            f"radial-tangential distortion ({', '.join(COLMAP_MODELS)}); undistort the images "
            "first (colmap image_undistorter)",
            path,
            line,
        )
    v = parse_floats(
        " ".join(tokens[2:]), path, line, 2 + COLMAP_MODELS[model], f"numbers (WIDTH HEIGHT, {model})"
    )
    size = (int(v[0]), int(v[1]))
    if not (v[0] == size[0] >= 1 and v[1] == size[1] >= 1):
        raise InputError(
            f"COLMAP camera: WIDTH and HEIGHT must be whole pixels, got {v[0]:g} {v[1]:g}", path, line
        )
    p = v[2:]
    if model.startswith("SIMPLE") or model == "RADIAL":  # one focal length: f cx cy [k1 [k2]]
        f, cx, cy, ks = p[0], p[1], p[2], p[3:]
        fx = fy = f
        dist = None if not ks.size else np.r_[ks, np.zeros(4 - ks.size)]  # k1 [k2] p1 p2 = 0
    else:  # fx fy cx cy [k1 k2 p1 p2 [k3 k4 k5 k6]]: OpenCV's order
        fx, fy, cx, cy = p[:4]
        dist = p[4:] if p.size > 4 else None
    K = check_K(intrinsics_matrix(fx, fy, cx - 0.5, cy - 0.5), path, line)
    return K, None if dist is None else check_distortion(dist, path, line), size


def _colmap_cameras(lines: list[tuple[int, str]], path: Path):
    """The one camera of a ``cameras.txt`` (:func:`colmap_camera`); a file of several
    different cameras is refused: the images of one folder are taken with one."""
    cameras = [colmap_camera(t, path, n) for n, t in lines]
    K, dist, size = cameras[0]
    for (n, _), (K2, dist2, size2) in zip(lines[1:], cameras[1:], strict=True):
        same_dist = (dist is None and dist2 is None) or (
            dist is not None and dist2 is not None and np.array_equal(dist, dist2)
        )
        if not (np.array_equal(K, K2) and same_dist and size == size2):
            raise InputError(
                f"{len(cameras)} different COLMAP cameras; a folder's images are read with one: "
                "keep the line of their camera",
                path,
                n,
            )
    return K, dist, size


def read_intrinsics_file(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """``(K (3, 3), distortion or None)`` from a text or YAML file (formats in the module doc)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("intrinsics file not found", path)
    if is_colmap_binary(path):  # COLMAP's default model output
        K, dist, _ = _colmap_cameras(camera_lines(path), path)
        return K, dist
    if path.suffix.lower() in (".yaml", ".yml"):
        data = load_yaml(path)
        if not isinstance(data, dict):
            raise InputError("intrinsics YAML must be a mapping", path)
        if all(k in data for k in ("fx", "fy", "cx", "cy")):
            try:
                K = intrinsics_matrix(*(float(data[k]) for k in ("fx", "fy", "cx", "cy")))
            except (TypeError, ValueError):
                raise InputError("fx, fy, cx, cy must be numbers", path) from None
        elif "K" in data or "camera_matrix" in data:
            key = "K" if "K" in data else "camera_matrix"
            arr = yaml_matrix(data[key], path, key)
            if arr.size != 9:
                raise InputError(f"{key}: expected 9 numbers, got {arr.size}", path)
            K = arr.reshape(3, 3)
        elif "intrinsics" in data:
            arr = yaml_matrix(data["intrinsics"], path, "intrinsics")
            if arr.size != 4:
                raise InputError(f"intrinsics: expected [fu, fv, cu, cv], got {arr.size} numbers", path)
            K = intrinsics_matrix(*arr)
        else:
            raise InputError(
                "no intrinsics found: expected fx/fy/cx/cy, K, camera_matrix or intrinsics", path
            )
        # the line of the entry read (of fx where the four are apart)
        line = yaml_key_line(path, next(k for k in ("fx", "K", "camera_matrix", "intrinsics") if k in data))
        return check_K(K, path, line), yaml_distortion(data, path)
    lines = read_lines(path, "intrinsics file")
    if not lines:
        raise InputError("intrinsics file is empty", path)
    first_no, first = lines[0]
    if is_colmap_camera_line(first):
        K, dist, _ = _colmap_cameras(lines, path)
        return K, dist
    if re.match(r"\s*P\d+\s*:", first):  # which P it would be depends on the folder it came from
        raise InputError(
            "a KITTI calib.txt (projection matrices P0-P3): run the KITTI sequence folder itself "
            "(image_0/ beside calib.txt), which reads the camera's P, or give fx fy cx cy",
            path,
            first_no,
        )
    v = parse_floats(first, path, first_no, what="intrinsics numbers")
    if v.size == 4:
        K, rest = intrinsics_matrix(*v), lines[1:]
    elif v.size == 3:
        if len(lines) < 3:
            raise InputError("a 3x3 K needs three lines of 3 numbers", path, first_no)
        rows = [v] + [parse_floats(t, path, n, 3, "numbers (row of K)") for n, t in lines[1:3]]
        K, rest = np.array(rows), lines[3:]
    else:
        raise InputError(
            f"expected 'fx fy cx cy' (4 numbers) or a row of K (3), got {v.size}", path, first_no
        )
    K = check_K(K, path, first_no)
    dist = None
    if rest:
        n, t = rest[0]
        dist = check_distortion(parse_floats(t, path, n, what="distortion coefficients"), path, n)
        if len(rest) > 1:
            raise InputError("unexpected extra line after the distortion coefficients", path, rest[1][0])
    return K, dist


def resolve_intrinsics(intrinsics, folder: Path, presets: dict | None = None):
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
        return check_K(intrinsics_matrix(*arr), "intrinsics argument"), None
    if arr.shape == (3, 3):
        return check_K(arr, "intrinsics argument"), None
    raise InputError(
        f"intrinsics must be (fx, fy, cx, cy), a 3x3 K, a file or a preset, got shape {arr.shape}",
        "intrinsics argument",
    )


def find_intrinsics_file(folder: Path) -> Path | None:
    for name in INTRINSICS_FILE_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


def read_camera_of(
    path: str | Path, first_image: str | Path
) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """``(K, distortion, warnings)`` of an intrinsics file for images like ``first_image``:
    :func:`read_intrinsics_file`, then :func:`~.sequence.camera_doubts` against that
    image's size (InputError when ``K`` cannot be its camera)."""
    K, dist = read_intrinsics_file(path)
    _, doubts = image_doubts(K, [str(first_image)], Path(path), stated_image_size(path))
    return K, dist, list(doubts)


def stated_image_size(path: str | Path) -> tuple[int, int] | None:
    """``(W, H)`` a camera file states its images to be (YAML: ROS and OpenCV
    ``image_width``/``image_height``, EuRoC and Kalibr ``resolution: [W, H]``; COLMAP's
    ``cameras.txt``: WIDTH HEIGHT), else None (a plain text file, no such keys, or keys
    that are not two whole numbers)."""
    path = Path(path)
    if not path.is_file():
        return None
    if is_colmap_binary(path):
        return _colmap_cameras(camera_lines(path), path)[2]
    if path.suffix.lower() not in (".yaml", ".yml"):
        lines = read_lines(path, "intrinsics file")
        if lines and is_colmap_camera_line(lines[0][1]):
            return _colmap_cameras(lines, path)[2]
        return None
    data = load_yaml(path)
    return yaml_image_size(data) if isinstance(data, dict) else None


def yaml_image_size(data: dict) -> tuple[int, int] | None:
    """``(W, H)`` of the ``image_width``/``image_height`` or ``resolution`` keys, else None."""
    value = data.get("resolution")
    if value is None and "image_width" in data and "image_height" in data:
        value = [data["image_width"], data["image_height"]]
    try:
        w, h = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        return None
    return (int(w), int(h)) if w.is_integer() and h.is_integer() and w > 0 and h > 0 else None
