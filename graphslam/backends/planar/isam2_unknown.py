"""Unknown data association for the 2-D iSAM2 back end: the part between iSAM2's
marginals and the associator (:mod:`.landmark_association`).

It owns what association needs across frames: the associator and its provisional
landmarks, the last read landmark positions (to pick the landmarks near a scan
without reading all of them), which landmarks were seen in one scan, and the
landmarks merged into others. Per scan it reads the joint marginal of the pose and
the landmarks near it from iSAM2 and returns the decisions; the back end adds the
factors.

**Merging** (the way back from a wrong "new landmark" decision): after a run
through a long stretch without sightings, the pose can come back further off
than the gate admits, and the landmarks it then sees are confirmed a second time.
Each scan, every landmark it paired is tested against the others within
:data:`MERGE_REACH_M` that were never seen in the same scan as it: the squared
Mahalanobis distance of their difference under iSAM2's exact joint marginal of the
two (cross term included), against the association gate. A pair within it, with no
other partner within it, is one landmark: the back end ties the two with a
zero-difference factor of :data:`MERGE_SIGMA_M` (which also closes the loop the
duplicate hid), and the younger id stops being offered to association and
reported. Two distinct landmarks a range sigma apart are kept apart by the test:
both are known to centimetres once seen a few times, and any two seen in one scan
are distinct by construction.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import gtsam_convert as conv
from graphslam.backends.planar.landmark_association import Decision, LandmarkAssociator

#: Landmarks farther apart than this are not tested for a merge, metres: a duplicate
#: sits where the drift put it, and the drift a gate-failing return carries here is
#: about a metre; further apart, the joint test would refuse anyway.
MERGE_REACH_M = 2.0
#: Standard deviation of the factor that ties two merged landmarks, metres: far
#: below any landmark's uncertainty, far above what conditions the system badly.
MERGE_SIGMA_M = 1e-3


class UnknownAssociation:
    """Association state of one iSAM2 run (module docstring)."""

    def __init__(self, gate_prob: float, confirm_sightings: int):
        self.associator = LandmarkAssociator(gate_prob, confirm_sightings)
        self.positions: dict[int, np.ndarray] = {}  # landmark id -> last read position
        self.active: list[int] = []  # landmarks offered to association (merged ones leave)
        self.together: set[tuple[int, int]] = set()  # pairs seen in one scan
        self.merged: dict[int, int] = {}  # younger id -> the id it was merged into

    def step(self, isam: gtsam.ISAM2, pose_id: int, observations) -> list[Decision]:
        """Decisions for the observations of ``pose_id`` (iSAM2 already holds the pose)."""
        wTb = conv.pose2_vector(isam.calculateEstimatePose2(X(pose_id)))
        pose_cov = np.asarray(isam.marginalCovariance(X(pose_id)))
        ids = np.array(self.active, dtype=np.int64)
        cached = np.array([self.positions[j] for j in self.active]).reshape(-1, 2)
        # reach: five sigmas of the farthest sighting's point, plus 0.5 m for a cached
        # position that has moved since it was read
        r_max = max(float(o.z[0]) for o in observations)
        sigma = math.sqrt(np.trace(pose_cov[:2, :2]) + r_max**2 * pose_cov[2, 2]
                          + max(np.trace(o.covariance) * max(1.0, r_max**2) for o in observations))
        near = ids[self.associator.near(observations, wTb, cached, 5.0 * sigma + 0.5)].tolist()
        for j in near:
            self.positions[j] = np.asarray(isam.calculateEstimatePoint2(L(j)))
        lm_w = np.array([self.positions[j] for j in near]).reshape(-1, 2)
        joint = pose_cov
        if near:  # iSAM2's joint marginal: pose-landmark correlations are what gate well
            keys = gtsam.KeyVector([X(pose_id)] + [L(j) for j in near])
            joint = isam.jointMarginalCovariance(keys).fullMatrix()
        decisions = self.associator.associate(observations, wTb, np.array(near, dtype=np.int64),
                                              lm_w, joint)
        paired = sorted({d.landmark_id for d in decisions if d.landmark_id is not None})
        self.together.update((a, b) for a in paired for b in paired if a < b)
        for d in decisions:
            if d.kind == "confirmed":
                self.positions[d.landmark()] = d.position()
                self.active.append(d.landmark())
        return decisions

    def merges(self, isam: gtsam.ISAM2, paired: list[int]) -> list[tuple[int, int]]:
        """``(keep, drop)`` pairs of landmarks found to be one (module docstring),
        tested from the landmarks ``paired`` in the scan just added to ``isam``."""
        out = []
        gate = self.associator.gate_d2
        for a in paired:
            if a in self.merged:
                continue
            pos_a = np.asarray(isam.calculateEstimatePoint2(L(a)))
            partners = []
            for b in self.active:
                if b == a or b in self.merged or (min(a, b), max(a, b)) in self.together:
                    continue
                if np.linalg.norm(self.positions[b] - pos_a) > MERGE_REACH_M:
                    continue
                pos_b = np.asarray(isam.calculateEstimatePoint2(L(b)))
                P = isam.jointMarginalCovariance(gtsam.KeyVector([L(a), L(b)])).fullMatrix()
                D = P[:2, :2] + P[2:, 2:] - P[:2, 2:] - P[2:, :2]
                delta = pos_a - pos_b
                if float(delta @ np.linalg.solve(D, delta)) <= gate:
                    partners.append(b)
            if len(partners) == 1:
                keep, drop = sorted((a, partners[0]))
                self.merged[drop] = keep
                self.active.remove(drop)
                out.append((keep, drop))
        return out
