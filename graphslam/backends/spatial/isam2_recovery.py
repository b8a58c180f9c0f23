"""What the visual iSAM2 back end does when gtsam meets an indeterminate system.

A mixin of :class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` (its own
module to keep the back end's size readable): it works on the back end's
landmark slots and iSAM2 instance.
"""

from __future__ import annotations

import numpy as np
from gtsam.symbol_shorthand import L

from graphslam.backends import factorization as fact
from slamcore.errors import GraphSlamError

__all__ = ["IndeterminateRecovery", "MAX_DROPS_PER_UPDATE"]

#: Landmarks one update may drop before giving up (each drop re-solves the whole graph;
#: more than a few in one frame means the frame itself is broken, not one match).
MAX_DROPS_PER_UPDATE = 5


class IndeterminateRecovery:
    """``_recover`` and ``_drop_landmark`` for the visual iSAM2 back end."""

    def _recover(self, exc: RuntimeError) -> None:
        """Cholesky met an indeterminate system near a landmark: the landmark goes.

        Seen when a wrong match accepted in a wide ellipse sends a landmark far off
        (on synthetic-images with an upper bound of the innovation covariance tried
        instead of the exact one, ellipses 6.5x larger: one landmark 12 km away), its
        depth then barely observable: QR does not help (the back-substitution meets the same near-zero
        pivot). So the landmark and its factors leave the graph, its track is ignored
        from then on (``stats()["landmarks_dropped_indeterminate"]``) and the rest is
        re-solved from the current values; repeated while gtsam names a landmark. A
        pose named is one line (GraphSlamError). Each re-solve starts again from the
        failed iSAM2 (it holds every factor and value), without all landmarks dropped so far."""
        failed, dropped = self._isam, []
        for _ in range(MAX_DROPS_PER_UPDATE):
            if not fact.is_indeterminate(exc):
                raise exc
            name = fact.failed_variable(exc)
            tid = int(name[1:]) if name[:1] == "l" and name[1:].isdigit() else None
            if tid is None or tid not in self._slot:
                break
            self._drop_landmark(tid)
            dropped.append(L(tid))
            try:
                self._isam = fact.rebuild_without(failed, self.config.isam2_params(), dropped)
                return
            except RuntimeError as again:
                exc = again
        raise GraphSlamError(f"isam2 (visual): indeterminate linear system near "
                             f"{fact.failed_variable(exc) or '?'} at frame {self._frames[-1]}") from None

    def _drop_landmark(self, tid: int) -> None:
        """Forget landmark ``tid``: its slot is removed (the later ones shift down)
        and its track is ignored from then on."""
        s, n = self._slot.pop(tid), self._n_lm
        for arr in (self._lm_pos, self._lm_nobs, self._lm_sigma, self._lm_last, self._lm_read):
            arr[s:n - 1] = arr[s + 1:n].copy()
        del self._lm_ids[s]
        for t in self._lm_ids[s:]:
            self._slot[t] -= 1
        self._n_lm -= 1
        self._root_slots = np.zeros(0, np.int64)
        self._rejected.add(tid)
        self._stats["landmarks_dropped_indeterminate"] += 1
