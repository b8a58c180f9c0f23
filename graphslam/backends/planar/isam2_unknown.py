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

**Splitting** (the way back from pairings that gave one landmark the sightings of two):
in a cluster of landmarks 0.2 m apart seen from 5 m, the first one mapped takes the
sightings of its unmapped neighbour as well, as long as the heading's uncertainty
covers their bearing difference (MRCLAM robot 3's first seconds: heading sigma 0.04
rad against 0.05 rad). Once the neighbour is seen in the same scan it starts a
candidate and is confirmed as a landmark of its own. Then every sighting that the
back end gave to a landmark within :data:`MERGE_REACH_M` of the new one is tested
again at the current estimate: one that the new landmark explains better (a smaller
squared Mahalanobis distance under the sighting's covariance, and inside the
association gate) is moved to it: its factor leaves iSAM2 and an equal one on the
new landmark enters, in one update. A sighting is never split between the two, and a
landmark still takes at most one sighting of a scan (a sighting from a pose that
already sees the new landmark stays where it is).

**Re-association** (the way back from every other wrong pairing, at the end of the
run): a pairing was decided at the estimate of its time, before the sightings that
followed corrected the pose and the landmarks. Lazy data association (Haehnel,
Burgard, Wegbreit and Thrun 2003) revisits such decisions with what is known later;
here, at the end, by coordinate descent on the joint posterior: at the batch
(Levenberg-Marquardt) estimate, every sighting in the graph is tested again against
every landmark, scan by scan, and the scan's sightings are given the landmarks that
explain them best jointly (least total squared Mahalanobis distance under each
sighting's covariance, one sighting per landmark, a move only inside the association
gate: :func:`reassign_scan`); the moves enter iSAM2 in one update, the estimate is
solved again and the pass repeated until nothing moves or ``reassociation_passes``
are spent. A landmark left without a sighting is tied to the one most of its
sightings went to, as a merge. On MRCLAM Dataset 6 without ids the association
accuracy as the estimate pairs the sightings is 0.79-0.89 (0.68-0.81 as decided, when
measured) and every robot's 15 landmarks are recovered by their own estimates, 14 on
four robots without it (``benchmarks/bench_mrclam.py``). The distance leaves out the pose's marginal
on purpose: it is mostly the drift since the start, common to the scan's candidates,
and with it the pass paired worse (accuracy 0.73-0.88).
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import gtsam_convert as conv
from graphslam.backends.planar.landmark_association import Decision, LandmarkAssociator
from slamcore.planar import geometry as se2
from slamcore.planar.records import Observation

#: Landmarks farther apart than this are not tested for a merge, metres: a duplicate
#: sits where the drift put it, and the drift a gate-failing return carries here is
#: about a metre; further apart, the joint test would refuse anyway.
MERGE_REACH_M = 2.0
#: Standard deviation of the factor that ties two merged landmarks, metres: far
#: below any landmark's uncertainty, far above what conditions the system badly.
MERGE_SIGMA_M = 1e-3


def _d2(obs: Observation, wTb: np.ndarray, landmarks_w: np.ndarray) -> np.ndarray:
    """(L,) squared Mahalanobis distances of sighting ``obs`` from each of
    ``landmarks_w`` (L, 2) seen from ``wTb`` (3,), under the sighting's own covariance."""
    predicted = se2.observe(np.broadcast_to(wTb, (len(landmarks_w), 3)), landmarks_w)
    nu = se2.innovation(np.asarray(obs.z)[None], predicted)
    return np.einsum("li,li->l", nu, np.linalg.solve(obs.covariance, nu.T).T)


