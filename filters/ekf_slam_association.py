"""Scan association of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`) when landmark ids are unknown.

Every landmark is predicted at once (:func:`predict_landmarks`), each
observation is gated against all of them (Mahalanobis, 2 dof), and JCBB
(:func:`filters.association.jcbb`) picks the jointly compatible pairing of
the scan (:func:`associate_scan`), from the joint innovation covariance of
the candidate pairs (:func:`pair_covariance`). An unpaired observation is
judged new by its distance to the landmarks *not* paired in the scan
(:func:`unpaired_distances`: mutual exclusion). A pairing inside a gate that
cannot tell its landmark from a new one (:func:`ambiguous_gates`) needs
support. A pairing that only the pose prior chose among landmarks the sensor
tells apart is held (``distinct_d2``). With ``provisional_sightings > 1`` a new
one waits on a :class:`ProvisionalList` first.

Observations are ``z = [range_m, bearing_rad]``; ``P`` is the filter's
covariance buffer (state ``[x, y, theta, m1x, m1y, ...]``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from filters.association import JcbbResult, ambiguous_pairings, individual_candidates, jcbb, mahalanobis_sq_2d
from slamcore.errors import GraphSlamError
from slamcore.planar import geometry as models


class ScanAssociation(NamedTuple):
    """What :func:`associate_scan` decides for one scan of ``m`` observations.

    Attributes:
        hypothesis: (m,) landmark slot of each observation, or None.
        novelty: (m, L) of each observation against each landmark (None without
            landmarks): the log-likelihood ratio of a new landmark over this one
            with the likelihood objective, else the squared Mahalanobis distance.
        jcbb: the search's :class:`~filters.association.JcbbResult` (None when no
            pair passed the gate).
        held: (m,) observations whose pairing only the pose prior chose
            (:func:`filters.association.ambiguous_pairings`): neither paired nor new.
    """

    hypothesis: list[int | None]
    novelty: np.ndarray | None
    jcbb: JcbbResult | None
    held: list[bool]


def predict_landmarks(x: np.ndarray, P: np.ndarray, Pmm: np.ndarray):
    """Predicted z (L, 2), H_x (L, 2, 3), H_m (L, 2, 2) and S - R (L, 2, 2) for every landmark. O(L).

    ``x``, ``P``: the state and covariance (buffers may be larger than the
    state); ``Pmm`` (L, 2, 2): the landmarks' marginal covariances.
    """
    L = len(Pmm)
    xr = x[:3]
    m = x[3 : 3 + 2 * L].reshape(L, 2)
    zhat = models.observe(xr, m)
    H_x, H_m = models.observe_jacobians(xr, m)
    Prr = P[:3, :3]
    Prm = P[:3, 3 : 3 + 2 * L].reshape(3, L, 2).transpose(1, 0, 2)  # (L, 3, 2)
    HxPrm = H_x @ Prm  # (L, 2, 2)
    cross = HxPrm @ H_m.transpose(0, 2, 1)
    S0 = (
        H_x @ Prr @ H_x.transpose(0, 2, 1)
        + cross
        + cross.transpose(0, 2, 1)
        + H_m @ Pmm @ H_m.transpose(0, 2, 1)
    )
    return zhat, H_x, H_m, S0


def pair_covariance(
    P: np.ndarray, H_x: np.ndarray, H_m: np.ndarray, Rs: np.ndarray, pairs: list[tuple[int, int]]
) -> np.ndarray:
    """Joint covariance (2p, 2p) of the innovations of the candidate ``pairs``
    ``(observation i, landmark l)``: ``A P A^T`` over the robot and the landmarks
    involved, plus each observation's ``R_i`` (``Rs`` (m, 2, 2)) on its own block.

    ``H_x``, ``H_m``: every landmark's Jacobians (:func:`predict_landmarks`).
    """
    pair_lm = np.array([p[1] for p in pairs])
    U = sorted(set(pair_lm.tolist()))
    col = {u: 3 + 2 * k for k, u in enumerate(U)}
    idx = [0, 1, 2] + [j for u in U for j in (3 + 2 * u, 4 + 2 * u)]
    Psub = P[np.ix_(idx, idx)]
    A = np.zeros((2 * len(pairs), len(idx)))
    for p, (_, lm) in enumerate(pairs):
        A[2 * p : 2 * p + 2, :3] = H_x[lm]
        A[2 * p : 2 * p + 2, col[lm] : col[lm] + 2] = H_m[lm]
    C = A @ Psub @ A.T
    for p, (i, _) in enumerate(pairs):
        C[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] += Rs[i]
    return C


def associate_scan(
    x: np.ndarray,
    P: np.ndarray,
    Pmm: np.ndarray,
    Z: np.ndarray,
    Rs: np.ndarray,
    *,
    gate: float,
    chi2_prob: float,
    max_candidates: int,
    max_nodes: int,
    likelihood: tuple[float, float] | None = None,
    distinct_d2: float | None = None,
) -> ScanAssociation:
    """Landmark slot (or None) of each observation of one scan, by gating then JCBB.

    ``Z`` (m, 2) observations with covariances ``Rs`` (m, 2, 2); ``gate``:
    the individual chi-square gate (2 dof) of ``chi2_prob``, the joint
    test's probability; at most ``max_candidates`` landmarks per observation
    and ``max_nodes`` pairing tests. Returns a :class:`ScanAssociation`.

    ``distinct_d2``: when given, a pairing that another jointly compatible
    hypothesis gives to a landmark the sensor tells apart (their predicted
    measurements differ by more than ``distinct_d2`` under the two landmarks'
    covariance and the sighting's noise) is held, searched over every compatible
    landmark (:func:`filters.association.ambiguous_pairings`).

    ``likelihood = (new_landmark_density_per_m2, detection_prob)`` makes JCBB
    maximise the likelihood objective (:func:`filters.association.jcbb` with
    ``pair_gain``): a new landmark seen at range r has density ``rho r`` per
    m rad in measurement space. The novelty is then the log-likelihood ratio of
    "new landmark" over "this landmark" (an observation is new where it is > 0
    against every landmark not paired in the scan); without it, the squared
    Mahalanobis distance (new beyond the caller's chi-square gate). With it,
    too, a pairing inside an ambiguous gate (:func:`ambiguous_gates`) that the
    measurement alone does not decide needs a second one in the hypothesis
    (the support rule of :class:`filters.association._LikelihoodSearch`).
    """
    m = len(Z)
    hyp: list[int | None] = [None] * m
    if not len(Pmm):
        return ScanAssociation(hyp, None, None, [False] * m)
    zhat, H_x, H_m, S0 = predict_landmarks(x, P, Pmm)
    nu = models.innovation(Z[:, None, :], zhat[None, :, :])  # (m, L, 2)
    S = S0[None] + Rs[:, None]  # (m, L, 2, 2), built once for d2 and the likelihood terms
    d2 = mahalanobis_sq_2d(nu, S)  # (m, L)
    det_S = _det2(S) if likelihood is not None else None
    # every compatible landmark for the ambiguity test; the closest few for JCBB
    cands = individual_candidates(d2, gate, len(Pmm) if distinct_d2 is not None else max_candidates)
    pairs = [(i, lm) for i, cl in enumerate(cands) for lm in cl]
    if not pairs:
        if likelihood is not None:
            return ScanAssociation(
                hyp, _likelihood_terms(Z, Rs, det_S, d2, *likelihood)[2], None, [False] * m
            )
        return ScanAssociation(hyp, d2, None, [False] * m)
    pair_obs = np.array([p[0] for p in pairs])
    pair_lm = np.array([p[1] for p in pairs])
    rank = np.array([r for cl in cands for r in range(len(cl))])
    few = np.flatnonzero(rank < max_candidates)
    rows = np.stack([2 * few, 2 * few + 1], axis=1).reshape(-1)
    C = pair_covariance(P, H_x, H_m, Rs, pairs)
    extra = {}
    novelty = d2
    if likelihood is not None:
        gain, noise_logdet, novelty = _likelihood_terms(Z, Rs, det_S, d2, *likelihood)
        # A wide-gate pairing stands alone only where the measurement itself,
        # without the prior odds of detection (which such a gate voids), favours
        # the landmark over a new one: N(nu; S) >= lambda, i.e. a novelty at most
        # -log(P_D / (1 - P_D)); otherwise it needs a second one's support.
        detection_log_odds = math.log(likelihood[1] / (1.0 - likelihood[1]))
        ambiguous = _ambiguous(Z, det_S, gate, chi2_prob, *likelihood) & (novelty > -detection_log_odds)
        extra = dict(
            pair_gain=gain[pair_obs[few]],
            noise_logdet=noise_logdet,
            pair_ambiguous=ambiguous[pair_obs[few], pair_lm[few]],
        )
    res: JcbbResult = jcbb(
        Z,
        zhat[pair_lm[few]],
        C[np.ix_(rows, rows)],
        pair_obs[few],
        pair_lm[few],
        chi2_prob=chi2_prob,
        max_nodes=max_nodes,
        individual_d2=d2[pair_obs[few], pair_lm[few]],
        **extra,
    )
    held = [False] * m
    if distinct_d2 is not None:
        chosen = [None if q is None else int(few[q]) for q in res.pairs]
        apart = _apart(chosen, pair_obs, pair_lm, zhat, H_m, P, Rs, distinct_d2)
        pair_nu = nu[pair_obs, pair_lm]
        held = ambiguous_pairings(
            chosen, pair_obs, pair_lm, C, pair_nu, apart, chi2_prob=chi2_prob, max_nodes=max_nodes
        )
    hyp = [None if h else lm for lm, h in zip(res.hypothesis, held, strict=True)]
    return ScanAssociation(hyp, novelty, res, held)


def _apart(chosen, pair_obs, pair_lm, zhat, H_m, P, Rs, distinct_d2: float) -> np.ndarray:
    """(P,) whether each pair's landmark is told apart by the sensor from the landmark
    chosen for its observation: the two predicted measurements' difference under the
    two landmarks' joint covariance (the pose known) and the sighting's noise, beyond
    ``distinct_d2`` (:func:`filters.association.ambiguous_pairings`)."""
    apart = np.zeros(len(pair_obs), dtype=bool)
    for q, (i, lq) in enumerate(zip(pair_obs.tolist(), pair_lm.tolist(), strict=True)):
        if chosen[i] is None or int(pair_lm[chosen[i]]) == lq:
            continue
        lj = int(pair_lm[chosen[i]])
        a, b = 3 + 2 * lj, 3 + 2 * lq
        A = np.hstack([H_m[lj], -H_m[lq]])  # (2, 4): d(zhat_j - zhat_q) / d(m_j, m_q)
        idx = [a, a + 1, b, b + 1]
        D = A @ P[np.ix_(idx, idx)] @ A.T + Rs[i]
        delta = models.innovation(zhat[lj], zhat[lq])
        apart[q] = float(delta @ np.linalg.solve(D, delta)) > distinct_d2
    return apart


def _det2(S: np.ndarray) -> np.ndarray:
    """Determinants of a stack of 2x2 matrices (..., 2, 2)."""
    return S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]


def _likelihood_terms(Z, Rs, det_S, d2, density_per_m2: float, detection_prob: float):
    """Per observation the log-odds of pairing over a new landmark ``gain`` (m,) and
    ``log det(2 pi R_i)`` (m,); per (observation, landmark) the novelty (m, L):
    ``-(gain_i - d2 / 2 - log det(2 pi S_il) / 2)``."""
    r = np.maximum(Z[:, 0], 1e-9)  # the density in (range, bearing) is rho r
    gain = math.log(detection_prob / (1.0 - detection_prob)) - np.log(density_per_m2 * r)
    two_pi = 2.0 * math.pi
    noise_logdet = np.log(np.linalg.det(two_pi * Rs))
    logdet_S = np.log(two_pi**2 * det_S)
    novelty = -(gain[:, None] - 0.5 * d2 - 0.5 * logdet_S)
    return gain, noise_logdet, novelty


def ambiguous_gates(
    Z, Rs, S0, gate: float, gate_prob: float, density_per_m2: float, detection_prob: float
) -> np.ndarray:
    """(m, L) bool: the gate of observation i on landmark l cannot tell that landmark
    from a new one on its own (:class:`filters.association._LikelihoodSearch`'s support rule).

    The gate ``nu^T S^-1 nu < gate`` is an ellipse of area ``pi gate sqrt(det S)``
    in (range, bearing); new landmarks fall in it ``lambda_i = rho r_i`` per m rad
    (the likelihood objective's density), so ``lambda_i V`` are expected there
    (the clutter count of Bar-Shalom & Fortmann's PDA), against ``P_D P_G`` for
    the mapped landmark (detected, and inside its gate). Ambiguous where
    ``lambda_i V >= P_D P_G``: a candidate found in the gate is then a priori no
    likelier the landmark than a new one, so the prior odds of detection
    ``P_D / (1 - P_D)`` that the likelihood objective grants a pairing do not
    hold there (:func:`associate_scan` lets such a pairing stand alone only where
    the measurement's own likelihood ratio favours the landmark). The gate
    quantile ``gate`` and its probability ``gate_prob`` are the individual gate's.
    ``Z`` (m, 2) range (m) and bearing (rad), ``Rs`` (m, 2, 2) their noise, ``S0``
    (L, 2, 2) the landmarks' predicted covariances; GraphSlamError on other shapes.
    """
    Z = _stack(Z, (2,), "Z")
    Rs, S0 = _stack(Rs, (2, 2), "Rs"), _stack(S0, (2, 2), "S0")
    if len(Rs) != len(Z):
        raise GraphSlamError(f"ambiguous_gates: {len(Z)} observations but {len(Rs)} noise matrices")
    return _ambiguous(Z, _det2(S0[None] + Rs[:, None]), gate, gate_prob, density_per_m2, detection_prob)


def _stack(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``a`` as a finite float array (n, *shape); GraphSlamError otherwise."""
    try:
        out = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise GraphSlamError(f"ambiguous_gates: {name} is not an array of numbers") from None
    if out.ndim != 1 + len(shape) or out.shape[1:] != shape or not np.all(np.isfinite(out)):
        raise GraphSlamError(
            f"ambiguous_gates: {name} needs finite shape (n, {', '.join(map(str, shape))}), got {out.shape}"
        )
    return out


def _ambiguous(Z, det_S, gate, gate_prob, density_per_m2, detection_prob) -> np.ndarray:
    """:func:`ambiguous_gates` from the determinants (m, L) of the innovation covariances."""
    r = np.maximum(Z[:, 0], 1e-9)
    expected_new = (density_per_m2 * r)[:, None] * math.pi * gate * np.sqrt(det_S)
    return expected_new >= detection_prob * gate_prob


def unpaired_distances(d2: np.ndarray | None, hypothesis: list[int | None]) -> np.ndarray:
    """(m,) squared Mahalanobis distance of each observation to its nearest landmark
    not paired in the scan (inf without landmarks).

    Mutual exclusion: a landmark paired with another observation of the scan
    cannot also be this one, so it does not stop this one from being new.
    """
    if d2 is None:
        return np.full(len(hypothesis), np.inf)
    taken = [s for s in hypothesis if s is not None]
    if taken:
        d2 = d2.copy()
        d2[:, taken] = np.inf
    return d2.min(axis=1)


class ProvisionalList:
    """Points sighted but not yet mapped (unknown association), matched by a world-frame gate.

    Each entry is the last inverse-observed point ``pt`` (2,) m, its
    covariance ``cov`` (2, 2) (``G_x P_rr G_x^T + G_z R G_z^T``, correlations
    ignored) and its sighting count.
    """

    def __init__(self, sightings: int, gate: float):
        self.sightings = sightings  # sightings before a point enters the map
        self.gate = gate  # chi-square (2 dof) on the difference of two points
        self.entries: list[dict | None] = []

    def sight(self, pt: np.ndarray, cov: np.ndarray, hit: set[int]) -> bool:
        """Count a sighting of ``pt`` against the nearest entry within the gate not
        already sighted this scan (``hit``, updated), or start an entry.

        True when the entry reaches ``sightings``: it leaves the list (its slot
        stays None until :meth:`compact`, so the indices in ``hit`` stay valid).
        """
        best: tuple[int, dict] | None = None  # (index, entry) of the nearest entry
        best_d2 = self.gate
        for k, e in enumerate(self.entries):
            if e is None or k in hit:
                continue
            d = pt - e["pt"]
            d2 = float(mahalanobis_sq_2d(d, cov + e["cov"]))
            if d2 < best_d2:
                best, best_d2 = (k, e), d2
        if best is None:
            self.entries.append({"pt": pt, "cov": cov, "count": 1})
            hit.add(len(self.entries) - 1)
            return False
        k, e = best
        e["count"] += 1
        e["pt"], e["cov"] = pt, cov
        hit.add(k)
        if e["count"] >= self.sightings:
            self.entries[k] = None
            return True
        return False

    def compact(self) -> None:
        """Drop the slots of entries that entered the map (end of a scan)."""
        self.entries = [e for e in self.entries if e is not None]
