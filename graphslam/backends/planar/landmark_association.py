"""Data association for the 2-D iSAM2 back end when observations carry no landmark id.

A part that owns its state (the provisional candidates) and decides, given the
back end's pose estimate and the joint marginal covariance of the pose and the
landmarks near it (:mod:`.isam2_unknown` reads them from iSAM2); it knows nothing
of gtsam. Per scan:

1. **Individual compatibility** of every observation with every landmark near it:
   the squared Mahalanobis distance of the innovation under ``S = J P J^T + R``
   with the exact joint marginal ``P`` of pose and landmark (cross terms
   included: a landmark seen a moment ago is known relative to the pose far
   better than either alone), against the chi-square (2 dof) quantile
   ``gate_prob``; the :data:`MAX_CANDIDATES` closest per observation go to JCBB,
   every compatible one to the ambiguity test (step 3).
2. **Joint compatibility** (JCBB, Neira and Tardos 2001; the EKF's
   :func:`filters.association.jcbb`): the largest set of pairings whose stacked
   innovation is jointly compatible under its joint covariance. The innovations
   of one scan share the pose's error; their correlation is what tells two
   landmarks a range sigma apart (MRCLAM: 0.18-0.26 m against 0.13 m) when the
   pose's heading is less certain than the bearings. Each landmark takes at most
   one observation of a scan.
3. **Ambiguity**: JCBB picks one hypothesis even when another pairs the same
   observations as well. Where the two give an observation landmarks the sensor
   tells apart, the choice was made by the pose prior, not by the sighting, and the
   observation is *held* (no factor, no candidate). The sensor tells two landmarks
   apart when their predicted measurements differ, with the pose known (the map's
   uncertainty and the sighting's noise), beyond the ``gate_prob`` quantile of its
   error: Gaussian unless the data's sensor field says its errors are Student-t
   (:meth:`LandmarkAssociator.set_error_dof`; MRCLAM: 5.1 dof, a 0.999 quantile of
   71 against the Gaussian's 13.8). Landmarks closer than that are a choice no
   sighting can make, and the pairing stands, as before. Why: after a long turn
   without sightings (MRCLAM robot 3, heading sigma 11 deg), one sighting fits
   landmarks a metre apart; pairing it to the nearest under the prior turned the
   heading 15 deg the wrong way with a sigma of 5 deg, and every later scan paired
   to that (ATE 0.74 m against 0.10 m with ids). Held, the next scan of four
   sightings pins the heading (ATE 0.12 m; ``benchmarks/bench_mrclam.py``).
4. **Provisional landmarks**: an observation JCBB leaves unpaired starts or
   extends a *candidate* (its position and covariance from the observation, the
   measurement noise and the pose marginal). A candidate takes one sighting per
   pose and enters the map after ``confirm_sightings`` sightings each compatible
   with it (the course's landmark management: a provisional list, so that one
   outlier does not become a landmark); its buffered sightings then enter the
   graph with it.

Returned decisions are plain records; the back end adds the factors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from filters.association import ambiguous_pairings, chi2_quantile, individual_candidates, jcbb, t2_quantile
from slamcore.errors import GraphSlamError
from slamcore.planar import geometry as se2

#: Individually compatible landmarks kept per observation for the joint test (the
#: EKF's default, ``[ekf] jcbb_max_candidates``): landmarks here come in clusters of
#: two or three.
MAX_CANDIDATES = 3
#: Pairing tests per scan (the EKF's default budget; scans here hold 1-6 sightings).
MAX_JCBB_NODES = 2000


@dataclass(eq=False)
class Candidate:
    """A landmark not yet in the map: its estimate and the sightings that support it."""

    mean_w: np.ndarray  # (2,)
    covariance: np.ndarray  # (2, 2)
    sightings: list = field(default_factory=list)  # Observation records


@dataclass(frozen=True)
class Decision:
    """What to do with one observation: ``kind`` is ``"landmark"`` (factor to
    ``landmark_id``), ``"confirmed"`` (new landmark ``landmark_id`` at ``mean_w``
    with the factors of ``sightings``), ``"candidate"`` (kept on the provisional
    list) or ``"held"`` (ambiguous: left out, module docstring step 3)."""

    kind: str
    landmark_id: int | None = None
    mean_w: np.ndarray | None = None
    sightings: tuple = ()

    def landmark(self) -> int:
        """``landmark_id`` of a ``"landmark"`` or ``"confirmed"`` decision."""
        if self.landmark_id is None:
            raise GraphSlamError(f"association: a {self.kind!r} decision names no landmark")
        return self.landmark_id

    def position(self) -> np.ndarray:
        """``mean_w`` of a ``"confirmed"`` decision."""
        if self.mean_w is None:
            raise GraphSlamError(f"association: a {self.kind!r} decision places no landmark")
        return self.mean_w


class LandmarkAssociator:
    """Unknown data association with a provisional list (module docstring)."""

    def __init__(self, gate_prob: float, confirm_sightings: int):
        self.gate_prob = gate_prob
        self.gate_d2 = chi2_quantile(gate_prob, 2)
        # two landmarks the sensor tells apart (step 3): Gaussian errors until the data's
        # sensor says otherwise (set_error_dof)
        self.distinct_d2 = self.gate_d2
        self.confirm_sightings = confirm_sightings
        self.candidates: list[Candidate] = []
        self._next_id = 0

    def set_error_dof(self, dof: float) -> None:
        """The sightings' errors are Student-t with ``dof`` degrees of freedom about their
        stated covariance (``inf``: Gaussian): two landmarks are told apart beyond that
        error's ``gate_prob`` quantile (module docstring, step 3)."""
        self.distinct_d2 = t2_quantile(self.gate_prob, dof)

    def near(self, observations, wTb: np.ndarray, landmarks_w: np.ndarray, reach_m: float) -> np.ndarray:
        """Indices of the landmarks (M, 2) within ``reach_m`` of any observed point:
        the only ones whose marginals the back end needs to fetch."""
        if len(landmarks_w) == 0 or not observations:
            return np.zeros(0, dtype=np.int64)
        pts = se2.inverse_observe(wTb[None], np.array([o.z for o in observations]))
        dist = np.linalg.norm(pts[:, None, :] - landmarks_w[None, :, :], axis=2)
        return np.flatnonzero(np.min(dist, axis=0) <= reach_m)

    def associate(
        self, observations, wTb: np.ndarray, ids: np.ndarray, landmarks_w: np.ndarray, joint_cov: np.ndarray
    ) -> list[Decision]:
        """Decisions for one scan.

        Args:
            observations: range-bearing Observation records of one pose.
            wTb: (3,) pose estimate.
            ids: (M,) candidate landmark ids (those near, :meth:`near`);
            landmarks_w: (M, 2) their estimates.
            joint_cov: (3 + 2M, 3 + 2M) joint marginal covariance of the pose and
                those landmarks, in that order (cross terms included).
        """
        m = len(observations)
        z = np.array([o.z for o in observations]).reshape(m, 2)
        R = np.array([o.covariance for o in observations]).reshape(m, 2, 2)
        hypothesis, held = self._joint(z, R, wTb, landmarks_w, joint_cov)
        pose_cov = joint_cov[:3, :3]
        decisions = []
        for obs, j, hold in zip(observations, hypothesis, held, strict=True):
            if hold:
                decisions.append(Decision("held"))
            elif j is not None:
                decisions.append(Decision("landmark", int(ids[j])))
            else:  # jointly compatible with no landmark: evidence of one not yet mapped
                decisions.append(self._provisional(obs, wTb, pose_cov))
        return decisions

    def _joint(self, z, R, wTb, landmarks_w, joint_cov) -> tuple[list[int | None], list[bool]]:
        """Per observation, the landmark column JCBB pairs it with (or None), and whether
        that pairing is held as ambiguous (step 3 of the module docstring).

        The innovations of one scan share the pose's error, and a landmark seen a
        moment ago is known relative to the pose far better than either alone:
        the exact joint covariance ``J P J^T + R`` of the candidate pairs (P the
        joint marginal of pose and landmarks) is what tells two landmarks a range
        sigma apart when the pose is less certain than the bearings.
        """
        m, k = len(z), len(landmarks_w)
        if k == 0:
            return [None] * m, [False] * m
        z_hat = se2.observe(wTb[None], landmarks_w)  # (M, 2)
        H_x, H_m = se2.observe_jacobians(wTb[None], landmarks_w)
        J = np.zeros((k, 2, 3 + 2 * k))  # Jacobian of each landmark's prediction
        J[:, :, :3] = H_x
        for j in range(k):
            J[j, :, 3 + 2 * j : 5 + 2 * j] = H_m[j]
        S0 = np.einsum("jac,cd,jbd->jab", J, joint_cov, J)  # (M, 2, 2)
        nu = se2.innovation(z[:, None, :], z_hat[None])  # (m, M, 2)
        d2 = np.einsum("ija,ijab,ijb->ij", nu, np.linalg.inv(S0[None] + R[:, None]), nu)
        # every compatible landmark for the ambiguity test; the closest few for JCBB
        cands = individual_candidates(d2, self.gate_d2, k)
        pair_obs = np.array([i for i, c in enumerate(cands) for _ in c], dtype=np.int64)
        pair_lm = np.array([j for c in cands for j in c], dtype=np.int64)
        if pair_obs.size == 0:
            return [None] * m, [False] * m
        rank = np.array([r for c in cands for r in range(len(c))], dtype=np.int64)
        Jp = J[pair_lm].reshape(-1, 3 + 2 * k)  # (2P, 3 + 2M)
        C = Jp @ joint_cov @ Jp.T
        for p, i in enumerate(pair_obs.tolist()):
            C[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] += R[i]
        few = np.flatnonzero(rank < MAX_CANDIDATES)
        rows = np.stack([2 * few, 2 * few + 1], axis=1).reshape(-1)
        result = jcbb(
            z,
            z_hat[pair_lm[few]],
            C[np.ix_(rows, rows)],
            pair_obs[few],
            pair_lm[few],
            chi2_prob=self.gate_prob,
            max_nodes=MAX_JCBB_NODES,
            individual_d2=d2[pair_obs[few], pair_lm[few]],
        )
        chosen = [None if p is None else int(few[p]) for p in result.pairs]
        Jm = J.copy()
        Jm[:, :, :3] = 0.0  # the predictions' dependence on the map alone (pose known)
        apart = self._apart(chosen, pair_obs, pair_lm, z_hat, R, Jm, joint_cov)
        nu = se2.innovation(z[pair_obs], z_hat[pair_lm])
        held = ambiguous_pairings(
            chosen, pair_obs, pair_lm, C, nu, apart, chi2_prob=self.gate_prob, max_nodes=MAX_JCBB_NODES
        )
        return result.hypothesis, held

    def _apart(self, chosen, pair_obs, pair_lm, z_hat, R, Jm, joint_cov) -> np.ndarray:
        """(P,) whether each pair's landmark is told apart by the sensor from the one
        chosen for its observation (module docstring, step 3): their predicted
        measurements' difference under the map's uncertainty (``Jm``: the
        predictions' Jacobians with the pose columns zeroed) and the sighting's noise,
        beyond ``distinct_d2``."""
        apart = np.zeros(len(pair_obs), dtype=bool)
        for q, (i, jq) in enumerate(zip(pair_obs.tolist(), pair_lm.tolist(), strict=True)):
            if chosen[i] is None or int(pair_lm[chosen[i]]) == jq:
                continue
            j = int(pair_lm[chosen[i]])
            delta = se2.innovation(z_hat[j], z_hat[jq])
            Jd = Jm[j] - Jm[jq]
            D = Jd @ joint_cov @ Jd.T + R[i]
            apart[q] = float(delta @ np.linalg.solve(D, delta)) > self.distinct_d2
        return apart

    @staticmethod
    def _costs(z, R, wTb, pose_cov, means_w, covs):
        """``d2`` and ``d2 + log det S`` of every (observation, point), (m, M)."""
        z_hat = se2.observe(wTb[None], means_w)
        H_x, H_m = se2.observe_jacobians(wTb[None], means_w)
        S0 = H_x @ pose_cov @ np.swapaxes(H_x, 1, 2) + H_m @ covs @ np.swapaxes(H_m, 1, 2)
        S = S0[None] + R[:, None]
        nu = se2.innovation(z[:, None, :], z_hat[None])
        d2 = np.einsum("ija,ijab,ijb->ij", nu, np.linalg.inv(S), nu)
        return d2, d2 + np.linalg.slogdet(S)[1]

    def _provisional(self, obs, wTb: np.ndarray, pose_cov: np.ndarray) -> Decision:
        """Extend the compatible candidate (the most likely) or start one; confirm it
        after ``confirm_sightings`` sightings. A candidate takes one sighting per pose:
        two observations of one scan are two landmarks."""
        z = np.asarray(obs.z, dtype=np.float64)
        best = None
        open_ = [c for c in self.candidates if c.sightings[-1].pose_id != obs.pose_id]
        if open_:  # one sighting per pose: two observations of a scan are two landmarks
            means = np.array([c.mean_w for c in open_])
            covs = np.array([c.covariance for c in open_])
            d2, nll = self._costs(z[None], np.asarray(obs.covariance)[None], wTb, pose_cov, means, covs)
            ok = np.flatnonzero(d2[0] <= self.gate_d2)
            if ok.size:
                best = open_[int(ok[np.argmin(nll[0, ok])])]
        point = se2.inverse_observe(wTb, z)
        G_x, G_z = se2.inverse_observe_jacobians(wTb, z)
        cov = G_z @ obs.covariance @ G_z.T + G_x @ pose_cov @ G_x.T
        if best is None:
            self.candidates.append(Candidate(point, cov, [obs]))
            return Decision("candidate")
        # information-weighted fusion of the candidate and the new point
        info_old, info_new = np.linalg.inv(best.covariance), np.linalg.inv(cov)
        best.covariance = np.linalg.inv(info_old + info_new)
        best.mean_w = best.covariance @ (info_old @ best.mean_w + info_new @ point)
        best.sightings.append(obs)
        if len(best.sightings) < self.confirm_sightings:
            return Decision("candidate")
        self.candidates.remove(best)
        new_id = self._next_id
        self._next_id += 1
        return Decision("confirmed", new_id, best.mean_w.copy(), tuple(best.sightings))
