"""Simulated FPGA pixel-rate Harris extractor with ping-pong point memories.

Models section 4.3 of the EKF-SLAM-on-FPGA paper (seed 003): pixels arrive in
raster order from the camera; a 5-line circular buffer holds the last five
image lines; the "Harris response" module produces one line of response per
incoming line, 6 lines behind the acquisition; the "Sort Harris" module keeps,
per tessellation cell, the best response above a threshold, and writes the
cells' winners into one of two dual-port memories (``Harris_LMK_A`` /
``Harris_LMK_B``) while the processor reads the other; the memories swap at the
end of each frame.

The simulation is line-vectorised (one numpy step per incoming line), with the
hardware's data flow and exactly the fixed-point arithmetic of
:func:`frontend.harris.harris_response_fixed`, so the points are bit-identical
to ``HarrisDetector(arithmetic="fixed")`` with the same config:

* raw line ``y`` enters the 5-line circular buffer (slot ``y % 5``);
* from the 5 buffered lines: smoothed line ``y-2`` (vertical then horizontal
  integer Gaussian, rounded ``>> 12``) enters a 3-line buffer;
* from it: derivatives and products of line ``y-3`` enter a 5-line buffer;
* from it: window sums and the response of line ``y-5`` (5 lines of
  look-ahead), held in ``latency_lines - 5`` line registers, so the response
  of line ``y - latency_lines`` leaves the pipeline while line ``y`` arrives
  (6 lines by default, as in the paper);
* "Sort Harris": each response line updates a running best per pixel column
  of the current cell row (value and row; strictly greater wins, so the
  earliest row keeps ties); when the last usable line of a cell row has gone
  by, each cell's winner (best value, then earliest row, then leftmost
  column: the first in raster order) is written to the write memory if above
  the threshold.

Ping-pong: frame ``n`` is written into memory ``n % 2`` (A, B, A, ...). It
becomes readable at its stamp, when the memories swap; until then the
processor keeps reading the other memory, whose content (frame ``n-1``, or
``n-2`` if ``n-1`` is not stamped yet) is not touched.

The filters of the simulation carry these integers in float64 words (every
value stays below 2^41 < 2^53, so each multiply and add is exact; the rounding
shifts are exact floors) because BLAS/``np.correlate`` on float64 are several
times faster per line than int64 numpy; the response itself is int64.
``pipeline_cycles`` (13, the paper's 13 pipelined operations) is the per-pixel
pipeline depth, counted in the timing only.

Timing model (:class:`FpgaTiming`): a line lasts ``(W + h_blank_px)`` pixel
clocks, a frame ``(H + v_blank_lines)`` lines. A frame pushed at ``t0_s``
(first pixel) finishes its write at ``t0 + ((H-1)(W+h_blank) + W) / f``; its
points become readable (memory swap) ``latency_lines`` lines plus
``pipeline_cycles`` clocks later. That instant is the frame's *stamp*
(``Features.ready_time_s``). Frames must not overlap: the next frame may start
``v_blank_lines`` (plus the last line's horizontal blanking) after the
previous one's last pixel.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from frontend.features import Features
from frontend.harris import GAUSS5_INT, K_SHIFT, REACH_PX, RESPONSE_SHIFT, HarrisConfig, cell_grid
from frontend.image import check_gray
from slamcore.config import Validated, bounded, with_overrides
from slamcore.errors import GraphSlamError, InputError

_S_SHIFT = 12
_W_SHIFT = 16
_SENTINEL = np.iinfo(np.int64).min


@dataclass(frozen=True)
class FpgaTiming(Validated):
    """Pixel-clock timing of the camera link and the Harris pipeline.

    The paper gives no clock; the defaults are the VESA 640x480@60 Hz timing
    (25.175 MHz, 800 clocks per line, 525 lines per frame).

    Attributes:
        pixel_clock_hz: one pixel enters per clock.
        h_blank_px: blanking clocks after each line.
        v_blank_lines: blanking lines after each frame.
        latency_lines: lines between a pixel row's arrival and its response
            row leaving the pipeline (paper: 6; must be >= 5, the look-ahead).
        pipeline_cycles: depth of the per-pixel pipeline in clocks (paper: 13
            pipelined operations).

    No config file sets it (it has no ``SECTION``): its errors name it
    ``fpgatiming``. None of these values sizes a buffer (the line registers
    hold at most the image's rows), so only their lower bounds are checked.
    """

    pixel_clock_hz: float = bounded(25.175e6, gt=0.0)
    h_blank_px: int = bounded(160, min=0)
    v_blank_lines: int = bounded(45, min=0)
    latency_lines: int = bounded(6, min=REACH_PX)
    pipeline_cycles: int = bounded(13, min=0)

    def line_s(self, width: int) -> float:
        """Duration of one line (pixels + horizontal blanking), seconds."""
        return (width + self.h_blank_px) / self.pixel_clock_hz

    def frame_period_s(self, shape: tuple[int, int]) -> float:
        """Shortest time between two frame starts, seconds."""
        h, w = shape
        return (h + self.v_blank_lines) * self.line_s(w)

    def write_end_s(self, shape: tuple[int, int], t0_s: float) -> float:
        """When the last pixel of a frame starting at ``t0_s`` has arrived."""
        h, w = shape
        return t0_s + ((h - 1) * (w + self.h_blank_px) + w) / self.pixel_clock_hz

    def ready_s(self, shape: tuple[int, int], t0_s: float) -> float:
        """The frame's stamp: end of write + latency lines + pipeline clocks."""
        h, w = shape
        return (
            self.write_end_s(shape, t0_s)
            + self.latency_lines * self.line_s(w)
            + self.pipeline_cycles / self.pixel_clock_hz
        )


@dataclass
class _Frame:
    index: int
    slot: int
    t0_s: float
    ready_s: float
    end_s: float
    width: int
    features: Features = field(repr=False)


class FpgaHarrisStream:
    """Pixel-rate Harris with ping-pong memories (also a :class:`Detector`).

    ``config``: a :class:`HarrisConfig` (its ``arithmetic`` is ignored: the
    stream is always fixed point); ``timing``: :class:`FpgaTiming`.
    ``push_frame(image, t0_s)`` streams one frame through the pipeline;
    ``read(now_s)`` returns what the processor can read at ``now_s``: the
    latest frame whose stamp is <= ``now_s`` (from the memory it was written
    to), or None before the first stamp.
    """

    SLOT_NAMES = ("Harris_LMK_A", "Harris_LMK_B")

    def __init__(self, config: HarrisConfig | None = None, timing: FpgaTiming | None = None, **overrides):
        self.config = with_overrides(config or HarrisConfig(arithmetic="fixed"), overrides, HarrisConfig)
        self.timing = timing or FpgaTiming()
        self._frames: deque[_Frame] = deque(maxlen=3)
        self._n_frames = 0

    # ------------------------------------------------------------- processor side

    @property
    def frames_pushed(self) -> int:
        return self._n_frames

    def next_start_s(self) -> float:
        """Earliest ``t0_s`` for the next frame (0 for the first): the last line's
        horizontal blanking plus ``v_blank_lines`` after the previous frame's last pixel."""
        if not self._frames:
            return 0.0
        last = self._frames[-1]
        return (
            last.end_s
            + self.timing.h_blank_px / self.timing.pixel_clock_hz
            + self.timing.v_blank_lines * self.timing.line_s(last.width)
        )

    def readable(self, now_s: float) -> tuple[int, str] | None:
        """``(frame index, memory name)`` readable at ``now_s``, or None."""
        f = self._readable_frame(now_s)
        return None if f is None else (f.index, self.SLOT_NAMES[f.slot])

    def read(self, now_s: float) -> Features | None:
        """Points of the readable memory at ``now_s`` (None before the first stamp).

        ``now_s`` must not precede the start of the last pushed frame (the
        simulation keeps only what the two memories can hold from then on).
        """
        if not math.isfinite(now_s):
            raise InputError(f"read time must be finite, got {now_s}")
        f = self._readable_frame(now_s)
        if f is None:
            return None
        # copies: the stream keeps its memories; a caller changing its points changes its own
        feats = f.features
        return dataclasses.replace(
            feats,
            xy_px=feats.xy_px.copy(),
            response=feats.response.copy(),
            descriptors=None if feats.descriptors is None else feats.descriptors.copy(),
            cell=None if feats.cell is None else feats.cell.copy(),
        )

    def _readable_frame(self, now_s: float) -> _Frame | None:
        if self._frames and now_s < self._frames[-1].t0_s:
            raise InputError(
                f"read at {now_s} s precedes the start of the last pushed frame ({self._frames[-1].t0_s} s)"
            )
        for f in reversed(self._frames):
            if f.ready_s <= now_s:
                return f
        return None

    # ------------------------------------------------------------- camera side

    def push_frame(self, image: np.ndarray, t0_s: float) -> float:
        """Stream one frame whose first pixel arrives at ``t0_s``. Returns its stamp.

        The frame is written into memory ``frame_index % 2`` (A, B, A, ...);
        it becomes readable at the stamp, when the memories swap.
        """
        image = check_gray(image)
        t0_s = float(t0_s)
        if not math.isfinite(t0_s):
            raise InputError(f"frame start time must be finite, got {t0_s}")
        if self._frames:
            earliest = self.next_start_s()
            # round-off of the stamps' own size: at a Unix-epoch time (1.4e9 s) one float
            # step is 2.4e-7 s, and frames one period apart were refused as overlapping
            # (hostile pass 24); 16 steps of float spacing, 1e-12 s near 0
            tol = max(1e-12, 16.0 * math.ulp(max(abs(t0_s), abs(earliest))))
            if t0_s < earliest - tol:
                raise InputError(
                    f"frame pushed at t0 = {t0_s:.9f} s overlaps the previous frame "
                    f"(earliest start {earliest:.9f} s)"
                )
        shape = image.shape
        features = self._stream(image)
        ready = self.timing.ready_s(shape, t0_s)
        features = Features(xy_px=features[0], response=features[1], cell=features[2], ready_time_s=ready)
        frame = _Frame(
            index=self._n_frames,
            slot=self._n_frames % 2,
            t0_s=t0_s,
            ready_s=ready,
            end_s=self.timing.write_end_s(shape, t0_s),
            width=shape[1],
            features=features,
        )
        self._frames.append(frame)
        self._n_frames += 1
        return ready

    def detect(self, image: np.ndarray) -> Features:
        """Drop-in :class:`Detector`: push at the earliest start, read at the stamp."""
        image = check_gray(image)
        ready = self.push_frame(image, self.next_start_s())
        features = self.read(ready)
        if features is None:  # the frame just pushed is readable at its stamp
            raise GraphSlamError(f"fpga_stream: no frame readable at its stamp {ready} s")
        return features

    # ------------------------------------------------------------- the pipeline

    def _stream(self, image: np.ndarray):
        cfg = self.config
        h, w = image.shape
        cs, border = cfg.cell_size_px, cfg.border_px
        thr = cfg.threshold_fixed
        k_num = cfg.k_num
        _, nc = cell_grid((h, w), cs)
        delay = self.timing.latency_lines - REACH_PX

        out_xy: list[np.ndarray] = []
        out_val: list[np.ndarray] = []
        out_cell: list[np.ndarray] = []
        if h <= 2 * border or w <= 2 * border:
            return _pack(out_xy, out_val, out_cell)

        # Circular buffers are read in parallel; the tap each slot gets rotates
        # with the write pointer: taps_for[y % 5][slot] is the Gaussian tap of
        # the line in ``slot`` when the newest line is ``y``.
        taps_for = np.zeros((5, 5), dtype=np.float64)
        for newest in range(5):
            for i in range(5):  # i = 0: oldest of the five lines
                taps_for[newest, (newest - 4 + i) % 5] = GAUSS5_INT[i]
        # Horizontal taps with the normalising shift folded in (exact binary
        # fractions); symmetric, so correlate == convolve.
        gauss_s = np.array(GAUSS5_INT, dtype=np.float64) / (1 << _S_SHIFT)
        gauss_w = np.array(GAUSS5_INT, dtype=np.float64) / (1 << _W_SHIFT)

        # Line buffers. The filters run on float64 words holding integers: every
        # value is an integer below 2^41 < 2^53 (pixels < 2^8, S < 2^12, products
        # < 2^24, window sums < 2^40), so each multiply and add is exact and the
        # results are the integers of harris_response_fixed, bit for bit; the
        # rounding shifts are floor(x / 2^n + 1/2), also exact. The
        # response (up to 2^57 before its shift) is computed in int64.
        raw = np.zeros((5, w), dtype=np.float64)  # the paper's 5-line circular buffer
        smooth = np.zeros((3, w - 4), dtype=np.float64)  # S lines (cols 2 .. w-3)
        prods = np.zeros((5, 3, w - 6), dtype=np.float64)  # Ix^2, Iy^2, IxIy (cols 3 .. w-4)
        prods_flat = prods.reshape(5, -1)
        deriv = np.zeros((2, w - 6), dtype=np.float64)  # Ix, Iy of one line
        hpad = np.zeros(3 * (w - 6), dtype=np.float64)  # horizontal window sums, 3 channels
        hview = hpad.reshape(3, w - 6)[:, : w - 10]
        abc = np.zeros((3, w - 10), dtype=np.int64)  # A, B, C of one line (cols 5 .. w-6)
        ac, bc = abc[0::2], abc[1:]  # views [A, C] and [B, C]
        abcc = np.zeros((2, w - 10), dtype=np.int64)
        n_h = 3 * (w - 6) - 4
        registers: deque = deque()  # response lines awaiting output

        # Sort Harris state: a running best per pixel column of the current cell
        # row (value, and the row it came from; strict > keeps the earliest row
        # on ties), laid out on the cell grid; usable columns [border, w - border).
        u0, u1 = border, w - border
        v_last_usable = h - border - 1
        col_best = np.full(nc * cs, _SENTINEL, dtype=np.int64)
        col_row = np.zeros(nc * cs, dtype=np.int64)
        cb, cr = col_best[u0:u1], col_row[u0:u1]
        better = np.zeros(u1 - u0, dtype=bool)
        cell_cols = np.arange(nc, dtype=np.int64)
        local = np.arange(cs, dtype=np.int64)
        big = np.iinfo(np.int64).max

        def sort_harris(v: int, r_line: np.ndarray) -> None:
            # r_line: response of row v for cols 5 .. w-6.
            if not border <= v <= v_last_usable:
                return
            seg = r_line[u0 - REACH_PX : u1 - REACH_PX]
            np.greater(seg, cb, out=better)
            np.copyto(cb, seg, where=better)
            np.copyto(cr, v, where=better)
            if v == min((v // cs + 1) * cs, v_last_usable + 1) - 1:
                # Cell row complete: per cell, the best value; among columns
                # holding it, the earliest row, then the leftmost column.
                blocks = col_best.reshape(nc, cs)
                best = blocks.max(axis=1)
                keep = best > thr
                if keep.any():
                    rows = col_row.reshape(nc, cs)
                    key = np.where(blocks == best[:, None], rows * cs + local, big)
                    j = key.argmin(axis=1)[keep]
                    cells = cell_cols[keep]
                    out_xy.append(np.column_stack([cells * cs + j, rows[cells, j]]))
                    out_val.append(best[keep])
                    out_cell.append((v // cs) * nc + cells)
                col_best.fill(_SENTINEL)

        for y in range(h):
            raw[y % 5] = image[y]
            if y < 4:
                continue
            # Smoothed line y-2: vertical Gaussian of the 5 buffered lines, then horizontal.
            s_line = smooth[(y - 2) % 3]
            np.add(np.correlate(taps_for[y % 5] @ raw, gauss_s, "valid"), 0.5, out=s_line)
            np.floor(s_line, out=s_line)
            if y < 6:
                continue
            # Derivatives and products of line y-3 (S lines y-4, y-3, y-2).
            s_mid = smooth[(y - 3) % 3]
            ix, iy = deriv
            np.subtract(s_mid[2:], s_mid[:-2], out=ix)
            np.subtract(smooth[(y - 2) % 3][1:-1], smooth[(y - 4) % 3][1:-1], out=iy)
            p = prods[(y - 3) % 5]
            np.multiply(deriv, deriv, out=p[:2])
            np.multiply(ix, iy, out=p[2])
            if y < 10:
                continue
            # Window sums of line y-5 (product lines y-7 .. y-3): vertical pass,
            # then one horizontal correlation over the three channels laid end
            # to end (the 4 outputs straddling two channels fall outside hview).
            np.add(np.correlate(taps_for[(y - 3) % 5] @ prods_flat, gauss_w, "valid"), 0.5, out=hpad[:n_h])
            np.floor(hview, out=abc, casting="unsafe")  # exact integers -> int64
            # R = A B - C^2 - ((A + B)^2 k_num >> 10), as response_from_abc_fixed.
            np.multiply(ac, bc, out=abcc)  # [A B, C^2]
            r_line = abcc[0] - abcc[1]  # a fresh line for the registers
            tr = abc[0] + abc[1]
            tr *= tr
            tr *= k_num
            tr >>= K_SHIFT
            r_line -= tr
            registers.append((y - 5, r_line))
            if len(registers) > delay:
                sort_harris(*registers.popleft())
        # Vertical blanking: the line registers drain.
        while registers:
            sort_harris(*registers.popleft())
        return _pack(out_xy, out_val, out_cell)


def _pack(out_xy, out_val, out_cell):
    if not out_xy:
        return (np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64))
    xy = np.concatenate(out_xy).astype(np.float64)
    val = np.concatenate(out_val).astype(np.float64) / 2.0**RESPONSE_SHIFT
    cell = np.concatenate(out_cell).astype(np.int64)
    return xy, val, cell
