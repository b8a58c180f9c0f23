"""Frame ranges of an image sequence: ``--frames START:STOP[:STEP]`` (numpy only).

:func:`parse_frames` reads the text of the flag into a :class:`slice` (Python
semantics: ``0:200``, ``200:``, ``1:160:2``, ``159::-2`` plays the sequence
backwards); :func:`select_frames` applies it to an :class:`ImageSequence` and
returns a :class:`FrameSelection`, itself an image sequence whose frame ``i``
is frame ``indices[i]`` of the original. Everything indexed by frame moves
with the images: paths, stamps, ground truth, and the sequence's own odometry,
composed over the skipped frames (``c_a T c_b`` is the product of the original
steps from ``a`` to ``b``, inverted when the range runs backwards). The
composed odometry's covariance is the sum of the per-step covariances (a
first-order bound that ignores the rotation between steps: the steps are
small and of equal noise, so it is the right size), and its stated sigmas
grow with the square root of the stride.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.errors import QUOTE_CHARS, ConfigError, quote
from slamcore.spatial.geometry import invert_pose

__all__ = ["parse_frames", "select_frames", "FrameSelection", "frame_indices"]


def parse_frames(text: str) -> slice:
    """``"START:STOP[:STEP]"`` -> slice; each part may be empty, STEP may be negative."""
    parts = str(text).split(":")
    if len(parts) not in (2, 3):
        raise ConfigError(f"--frames must be START:STOP[:STEP], got {quote(str(text))}")
    try:
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise ConfigError(
            f"--frames must be START:STOP[:STEP] with integers, got {quote(str(text))}"
        ) from None
    step = vals[2] if len(vals) == 3 else None
    if step == 0:
        raise ConfigError("--frames step must not be 0")
    return slice(vals[0], vals[1], step)


def frame_indices(frames: slice, n: int) -> np.ndarray:
    """The original frame indices ``frames`` picks out of ``n`` (ConfigError when none)."""
    idx = np.arange(n)[frames]
    if len(idx) == 0:
        shown = _text(frames)  # a 4000-digit bound is quoted by its start
        shown = shown if len(shown) <= QUOTE_CHARS else quote(shown)
        raise ConfigError(f"--frames {shown} selects no frame of a {n}-frame sequence")
    return idx.astype(np.int64)


def _text(s: slice) -> str:
    parts = ["" if v is None else str(v) for v in (s.start, s.stop)]
    return ":".join(parts + ([] if s.step is None else [str(s.step)]))


@dataclass(frozen=True, eq=False, kw_only=True)
class FrameSelection(ImageSequence):
    """Frames ``indices`` of ``base`` as an image sequence (module docstring).

    Extra attributes:
        base: the full sequence.
        indices: (N,) int64 original frame index of each frame.
        odometry, odometry_covariance, odometry_sigmas: composed from the base's
            own odometry, or None when it has none.
        config: the base's ``config`` (the synthetic scene's), or None.
    """

    base: ImageSequence
    indices: np.ndarray
    odometry: np.ndarray | None = None
    odometry_covariance: np.ndarray | None = None
    odometry_sigmas: tuple[float, float] | None = None
    #: why the base's own odometry source was left out (a ROS bag's), or None
    odometry_unused: str | None = None
    config: object = field(default=None)
    #: what the reader made of the source (a ROS bag's topics), as the base says it
    notes: tuple[str, ...] = ()

    # ``load`` is ImageSequence's: the base's stored image undistorted at this selection's
    # own ``K`` and distortion, which a camera estimated after the selection replaces
    # (``--frames`` with ``--intrinsics estimate``); the base's would keep the guess.
    def load_raw(self, i: int) -> np.ndarray:
        return self.base.load_raw(int(self.indices[i]))


def source_indices(sequence: ImageSequence) -> np.ndarray:
    """(N,) int64 index of each frame in the sequence as read: a selection's picks, else
    0..N-1 (the time column of a sequence without times, in run and localize outputs)."""
    if isinstance(sequence, FrameSelection):
        return np.asarray(sequence.indices, dtype=np.int64)
    return np.arange(len(sequence), dtype=np.int64)


def select_frames(sequence: ImageSequence, frames: slice | None) -> ImageSequence:
    """``sequence`` restricted to ``frames`` (None: unchanged)."""
    if frames is None:
        return sequence
    idx = frame_indices(frames, len(sequence))
    odo, cov, sig = _composed_odometry(sequence, idx)
    past = _past_the_end(frames, len(sequence))
    return FrameSelection(
        name=sequence.name,
        image_paths=[sequence.image_paths[i] for i in idx],
        stamps_s=None if sequence.stamps_s is None else np.asarray(sequence.stamps_s)[idx],
        K=sequence.K,
        distortion=sequence.distortion,
        wTc_true=None if sequence.wTc_true is None else np.asarray(sequence.wTc_true)[idx],
        image_size=sequence.image_size,
        source_path=sequence.source_path,
        camera_warnings=sequence.camera_warnings,
        frame_warnings=(*sequence.frame_warnings, *past),
        base=sequence,
        indices=idx,
        odometry=odo,
        odometry_covariance=cov,
        odometry_sigmas=sig,
        odometry_unused=getattr(sequence, "odometry_unused", None),
        config=getattr(sequence, "config", None),
        notes=tuple(getattr(sequence, "notes", ())),
    )


def _past_the_end(frames: slice, n: int) -> tuple[str, ...]:
    """A line when ``frames`` names frames past the sequence's last (a slice clips them,
    so ``--frames 0:5000`` on a 1100-frame folder ran 1100 frames unsaid)."""
    step = frames.step or 1
    bound = frames.stop if step > 0 else frames.start
    if bound is None or bound <= (n if step > 0 else n - 1):
        return ()
    shown = _text(frames)
    shown = shown if len(shown) <= QUOTE_CHARS else quote(shown)
    return (f"--frames {shown} reaches past the sequence's {n} frames (0 to {n - 1}): only those are run",)


def _composed_odometry(sequence, idx: np.ndarray):
    """``(odometry (N-1, 4, 4), covariances (N-1, 6, 6), sigmas)`` between picked frames,
    or Nones when the sequence has no odometry."""
    odo = getattr(sequence, "odometry", None)
    if odo is None:
        return None, None, None
    odo = np.asarray(odo, dtype=np.float64)
    cov1 = np.broadcast_to(np.asarray(sequence.odometry_covariance, np.float64), (len(odo), 6, 6))
    out = np.empty((max(len(idx) - 1, 0), 4, 4))
    cov = np.empty((len(out), 6, 6))
    for k, (a, b) in enumerate(zip(idx[:-1], idx[1:], strict=True)):
        lo, hi = (a, b) if b >= a else (b, a)
        T = np.eye(4)
        for j in range(lo, hi):
            T = T @ odo[j]
        out[k] = T if b >= a else invert_pose(T)
        cov[k] = cov1[lo:hi].sum(axis=0)
    sig = getattr(sequence, "odometry_sigmas", None)
    stride = int(np.max(np.abs(np.diff(idx)))) if len(idx) > 1 else 1
    if sig is not None and sig[0] is not None:
        sig = (sig[0] * math.sqrt(stride), sig[1] * math.sqrt(stride))
    return out, cov, sig


@dataclass(frozen=True, eq=False, kw_only=True)
class BlackedOut(FrameSelection):
    """A frame selection whose frames ``black`` (indices into it) load as all-zero
    images: a camera covered or blinded for a while (tracking-loss tests)."""

    black: frozenset = frozenset()

    def load_raw(self, i: int) -> np.ndarray:  # ``load`` undistorts it: black stays black
        image = super().load_raw(i)
        return np.zeros_like(image) if i in self.black else image


def black_out(sequence: ImageSequence, black) -> BlackedOut:
    """``sequence`` with the frames ``black`` (indices) blacked out, everything else kept."""
    sel = sequence if isinstance(sequence, FrameSelection) else select_frames(sequence, slice(None))
    kept = {f.name: getattr(sel, f.name) for f in fields(sel) if f.init and f.name != "black"}
    return BlackedOut(**kept, black=frozenset(int(i) for i in black))
