"""Which older images may answer a query: the recent-frame exclusion that fits the input.

An image resembles the images just before it because they are recent, not
because the camera came back: those must not answer its query. How many to
exclude depends on the input (the ``mode`` of
:class:`loopclosure.detector.LoopDetectorConfig`; ``"auto"`` picks):

- ``"video"``: consecutive frames overlap heavily. The most recent
  ``exclude_recent_s`` seconds are excluded when the images have timestamps,
  else the most recent ``exclude_recent`` frames; temporal consistency over
  ``consistency_k`` consecutive queries applies (:mod:`loopclosure.detector`).
- ``"keyframes"``: a sparse folder, consecutive images barely overlap (photos
  taken a few steps apart). A frame or time window would exclude most of the
  folder; instead the previous image is excluded, and so is every earlier
  one still linked to the query by a chain of consecutive images that
  overlap (ORB-SLAM excludes a keyframe's covisible neighbours from its loop
  candidates in the same spirit; Mur-Artal et al., T-RO 2015, Sec. VII-A).
  Consecutive queries see different places, so temporal consistency cannot
  be asked: one geometrically verified query suffices.

``"auto"`` measures the overlap of consecutive images (share of features
with a ratio-test, cross-checked match: :func:`consecutive_overlap`) and
chooses keyframes when the median is below ``keyframe_overlap``.
"""

from __future__ import annotations

import re
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from loopclosure.matching import match_descriptors

__all__ = ["Mode", "consecutive_overlap", "choose_mode", "recent_window", "timestamps_from_names", "MODES"]

#: ``[loops] mode`` values (module docstring).
Mode = Literal["covisibility", "auto", "video", "keyframes"]
MODES = typing.get_args(Mode)

#: Features compared per image when measuring overlap: the strongest ones
#: (ORB output is sorted by response), enough for a share to two decimals.
OVERLAP_FEATURES = 500


def consecutive_overlap(desc_a: np.ndarray, desc_b: np.ndarray) -> float:
    """Share of features (of the image with fewer) that have a ratio-test, mutual match."""
    a = np.asarray(desc_a, np.uint8)[:OVERLAP_FEATURES]
    b = np.asarray(desc_b, np.uint8)[:OVERLAP_FEATURES]
    if min(len(a), len(b)) < 2:
        return 0.0
    return len(match_descriptors(a, b)) / min(len(a), len(b))


def choose_mode(mode: str, overlaps: Sequence[float], keyframe_overlap: float) -> str:
    """``mode`` unless it is ``"auto"``: then keyframes when the median overlap is below
    ``keyframe_overlap``, else video."""
    if mode != "auto":
        return mode
    if len(overlaps) == 0:
        return "video"  # one image: nothing to exclude either way
    return "keyframes" if float(np.median(overlaps)) < keyframe_overlap else "video"


def recent_window(
    i: int, mode: str, config, overlaps: Sequence[float], timestamps: Sequence[float] | None = None
) -> int:
    """How many images just before image ``i`` its query must not return.

    ``config``: its ``exclude_recent``, ``exclude_recent_s`` and
    ``keyframe_overlap`` (:class:`loopclosure.detector.LoopDetectorConfig`);
    ``overlaps[k]`` is the overlap of images k and k+1 (known for k < i);
    ``timestamps`` (seconds, one per image so far) or None.
    """
    if mode == "keyframes":
        n = 1  # the previous image always
        while i - n - 1 >= 0 and overlaps[i - n - 1] >= config.keyframe_overlap:
            n += 1
        return min(n, i)
    if timestamps is not None:
        t = np.asarray(timestamps[:i], float)
        return int(np.count_nonzero(t > timestamps[i] - config.exclude_recent_s))
    return min(config.exclude_recent, i)


_NUMBER = re.compile(r"[0-9]+\.[0-9]+\Z")


def timestamps_from_names(paths: Sequence[Path]) -> np.ndarray | None:
    """Seconds from file names such as ``1305031102.175304.png`` (TUM RGB-D, EuRoC in ns).

    Returns None unless every stem is a decimal number with a fraction part
    (``000012.png`` is a frame counter, not a time) and they increase.
    """
    stems = [Path(p).stem for p in paths]
    if not stems or not all(_NUMBER.match(s) for s in stems):
        return None
    t = np.array([float(s) for s in stems])
    return t if np.all(np.diff(t) > 0) else None
