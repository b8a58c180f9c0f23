"""Negative information: landmarks the sensor should have seen and did not.

A filter with unknown data association starts a landmark from any sighting
that fits no mapped one, so a wrong association or a drifted pose leaves a
duplicate behind: a second estimate of a landmark whose sightings now go to
the first. The filter never sees the duplicate again, yet it stays in the map
(and in the EKF's state) for good. The textbook remedy is the landmark's
existence evidence: every frame in which the landmark lies inside the sensor's
field but is not reported counts against it (Montemerlo et al., FastSLAM,
AAAI 2002, Sec. 5; Thrun, Burgard & Fox, Probabilistic Robotics, Sec. 10.3.4).

The decision here is Page's CUSUM test (Biometrika 1954) of "the landmark is
there, reported with probability ``p`` per frame" against "nothing is there":
each miss in the field adds ``-log(1 - p)`` to the landmark's score, a
sighting resets it to 0, and the landmark is removed when the score reaches
``-log(alpha)``, that is when the misses since its last sighting have
probability at most ``alpha`` under "it is there". Resetting on a sighting
(rather than adding evidence for every sighting, as an existence log-odds
does) lets a duplicate that was fed for a while go once it stops being fed;
a real landmark is removed with probability ``alpha`` per run of misses.

Which landmarks lie in the field is the owning filter's business (it knows
its pose and its uncertainty); this module keeps the scores (FastSLAM keeps one per
particle and landmark beside its map, :mod:`filters.fastslam_map`, with the steps of
:func:`cusum_steps`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from slamcore.errors import GraphSlamError


def cusum_steps(detection_prob: float, alpha: float) -> tuple[float, float]:
    """``(miss, limit)`` of the test (module docstring): what one miss in the field adds to
    a landmark's score, and the score at which it is removed.

    Args:
        detection_prob: probability that a landmark in the field is reported in a
            frame that reports something, in (0, 1].
        alpha: probability of removing a landmark that is there, per run of
            misses, in (0, 1).
    """
    if not 0.0 < detection_prob <= 1.0 or not 0.0 < alpha < 1.0:
        raise GraphSlamError(f"missed sightings: detection_prob {detection_prob}, alpha {alpha}")
    # log(0) for a sensor that sees everything in its field: one miss is enough
    miss = math.inf if detection_prob >= 1.0 else -math.log1p(-detection_prob)
    return miss, -math.log(alpha)


class MissedSightings:
    """The CUSUM score of each landmark id (see the module docstring).

    Args:
        detection_prob: probability that a landmark in the field is reported in a
            frame that reports something, in (0, 1].
        alpha: probability of removing a landmark that is there, per run of
            misses, in (0, 1).
    """

    def __init__(self, detection_prob: float, alpha: float):
        self._miss, self._limit = cusum_steps(detection_prob, alpha)
        self._score: dict[int, float] = {}

    def frame(self, seen: Iterable[int], missed: Iterable[int]) -> list[int]:
        """Score one frame: ``seen`` ids were reported, ``missed`` ids lay in the field
        and were not (an id in both counts as seen). Returns the missed ids to remove,
        in the order given, and forgets them."""
        seen_ids = set(seen)
        for lid in seen_ids:
            self._score.pop(lid, None)
        out = []
        for lid in missed:
            if lid in seen_ids:
                continue
            score = self._score.get(lid, 0.0) + self._miss
            if score >= self._limit:
                self._score.pop(lid, None)
                out.append(lid)
            else:
                self._score[lid] = score
        return out

    def score(self, lid: int) -> float:
        """The landmark's score, 0 right after a sighting."""
        return self._score.get(lid, 0.0)
