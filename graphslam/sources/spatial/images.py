"""Image-sequence readers: KITTI odometry, TUM RGB-D, EuRoC MAV, a plain folder.

Every reader returns an :class:`ImageSequence` (numpy + OpenCV only, no gtsam):
ordered image paths, timestamps, intrinsics ``K`` (3, 3), distortion, optional
ground truth ``wTc_true`` (N, 4, 4, camera-to-world: ``p_w = wTc @ p_c``,
camera looking along +z) and the image size ``(W, H)``. Images are read lazily
by :meth:`ImageSequence.load` as (H, W) uint8 greyscale, with the distortion
the calibration states (TUM fr1/fr2 presets, EuRoC
``distortion_coefficients``, an intrinsics file's distortion line) removed, so
``K`` is a pinhole model of what it returns.

Bad input raises :class:`~slamcore.errors.InputError` naming the file and, for
a malformed line, its 1-based line number; a missing file or a count mismatch
gives a one-line message. Every reader checks its camera against the first image
(:func:`~.sequence.image_doubts`): intrinsics that cannot be its camera (a
principal point outside it, a view wider than a pinhole's, a YAML file stating
another image size) are refused; a principal point far from the centre is kept in
``ImageSequence.camera_warnings``, and ``ImageSequence.warnings`` adds frames
stored twice.

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
``img10``; a name that is one decimal number by its value: ``1.25.png`` before
``1.5.png``); two names of one place in that order (``frame_1.png`` and
``frame_01.png``, ``3.png`` and ``3.jpg``) are refused. No timestamps, no ground
truth. Intrinsics from a file:

* text (any name not ending in ``.yaml``/``.yml``), ``#`` comments, numbers
  separated by spaces or commas, either ``fx fy cx cy`` on one line, or the
  three rows of ``K`` on three lines; optionally one more line with the OpenCV
  distortion coefficients ``k1 k2 p1 p2 [k3 ...]``;
* YAML: ``fx, fy, cx, cy`` keys, or ``K``/``camera_matrix`` (3x3 nested list,
  9-list or OpenCV ``{rows, cols, data}``), or EuRoC's ``intrinsics: [fu, fv,
  cu, cv]``; optional ``distortion`` / ``distortion_coefficients`` /
  ``dist_coeffs`` (list or ``{data}``). ``%YAML`` directives are ignored;
* COLMAP's ``cameras.txt`` or ``cameras.bin``: ``SIMPLE_PINHOLE``, ``PINHOLE``,
  ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` or ``FULL_OPENCV``, one camera (a
  fisheye model is refused: undistort the images first); the principal point moved
  half a pixel to OpenCV's convention, the images checked to be WIDTH x HEIGHT.

Without ``intrinsics_file`` the folder is searched for
:data:`INTRINSICS_FILE_NAMES`; if none is found an InputError says so.

:func:`read_image_sequence` picks the reader from the folder layout.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from graphslam.sources.spatial.calibration import (
    INTRINSICS_FILE_NAMES,
    TUM_INTRINSICS,
    find_intrinsics_file,
    is_estimate,
    load_yaml,
    read_intrinsics_file,
    resolve_intrinsics,
    start_camera,
    stated_image_size,
    yaml_distortion,
    yaml_image_size,
    yaml_key_line,
    yaml_matrix,
)
from graphslam.sources.spatial.kitti import read_kitti
from graphslam.sources.spatial.sequence import (
    ASSOCIATION_MAX_DT_S,
    IMAGE_EXTENSIONS,
    ImageSequence,
    associate,
    check_exist,
    check_increasing,
    check_K,
    check_rotation,
    image_doubts,
    image_size,
    images_below,
    list_images,
    parse_euroc_line,
    parse_floats,
    quat_to_rotation,
    read_lines,
)
from slamcore.errors import ConfigError, InputError, quote
from slamcore.files import folder_name, inside_folder
from slamcore.spatial.camera import intrinsics_matrix


def listed_file(folder: Path, name: str, listing: Path, line: int) -> Path:
    """``folder / name`` of an image list (``rgb.txt``, ``data.csv``), refused when it
    leaves ``folder`` (``../../x.png``, ``/etc/passwd``): a data set names only its
    own files, and a list from elsewhere must not make a run read any file."""
    path = inside_folder(folder, name)
    if path is None:
        raise InputError(f"image {quote(name)} is outside the sequence folder {folder}", listing, line)
    return path


# --------------------------------------------------------------------------- TUM RGB-D


def _keep_matched(
    paths: list[str], stamps: np.ndarray, gt_t: np.ndarray, gt_T: list, max_dt_s: float, gpath: Path
) -> tuple[list[str], np.ndarray, np.ndarray, list[str]]:
    """Images with a ground-truth stamp within ``max_dt_s``, their ``wTc`` (N, 4, 4), and
    a doubt naming the others, which are dropped (TUM and EuRoC truth often starts after
    the first images; a gap in it drops images in the middle, which the run then jumps
    as one step: it was silent, thirteenth hostile pass)."""
    order = np.argsort(gt_t, kind="stable")
    idx = associate(stamps, gt_t[order], max_dt_s)
    keep = idx >= 0
    if not np.any(keep):
        raise InputError(f"no image has ground truth within {max_dt_s} s", gpath)
    doubts = []
    dropped = int(np.count_nonzero(~keep))
    if dropped:
        kept = np.flatnonzero(keep)
        inside = int(np.count_nonzero(~keep[kept[0] : kept[-1] + 1]))
        where = (
            f", {inside} of them between images that have it (the run steps over them at once)"
            if inside
            else " (before the truth starts or after it ends)"
        )
        doubts.append(
            f"{dropped} of {len(paths)} images have no ground truth within {max_dt_s} s in "
            f"{gpath.name} and are left out of the run{where}"
        )
    return (
        [p for p, k in zip(paths, keep, strict=True) if k],
        stamps[keep],
        np.array(gt_T)[order][idx[keep]],
        doubts,
    )


def read_tum_rgbd(
    folder: str | Path, intrinsics=None, max_dt_s: float = ASSOCIATION_MAX_DT_S
) -> ImageSequence:
    """A TUM RGB-D sequence folder (``rgb.txt``, ``rgb/``, ``groundtruth.txt``).

    ``intrinsics``: ``(fx, fy, cx, cy)``, a (3, 3) K, an intrinsics file path,
    or a preset of :data:`TUM_INTRINSICS`; see the module doc for the fallbacks.
    """
    folder = Path(folder)
    rgb = folder / "rgb.txt"
    times: list[float] = []
    paths: list[str] = []
    numbers: list[int] = []
    for n, t in read_lines(rgb, "TUM rgb.txt"):
        numbers.append(n)
        parts = t.split()
        if len(parts) != 2:
            raise InputError(f"expected 'timestamp filename', got {quote(t)}", rgb, n)
        # a decimal number, finite: float() alone takes "nan", "inf", "1_000"
        times.append(float(parse_floats(parts[0], rgb, n, 1, "timestamp")[0]))
        paths.append(str(listed_file(folder, parts[1], rgb, n)))
    if not paths:
        raise InputError("no images listed", rgb)
    stamps = np.array(times)
    check_increasing(stamps, numbers, rgb)
    check_exist(paths, rgb)

    camera_from: Path | str = folder
    if intrinsics is not None:
        K, dist = resolve_intrinsics(intrinsics, folder, TUM_INTRINSICS)
        camera_from = Path(intrinsics) if isinstance(intrinsics, (str, Path)) else "intrinsics argument"
        if isinstance(intrinsics, str) and intrinsics.lower() in TUM_INTRINSICS:
            camera_from = f"the TUM camera {intrinsics}"
    elif (f := find_intrinsics_file(folder)) is not None:
        K, dist = read_intrinsics_file(f)
        camera_from = f
    else:
        m = re.search(r"freiburg([123])", folder.resolve().name)
        if m is None:
            raise InputError(
                f"no intrinsics: {NO_INTRINSICS_HINT}, or name the folder after its "
                "camera (rgbd_dataset_freiburg1_..., 2 or 3: TUM's calibrations)",
                folder,
            )
        fxy, d = TUM_INTRINSICS["fr" + m.group(1)]
        K, dist = intrinsics_matrix(*fxy), None if d is None else np.array(d)

    wTc = None
    dropped: list[str] = []  # images left out for want of truth (none without a truth file)
    gpath = folder / "groundtruth.txt"
    if gpath.is_file():
        gt_t, gt_T, gt_lines = [], [], []
        for n, t in read_lines(gpath, "TUM groundtruth.txt"):
            v = parse_floats(t, gpath, n, 8, "numbers (timestamp tx ty tz qx qy qz qw)")
            T = np.eye(4)
            T[:3, :3] = quat_to_rotation(v[7], v[4], v[5], v[6], gpath, n)
            T[:3, 3] = v[1:4]
            gt_t.append(v[0])
            gt_T.append(T)
            gt_lines.append(n)
        # a repeated stamp gives one image two truths (association picks one silently)
        check_increasing(gt_t, gt_lines, gpath, "groundtruth timestamps")
        paths, stamps, wTc, dropped = _keep_matched(paths, stamps, np.array(gt_t), gt_T, max_dt_s, gpath)
    stated = stated_image_size(camera_from) if isinstance(camera_from, Path) else None
    size, doubts = image_doubts(K, paths, camera_from, stated)
    return ImageSequence(
        f"tum-{folder_name(folder)}", paths, stamps, K, dist, wTc, size, str(folder), doubts, tuple(dropped)
    )


# --------------------------------------------------------------------------- EuRoC


def read_euroc(
    folder: str | Path, camera: str = "cam0", max_dt_s: float = ASSOCIATION_MAX_DT_S
) -> ImageSequence:
    """A EuRoC MAV sequence folder (the one holding ``mav0/``, or ``mav0`` itself)."""
    folder = Path(folder)
    mav = folder if (folder / camera).is_dir() and not (folder / "mav0").is_dir() else folder / "mav0"
    cam = mav / camera
    csv = cam / "data.csv"
    times: list[float] = []
    paths: list[str] = []
    numbers: list[int] = []
    for n, t in read_lines(csv, f"EuRoC {camera}/data.csv"):
        numbers.append(n)
        parts = [p.strip() for p in t.split(",")]
        if len(parts) != 2 or not parts[1]:
            raise InputError(f"expected 'timestamp_ns,filename', got {quote(t)}", csv, n)
        try:
            times.append(int(parts[0]) * 1e-9)
        except ValueError:
            raise InputError(f"bad timestamp {quote(parts[0])}", csv, n) from None
        paths.append(str(listed_file(cam / "data", parts[1], csv, n)))
    if not paths:
        raise InputError("no images listed", csv)
    stamps = np.array(times)
    check_increasing(stamps, numbers, csv)
    check_exist(paths, csv)

    ypath = cam / "sensor.yaml"
    if not ypath.is_file():
        raise InputError("EuRoC sensor.yaml not found", ypath)
    data = load_yaml(ypath)
    if not isinstance(data, dict) or "intrinsics" not in data:
        raise InputError("no 'intrinsics: [fu, fv, cu, cv]' entry", ypath)
    intr = yaml_matrix(data["intrinsics"], ypath, "intrinsics")
    if intr.size != 4:
        raise InputError(f"intrinsics: expected 4 numbers, got {intr.size}", ypath)
    K = check_K(intrinsics_matrix(*intr), ypath, yaml_key_line(ypath, "intrinsics"))
    dist = yaml_distortion(data, ypath, ("distortion_coefficients",))
    T_BS = np.eye(4)
    if data.get("T_BS") is not None:
        arr = yaml_matrix(data["T_BS"], ypath, "T_BS")
        if arr.size != 16:
            raise InputError(f"T_BS: expected 16 numbers, got {arr.size}", ypath)
        T_BS = arr.reshape(4, 4)
        # said here, not as "estimate poses must be rigid" from the scoring, with no file
        if not np.allclose(T_BS[3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError(
                f"T_BS: the bottom row is {T_BS[3].tolist()}, not [0, 0, 0, 1] (written column-major?)", ypath
            )
        check_rotation(T_BS[:3, :3], ypath, None)

    wTc = None
    dropped: list[str] = []  # images left out for want of truth (none without a truth file)
    gpath = mav / "state_groundtruth_estimate0" / "data.csv"
    if gpath.is_file():
        gt_t, gt_T = [], []
        for n, t in read_lines(gpath, "EuRoC ground truth"):
            v = parse_euroc_line(t, gpath, n, "t_ns,px,py,pz,qw,qx,qy,qz,...")
            if v.size < 8:
                raise InputError(f"expected at least 8 numbers, got {v.size}", gpath, n)
            T = np.eye(4)
            T[:3, :3] = quat_to_rotation(v[4], v[5], v[6], v[7], gpath, n)
            T[:3, 3] = v[1:4]
            gt_t.append(v[0] * 1e-9)
            gt_T.append(T @ T_BS)
        paths, stamps, wTc, dropped = _keep_matched(paths, stamps, np.array(gt_t), gt_T, max_dt_s, gpath)
    size, doubts = image_doubts(K, paths, ypath, yaml_image_size(data))
    return ImageSequence(
        f"euroc-{folder_name(folder)}", paths, stamps, K, dist, wTc, size, str(folder), doubts, tuple(dropped)
    )


# --------------------------------------------------------------------------- plain folder


#: What a folder without a camera needs (said by the plain and the TUM readers).
NO_INTRINSICS_HINT = (
    f"pass --intrinsics FILE ('fx fy cx cy', or the 3x3 K) or add one of "
    f"{', '.join(INTRINSICS_FILE_NAMES)} beside the images"
)


def read_image_folder(
    folder: str | Path, intrinsics_file: str | Path | None = None, intrinsics=None
) -> ImageSequence:
    """Images of a folder in natural file-name order, intrinsics from a file (or ``intrinsics``)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("image folder not found", folder)
    paths = list_images(folder)
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)}){images_below(folder)}", folder)
    camera_from: Path | str
    if is_estimate(intrinsics):  # the start of the estimate: the images' own size
        K, dist = start_camera(image_size(str(paths[0]))), None
        camera_from = "--intrinsics estimate"
    elif intrinsics is not None:
        K, dist = resolve_intrinsics(intrinsics, folder)
        camera_from = Path(intrinsics) if isinstance(intrinsics, (str, Path)) else "intrinsics argument"
    elif intrinsics_file is not None:
        K, dist = read_intrinsics_file(intrinsics_file)
        camera_from = Path(intrinsics_file)
    elif (f := find_intrinsics_file(folder)) is not None:
        K, dist = read_intrinsics_file(f)
        camera_from = f
    else:
        raise InputError(
            f"no intrinsics: {NO_INTRINSICS_HINT}; or let graphslam run estimate them from the "
            "photos (--intrinsics estimate)",
            folder,
        )
    stated = stated_image_size(camera_from) if isinstance(camera_from, Path) else None
    size, doubts = image_doubts(K, paths, camera_from, stated)
    return ImageSequence(
        f"folder-{folder_name(folder)}", paths, None, K, dist, None, size, str(folder), doubts
    )


