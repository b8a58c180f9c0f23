"""Harris corners with per-cell selection, as on the FPGA of the EKF-SLAM paper.

The paper (seed 003, section 4.3) extracts Harris points at pixel rate: a 5x5
Gaussian filter of the image, partial derivatives in u and v, then the Harris
response per pixel, all on 5x5 windows read from a 5-line circular buffer
(6-line latency, 13 pipelined operations, fixed point with shift
approximations). The image is then tessellated into cells and only the best
response above a threshold is kept in each cell. The paper gives neither k, the
cell size, the derivative kernel nor the structure-tensor window; the choices
below are ours and are stated here.

Pipeline (the same for both arithmetics; ``I`` is the image in [0, 255])::

    S  = G5 * I                      5x5 Gaussian, sampled at sigma = 1 px (separable)
    Ix = (S[v, u+1] - S[v, u-1]) / 2 central differences on S
    Iy = (S[v+1, u] - S[v-1, u]) / 2
    A, B, C = G5 * Ix^2, G5 * Iy^2, G5 * IxIy
                                     Harris window: the same 5x5 Gaussian
    R  = A B - C^2 - k (A + B)^2     k = 0.04 (the usual value; not in the paper)

A response at pixel (u, v) reads image rows v-5 .. v+5 (2 for the smoothing,
1 for the derivative, 2 for the window): pixels closer than 5 px to the edge
have no response, so ``border_px`` must be >= 5. In the stream
(:mod:`frontend.fpga_stream`) this look-ahead of 5 lines plus one line of
output registers is the paper's 6-line latency.

Tessellation: cells of ``cell_size_px`` square from the top-left corner (the
last row and column of cells may be cut by the image edge); cell index =
``cell_row * n_cell_cols + cell_col``. In each cell, among pixels at least
``border_px`` from every edge, the largest response wins, ties going to the
first pixel in raster order; it is kept only if strictly above ``threshold``.
Points come out sorted by cell index.

Arithmetics:

* ``"float"``: floating-point reference (OpenCV ``sepFilter2D``), sampled Gaussian
  ``exp(-x^2/2)`` for x = -2..2, normalised:
  ``[0.05449, 0.24420, 0.40262, 0.24420, 0.05449]``. The detector computes
  it in float32 (:func:`harris_response_float`; float64 on request).
* ``"fixed"``: exact integer arithmetic as the hardware would do it, only
  constant multiplies (each a few shifts and adds), adds and shifts:

  ====================  =================================================  ======================
  quantity              fixed-point form                                    word width
  ====================  =================================================  ======================
  pixel                 u8                                                  8 bits
  Gaussian taps         ``[14, 62, 104, 62, 14] / 2^8`` per axis            14 = 16-2, 62 = 64-2,
                        (``>> 8``)                                          104 = 64+32+8
  S                     ``(G5v G5h I + 2^11) >> 12`` (rounded), Q8.4        u12
  Ix, Iy                ``S[u+1] - S[u-1]`` (= 32 x float Ix, no halving)   s13
  Ix^2, Iy^2, IxIy      exact products                                      u24, u24, s25
  window sums           ``G5v G5h P`` before the shift                      s41
  A, B, C               ``(G5v G5h P + 2^15) >> 16`` (rounded)              u24, u24, s25
                                                                            (scale 2^10)
  k (A+B)^2             ``((A+B)^2 * 41) >> 10``; 41 = 32+8+1,               (A+B)^2: 50 bits,
                        i.e. k ~= 41/1024 = 1/32 + 1/128 + 1/1024           x 41: 56 bits
  R                     ``A B - C^2 - k (A+B)^2``                           s53, int64
  ====================  =================================================  ======================

  ``R_fixed ~= 2^20 R_float``; reported responses are ``R_fixed / 2^20``
  (exact in float64) so thresholds and scores share the float units, and the
  threshold test is done in integers (``R_fixed > floor(threshold * 2^20)``).

Approximation errors (measured; ``tests/frontend/test_harris.py`` asserts bounds on
them and ``benchmarks/bench_harris.py`` prints them):

* Gaussian taps: largest tap error 0.0036 of the unit gain (104/256 = 0.40625
  vs 0.40262, +0.9 %; 62/256 -0.8 %; 14/256 +0.4 %); the taps sum to 1
  exactly, so flat regions are unbiased; standard deviation 0.960 px instead
  of 0.961 px.
* S rounded to 1/16 grey level: error <= 1/32 grey level.
* k: 41/1024 = 0.0400390625 vs 0.04, relative error +0.098 %.
* A, B, C rounded to 2^-10 of a squared float gradient unit.
* Overall, on KITTI 07 frame 0 where |R| > 1e4: relative error of the fixed
  response median 0.56 %, 99th percentile 3.1 %.
* Tessellated points (default config) identical in cell and position between
  fixed and float on all 160 KITTI 07 frames: 25959 of 26470 (union), 98.07 %.

The float detector fuses smoothing and derivative into derivative-of-Gaussian
kernels (one ``sepFilter2D`` per derivative), runs in float32 with OpenCV
element-wise calls and reuses its work buffers (about 3 ms on a VGA frame,
response and cells, against 8 ms in float64 with numpy temporaries).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import cv2
import numpy as np

from frontend.features import Features
from frontend.image import MAX_SIDE_PX, check_gray
from slamcore.config import Validated, bounded, with_overrides
from slamcore.errors import InputError

#: Pixels of look-ahead of one response on each side (2 smoothing + 1 derivative + 2 window).
REACH_PX = 5

#: Float reference Gaussian: exp(-x^2/2) for x = -2..2, normalised to sum 1.
GAUSS5_FLOAT = np.exp(-0.5 * np.arange(-2, 3, dtype=np.float64) ** 2)
GAUSS5_FLOAT /= GAUSS5_FLOAT.sum()
GAUSS5_FLOAT.flags.writeable = False

#: Integer Gaussian taps, normalised by a right shift of GAUSS5_SHIFT per axis.
GAUSS5_INT = (14, 62, 104, 62, 14)
GAUSS5_SHIFT = 8
#: Fractional bits kept in the smoothed image S.
S_FRAC_BITS = 4
#: k ~= K_NUM / 2^K_SHIFT.
K_SHIFT = 10
#: R_fixed ~= 2^RESPONSE_SHIFT * R_float (derivatives are 2 * 2^S_FRAC_BITS times the float ones).
RESPONSE_SHIFT = 4 * (S_FRAC_BITS + 1)

_INT_SENTINEL = np.iinfo(np.int64).min


@dataclass(frozen=True)
class HarrisConfig(Validated):
    """Harris detector settings (config section ``[harris]``).

    Attributes:
        k: Harris sensitivity in ``R = det - k trace^2`` (0.04, the usual value;
            the paper does not give it). Fixed point uses ``round(k * 1024) / 1024``.
        cell_size_px: side of the square tessellation cells, pixels.
        threshold: a cell keeps its best point only if ``R > threshold``; R in
            float units (image in grey levels 0..255, derivatives by central
            differences), i.e. grey level^4. On KITTI 07's 160 frames (1226x370,
            pixels 5 or more from an edge) R > 1e4 holds at 1.6-3.2 % of the
            pixels (median 2.4 %), the 99th percentile of R is 2.0e4-9.5e4 (median
            4.8e4), and the default 1e4 leaves a point in 110-213 of the 468 cells.
        arithmetic: ``"float"`` (floating-point reference) or ``"fixed"`` (hardware
            integer arithmetic, bit-identical to :mod:`frontend.fpga_stream`).
        border_px: pixels closer than this to an edge never win a cell (>= 5,
            the reach of the 5x5 smoothing + derivative + 5x5 window).
    """

    SECTION: ClassVar[str] = "harris"

    # below half a fixed-point step (1/2048) k rounds to 0 in the hardware's k_num / 1024
    k: float = bounded(0.04, gt=0.5 / (1 << K_SHIFT), lt=0.25)
    cell_size_px: int = bounded(32, min=1, max=MAX_SIDE_PX)
    # the fixed-point threshold threshold * 2^20 must fit the int64 response
    threshold: float = bounded(1.0e4, min=0.0, lt=2.0 ** (62 - RESPONSE_SHIFT))
    arithmetic: Literal["float", "fixed"] = "float"
    border_px: int = bounded(8, min=REACH_PX, max=MAX_SIDE_PX)

    @property
    def k_num(self) -> int:
        """Fixed-point k numerator: ``k ~= k_num / 1024``."""
        return int(round(self.k * (1 << K_SHIFT)))

    @property
    def threshold_fixed(self) -> int:
        """Integer threshold on ``R_fixed`` (``R_fixed > threshold_fixed``)."""
        return int(math.floor(self.threshold * 2.0**RESPONSE_SHIFT))


# --------------------------------------------------------------------------- float


def _float_image(image) -> np.ndarray:
    """``image`` as float64 (H, W), non-empty and finite; InputError otherwise (OpenCV's
    own errors, or a colour image filtered per channel, or NaN spreading, before)."""
    a = np.asarray(image)
    if a.ndim != 2 or a.size == 0 or a.dtype.kind not in "uif":
        raise InputError(f"image: expected a non-empty (H, W) array of numbers, got {a.dtype} {a.shape}")
    a = a.astype(np.float64, copy=False)
    if not np.all(np.isfinite(a)):
        raise InputError("image: non-finite pixel values")
    return a


def smooth_float(image: np.ndarray, kernel: np.ndarray = GAUSS5_FLOAT) -> np.ndarray:
    """Separable smoothing of a uint8 or float image, float64 out (reflect-101 borders);
    ``kernel`` (k,), k odd, finite: an even one would shift the image half a pixel."""
    a = _float_image(image)
    try:
        k = np.asarray(kernel, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("smoothing kernel: need a 1-D array of numbers") from None
    if k.ndim != 1 or len(k) % 2 == 0 or not np.all(np.isfinite(k)):
        raise InputError(f"smoothing kernel: need a finite 1-D array of odd length, got shape {k.shape}")
    return cv2.sepFilter2D(a, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT_101)


_DIFF = np.array([-0.5, 0.0, 0.5])
_ONE = np.array([1.0])
_DIFF.flags.writeable = _ONE.flags.writeable = False


def _buffers(work: dict | None, shape: tuple[int, int], names: str, dtype=np.float64) -> list:
    """Work arrays reused between calls of the same shape (spares page faults)."""
    if work is None:
        return [np.empty(shape, dtype) for _ in names.split()]
    out = []
    for name in names.split():
        buf = work.get(name)
        if buf is None or buf.shape != shape or buf.dtype != dtype:
            buf = work[name] = np.empty(shape, dtype)
        out.append(buf)
    return out


def _response_from_derivatives(ix, iy, k, window, work=None):
    """``R = AB - C^2 - k (A+B)^2`` with ``A, B, C`` the ``window``-filtered products.

    Works in the dtype of ``ix`` (float32 or float64). OpenCV element-wise calls
    into reused buffers: numpy temporaries of a VGA frame cost page faults that
    take longer than the arithmetic.
    """
    border = cv2.BORDER_REFLECT_101
    depth = cv2.CV_32F if ix.dtype == np.float32 else cv2.CV_64F
    p, a, b, c, r = _buffers(work, ix.shape, "p a b c r", ix.dtype)
    cv2.sepFilter2D(cv2.multiply(ix, ix, dst=p), depth, window, window, dst=a, borderType=border)
    cv2.sepFilter2D(cv2.multiply(iy, iy, dst=p), depth, window, window, dst=b, borderType=border)
    cv2.sepFilter2D(cv2.multiply(ix, iy, dst=p), depth, window, window, dst=c, borderType=border)
    cv2.multiply(a, b, dst=r)
    cv2.subtract(r, cv2.multiply(c, c, dst=p), dst=r)
    cv2.add(a, b, dst=a)  # trace
    cv2.subtract(r, cv2.multiply(a, a, dst=p, scale=float(k)), dst=r)
    return r


def structure_response_float(smoothed: np.ndarray, k: float, window: np.ndarray = GAUSS5_FLOAT) -> np.ndarray:
    """Harris response of an already smoothed float64 image, same shape.

    Central-difference derivatives, products, separable ``window`` on the
    products, ``R = AB - C^2 - k (A+B)^2``. Values within 5 px of an edge use
    reflected borders and are not used by the detector.
    """
    smoothed = _float_image(smoothed)  # the check smooth_float applies
    border = cv2.BORDER_REFLECT_101
    ix = cv2.sepFilter2D(smoothed, cv2.CV_64F, _DIFF, _ONE, borderType=border)
    iy = cv2.sepFilter2D(smoothed, cv2.CV_64F, _ONE, _DIFF, borderType=border)
    return _response_from_derivatives(ix, iy, k, window)


#: Central difference of the Gaussian-smoothed image as one 7-tap correlation
#: kernel: (S[u+1] - S[u-1]) / 2 with S = G5 * I.
DGAUSS7_FLOAT = 0.5 * (
    np.concatenate([[0.0, 0.0], GAUSS5_FLOAT]) - np.concatenate([GAUSS5_FLOAT, [0.0, 0.0]])
)
DGAUSS7_FLOAT.flags.writeable = False


def harris_response_float(
    image: np.ndarray, k: float = 0.04, work: dict | None = None, dtype=np.float32
) -> np.ndarray:
    """(H, W) Harris response of a uint8 image, float arithmetic in ``dtype``.

    Smoothing and derivative are fused into derivative-of-Gaussian kernels
    (7 taps along the derivative, 5 across), which is the same linear map as
    :func:`smooth_float` then central differences, up to float rounding and
    the reflected border (within 5 px of the edge, never used). ``dtype``:
    float32 (default, the detector's: about 3x faster than float64 on a VGA
    frame; relative rounding ~1e-7 per term, far below the fixed point's
    0.5 % and never decisive at the 1e4 threshold) or float64 (reference).
    ``work``: a dict of reusable buffers (the result is one of them: copy it
    to keep it).
    """
    image = check_gray(image)  # a uint16 or float frame is refused, not misread
    border = cv2.BORDER_REFLECT_101
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise InputError(f"dtype must be float32 or float64, got {dtype}")
    depth = cv2.CV_32F if dtype == np.float32 else cv2.CV_64F
    ix, iy = _buffers(work, image.shape, "ix iy", dtype)
    cv2.sepFilter2D(image, depth, DGAUSS7_FLOAT, GAUSS5_FLOAT, dst=ix, borderType=border)
    cv2.sepFilter2D(image, depth, GAUSS5_FLOAT, DGAUSS7_FLOAT, dst=iy, borderType=border)
    return _response_from_derivatives(ix, iy, k, GAUSS5_FLOAT, work)


# --------------------------------------------------------------------------- fixed


def g5_rows(x: np.ndarray) -> np.ndarray:
    """Unnormalised integer 5-tap Gaussian along axis 0 ("valid": 4 rows fewer).

    ``14 (x0 + x4) + 62 (x1 + x3) + 104 x2``: three constant multiplies, four adds.
    """
    t = GAUSS5_INT
    return t[0] * (x[:-4] + x[4:]) + t[1] * (x[1:-3] + x[3:-1]) + t[2] * x[2:-2]


def g5_cols(x: np.ndarray) -> np.ndarray:
    """Same as :func:`g5_rows` along the last axis."""
    t = GAUSS5_INT
    return t[0] * (x[..., :-4] + x[..., 4:]) + t[1] * (x[..., 1:-3] + x[..., 3:-1]) + t[2] * x[..., 2:-2]


def round_shift(x: np.ndarray, n: int) -> np.ndarray:
    """``(x + 2^(n-1)) >> n``: round-half-up right shift (arithmetic, exact on integers)."""
    return (x + (1 << (n - 1))) >> n


_S_SHIFT = 2 * GAUSS5_SHIFT - S_FRAC_BITS  # 12
_W_SHIFT = 2 * GAUSS5_SHIFT  # 16


def response_from_abc_fixed(a: np.ndarray, b: np.ndarray, c: np.ndarray, k_num: int) -> np.ndarray:
    """``A B - C^2 - ((A + B)^2 * k_num) >> 10`` in int64."""
    tr = a + b
    return a * b - c * c - ((tr * tr * k_num) >> K_SHIFT)


def harris_response_fixed(image: np.ndarray, k_num: int = 41) -> np.ndarray:
    """(H, W) int64 fixed-point Harris response (``~2^20 R_float``).

    Pixels within :data:`REACH_PX` of an edge hold ``iinfo(int64).min``. The image
    must be uint8: the int32 stages are sized for 8-bit pixels (a uint16 frame
    overflowed them silently).
    """
    image = check_gray(image)
    h, w = image.shape
    out = np.full((h, w), _INT_SENTINEL, dtype=np.int64)
    if h <= 2 * REACH_PX or w <= 2 * REACH_PX:
        return out
    raw = image.astype(np.int32)
    s = round_shift(g5_cols(g5_rows(raw)), _S_SHIFT)  # rows/cols 2 .. n-3
    ix = (s[1:-1, 2:] - s[1:-1, :-2]).astype(np.int64)  # rows/cols 3 .. n-4
    iy = (s[2:, 1:-1] - s[:-2, 1:-1]).astype(np.int64)
    a = round_shift(g5_cols(g5_rows(ix * ix)), _W_SHIFT)  # rows/cols 5 .. n-6
    b = round_shift(g5_cols(g5_rows(iy * iy)), _W_SHIFT)
    c = round_shift(g5_cols(g5_rows(ix * iy)), _W_SHIFT)
    out[REACH_PX : h - REACH_PX, REACH_PX : w - REACH_PX] = response_from_abc_fixed(a, b, c, k_num)
    return out


# --------------------------------------------------------------------------- cells


def cell_grid(shape: tuple[int, int], cell_size_px: int) -> tuple[int, int]:
    """(rows, cols) of tessellation cells covering an image of ``shape``."""
    h, w = shape
    return -(-h // cell_size_px), -(-w // cell_size_px)


def tessellate(
    response: np.ndarray, cell_size_px: int, border_px: int, threshold, work: dict | None = None
) -> tuple:
    """Best response per cell, first in raster order on ties, kept if ``> threshold``.

    ``response``: (H, W) float or int array; pixels closer than ``border_px``
    to an edge are ignored. Returns ``(xy_px (N,2) float64, values (N,) same
    dtype as response, cell (N,) int64)`` sorted by cell index. ``work``: a
    dict of reusable buffers.
    """
    if not (isinstance(cell_size_px, (int, np.integer)) and cell_size_px >= 1):
        raise InputError(f"cell_size_px must be an integer >= 1, got {cell_size_px!r}")
    if not (isinstance(border_px, (int, np.integer)) and border_px >= 0):
        raise InputError(f"border_px must be an integer >= 0, got {border_px!r}")
    h, w = response.shape
    cs = cell_size_px
    nr, nc = cell_grid((h, w), cs)
    dtype = response.dtype
    fill = -np.inf if dtype.kind == "f" else np.iinfo(dtype).min
    key = ("tess", h, w, cs, border_px, dtype.str)
    padded = None if work is None else work.get(key)
    if padded is None:
        padded = np.full((nr * cs, nc * cs), fill, dtype=dtype)
        if work is not None:
            work[key] = padded
    if h > 2 * border_px and w > 2 * border_px:
        padded[border_px : h - border_px, border_px : w - border_px] = response[
            border_px : h - border_px, border_px : w - border_px
        ]
    # Max per (cell row, pixel row, cell column), then per cell; the winner is
    # the first pixel row reaching the cell max, then its first such column.
    row_max = padded.reshape(nr, cs, nc, cs).max(axis=3)  # (nr, cs, nc)
    best = row_max.max(axis=1)  # (nr, nc)
    keep_r, keep_c = np.nonzero(best > threshold)
    vals = best[keep_r, keep_c]
    first_row = np.argmax(row_max[keep_r, :, keep_c] == vals[:, None], axis=1)
    v = keep_r * cs + first_row
    rows = padded[v[:, None], keep_c[:, None] * cs + np.arange(cs)]  # (N, cs)
    u = keep_c * cs + np.argmax(rows == vals[:, None], axis=1)
    xy = np.column_stack([u, v]).astype(np.float64)
    return xy, vals, (keep_r * nc + keep_c).astype(np.int64)


# --------------------------------------------------------------------------- detector


class HarrisDetector:
    """Harris + tessellation (:class:`frontend.features.Detector`).

    ``HarrisDetector(config)`` or ``HarrisDetector(arithmetic="fixed", ...)``
    (keyword overrides of :class:`HarrisConfig`).
    """

    def __init__(self, config: HarrisConfig | None = None, **overrides):
        self.config = with_overrides(config or HarrisConfig(), overrides, HarrisConfig)
        self._work: dict = {}

    def response(self, image: np.ndarray) -> np.ndarray:
        """Full (H, W) response in float units (float64), NaN-free. The fixed arithmetic
        is -inf where its windows leave the image (the FPGA's pipeline has no pixel
        there); the float one is finite there, its filters reflecting the image at the
        edge. Neither band holds a detection: ``detect`` keeps ``border_px`` clear."""
        image = check_gray(image)
        cfg = self.config
        if cfg.arithmetic == "float":
            return harris_response_float(image, cfg.k).astype(np.float64)
        r = harris_response_fixed(image, cfg.k_num)
        out = r.astype(np.float64) / 2.0**RESPONSE_SHIFT
        out[r == _INT_SENTINEL] = -np.inf
        return out

    def detect(self, image: np.ndarray) -> Features:
        """``image``: (H, W) uint8. Best point per cell above the threshold."""
        image = check_gray(image)
        cfg = self.config
        if cfg.arithmetic == "float":
            r = harris_response_float(image, cfg.k, self._work)
            xy, val, cell = tessellate(r, cfg.cell_size_px, cfg.border_px, cfg.threshold, self._work)
            resp = val.astype(np.float64)
        else:
            r = harris_response_fixed(image, cfg.k_num)
            xy, val, cell = tessellate(r, cfg.cell_size_px, cfg.border_px, cfg.threshold_fixed, self._work)
            resp = val.astype(np.float64) / 2.0**RESPONSE_SHIFT
        return Features(xy_px=xy, response=resp, cell=cell)
