"""JCBB's likelihood objective (``[ekf] jcbb_objective = "likelihood"``, issue 17 item 4)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from filters.association import chi2_quantile, jcbb
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


def _exhaustive_best(C, nu, pair_obs, pair_lm, gain, m):
    """Best score over every hypothesis (one pair per observation at most, one per landmark)."""
    best, best_h = 0.0, ()
    options = [[None] + [p for p in range(len(pair_obs)) if pair_obs[p] == i] for i in range(m)]
    for choice in itertools.product(*options):
        pairs = [p for p in choice if p is not None]
        if len({pair_lm[p] for p in pairs}) < len(pairs) or not pairs:
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


@pytest.mark.parametrize("seed", range(8))
def test_branch_and_bound_finds_the_exhaustive_optimum(seed):
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
    res = jcbb(z, z_pred, C, pair_obs, pair_lm, chi2_prob=0.99, max_nodes=10 ** 6,
               pair_gain=gain, noise_logdet=np.full(m, NOISE_LOGDET))
    nu = models.innovation(z[pair_obs], z_pred).reshape(-1)
    expected = _exhaustive_best(C, nu, pair_obs, pair_lm, gain, m)
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
