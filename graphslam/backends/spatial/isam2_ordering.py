"""Where the visual iSAM2 back end asks gtsam to eliminate its variables.

A mixin of :class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` (its own
module to keep the back end's size readable): it reads the back end's pending
factor graph, frames and landmark slots, and gives each ``ISAM2.update`` its
constrained ordering groups and the keys to re-eliminate (``predicted_in_root``
and ``newest_pose_last`` in :class:`VisualIsam2Config`).
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

__all__ = ["RootOrdering", "ROOT_EXTRA_CANDIDATES", "ROOT_MARGIN"]

#: Landmarks put in the root beyond ``max_predictions`` (``predicted_in_root``):
#: the selection made before the update can differ from the one made after it
#: at the image border and between landmarks seen equally often. A landmark
#: predicted outside the root still gets its exact covariance, only slower
#: (``stats()["predicted_outside_root"]``: 1 in 2990 predictions in the benchmark;
#: none of 5565 on real images: KITTI 07's 160 frames, derived odometry seeds 0-2
#: with ``benchmarks/kitti07_visual.toml``, and seed 2 without it).
ROOT_EXTRA_CANDIDATES = 5
#: ... and chosen in the image grown by this fraction of its size each side (13
#: pixels at VGA): the landmarks the update moves into view are at the border.
ROOT_MARGIN = 0.02


class RootOrdering:
    """``_ordering_hint`` for the visual iSAM2 back end."""

    def _ordering_hint(self) -> tuple[gtsam.KeyGroupMap | None, gtsam.KeyList]:
        """Keys the next ``ISAM2.update`` eliminates last (None: gtsam's default
        ordering), and keys it re-eliminates though no new factor touches them.

        ``predicted_in_root``: the rest of the new factors' keys, then the previous
        pose, then the landmarks :meth:`predict_observations` is likely to select
        (chosen the same way at the newest pose's current value, in the image grown
        by ``ROOT_MARGIN``, ``ROOT_EXTRA_CANDIDATES`` more than ``max_predictions``),
        then the newest pose. The last three groups make those keys the root clique
        alone (the rest's separator lacks the newest pose, so gtsam does not merge
        it in), and their joint marginal is read from that clique without touching
        the cliques of the other landmarks in view below it. The first group is
        where gtsam's default ordering puts the new factors' keys (last): left to
        COLAMD among the untouched variables, they were eliminated early and every
        later update re-eliminated a larger tree (1.40x the bare update against
        1.00x, 300-frame benchmark). Every candidate is re-eliminated, though no new
        factor may touch it (a landmark coming back into view): iSAM2 would leave it
        deep in the tree and ignore its group, and a joint marginal reaching it
        there cost up to 3 s a frame at the loop closure of the benchmark room.
        """
        self._root_slots = np.zeros(0, np.int64)
        reelim = gtsam.KeyList()
        if not self._frames or not (self.config.newest_pose_last or self.config.predicted_in_root):
            return None, reelim
        newest = self._frames[-1]
        order: list[list[int]] = []  # groups of keys, eliminated in this order, after the rest
        if self.config.predicted_in_root and self._n_lm and len(self._frames) > 1:
            cap = self.config.max_predictions
            self._root_slots = self._select_in_view(
                self._pose(newest), cap + ROOT_EXTRA_CANDIDATES if cap else 0, margin=ROOT_MARGIN)
            order.append([X(self._frames[-2])])
            order.append([L(self._lm_ids[s]) for s in self._root_slots.tolist()])
            for key in order[-1]:
                reelim.push_back(key)
        order.append([X(newest)])
        new_keys = list(self._graph.keyVector())  # (iterating a temporary KeySet crashes)
        hinted = {key for keys in order for key in keys}
        if self.config.predicted_in_root:
            order.insert(0, [key for key in new_keys if key not in hinted])
        order = [keys for keys in order if keys]
        # ccolamd wants every group number below the count of variables it orders,
        # of which the new factors' and the re-eliminated keys are a lower bound
        if len(order) >= len(hinted.union(new_keys)):
            order = order[-1:]
        groups = gtsam.KeyGroupMap()
        for number, keys in enumerate(order, start=1):
            for key in keys:
                groups.insert2(key, number)
        return groups, reelim