class UnknownAssociation:
    """Association state of one iSAM2 run (module docstring)."""

    def __init__(self, gate_prob: float, confirm_sightings: int):
        self.associator = LandmarkAssociator(gate_prob, confirm_sightings)
        self.positions: dict[int, np.ndarray] = {}  # landmark id -> last read position
        self.active: list[int] = []  # landmarks offered to association (merged ones leave)
        self.together: set[tuple[int, int]] = set()  # pairs seen in one scan
        self.merged: dict[int, int] = {}  # younger id -> the id it was merged into
        # landmark id -> its sightings in iSAM2: (factor index, sighting as given, as added)
        self.sightings: dict[int, list[tuple[int, Observation, Observation]]] = {}
        # id(observation) -> (pose id, its place in its scan), for the final pairings;
        # ids of observations not kept may be reused, but only kept ones are looked up
        self.slots: dict[int, tuple[int, int]] = {}
        self.moved = 0  # sightings re-association moved
        self.settled = True  # False: its last pass still moved sightings
        self.ran = False  # re-association has run

    def record(self, landmark_id: int, index: int, given: Observation, added: Observation) -> None:
        """The back end added sighting ``given`` (as ``added``: its weighed covariance) of
        ``landmark_id`` as iSAM2's factor ``index``."""
        self.sightings.setdefault(landmark_id, []).append((index, given, added))

    def split(self, isam: gtsam.ISAM2, confirmed: list[int], first_index: int, kernel) -> int:
        """Move to each landmark of ``confirmed`` (just entered ``isam``) the sightings of its
        neighbours it explains better (module docstring, *splitting*), in one iSAM2 update:
        their factors leave, equal ones on the new landmark (``kernel``: the back end's
        sighting kernel and its parameter) enter at indices from ``first_index``. Returns
        the number of factors added."""
        poses: dict[int, np.ndarray] = {}  # estimates read once per split, not per sighting
        moves = [m for lid in confirmed for m in self._explained_better(isam, lid, poses)]
        if not moves:
            return 0
        graph = gtsam.NonlinearFactorGraph()
        for _, given, added, to in moves:
            self.record(to, first_index + graph.size(), given, added)
            graph.add(conv.bearing_range_factor(added, to, *kernel))
        isam.update(graph, gtsam.Values(), [m[0] for m in moves])
        return int(graph.size())

    def _explained_better(
        self, isam: gtsam.ISAM2, new_id: int, poses: dict[int, np.ndarray]
    ) -> list[tuple[int, Observation, Observation, int]]:
        """``(factor index, sighting as given, as added, new_id)`` of each sighting of a
        landmark near ``new_id`` that ``new_id`` explains better, taken off its list;
        ``poses``: the pose estimates read so far in this split, by pose id."""
        pos_new = np.asarray(isam.calculateEstimatePoint2(L(new_id)))
        # a landmark takes one sighting per scan: not from a pose that already sees it
        taken = {given.pose_id for _, given, _ in self.sightings.get(new_id, [])}
        moved = []
        for lid in self.active:  # merged landmarks have left it
            if lid == new_id:
                continue
            pos = np.asarray(isam.calculateEstimatePoint2(L(lid)))
            if np.linalg.norm(pos - pos_new) > MERGE_REACH_M:
                continue
            keep = []
            for index, given, added in self.sightings.get(lid, []):
                wTb = poses.get(given.pose_id)
                if wTb is None:
                    wTb = poses[given.pose_id] = conv.pose2_vector(
                        isam.calculateEstimatePose2(X(given.pose_id))
                    )
                d2 = _d2(given, wTb, np.array([pos, pos_new]))
                if given.pose_id not in taken and d2[1] < d2[0] and d2[1] <= self.associator.gate_d2:
                    moved.append((index, given, added, new_id))
                    taken.add(given.pose_id)
                else:
                    keep.append((index, given, added))
            self.sightings[lid] = keep
        return moved

    def step(self, isam: gtsam.ISAM2, pose_id: int, observations) -> list[Decision]:
        """Decisions for the observations of ``pose_id`` (iSAM2 already holds the pose)."""
        for k, obs in enumerate(observations):
            self.slots[id(obs)] = (pose_id, k)
        wTb = conv.pose2_vector(isam.calculateEstimatePose2(X(pose_id)))
        # gtsam's marginals are in the pose's body frame; the association's Jacobians in the world's
        pose_cov = conv.pose2_covariance_from_gtsam(wTb[2], isam.marginalCovariance(X(pose_id)))
        ids = np.array(self.active, dtype=np.int64)
        cached = np.array([self.positions[j] for j in self.active]).reshape(-1, 2)
        # reach: five sigmas of the farthest sighting's point, plus 0.5 m for a cached
        # position that has moved since it was read
        r_max = max(float(o.z[0]) for o in observations)
        sigma = math.sqrt(
            np.trace(pose_cov[:2, :2])
            + r_max**2 * pose_cov[2, 2]
            + max(np.trace(o.covariance) * max(1.0, r_max**2) for o in observations)
        )
        near = ids[self.associator.near(observations, wTb, cached, 5.0 * sigma + 0.5)].tolist()
        for j in near:
            self.positions[j] = np.asarray(isam.calculateEstimatePoint2(L(j)))
        lm_w = np.array([self.positions[j] for j in near]).reshape(-1, 2)
        joint = pose_cov
        if near:  # iSAM2's joint marginal: pose-landmark correlations are what gate well
            keys = gtsam.KeyVector([X(pose_id)] + [L(j) for j in near])
            joint = conv.pose2_covariance_from_gtsam(wTb[2], isam.jointMarginalCovariance(keys).fullMatrix())
        decisions = self.associator.associate(observations, wTb, np.array(near, dtype=np.int64), lm_w, joint)
        paired = sorted({d.landmark_id for d in decisions if d.landmark_id is not None})
        self.together.update((a, b) for a in paired for b in paired if a < b)
        for d in decisions:
            if d.kind == "confirmed":
                self.positions[d.landmark()] = d.position()
                self.active.append(d.landmark())
        return decisions

    def pairings(self) -> dict[tuple[int, int], int]:
        """``(pose id, place in its scan) -> landmark id`` of every sighting in the graph
        now (a sighting of a merged landmark under the id it was merged into)."""
        return {
            self.slots[id(given)]: lid for lid in self.active for _, given, _ in self.sightings.get(lid, [])
        }

    def reassociate(
        self, isam: gtsam.ISAM2, values: gtsam.Values, first_index: int, kernel
    ) -> tuple[int, list[tuple[int, int, gtsam.BetweenFactorPoint2]]]:
        """One pass of re-association at the estimate ``values`` (module docstring): the
        sightings that move leave ``isam`` and enter again on their new landmarks, in one
        update, at factor indices from ``first_index`` (``kernel``: the back end's
        sighting kernel and its parameter). Returns ``(factors added, ties)``, ``ties``
        as :meth:`merges` gives them, for the landmarks left without a sighting (already
        in ``isam``)."""
        positions = {lid: np.asarray(values.atPoint2(L(lid))) for lid in self.active}
        by_pose: dict[int, list[tuple[int, int, Observation, Observation]]] = {}
        for lid in self.active:
            for index, given, added in self.sightings.get(lid, []):
                by_pose.setdefault(given.pose_id, []).append((lid, index, given, added))
        moves = []
        for pid in sorted(by_pose):
            sights = by_pose[pid]
            wTb = conv.pose2_vector(values.atPose2(X(pid)))
            moves += [
                (sights[k], to) for k, to in reassign_scan(sights, wTb, positions, self.associator.gate_d2)
            ]
        if not moves:
            return 0, []
        gone = {index for (_, index, _, _), _ in moves}
        for lid in self.active:
            self.sightings[lid] = [r for r in self.sightings.get(lid, []) if r[0] not in gone]
        graph = gtsam.NonlinearFactorGraph()
        went: dict[int, dict[int, int]] = {}  # landmark -> where its moved sightings went
        for (lid, _, given, added), to in moves:
            self.record(to, first_index + graph.size(), given, added)
            graph.add(conv.bearing_range_factor(added, to, *kernel))
            went.setdefault(lid, {}).setdefault(to, 0)
            went[lid][to] += 1
        ties = []
        for lid in [j for j in self.active if not self.sightings.get(j) and j in went]:
            keep = max(went[lid].items(), key=lambda kv: (kv[1], -kv[0]))[0]
            self.merged[lid] = keep
            self.active.remove(lid)
            ties.append((keep, lid, _tie(keep, lid)))
            graph.add(ties[-1][2])
        isam.update(graph, gtsam.Values(), sorted(gone))
        self.moved += len(moves)
        return int(graph.size()), ties

    def merges(
        self, isam: gtsam.ISAM2, paired: list[int]
    ) -> list[tuple[int, int, gtsam.BetweenFactorPoint2]]:
        """``(keep, drop, tie)`` of each pair of landmarks found to be one (module
        docstring), tested from the landmarks ``paired`` in the scan just added to ``isam``;
        ``tie`` is the factor that makes them one."""
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
                self.sightings.setdefault(keep, []).extend(self.sightings.pop(drop, []))
                out.append((keep, drop, _tie(keep, drop)))
        return out


