"""Greyscale image loading and validation for the front end (numpy + OpenCV).

Every detector takes an ``(H, W)`` ``uint8`` greyscale image and calls
:func:`check_gray` first, so a colour image, a float image or an empty array
fails with one clear :class:`~slamcore.errors.InputError` instead of a
confusing OpenCV assertion deep inside a filter.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from slamcore.errors import InputError

# Bounds of the front-end settings (``bounded(..., max=...)`` in the config
# dataclasses): what a camera gives, so that a typo is refused at once instead
# of allocating, or asking OpenCV to allocate, more than the machine holds.

#: Longest image side a pixel size is checked against: 4096 px, the width of a
#: 4K (DCI) sensor. A cell, window or border longer than this covers more than
#: a frame and only costs memory (the Harris tessellation pads the response to
#: whole cells: ``cell_size_px ** 2`` values at least).
MAX_SIDE_PX = 4096

#: Points of one frame at most: the pixels of a ``MAX_SIDE_PX`` square frame
#: (2^24). No frame gives more corners than pixels, so a per-frame count or cap
#: above it is a typo (OpenCV's ORB fails with ``bad_alloc`` from 2^30 asked).
MAX_POINTS_PER_FRAME = MAX_SIDE_PX * MAX_SIDE_PX

#: Longest side of a descriptor or correlation patch: a patch is a local
#: window, and at 255 px it already spans half a VGA frame. Each costs
#: ``side ** 2`` floats per point (the tracker gathers one per candidate
#: corner at once; ORB pads every pyramid level by its patch and border).
MAX_PATCH_PX = 255


def check_gray(image: object, what: str = "image") -> np.ndarray:
    """Return ``image`` if it is a non-empty ``(H, W)`` ``uint8`` array, else raise.

    Float images (even in [0, 1]) are refused rather than silently rescaled:
    the caller knows its scale, we do not. Raises :class:`InputError` naming
    ``what``.
    """
    if not isinstance(image, np.ndarray):
        raise InputError(f"{what}: expected a numpy array, got {type(image).__name__}")
    if image.ndim != 2:
        hint = ""
        if image.ndim == 3 and image.shape[-1] in (3, 4):
            hint = " (colour image: convert with cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))"
        raise InputError(f"{what}: expected a (H, W) greyscale image, got shape {image.shape}{hint}")
    if image.size == 0:
        raise InputError(f"{what}: empty image, shape {image.shape}")
    if image.dtype != np.uint8:
        hint = ""
        if image.dtype.kind == "f":
            hint = " (float image: scale it yourself, e.g. np.round(img * 255).astype(np.uint8))"
        raise InputError(f"{what}: expected dtype uint8, got {image.dtype}{hint}")
    return image


#: How far from the end of a JPEG its end-of-image marker may be (some writers
#: pad), bytes. Only the tail counts: an EXIF thumbnail has its own marker early on.
END_MARKER_SLACK = 256
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: A PNG's IEND chunk, whole (length 0, type, CRC): a file that holds it was written to
#: its end, whatever trails it.
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
_JPEG_START = b"\xff\xd8"


@contextlib.contextmanager
def quiet_opencv() -> Iterator[None]:
    """OpenCV's own log silenced for the block: a decoder that cannot read a file
    (a float TIFF, say) prints a ``[ WARN ]`` line of its own before returning None,
    and the caller's one-line error then comes second."""
    old = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(old)


#: What libjpeg and libpng print, straight to the process's standard error, when they
#: decode a damaged file and hand back an image all the same (the rest grey or wrong).
_DECODER_DAMAGE = ("Corrupt JPEG data", "libpng error", "libpng warning", "Premature end of JPEG file")
_DECODE_LOCK = threading.Lock()


@contextlib.contextmanager
def _decoder_messages() -> Iterator[list[str]]:
    """File descriptor 2 caught for the block: what the C decoders print there (they bypass
    Python and OpenCV's log) comes back as lines in the yielded list, to be judged by the
    caller. One block at a time (the descriptor is the process's)."""
    lines: list[str] = []
    with _DECODE_LOCK, tempfile.TemporaryFile() as caught:
        sys.stderr.flush()
        saved = os.dup(2)
        try:
            os.dup2(caught.fileno(), 2)
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            lines.extend(caught.read().decode("utf-8", "replace").splitlines())


