"""KITTI odometry sequences: ``calib.txt``, ``poses.txt``, ``times.txt`` and ``image_<c>/``.

* ``calib.txt``: lines ``P<c>: 12 numbers`` (row-major 3x4 projection of
  rectified camera ``c``); ``K`` is its left 3x3 block and ``P[:, 3] = K t``
  gives the camera's offset from camera 0.
* ``poses.txt``: one line per frame, 12 numbers, the row-major 3x4 ``wTc_k``
  mapping points of camera 0 at frame k into camera 0 at frame 0 (the world).
* ``times.txt``: one time in seconds per frame.

Ground truth is ``poses.txt`` in the sequence folder or, in the KITTI odometry
download's own layout (``dataset/sequences/07/`` beside ``dataset/poses/07.txt``),
``../../poses/<sequence>.txt``. ``times.txt`` and the poses file may cover more
frames than the folder holds (a few frames copied out of a sequence): the
frames are then picked by the number in each image's file name (``000042.png``
is frame 42). A poses file that ends before the images leaves the frames after
its last pose out of the run, and says so (as a TUM folder's frames without
truth are).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphslam.sources.spatial.sequence import (
    IMAGE_EXTENSIONS,
    ImageSequence,
    check_increasing,
    check_K,
    check_rotation,
    image_doubts,
    list_images,
    parse_floats,
    read_lines,
)
from slamcore.errors import InputError, quote
from slamcore.files import folder_name


def read_kitti_calib(path: str | Path, camera: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(K (3, 3), c0Tck (4, 4))`` of camera ``camera`` from a KITTI ``calib.txt``."""
    path = Path(path)
    found = {}
    for n, text in read_lines(path, "KITTI calib.txt"):
        if ":" not in text:
            raise InputError(f"malformed line, expected 'NAME: numbers': {quote(text)}", path, n)
        key, rest = text.split(":", 1)
        vals = parse_floats(rest, path, n, what="numbers")
        found[key.strip()] = (vals, n)
    key = f"P{camera}"
    if key not in found:
        raise InputError(f"no {key} line (cameras present: {sorted(found)})", path)
    vals, n = found[key]
    if vals.size != 12:
        raise InputError(f"{key}: expected 12 numbers, got {vals.size}", path, n)
    P = vals.reshape(3, 4)
    K = check_K(P[:, :3], path, n)
    ckTc0 = np.eye(4)
    ckTc0[:3, 3] = np.linalg.solve(K, P[:, 3])
    c0Tck = np.eye(4)
    c0Tck[:3, 3] = -ckTc0[:3, 3]
    return K, c0Tck


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """(N, 4, 4) ``wTc_k`` from a KITTI ``poses.txt`` (12 numbers per line, row-major 3x4)."""
    path = Path(path)
    lines = read_lines(path, "KITTI poses.txt")
    if not lines:
        raise InputError("no poses", path)
    wTc = np.tile(np.eye(4), (len(lines), 1, 1))
    for k, (n, text) in enumerate(lines):
        wTc[k, :3, :] = parse_floats(text, path, n, 12, "numbers (row-major 3x4 pose)").reshape(3, 4)
        check_rotation(wTc[k, :3, :3], path, n)
    return wTc


def kitti_poses_path(folder: Path) -> Path | None:
    """The sequence's ground-truth file: ``poses.txt`` beside the images, else
    ``dataset/poses/<name>.txt`` of the KITTI odometry layout; None if neither."""
    for p in (folder / "poses.txt", folder.parent.parent / "poses" / f"{folder.name}.txt"):
        if p.is_file():
            return p
    return None


def _per_image(rows: np.ndarray, paths: list[str], what: str, img_dir: Path, source: Path) -> np.ndarray:
    """``rows`` (one per frame of the sequence) for the images present: all of
    them when the counts agree, else those of the frame numbers in the names."""
    if len(rows) == len(paths):
        return rows
    stems = [Path(p).stem for p in paths]
    if len(rows) > len(paths) and all(s.isascii() and s.isdigit() for s in stems):
        # (two names of one frame, 000010.png and 0000010.png, were refused by list_images)
        numbers = np.array([int(s) for s in stems])
        if numbers.max() < len(rows):
            return rows[numbers]
    raise InputError(f"{len(rows)} {what} but {len(paths)} images in {img_dir}", source)


def read_kitti(folder: str | Path, camera: int = 0) -> ImageSequence:
    """A KITTI odometry sequence folder (``image_<camera>/``, ``calib.txt``, ...)."""
    folder = Path(folder)
    img_dir = folder / f"image_{camera}"
    if not img_dir.is_dir():
        raise InputError(f"KITTI image folder image_{camera}/ not found", folder)
    # by frame number, not text: 0000010.png (frame 10) is after 000005.png; every image
    # format a plain folder takes (pass 23: frames saved as .jpg, or .PNG, were left out
    # unsaid, the run jumping over them)
    paths = list_images(img_dir)
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)})", img_dir)
    K, c0Tck = read_kitti_calib(folder / "calib.txt", camera)
    ppath = kitti_poses_path(folder)
    poses = read_kitti_poses(ppath) if ppath is not None else None
    notes: tuple[str, ...] = ()
    if ppath is not None and poses is not None:
        paths, notes = _covered_by_truth(paths, len(poses), ppath)
    stamps = None
    tpath = folder / "times.txt"
    if tpath.is_file():
        lines = read_lines(tpath, "KITTI times.txt")
        stamps = np.array([parse_floats(t, tpath, n, 1, "time in seconds")[0] for n, t in lines])
        check_increasing(stamps, [n for n, _ in lines], tpath)
        stamps = _per_image(stamps, paths, "timestamps", img_dir, tpath)
    wTc = None
    if ppath is not None and poses is not None:
        wTc = _per_image(poses, paths, "poses", img_dir, ppath)
        if camera != 0:
            wTc = wTc @ c0Tck
    size, doubts = image_doubts(K, paths, folder / "calib.txt")
    return ImageSequence(
        f"kitti-{folder_name(folder)}", paths, stamps, K, None, wTc, size, str(folder), doubts, notes
    )


def _covered_by_truth(paths: list[str], n_poses: int, ppath: Path) -> tuple[list[str], tuple[str, ...]]:
    """The images ``ppath`` has a pose for, and a line saying how many were left out.

    A poses file that ends before the images (a truth cut short, a sequence with
    frames added) leaves the frames after it without truth; as TUM folders do,
    those frames are left out and said, rather than the whole folder refused
    (a ``--frames`` range inside the truth was refused for frames it never used).
    Frames are the numbers in the names where every name is one, else the order."""
    if n_poses >= len(paths):
        return paths, ()
    stems = [Path(p).stem for p in paths]
    if all(s.isascii() and s.isdigit() for s in stems):
        kept = [p for p, s in zip(paths, stems, strict=True) if int(s) < n_poses]
    else:
        kept = paths[:n_poses]
    if not kept:  # no image inside the truth: refused as the counts' mismatch
        return paths, ()
    note = (
        f"{len(paths) - len(kept)} of {len(paths)} images come after the last of the {n_poses} "
        f"poses in {ppath.name} and are left out of the run (no ground truth)"
    )
    return kept, (note,)