def _tie(keep: int, drop: int) -> gtsam.BetweenFactorPoint2:
    """The factor that makes landmark ``drop`` one with ``keep``."""
    return gtsam.BetweenFactorPoint2(
        L(keep), L(drop), gtsam.Point2(0.0, 0.0), gtsam.noiseModel.Isotropic.Sigma(2, MERGE_SIGMA_M)
    )


def reassign_scan(
    sights: list[tuple[int, int, Observation, Observation]],
    wTb: np.ndarray,
    positions: dict[int, np.ndarray],
    gate_d2: float,
) -> list[tuple[int, int]]:
    """``(k, landmark id)`` for each sighting ``sights[k]`` of one scan that the
    landmarks at ``positions`` (id -> (2,) world point) seen from ``wTb`` (3,)
    explain better elsewhere: the assignment of the scan's sightings to distinct
    landmarks with the least total squared Mahalanobis distance under each
    sighting's covariance (``sights``: ``(landmark id now, factor index, sighting
    as given, as added)``). A sighting may always stay where it is; it moves only to
    a landmark within ``gate_d2``."""
    from scipy.optimize import linear_sum_assignment

    ids = sorted({s[0] for s in sights} | set(positions))
    column = {lid: c for c, lid in enumerate(ids)}
    points = np.array([positions[lid] for lid in ids], dtype=np.float64).reshape(-1, 2)
    cost = np.full((len(sights), len(ids)), np.inf)  # inf: a move outside the gate
    for k, (lid, _, given, _) in enumerate(sights):
        d2 = _d2(given, wTb, points)
        allowed = d2 <= gate_d2
        allowed[column[lid]] = True
        cost[k, allowed] = d2[allowed]
    # a finite stand-in for barred pairs: the solver needs a feasible full matching
    finite = np.where(np.isfinite(cost), cost, 1e12)
    rows, cols = linear_sum_assignment(finite)
    return [
        (k, ids[c])
        for k, c in zip(rows.tolist(), cols.tolist(), strict=True)
        if ids[c] != sights[k][0] and np.isfinite(cost[k, c])
    ]