def to_gray(image: np.ndarray | None) -> np.ndarray | None:
    """A decoded image (H, W), (H, W, 3) BGR or (H, W, 4) BGRA as (H, W) grey: colour by
    OpenCV's ``cvtColor`` (ITU-R BT.601 weights, rounded), the one conversion of every
    source. A decoder's own grey (``IMREAD_GRAYSCALE``: libpng's weights, one level below
    on half the pixels of the desk photos; libjpeg's luma) made the same photos differ
    read from a folder and from a bag of raw ``bgr8`` images (hostile pass 21)."""
    if image is None or image.ndim == 2:
        return image
    code = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}.get(image.shape[2])
    if code is None:  # a two-channel file, grey and alpha: the grey
        return np.ascontiguousarray(image[..., 0])
    return cv2.cvtColor(image, code)


def decode_gray(data: bytes, path: str | Path) -> np.ndarray:
    """Decode the bytes of an image file as ``(H, W)`` ``uint8`` greyscale.

    A PNG without its ``IEND`` chunk or a JPEG without its end-of-image marker
    (a truncated file) is refused before decoding: OpenCV would decode the part
    it has, fill the rest with grey and name no file. A 16-bit image whose values
    sit in its low bits (near black as 8 bits: :func:`check_sixteen_bit_levels`) is refused
    too. Raises :class:`InputError` naming ``path``.
    """
    if data.startswith(_PNG_SIGNATURE) and _PNG_IEND not in data:
        raise InputError("truncated PNG (no IEND chunk)", path)
    if data.startswith(_JPEG_START) and b"\xff\xd9" not in data[-END_MARKER_SLACK:]:
        raise InputError("truncated JPEG (no end-of-image marker)", path)
    image = None
    said: list[str] = []
    if data:
        with quiet_opencv(), _decoder_messages() as said:
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_ANYCOLOR)
        image = to_gray(image)
    damage = [ln.strip() for ln in said if any(d in ln for d in _DECODER_DAMAGE)]
    if damage:
        # a JPEG cut inside with its end marker kept decoded to grey below the cut, used
        # as a frame with only libjpeg's bare line, naming no file (hostile pass 17)
        raise InputError(f"damaged image data ({damage[0]})", path)
    if said:  # another message on the descriptor meanwhile: not ours to drop
        sys.stderr.write("\n".join(said) + "\n")
    if image is None or image.size == 0:
        raise InputError("cannot read image (not an image file, or an unsupported format)", path)
    if _levels(image) <= MAX_LEVELS_OF_LOW_16_BIT and _is_sixteen_bit(data):
        check_sixteen_bit_levels(image, path)  # near flat: 16-bit values in the low bits
    return check_gray(image, what=str(path))


#: Most grey levels (of 256) a 16-bit image may span once read as 8 bits and still be
#: refused: 16 levels are 4 bits, all that is left of a 12-bit camera's raw values
#: stored in the low bits of 16 (of 10-bit values: 1 bit), or of a depth map in
#: millimetres or TUM's fifths of one; no corner detector works on so few.
MAX_LEVELS_OF_LOW_16_BIT = 16


def _levels(image: np.ndarray) -> int:
    """Grey levels from the darkest pixel to the brightest, both counted."""
    return int(image.max()) - int(image.min()) + 1


def _is_sixteen_bit(data: bytes) -> bool:
    """Whether the image file ``data`` holds 16-bit values (decoded again: called only
    for a flat image; a flat 8-bit one is a blank frame, said where features are counted)."""
    with quiet_opencv():
        deep = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    return deep is not None and deep.dtype == np.uint16


def check_sixteen_bit_levels(image: np.ndarray, path: str | Path) -> None:
    """InputError when ``image``, the 8-bit reading of a 16-bit image (its top 8 bits:
    OpenCV's, and cv_bridge's scale by 1/256), spans at most
    :data:`MAX_LEVELS_OF_LOW_16_BIT` grey levels: the values sit in the low bits (a
    depth map, a 12-bit camera's raw data), and the image is near black. One rule for
    image files and ROS bags' mono16 images."""
    if _levels(image) > MAX_LEVELS_OF_LOW_16_BIT:
        return
    lo, hi = int(image.min()), int(image.max())
    raise InputError(
        f"16-bit image whose values sit in the low bits: read as 8 bits (the top 8 of 16) "
        f"it spans {hi - lo + 1} grey levels ({lo} to {hi}); a depth map, or a camera's "
        "raw 10- or 12-bit values? give 8-bit images (scaled to 0-255)",
        path,
    )


def load_gray(path: str | Path) -> np.ndarray:
    """Read an image file as ``(H, W)`` ``uint8`` greyscale (:func:`to_gray`).

    Raises :class:`InputError` naming the file when it is missing, unreadable,
    truncated (:func:`decode_gray`) or not an image.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("image file not found", path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read image ({e.strerror})", path) from None
    return decode_gray(data, path)
