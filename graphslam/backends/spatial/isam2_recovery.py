"""What the visual iSAM2 back end does when gtsam meets an indeterminate system.

:func:`recover_dropping_landmarks` is a part of
:class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` that owns no state: it
takes the failed iSAM2, its settings, the mapped landmarks and a way to forget one,
and returns the iSAM2 to go on with. It is its own part because the retry loop is
about gtsam's failure (which variable it names, how often to retry), not about how
the back end keeps its landmarks.
"""

from __future__ import annotations

from collections.abc import Callable, Container

import gtsam
from gtsam.symbol_shorthand import L

from graphslam.backends import factorization as fact
from graphslam.backends.spatial.isam2_config import VisualIsam2Config
from slamcore.errors import GraphSlamError

__all__ = ["recover_dropping_landmarks", "MAX_DROPS_PER_UPDATE"]

#: Landmarks one update may drop before giving up (each drop re-solves the whole graph;
#: more than a few in one frame means the frame itself is broken, not one match).
MAX_DROPS_PER_UPDATE = 5


def recover_dropping_landmarks(
    exc: RuntimeError,
    failed: gtsam.ISAM2,
    config: VisualIsam2Config,
    mapped: Container[int],
    drop: Callable[[int], None],
    frame: int,
) -> gtsam.ISAM2:
    """Cholesky met an indeterminate system near a landmark: the landmark goes.

    ``exc`` is what ``failed.update`` raised at frame ``frame``; ``mapped`` holds the
    track ids of the mapped landmarks, and ``drop(track id)`` forgets one (it is no
    longer in ``mapped`` afterwards). Returns a fresh iSAM2 (``config``'s settings).

    Seen when a wrong match accepted in a wide ellipse sends a landmark far off
    (on synthetic-images with an upper bound of the innovation covariance tried
    instead of the exact one, ellipses 6.5x larger: one landmark 12 km away), its
    depth then barely observable: QR does not help (the back-substitution meets the same near-zero
    pivot). So the landmark and its factors leave the graph, its track is ignored
    from then on (``stats()["landmarks_dropped_indeterminate"]``) and the rest is
    re-solved from the current values; repeated while gtsam names a landmark. A
    pose named is one line (GraphSlamError). Each re-solve starts again from the
    failed iSAM2 (it holds every factor and value), without all landmarks dropped so far."""
    dropped = []
    for _ in range(MAX_DROPS_PER_UPDATE):
        if not fact.is_indeterminate(exc):
            raise exc
        name = fact.failed_variable(exc)
        tid = int(name[1:]) if name[:1] == "l" and name[1:].isdigit() else None
        if tid is None or tid not in mapped:
            break
        drop(tid)
        dropped.append(L(tid))
        try:
            return fact.rebuild_without(failed, config.isam2_params(), dropped)
        except RuntimeError as again:
            exc = again
    raise GraphSlamError(
        f"isam2 (visual): indeterminate linear system near "
        f"{fact.failed_variable(exc) or '?'} at frame {frame}"
    ) from None
