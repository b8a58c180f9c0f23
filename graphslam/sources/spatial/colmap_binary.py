"""COLMAP's binary sparse model (``cameras.bin``, ``images.bin``), COLMAP's default
output, as the lines of its text export: the text readers
(:func:`graphslam.sources.spatial.calibration.colmap_camera`, the ``images.txt``
reader of :mod:`graphslam.sources.ground_truth`) then read both forms alike.

Layout (COLMAP's "Output Format" page; little endian): ``cameras.bin`` is a uint64
count, then per camera int32 id, int32 model id, uint64 width, uint64 height and the
model's float64 parameters; ``images.bin`` is a uint64 count, then per image int32
id, float64 qw qx qy qz tx ty tz, int32 camera id, the name ending in a NUL byte, a
uint64 count of 2-D points and 24 bytes a point (skipped). Written by hand: COLMAP's
own reader (``pycolmap``) is a large compiled dependency for two short formats.
"""

from __future__ import annotations

import struct
from pathlib import Path

from slamcore.errors import InputError

#: COLMAP's model ids -> (name, parameter count) (``colmap/src/colmap/sensor/models.h``).
MODEL_IDS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}

#: More records than any model holds (a text file or another binary read as one: its
#: first 8 bytes as a count of billions).
MAX_RECORDS = 10_000_000


def is_colmap_binary(path: Path) -> bool:
    """Whether ``path`` is named as a COLMAP binary model file (``*.bin``)."""
    return Path(path).suffix.lower() == ".bin"


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise InputError(f"cannot read the COLMAP model file: {e.strerror}", path) from None
        self.at = 0

    def take(self, fmt: str, what: str):
        size = struct.calcsize(fmt)
        if self.at + size > len(self.data):
            raise InputError(f"COLMAP binary file ends inside {what} (byte {self.at})", self.path)
        values = struct.unpack_from(fmt, self.data, self.at)
        self.at += size
        return values

    def skip(self, n_bytes: int, what: str) -> None:
        # checked before any struct format is built: a damaged count of 2**62 points made
        # one too long for struct ("total struct size too long", a traceback)
        if n_bytes > len(self.data) - self.at:
            raise InputError(f"COLMAP binary file ends inside {what} (byte {self.at})", self.path)
        self.at += n_bytes

    def count(self, what: str) -> int:
        (n,) = self.take("<Q", f"the count of {what}")
        if n > MAX_RECORDS:
            raise InputError(f"not a COLMAP binary {what} file (it would hold {n} records)", self.path)
        return n

    def name(self) -> str:
        end = self.data.find(b"\x00", self.at)
        if end < 0:
            raise InputError(f"COLMAP binary file ends inside an image name (byte {self.at})", self.path)
        raw, self.at = self.data[self.at : end], end + 1
        return raw.decode("utf-8", errors="replace")

    def done(self) -> None:
        if self.at != len(self.data):
            raise InputError(
                f"COLMAP binary file has {len(self.data) - self.at} bytes after its last record", self.path
            )


def camera_lines(path: Path) -> list[tuple[int, str]]:
    """``cameras.bin`` as ``cameras.txt`` lines ``(record number, text)``."""
    r = _Reader(path)
    lines = []
    for k in range(1, r.count("cameras") + 1):
        cam_id, model_id, width, height = r.take("<iiQQ", f"camera record {k}")
        if model_id not in MODEL_IDS:
            raise InputError(f"camera record {k}: unknown COLMAP camera model id {model_id}", path)
        model, n = MODEL_IDS[model_id]
        params = r.take(f"<{n}d", f"camera record {k}")
        lines.append((k, " ".join([str(cam_id), model, str(width), str(height), *map(repr, params)])))
    r.done()
    return lines


def image_lines(path: Path) -> list[tuple[int, str]]:
    """``images.bin`` as ``images.txt`` image lines ``(record number, text)`` (the 2-D
    points skipped)."""
    r = _Reader(path)
    lines = []
    for k in range(1, r.count("images") + 1):
        image_id, *pose, cam_id = r.take("<i7di", f"image record {k}")
        name = r.name()
        (n_points,) = r.take("<Q", f"image record {k}")
        r.skip(24 * n_points, f"the 2-D points of image record {k}")
        lines.append((k, " ".join([str(image_id), *map(repr, pose), str(cam_id), name])))
    r.done()
    return lines
