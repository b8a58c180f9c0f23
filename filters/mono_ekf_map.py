"""State surgery of the monocular EKF (:class:`filters.mono_ekf.MonoEkf`): adding,
re-parametrising and dropping landmarks.

Functions of the state ``x`` (n,) and covariance ``P`` (n, n) that return new
arrays; the landmarks' bookkeeping (track ids, counters) is the slot store's
(:class:`filters.mono_ekf_slots.LandmarkSlots`).
Landmarks are addressed by slot (state order) through ``off`` (first state
index of each), ``kinds`` (:data:`filters.landmark_params.IDP`, ``AHP`` or
``EUCLIDEAN``) and ``idx`` (padded state indices, (k, 7)).
"""

from __future__ import annotations

import numpy as np

from filters import landmark_params as lp


def farthest_candidates(cand_uv: np.ndarray, taken_uv: np.ndarray, count: int) -> list[int]:
    """Indices into ``cand_uv`` (c, 2) px of ``count`` candidates chosen greedily farthest
    from ``taken_uv`` (t, 2) px and from each other, so new points spread over the image.

    Ties go to the first candidate (input order).
    """
    chosen = []
    dmin = np.full(len(cand_uv), np.inf)
    for t in taken_uv:
        dmin = np.minimum(dmin, np.sum((cand_uv - t) ** 2, axis=1))
    for _ in range(count):
        j = int(np.argmax(dmin))  # first of ties: input order
        chosen.append(j)
        dmin = np.minimum(dmin, np.sum((cand_uv - cand_uv[j]) ** 2, axis=1))
        dmin[j] = -1.0
    return chosen


