"""The per-scan arithmetic of FastSLAM (:class:`filters.fastslam.FastSlam`): landmark EKF
steps of every (particle, observation) pair at once, and one step of FastSLAM 2.0's pose
proposal.

Functions of explicit inputs, no state of their own: the particle set
(:class:`filters.fastslam_particles.ParticleSet`) passes its landmark maps
(:class:`~filters.fastslam_map.ParticleMaps`, written copy-on-write), its poses, its
log-weights (added to in place where a step weighs the particles) and its recovery counter
(:class:`filters.numerics.Recoveries`).

Landmark steps (:func:`landmark_steps`): one elementwise pass over all (particle,
observation) pairs of a scan whose observations go to distinct landmarks of each particle
(mutual exclusion, or distinct known ids), so the updates are independent of their order;
with known association the pairs form an (N, K) block, else flat arrays. The 2.0 proposal
(:func:`refine_proposal`) is sequential over the observations (each refines the Gaussian
the next one is linearised at) and vectorised over particles.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from filters.fastslam_map import ParticleMaps
from filters.fastslam_math import (
    all_positive_definite3,
    floor_hits,
    inv2,
    landmark_update,
    new_landmark,
    positive_definite,
    positive_definite2,
    proposal_update,
    raise_to_floor,
    range_bearing,
    sandwich,
    spread_noise,
    tr,
    widened_d2,
)
from filters.numerics import REL_VARIANCE_FLOOR, Recoveries
from filters.numerics import symmetrise as sym
from slamcore.planar.records import Observation

__all__ = [
    "floor_noise",
    "joseph_where_indefinite",
    "landmark_joseph",
    "landmark_steps",
    "refine_proposal",
    "weight_shares",
]


def weight_shares(maps: ParticleMaps, p: np.ndarray, obs: list[Observation], k) -> np.ndarray | None:
    """Share of each (record ``p``, observation ``obs[k]``) pair's log-likelihood that a
    particle's weight takes: :meth:`~slamcore.planar.sighting_correlation.SightingCorrelation.weight_share`
    of the time since the record's latest sighting by the same sensor (``p`` and ``k``
    broadcast together; a record last seen by another sensor, or never with a time,
    counts in full). None when no observation states a correlation and a time (every
    share is 1).

    Why the weights only: a particle's weight is the evidence for its path, and a burst
    of sightings whose errors repeat is one piece of evidence, not one per sighting (on
    MRCLAM the range errors of one landmark correlate 0.97 within 0.3 s); counted in
    full, a burst collapses the particles onto the path that explains its shared error.
    The landmark EKFs and FastSLAM 2.0's proposal keep the stated noise: inflated there
    as well (measured earlier, :mod:`slamcore.planar.sighting_correlation`), the weaker
    sightings left the paths to the odometry."""
    timed = [o.correlation is not None and o.stamp_s is not None for o in obs]
    if not any(timed):
        return None
    p = np.asarray(p)
    kk = np.broadcast_to(np.asarray(k), np.broadcast_shapes(p.shape, np.shape(k)))
    p = np.broadcast_to(p, kk.shape)
    out = np.ones(kk.shape)
    for j, o in enumerate(obs):
        model = o.correlation
        if model is None or o.stamp_s is None:
            continue
        sel = kk == j
        rec = p[sel]
        same = maps.pool_sensor[rec] == model.sensor
        dt = np.where(same, o.stamp_s - maps.pool_seen[rec], np.inf)
        out[sel] = model.weight_share(dt)
    return out


def landmark_steps(
    maps: ParticleMaps,
    obs: list[Observation],
    cols: list[np.ndarray],
    poses: np.ndarray,
    recoveries: Recoveries,
    *,
    known: bool,
    logw: np.ndarray | None = None,
    log_p0: Callable[[np.ndarray], float] | None = None,
    temper: bool = False,
    dof: float = math.inf,
    robust: bool = False,
    skip: np.ndarray | None = None,
) -> None:
    """EKF update (or initialisation) of each particle's landmark ``cols[k]`` of every
    observation ``k``, all (particle, observation) pairs in one elementwise pass. Each
    new record keeps the observation's time and sensor (:class:`ParticleMaps`).

    ``known``: known association (one column per observation for all particles).
    ``logw``: when given, the 1.0 weights are added to it in place: the measurement
    likelihood of an updated landmark, and ``log_p0(R)`` of a new one when ``log_p0`` is
    given (unknown association); with ``temper``, an updated landmark's likelihood is
    taken at its :func:`weight_shares`, under the sensor's error law (``dof``:
    :func:`~filters.fastslam_math.log_likelihood`); with ``robust`` (after 2.0's draw), an
    updated landmark takes the sighting's noise times the law's factor
    (:func:`~filters.fastslam_math.t_noise_factor`). The observations must go to distinct
    landmarks of a particle (mutual exclusion, or distinct known ids); the updates are then
    independent of their order. ``skip`` (N, K): pairs left out (2.0's misread ids).
    """
    Z = np.array([o.z for o in obs], dtype=float)
    R = np.array([o.covariance for o in obs], dtype=float)
    stamps = np.array([-np.inf if o.stamp_s is None else o.stamp_s for o in obs], dtype=float)
    sensors = np.array([-1 if o.correlation is None else o.correlation.sensor for o in obs], dtype=np.int32)
    seen = (stamps, sensors)
    T = maps.table
    rows = np.arange(len(poses))
    if known:  # one column per observation for all particles
        col = np.array([int(c[0]) for c in cols])
        ptr = T[:, col]
    else:
        col = np.stack(cols, axis=1)
        ptr = T[rows[:, None], col]
    old = ptr >= 0
    new = ~old
    if skip is not None:
        old, new = old & ~skip, new & ~skip
    for mask, update in ((old, True), (new, False)):
        if mask.any():
            pairs = _pairs(mask, col, rows)
            if update:
                shares = obs if temper else None
                _update_pairs(maps, pairs, ptr, Z, R, poses, recoveries, logw, seen, shares, dof, robust)
            else:
                _init_pairs(
                    maps, pairs, Z, R, poses, recoveries, logw if log_p0 is not None else None, log_p0, seen
                )


def _pairs(mask: np.ndarray, col: np.ndarray, rows: np.ndarray):
    """``(particles, k, cols)`` index arrays of the True (particle, observation) pairs:
    (N, 1), (1, K') and (N or 1, K') when every observation's column is all-True or
    all-False (always so with known association), flat (M,) arrays otherwise."""
    every = mask.all(axis=0)
    if np.array_equal(every, mask.any(axis=0)):
        k = np.flatnonzero(every)
        c = col[k] if col.ndim == 1 else col[:, k]
        return rows[:, None], k[None, :], c[None, :] if col.ndim == 1 else c
    i, k = np.nonzero(mask)
    return i, k, col[k] if col.ndim == 1 else col[i, k]


def _add_weights(logw: np.ndarray, particles: np.ndarray, logl: np.ndarray) -> None:
    if particles.ndim == 2:
        logw += logl.sum(axis=1)
    else:
        logw += np.bincount(particles, logl, minlength=len(logw))


def _update_pairs(
    maps: ParticleMaps,
    pairs,
    ptr,
    Z,
    R,
    poses,
    recoveries: Recoveries,
    logw: np.ndarray | None,
    seen: tuple[np.ndarray, np.ndarray],
    tempered_by: list[Observation] | None,
    dof: float,
    robust: bool,
) -> None:
    i, k, c = pairs
    p = ptr[i, k]
    m, P = maps.pool_mean[p], maps.pool_cov[p]
    mx, my = m[..., 0], m[..., 1]
    p00, p01, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 1]
    a, b, cc, d, nu_r, nu_b = range_bearing(poses[i, 0], poses[i, 1], poses[i, 2], mx, my, Z[k, 0], Z[k, 1])
    r00, r01, r11 = R[k, 0, 0], R[k, 0, 1], R[k, 1, 1]
    mv = np.maximum(p00, p11)
    r00, r11 = floor_noise(recoveries, r00, r11, mv * (a * a + b * b), mv * (cc * cc + d * d))
    dmx, dmy, P_new, logl, f = landmark_update(
        a, b, cc, d, nu_r, nu_b, p00, p01, p11, r00, r01, r11, dof, robust
    )
    ok = positive_definite2(*P_new)
    if not ok.all():  # the repair takes the noise the gain took
        r_used = (r00 * f, r01 * f, r11 * f)
        P_new = landmark_joseph(recoveries, ~ok, (p00, p01, p11), (a, b, cc, d), r_used, P_new)
    if logw is not None:
        share = None if tempered_by is None else weight_shares(maps, p, tempered_by, k)
        _add_weights(logw, i, logl if share is None else logl * share)
    _write(maps, i, c, (mx + dmx, my + dmy), P_new, seen, k)


def _init_pairs(
    maps: ParticleMaps,
    pairs,
    Z,
    R,
    poses,
    recoveries: Recoveries,
    logw: np.ndarray | None,
    log_p0: Callable[[np.ndarray], float] | None,
    seen: tuple[np.ndarray, np.ndarray],
) -> None:
    i, k, c = pairs
    z0, z1 = Z[k, 0], Z[k, 1]
    r00, r01, r11 = R[k, 0, 0], R[k, 0, 1], R[k, 1, 1]
    mean, P0, g = new_landmark(poses[i, 0], poses[i, 1], poses[i, 2], z0, z1, r00, r01, r11)
    # a 1e-9 m range against a 10 deg bearing makes P0 rank one in float64: floor R
    # against P0's own spread ([1, 1/r^2]: |rows of H_m|^2)
    mv = np.maximum(P0[0], P0[2])
    f00, f11 = floor_noise(recoveries, r00, r11, mv, mv * (1.0 / np.maximum(z0, 1e-300) ** 2))
    if f00 is not r00 or f11 is not r11:
        P0 = spread_noise(g, f00, r01, f11)
    _write(maps, i, c, mean, P0, seen, k)
    if logw is not None and log_p0 is not None:
        lp0 = np.array([log_p0(r) for r in R])
        _add_weights(logw, i, np.broadcast_to(lp0[k], np.broadcast_shapes(i.shape, k.shape)))


def _write(maps: ParticleMaps, i, c, mean, cov, seen: tuple[np.ndarray, np.ndarray], k) -> None:
    """New pool records of the pairs' landmarks from their entries (upper triangles), with
    the time and sensor ``seen`` (per observation) of observation ``k`` of each pair."""
    shape = np.broadcast_shapes(np.shape(i), np.shape(c), np.shape(mean[0]))
    sl = maps.allocate(i, c)
    m = maps.pool_mean[sl].reshape(shape + (2,))
    P = maps.pool_cov[sl].reshape(shape + (2, 2))
    m[..., 0], m[..., 1] = mean
    P[..., 0, 0], P[..., 0, 1], P[..., 1, 1] = cov
    P[..., 1, 0] = cov[1]
    kk = np.broadcast_to(k, shape).ravel()
    maps.pool_seen[sl] = seen[0][kk]
    maps.pool_sensor[sl] = seen[1][kk]


def floor_noise(recoveries: Recoveries, r00, r11, pv0, pv1):
    """``R``'s variances raised to the float64 floor of :mod:`filters.numerics` against the
    prior variances ``pv0, pv1`` (counted in ``recoveries``); the same objects when nothing
    is raised."""
    hit, f0, f1 = floor_hits(r00, r11, pv0, pv1)
    if not hit.any():
        return r00, r11
    recoveries.add("noise_floor", int(np.count_nonzero(hit)))
    return raise_to_floor(r00, f0), raise_to_floor(r11, f1)


def landmark_joseph(recoveries: Recoveries, bad, P, H, R, P_new):
    """The landmark covariances ``P_new`` (entries) recomputed in Joseph form where
    the short form lost definiteness (:func:`joseph_where_indefinite`)."""

    def mats(e):  # (nb, 2, 2) of the bad pairs from upper-triangle or 4 entries
        e = e if len(e) == 4 else (e[0], e[1], e[1], e[2])
        full = [np.broadcast_to(x, bad.shape) for x in e]
        return np.stack(full, axis=-1)[bad].reshape(-1, 2, 2)

    Pm, Hm, Rm = mats(P), mats(H), mats(R)
    PHt = Pm @ tr(Hm)
    K = PHt @ inv2(Hm @ PHt + Rm)[0]
    fixed = joseph_where_indefinite(recoveries, mats(P_new), Pm, K, Hm, lambda: Rm)
    out = tuple(np.array(np.broadcast_to(e, bad.shape)) for e in P_new)
    for e, (r, c) in zip(out, ((0, 0), (0, 1), (1, 1)), strict=True):
        e[bad] = fixed[:, r, c]
    return out


def joseph_where_indefinite(recoveries: Recoveries, P_new, P, K, H, noise):
    """``P_new`` (n, k, k), recomputed in Joseph form ``(I - K H) P (I - K H)^T + K R K^T``
    (positive semi-definite by construction) where the short form lost definiteness.

    ``noise()`` gives ``R`` (2, 2) or (n, 2, 2), built only when needed.
    """
    bad = ~positive_definite(P_new)
    if np.any(bad):
        recoveries.add("joseph_fallback", int(np.count_nonzero(bad)))
        R = np.broadcast_to(noise(), (len(P),) + (2, 2))[bad]
        IKH = np.eye(P.shape[-1]) - K[bad] @ H[bad]
        P_new = P_new.copy()
        P_new[bad] = sym(IKH @ P[bad] @ tr(IKH) + K[bad] @ R @ tr(K[bad]))
    return P_new


def refine_proposal(
    maps: ParticleMaps,
    o: Observation,
    p: np.ndarray,
    x: np.ndarray,
    Sx: np.ndarray,
    careful: bool,
    recoveries: Recoveries,
    dof: float = math.inf,
    misread: tuple[np.ndarray, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, np.ndarray]:
    """2.0: the proposal N(x, Sx) of some particles refined by observation ``o`` of their
    landmark records ``p``: ``(x_new, S_new, logl, ok, misread)``, ``logl`` the particles'
    weights under the sensor's error law (``dof``).

    ``misread``: ``(C, d2_gate)``, the particle cloud's pose covariance (3, 3) and a
    squared Mahalanobis gate. A particle whose innovation lies beyond the gate under
    ``H_x (Sx + C) H_x^T + H_m P H_m^T + R`` keeps its proposal unrefined (the returned
    (n,) mask is True there, and the caller leaves its landmark record too); its weight
    still takes ``logl``. A barcode misread as
    another landmark's (MRCLAM robot 5 read landmark 8, 2.9 m ahead, as landmark 18, 6 m
    behind, four frames running) otherwise pulled every particle's pose by the full
    Kalman step, 0.14 rad a frame, and the run lost the robot for 500 frames. ``C``
    widens the gate by the cloud's spread: after a stretch without sightings the
    particles' drift from their maps is about that spread (the EKF gates with its pose
    covariance for the same reason), and a sighting that closes such a loop must pull.

    ``careful``: symmetrise and check the new covariance (Joseph form where it lost
    definiteness); else it is neither, and ``ok`` says whether ``L`` was positive
    definite for every particle (see :meth:`ParticleSet._proposal
    <filters.fastslam_particles.ParticleSet._proposal>`)."""
    R = o.covariance
    m, P = maps.pool_mean[p], maps.pool_cov[p]
    Pf = P.reshape(-1, 4)
    p00, p01, p11 = Pf[:, 0], Pf[:, 1], Pf[:, 3]
    a, b, c, d, nu_r, nu_b = range_bearing(x[:, 0], x[:, 1], x[:, 2], m[:, 0], m[:, 1], o.z[0], o.z[1])
    (h00, h01, h11), _ = sandwich(a, b, c, d, p00, p01, p11)
    r00, r11 = _proposal_floor(recoveries, R, Pf, Sx, a, b, c, d)
    # the noise besides the pose's (landmark and measurement) is HmPHmt + Rf
    noise = (h00 + r00, h01 + R[0, 1], h11 + r11)
    neg_dmu, S_new, logl, K, ok, L = proposal_update(Sx, a, b, c, d, nu_r, nu_b, *noise, dof=dof)
    x_new = x - neg_dmu  # heading unwrapped: bearings are wrapped, and so is the draw
    out = np.zeros(len(a), dtype=bool)
    if misread is not None:
        C, gate_d2 = misread
        out = widened_d2(L, C, a, b, c, d, nu_r, nu_b) > gate_d2
        if out.any():
            x_new = np.where(out[:, None], x, x_new)
            S_new = np.where(out[:, None, None], Sx, S_new)
    if careful:
        S_new = sym(S_new)
        if not all_positive_definite3(S_new):
            H_x = np.zeros((len(a), 2, 3))
            H_x[:, 0, 0], H_x[:, 0, 1], H_x[:, 1, 0], H_x[:, 1, 1] = -a, -b, -c, -d
            H_x[:, 1, 2] = -1.0
            n = np.stack(np.broadcast_arrays(noise[0], noise[1], noise[1], noise[2]), -1)
            S_new = joseph_where_indefinite(
                recoveries, S_new, Sx, -np.stack(K, -1), H_x, lambda: n.reshape(-1, 2, 2)
            )
    return x_new, S_new, logl, ok, out


def _proposal_floor(recoveries: Recoveries, R, Pf, Sx, a, b, c, d):
    """2.0: ``R``'s variances raised to the float64 floor (:func:`floor_noise`) against the
    prior variances ``var(P) |H_m rows|^2 + var(Sx) |H_x rows|^2`` (largest variances
    of each), after a cheap bound over all particles that clears the usual case."""
    cd = c * c + d * d
    big_P = np.maximum.reduce(Pf[:, ::3], axis=None)
    big_S = np.maximum.reduce(Sx.reshape(-1, 9)[:, ::4], axis=None)
    big_cd = np.maximum.reduce(cd)
    slack = 1.0 + 1e-9  # |H_m row 0|^2 = 1 up to round-off
    if (
        R[0, 0] >= REL_VARIANCE_FLOOR * (big_P + big_S) * slack
        and R[1, 1] >= REL_VARIANCE_FLOOR * (big_P * big_cd + big_S * (big_cd + 1.0)) * slack
    ):
        return R[0, 0], R[1, 1]  # NaN variances fail the bound and take the exact test
    mvP = np.maximum(Pf[:, 0], Pf[:, 3])
    mvS = np.maximum.reduce(Sx.reshape(-1, 9)[:, ::4], axis=1)
    ab = a * a + b * b
    return floor_noise(recoveries, R[0, 0], R[1, 1], (mvP + mvS) * ab, mvP * cd + mvS * (cd + 1.0))