# --------------------------------------------------------------------------- detection


def sequence_files(path: str | Path) -> list[Path]:
    """Every file a run of the image folder ``path`` may read: the folder's files through
    symbolic links (:func:`~slamcore.input_files.files_below`), and a KITTI sequence's
    ground truth outside it (``dataset/poses/07.txt`` beside ``dataset/sequences/07``,
    :func:`~graphslam.sources.spatial.kitti.kitti_poses_path`). A sweep's fingerprint of
    the data (a truth corrected there left the sweep's old results standing)."""
    from graphslam.sources.spatial.kitti import kitti_poses_path
    from slamcore.input_files import files_below

    path = Path(path)
    files = files_below(path)
    truth = kitti_poses_path(path) if (path / "calib.txt").is_file() else None
    return files if truth is None or truth in files else [*files, truth]


def read_image_sequence(path: str | Path, intrinsics_file: str | Path | None = None, **kw) -> ImageSequence:
    """Detect the layout of ``path`` and read it.

    EuRoC if ``mav0/cam0/data.csv`` (or ``cam0/data.csv``) exists; TUM if
    ``rgb.txt``; KITTI if ``calib.txt`` and an ``image_<c>/`` folder; otherwise
    a plain image folder. ``intrinsics_file`` (``--intrinsics``): the camera of a
    plain or TUM folder (refused for EuRoC and KITTI, which carry theirs). ``kw``
    goes to the chosen reader.
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError("image sequence folder not found", path)
    euroc = (path / "mav0" / "cam0" / "data.csv").is_file() or (path / "cam0" / "data.csv").is_file()
    kitti = (path / "calib.txt").is_file() and any(path.glob("image_[0-9]"))
    if intrinsics_file is not None and (euroc or kitti):
        # two cameras for one run: the data set's own is the one its poses were made with
        raise ConfigError(
            f"--intrinsics: a {'EuRoC' if euroc else 'KITTI'} sequence carries its own camera "
            f"({'sensor.yaml' if euroc else 'calib.txt'}); it applies to plain and TUM folders"
        )
    if euroc:
        return read_euroc(path, **kw)
    if (path / "rgb.txt").is_file():
        if is_estimate(intrinsics_file):
            raise ConfigError(
                "--intrinsics estimate applies to plain image folders; a TUM RGB-D folder's "
                "camera is named by the folder (rgbd_dataset_freiburg1_...) or given by a file"
            )
        if intrinsics_file is not None:
            kw["intrinsics"] = Path(intrinsics_file)
        return read_tum_rgbd(path, **kw)
    if kitti:
        if (path / "image_0").is_dir() or "camera" in kw:
            return read_kitti(path, **kw)
        # a colour download holds image_2/ (and image_3/) only: refused before, though
        # the reader takes any camera of calib.txt, its truth moved to that camera
        cams = sorted(p for p in path.glob("image_[0-9]") if p.is_dir())
        camera = int(cams[0].name[-1])
        seq = read_kitti(path, camera=camera, **kw)
        note = (
            f"image_0/ is absent: camera {camera} ({cams[0].name}/) is read, with P{camera} of "
            f"calib.txt and the ground truth moved to it"
        )
        return dataclasses.replace(seq, frame_warnings=(note, *seq.frame_warnings))
    kitti_images = [p for p in sorted(path.glob("image_[0-9]")) if p.is_dir()]
    if kitti_images and not list_images(path):  # said as what it is, not "no images"
        raise InputError(
            f"a KITTI sequence ({kitti_images[0].name}/) without calib.txt: its camera "
            "matrices (lines P0: ... P3:) are needed",
            path / "calib.txt",
        )
    if is_estimate(intrinsics_file):
        kw["intrinsics"] = intrinsics_file
    elif intrinsics_file is not None:
        kw["intrinsics_file"] = intrinsics_file
    return read_image_folder(path, **kw)