def augment_with_landmarks(
    x: np.ndarray,
    P: np.ndarray,
    L: np.ndarray,
    G_pose: np.ndarray,
    G_uv: np.ndarray,
    G_rho: np.ndarray,
    var: float,
    sigma_rho: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(x', P')`` with the k new landmarks ``L`` (k, s) appended (undelayed initialisation).

    ``G_pose`` (k, s, 7), ``G_uv`` (k, s, 2), ``G_rho`` (s,): the inverse
    observation model's Jacobians (:func:`filters.landmark_params.init_landmarks`);
    ``var`` the pixel variance (px^2), ``sigma_rho`` the inverse-distance
    prior's std (1/m). Cross-covariances ``G_pose P[:7, :]``; each landmark's
    own block adds its pixel and prior terms (landmarks are correlated only
    through the pose). O(n k s).
    """
    k, s = G_pose.shape[:2]
    n = len(x)
    Gr = G_pose.reshape(k * s, 7)
    P_LX = Gr @ P[:7, :]
    P_LL = Gr @ P_LX[:, :7].T
    own = var * G_uv @ G_uv.transpose(0, 2, 1) + sigma_rho**2 * np.outer(G_rho, G_rho)
    for j in range(k):
        P_LL[j * s : (j + 1) * s, j * s : (j + 1) * s] += own[j]
    P_new = np.empty((n + k * s, n + k * s))
    P_new[:n, :n] = P
    P_new[n:, :n] = P_LX
    P_new[:n, n:] = P_LX.T
    P_new[n:, n:] = 0.5 * (P_LL + P_LL.T)
    return np.concatenate([x, L.reshape(-1)]), P_new


def linear_enough(
    x: np.ndarray, P: np.ndarray, idx: np.ndarray, kinds: np.ndarray, threshold: float, exclude=()
) -> dict:
    """``{slot: (p_w (3,) m, J (3, s))}`` of the landmarks linear enough to become Euclidean.

    Linearity index (Civera et al. 2008) ``L = 4 sigma_d / d |cos alpha|``
    below ``threshold``, over the non-Euclidean landmarks with ``rho > 0``
    not in ``exclude``; ``J`` is the conversion's Jacobian w.r.t. the
    landmark's ``s`` parameters. The camera position is ``x[0:3]``.
    """
    slots = np.array([i for i in np.flatnonzero(kinds != lp.EUCLIDEAN) if i not in exclude], dtype=np.int64)
    if not len(slots):
        return {}
    idx = idx[slots]
    kinds = kinds[slots]
    L = x[idx]
    rows = np.arange(len(slots))
    rho_col = np.where(kinds == lp.IDP, 5, 6)
    rho = L[rows, rho_col]
    var_rho = P[idx[rows, rho_col], idx[rows, rho_col]]
    ok = rho > 0
    if not ok.any():
        return {}
    slots, kinds, L, rho, var_rho = (a[ok] for a in (slots, kinds, L, rho, var_rho))
    p_w, J = lp.to_euclidean(kinds, L)
    ray0 = p_w - L[:, 0:3]  # anchor ray, length |C| / rho
    ray = p_w - x[0:3]
    d0 = np.linalg.norm(ray0, axis=1)
    d = np.linalg.norm(ray, axis=1)
    sigma_d = np.sqrt(np.maximum(var_rho, 0.0)) / rho * d0  # = |C| sigma_rho / rho^2
    cos_a = np.einsum("ki,ki->k", ray0, ray) / (d0 * d)
    lin = 4.0 * sigma_d / d * np.abs(cos_a)
    conv = np.flatnonzero(lin < threshold)
    return {int(slots[j]): (p_w[j], J[j, :, : lp.SIZE[int(kinds[j])]]) for j in conv}


def inverse_distances(x: np.ndarray, idx: np.ndarray, kinds: np.ndarray) -> np.ndarray:
    """Inverse distance (k,) 1/m of every landmark from the camera position ``x[0:3]``.

    With the anchor form ``p = A + C / W`` (``W = rho``, or 1 for a Euclidean
    point), ``1 / |p - c| = W / |W (A - c) + C|``: continuous through ``rho = 0``
    (a point at infinity has inverse distance 0); ``rho < 0`` is clipped to 0.
    """
    L = x[idx]
    W = np.where(kinds == lp.IDP, L[:, 5], np.where(kinds == lp.AHP, L[:, 6], 1.0))
    C = np.zeros((len(L), 3))
    idp, ahp = kinds == lp.IDP, kinds == lp.AHP
    C[idp] = lp.idp_direction(L[idp, 3], L[idp, 4])
    C[ahp] = L[ahp, 3:6]
    W = np.maximum(W, 0.0)
    n = np.linalg.norm(W[:, None] * (L[:, 0:3] - x[0:3]) + C, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, W / n, 0.0)


def euclidean_conversion(
    x: np.ndarray, idx: np.ndarray, kinds: np.ndarray, slot: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """``(p_w (3,) m, J (3, s))`` converting landmark ``slot`` to Euclidean whatever its
    linearity, or None when it is Euclidean already or has ``rho <= 0``."""
    if kinds[slot] == lp.EUCLIDEAN:
        return None
    L = x[idx[slot]][None]
    if L[0, 5 if kinds[slot] == lp.IDP else 6] <= 0:
        return None
    p_w, J = lp.to_euclidean(kinds[slot : slot + 1], L)
    return p_w[0], J[0, :, : lp.SIZE[int(kinds[slot])]]


def euclidean_points(x: np.ndarray, idx: np.ndarray, kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every landmark as a Euclidean point ``p_w`` (k, 3) m, and which are meaningful
    (k,) bool: Euclidean already or ``rho > 0`` (a non-positive inverse distance has
    no Euclidean point)."""
    L = x[idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        p_w, _ = lp.to_euclidean(kinds, L)
    rho = np.where(kinds == lp.IDP, L[:, 5], L[:, 6])
    ok = (kinds == lp.EUCLIDEAN) | (rho > 0)
    return p_w, ok


#: Standard deviations of the inverse distance that must separate it from zero for a
#: landmark's depth to count as measured: within two, its 95 % interval reaches
#: infinity (no parallax yet), and its point is the initial guess's depth.
DEPTH_BOUND_SIGMAS = 2.0


def undetermined_depths(
    x: np.ndarray, P: np.ndarray, idx: np.ndarray, kinds: np.ndarray, prior_var: np.ndarray | None = None
) -> np.ndarray:
    """(k,) bool: inverse-depth landmarks with a point (``rho > 0``, as
    :func:`euclidean_points`) whose ``rho`` is within :data:`DEPTH_BOUND_SIGMAS` of zero,
    or, given each landmark's prior variance of ``rho`` (k,), whose variance is above half
    of it: the sightings told less of the depth than the prior did (information adds, so
    that is posterior information below twice the prior's). The priors put ``rho0`` at
    exactly two sigmas, so a camera that only turned left every landmark a hair inside
    the first test's bound, counted as measured at the guessed depth (hostile pass 13).
    Euclidean landmarks are measured by construction."""
    col = np.where(kinds == lp.IDP, 5, 6)
    rows = idx[np.arange(len(kinds)), col]
    rho, var = x[rows], P[rows, rows]
    bound = DEPTH_BOUND_SIGMAS * np.sqrt(np.maximum(var, 0.0))
    unmeasured = rho <= bound
    if prior_var is not None:
        unmeasured |= var > 0.5 * np.asarray(prior_var, dtype=np.float64)
    return (kinds != lp.EUCLIDEAN) & (rho > 0) & unmeasured


def transform_state(
    x: np.ndarray, P: np.ndarray, off: np.ndarray, kinds: np.ndarray, changes: dict
) -> tuple[np.ndarray, np.ndarray]:
    """``(x', P')`` with the landmark slots in ``changes`` dropped (value None) or
    converted to Euclidean (value ``(p_w, J)``).

    ``X <- f(X)``, ``P <- T P T^T`` with ``T`` the identity on the kept
    entries plus the converted 3 x s blocks ``J``. Kept entries keep their
    order; converted landmarks move to the end of the state, in the order of
    ``changes``, so the kept block is one fancy-index gather
    ``P[keep][:, keep]`` and the converted rows are ``J P[L_i, :]``: O(n^2),
    no n x n product.
    """
    n = len(x)
    keep = np.ones(n, dtype=bool)
    conv = []
    for i, ch in changes.items():
        o, s = int(off[i]), lp.SIZE[int(kinds[i])]
        keep[o : o + s] = False
        if ch is not None:
            conv.append((np.arange(o, o + s), ch[1], ch[0]))
    kidx = np.flatnonzero(keep)
    m, c3 = len(kidx), 3 * len(conv)
    P_new = np.empty((m + c3, m + c3))
    P_new[:m, :m] = P[np.ix_(kidx, kidx)]
    x_new = np.empty(m + c3)
    x_new[:m] = x[kidx]
    if conv:
        Y = np.concatenate([J @ P[src] for src, J, _ in conv])  # (3c, n)
        P_new[m:, :m] = Y[:, kidx]
        P_new[:m, m:] = P_new[m:, :m].T
        for b, (_, _, p_w) in enumerate(conv):
            x_new[m + 3 * b : m + 3 * b + 3] = p_w
            for b2, (src2, J2, _) in enumerate(conv):
                P_new[m + 3 * b : m + 3 * b + 3, m + 3 * b2 : m + 3 * b2 + 3] = (
                    Y[3 * b : 3 * b + 3, src2] @ J2.T
                )
        Pc = P_new[m:, m:]
        Pc[...] = 0.5 * (Pc + Pc.T)
    return x_new, P_new
