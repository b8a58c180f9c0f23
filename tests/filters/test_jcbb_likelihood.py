"""JCBB's likelihood objective (``[ekf] jcbb_objective = "likelihood"``, issue 17 item 4)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from filters.association import chi2_quantile, jcbb
from filters.ekf_slam_association import ambiguous_gates, associate_scan, predict_landmarks
from filters.ekf_slam_config import EkfSlamConfig
from graphslam import registry
from graphslam.evaluation import planar as metrics
from graphslam.pipelines import planar as pipeline
from slamcore.errors import ConfigError
from slamcore.planar import geometry as models

#: log(P_D / (1 - P_D)) - log(rho r) at P_D 0.9, rho 0.015 / m2, r 6 m.
GAIN = math.log(9.0) - math.log(0.015 * 6.0)
R = np.diag([0.2 ** 2, math.radians(10.0) ** 2])
NOISE_LOGDET = math.log(np.linalg.det(2 * math.pi * R))
#: Loop broken: final ATE above this times the known-association ATE (issue 17).
BROKEN_LOOP_RATIO = 2.0


def _one(S: np.ndarray, d2: float, gain: float = GAIN):
    """One observation, one candidate whose innovation has squared distance d2 under S."""
    z_pred = np.array([[6.0, 0.0]])
    z = z_pred + np.array([[math.sqrt(d2 * S[0, 0]), 0.0]])
    return jcbb(z, z_pred, S, np.array([0]), np.array([0]), chi2_prob=0.99,
                pair_gain=np.array([gain]), noise_logdet=np.array([NOISE_LOGDET]))


def test_a_wide_gate_does_not_buy_a_pairing():
    """d2 = 4 passes the 0.99 gate (9.21) either way; against a landmark known to
    5 m the pairing explains the sighting worse than a new landmark, against one
    known to 0.2 m much better."""
    d2 = 4.0
    assert d2 < chi2_quantile(0.99, 2)
    wide = np.diag([25.0, 0.5])
    count = jcbb(np.array([[6.0 + 2 * 5.0, 0.0]]), np.array([[6.0, 0.0]]), wide,
                 np.array([0]), np.array([0]), chi2_prob=0.99)
    assert count.hypothesis == [0]  # the count objective takes it
    assert _one(wide, d2).hypothesis == [None]
    assert _one(np.diag([0.05, 0.01]), d2).hypothesis == [0]


def _exhaustive_best(C, nu, pair_obs, pair_lm, gain, m, ambiguous=None):
    """Best score over every hypothesis (one pair per observation at most, one per
    landmark; with ``ambiguous``, never exactly one ambiguous pair)."""
    best, best_h = 0.0, ()
    options = [[None] + [p for p in range(len(pair_obs)) if pair_obs[p] == i] for i in range(m)]
    for choice in itertools.product(*options):
        pairs = [p for p in choice if p is not None]
        if len({pair_lm[p] for p in pairs}) < len(pairs) or not pairs:
            continue
        if ambiguous is not None and sum(bool(ambiguous[p]) for p in pairs) == 1:
            continue
        rows = np.array([[2 * p, 2 * p + 1] for p in pairs]).reshape(-1)
        Cs = C[np.ix_(rows, rows)]
        v = nu[rows]
        nis = float(v @ np.linalg.solve(Cs, v))
        if nis > chi2_quantile(0.99, 2 * len(pairs)):
            continue
        score = sum(gain[p] for p in pairs) - 0.5 * nis \
            - 0.5 * math.log(np.linalg.det(2 * math.pi * Cs))
        if score > best:
            best, best_h = score, tuple(sorted(pairs))
    return best_h


@pytest.mark.parametrize("seed, with_support_rule", [(s, s % 2 == 1) for s in range(12)])
def test_branch_and_bound_finds_the_exhaustive_optimum(seed, with_support_rule):
    rng = np.random.default_rng(seed)
    m, L = 4, 3
    pair_obs = np.repeat(np.arange(m), L)
    pair_lm = np.tile(np.arange(L), m)
    A = rng.normal(size=(2 * len(pair_obs), 5)) * rng.uniform(0.1, 1.5)
    C = A @ A.T + np.kron(np.eye(len(pair_obs)), R)
    z_pred = np.column_stack([rng.uniform(3, 8, len(pair_obs)), rng.uniform(-1, 1, len(pair_obs))])
    z = np.column_stack([rng.uniform(3, 8, m), rng.uniform(-1, 1, m)])
    z[pair_obs[::L], :] = z_pred[::L] + rng.normal(scale=0.3, size=(m, 2))
    gain = rng.uniform(0.0, 6.0, len(pair_obs))
    ambiguous = rng.random(len(pair_obs)) < 0.5 if with_support_rule else None
    res = jcbb(z, z_pred, C, pair_obs, pair_lm, chi2_prob=0.99, max_nodes=10 ** 6,
               pair_gain=gain, noise_logdet=np.full(m, NOISE_LOGDET), pair_ambiguous=ambiguous)
    nu = models.innovation(z[pair_obs], z_pred).reshape(-1)
    expected = _exhaustive_best(C, nu, pair_obs, pair_lm, gain, m, ambiguous)
    got = tuple(sorted(p for p in res.pairs if p is not None))
    assert got == expected
    assert not res.budget_exhausted


def test_likelihood_needs_the_noise_term():
    with pytest.raises(ValueError):
        jcbb(np.zeros((1, 2)), np.zeros((1, 2)), np.eye(2), np.array([0]), np.array([0]),
             pair_gain=np.array([1.0]))


def test_config_refuses_an_unknown_objective_and_a_certain_detection():
    with pytest.raises(ConfigError, match="ekf.jcbb_objective"):
        EkfSlamConfig(jcbb_objective="most")
    with pytest.raises(ConfigError, match="ekf.detection_prob"):
        EkfSlamConfig(detection_prob=1.0)


def _ate(ds, overrides):
    est = pipeline.run(ds, registry.make_backend("ekf", overrides=overrides)).estimate
    return metrics.ate(est.pose_ids, est.wTb, *ds.ground_truth())["rmse_m"]


def test_seed_1_loop_holds_with_the_likelihood_objective():
    """Issue 17: on seed 1 the count objective pairs a first sighting with a
    landmark mapped a lap earlier and breaks the loop (6.0 m against 1.45 m
    with known association); the likelihood objective keeps it (1.44 m)."""
    ds = registry.load_dataset("synthetic", seed=1)
    known = _ate(ds, {"association": "known"})
    count = _ate(ds, {"association": "unknown", "jcbb_objective": "count"})
    likelihood = _ate(ds, {"association": "unknown", "jcbb_objective": "likelihood"})
    assert count > BROKEN_LOOP_RATIO * known
    assert likelihood <= BROKEN_LOOP_RATIO * known


# The support rule (issue 17 item 4): a first sighting inside the wide gate of a
# landmark mapped long ago, backed in its scan only by a recently mapped one.
#: Robot pose covariance after a long stretch without re-observation: 2 m, 3 deg.
DRIFTED_PRR = np.diag([2.0 ** 2, 2.0 ** 2, math.radians(3.0) ** 2])
#: An old landmark's own variance (m^2), uncorrelated with the drifted pose.
OLD_VAR = 0.05 ** 2
#: Density and detection probability of the default likelihood objective.
LIKELIHOOD = (0.015, 0.9)
GATE = chi2_quantile(0.999, 2)
DETECTION_LOG_ODDS = math.log(0.9 / 0.1)


def _marginals(x, P):
    return np.stack([P[k:k + 2, k:k + 2] for k in range(3, len(x), 2)])


def _associate(x, P, Z):
    hyp, novelty, _, _ = associate_scan(x, P, _marginals(x, P), Z, np.stack([R] * len(Z)), gate=GATE,
                                     chi2_prob=0.999, max_candidates=3, max_nodes=2000,
                                     likelihood=LIKELIHOOD)
    return hyp, novelty


def _old_and_recent():
    """State: drifted robot at the origin, slot 0 an old landmark at (7, 0), slot 1
    a landmark mapped from this very pose (correlated with it) at z = (5 m, 0.6 rad)."""
    recent_z = np.array([5.0, 0.6])
    G_x, G_z = models.inverse_observe_jacobians(np.zeros(3), recent_z)
    x = np.concatenate([np.zeros(3), [7.0, 0.0], models.inverse_observe(np.zeros(3), recent_z)])
    P = np.zeros((7, 7))
    P[:3, :3] = DRIFTED_PRR
    P[3:5, 3:5] = np.eye(2) * OLD_VAR
    P[5:7, 5:7] = G_x @ DRIFTED_PRR @ G_x.T + G_z @ R @ G_z.T
    P[5:7, :3] = G_x @ DRIFTED_PRR
    P[:3, 5:7] = P[5:7, :3].T
    return x, P, recent_z


def test_a_recent_landmark_does_not_support_a_wide_gate_pairing():
    """A first sighting 3 m beyond the old landmark: inside its wide gate, explained
    a little better by it than by a new landmark (only thanks to the prior odds of
    detection); the recent landmark's pairing in the same scan is no support.
    Before the rule JCBB paired it with the old landmark (the seed-3 failure)."""
    x, P, recent_z = _old_and_recent()
    Z = np.array([recent_z, [10.0, 0.0]])
    hyp, novelty = _associate(x, P, Z)
    assert ambiguous_gates(Z, np.stack([R, R]), _s0(x, P), GATE, 0.999, *LIKELIHOOD)[1, 0]
    assert -DETECTION_LOG_ODDS < novelty[1, 0] < 0.0  # the construction's premise
    assert hyp == [1, None]


def test_a_decisive_lone_pairing_still_closes_the_loop():
    """The old landmark seen where it is predicted: the measurement alone favours it."""
    x, P, recent_z = _old_and_recent()
    hyp, novelty = _associate(x, P, np.array([recent_z, [7.0, 0.0]]))
    assert novelty[1, 0] < -DETECTION_LOG_ODDS
    assert hyp == [1, 0]


def test_two_wide_gate_pairings_support_each_other():
    """Two old landmarks seen from 3 m behind the estimate: neither decisive alone,
    jointly compatible (one pose error explains both), so both are paired."""
    olds = np.array([[7.0, 0.0], [5.0, 5.0]])
    x = np.concatenate([np.zeros(3), olds.ravel()])
    P = np.zeros((7, 7))
    P[:3, :3] = DRIFTED_PRR
    P[3:, 3:] = np.eye(4) * OLD_VAR
    Z = models.observe(np.array([-3.0, 0.0, 0.0]), olds)
    hyp, novelty = _associate(x, P, Z)
    assert all(-DETECTION_LOG_ODDS < novelty[i, i] < 0.0 for i in range(2))
    assert hyp == [0, 1]


def _s0(x, P):
    return predict_landmarks(x, P, _marginals(x, P))[3]


def test_seed_3_loop_holds():
    """Issue 17: seed 3 broke the loop (5.18 m against 1.57 m with known association)
    by the pattern above; with the support rule it holds."""
    ds = registry.load_dataset("synthetic", seed=3)
    known = _ate(ds, {"association": "known"})
    assert _ate(ds, {"association": "unknown"}) <= BROKEN_LOOP_RATIO * known
