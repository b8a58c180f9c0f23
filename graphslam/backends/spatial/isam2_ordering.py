"""Where the visual iSAM2 back end asks gtsam to eliminate its variables.

:class:`RootOrderingPolicy` is a part of
:class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` that gives each
``ISAM2.update`` its constrained ordering groups and the keys to re-eliminate
(``predicted_in_root`` and ``newest_pose_last`` in :class:`VisualIsam2Config`). It
owns the one piece of state this produces, the landmark slots the last update put in
the root clique (the back end counts the predictions outside them); it is its own
part because the ordering is a policy of its settings and explicit inputs (the
frames, the pending factors, the mapped landmark ids and a selection of those in
view), not of the back end's internals.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

__all__ = ["RootOrderingPolicy", "ROOT_EXTRA_CANDIDATES", "ROOT_MARGIN"]

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


class RootOrderingPolicy:
    """The ordering hint of the visual iSAM2 back end.

    Attributes:
        root_slots: landmark slots the last hint put in the root (empty: none, or the
            slots have shifted since: :meth:`forget_root`).
    """

    def __init__(self, predicted_in_root: bool, newest_pose_last: bool, max_predictions: int) -> None:
        self.predicted_in_root = predicted_in_root
        self.newest_pose_last = newest_pose_last
        self.max_predictions = max_predictions
        self.root_slots = np.zeros(0, np.int64)

    def forget_root(self) -> None:
        """The slots have shifted (a landmark dropped): the root's are unknown."""
        self.root_slots = np.zeros(0, np.int64)

    def outside_root(self, slots: np.ndarray) -> int:
        """How many of ``slots`` the last hint did not put in the root."""
        return int(np.count_nonzero(~np.isin(slots, self.root_slots)))

    def hint(
        self,
        frames: Sequence[int],
        graph: gtsam.NonlinearFactorGraph,
        landmark_ids: Sequence[int],
        select: Callable[[int, float], np.ndarray],
    ) -> tuple[gtsam.KeyGroupMap | None, gtsam.KeyList]:
        """Keys the next ``ISAM2.update`` eliminates last (None: gtsam's default
        ordering), and keys it re-eliminates though no new factor touches them, for
        the pending factors ``graph`` after ``frames`` (the newest last).
        ``landmark_ids`` are the mapped landmarks' track ids by slot, and
        ``select(count, margin)`` the slots of those in view of the newest pose
        (the back end's selection for its predictions).

        ``predicted_in_root``: the rest of the new factors' keys, then the previous
        pose, then the landmarks the back end's ``predict_observations`` is likely
        to select (chosen the same way at the newest pose's current value, in the
        image grown by ``ROOT_MARGIN``, ``ROOT_EXTRA_CANDIDATES`` more than
        ``max_predictions``), then the newest pose. The last three groups make those
        keys the root clique alone (the rest's separator lacks the newest pose, so
        gtsam does not merge it in), and their joint marginal is read from that
        clique without touching the cliques of the other landmarks in view below
        it. The first group is where gtsam's default ordering puts the new factors'
        keys (last): left to COLAMD among the untouched variables, they were
        eliminated early and every later update re-eliminated a larger tree (1.40x
        the bare update against 1.00x, 300-frame benchmark). Every candidate is
        re-eliminated, though no new factor may touch it (a landmark coming back
        into view): iSAM2 would leave it deep in the tree and ignore its group, and
        a joint marginal reaching it there cost up to 3 s a frame at the loop
        closure of the benchmark room.
        """
        self.root_slots = np.zeros(0, np.int64)
        reelim = gtsam.KeyList()
        if not frames or not (self.newest_pose_last or self.predicted_in_root):
            return None, reelim
        newest = frames[-1]
        order: list[list[int]] = []  # groups of keys, eliminated in this order, after the rest
        if self.predicted_in_root and len(landmark_ids) and len(frames) > 1:
            cap = self.max_predictions
            self.root_slots = select(cap + ROOT_EXTRA_CANDIDATES if cap else 0, ROOT_MARGIN)
            order.append([X(frames[-2])])
            order.append([L(landmark_ids[s]) for s in self.root_slots.tolist()])
            for key in order[-1]:
                reelim.push_back(key)
        order.append([X(newest)])
        new_keys = list(graph.keyVector())  # (iterating a temporary KeySet crashes)
        hinted = {key for keys in order for key in keys}
        if self.predicted_in_root:
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
