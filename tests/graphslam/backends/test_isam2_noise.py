"""iSAM2 on the synthetic world at noise settings that used to end in
``IndeterminateSystem`` (issue 14): it runs to the end, says it switched to QR,
and reaches the same estimate as a QR-only run."""

from __future__ import annotations

import pytest

from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
from graphslam.pipelines import planar as pipeline
from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic
from slamcore.errors import ConfigError, GraphSlamError

#: Pose agreement of the auto (Cholesky then QR) run with a QR-only run, metres:
#: both polish the same graph with LM from nearby starts.
SAME_ESTIMATE_TOL_M = 1e-4

CRASH_CASES = [
    ({"sigma_w_degps": 0.5}, 0), ({"sigma_w_degps": 0.5}, 1),
    ({"sigma_v_mps": 0.5}, 0), ({"sigma_v_mps": 0.5}, 1),
    ({"sigma_r_m": 1e-3}, 0), ({"sigma_r_m": 1e-3}, 1),
]


def _run(world, seed, factorization, max_steps=None):
    """The cases were found with Gaussian sightings: no robust kernel, so that they stay
    the systems that are indeterminate (a Cauchy kernel reweights them away)."""
    ds = make_synthetic(SyntheticConfig(seed=seed, **world))
    backend = Isam2Backend(Isam2Config(factorization=factorization, observation_kernel="none"))
    return pipeline.run(ds, backend, max_steps=max_steps)


@pytest.mark.parametrize("world,seed", CRASH_CASES)
def test_auto_factorization_survives(world, seed):
    result = _run(world, seed, "auto")
    assert result.steps == len(make_synthetic(SyntheticConfig(seed=seed, **world)).frames)
    assert len(result.numerical_recoveries) == 1
    assert "QR" in result.numerical_recoveries[0]


def test_auto_matches_qr_only():
    auto = _run({"sigma_w_degps": 0.5}, 0, "auto").estimate
    qr = _run({"sigma_w_degps": 0.5}, 0, "qr").estimate
    assert abs(auto.wTb - qr.wTb)[:, :2].max() < SAME_ESTIMATE_TOL_M


def test_cholesky_only_fails_with_one_line():
    with pytest.raises(GraphSlamError, match="indeterminate.*auto"):
        _run({"sigma_w_degps": 0.5}, 0, "cholesky")


def test_default_world_takes_no_fallback():
    assert _run({}, 0, "auto", max_steps=200).numerical_recoveries == []


def test_factorization_is_checked():
    with pytest.raises(ConfigError, match="factorization"):
        Isam2Config(factorization="lu")


#: The course's noise values; the grid scales each by 0.1 and 10, alone and all together.
COURSE_NOISE = {"sigma_v_mps": 0.05, "sigma_w_degps": 0.1, "sigma_r_m": 0.2,
                "sigma_phi_deg": 10.0}
NOISE_GRID = ([{k: v * f} for k, v in COURSE_NOISE.items() for f in (0.1, 10.0)]
              + [{k: v * f for k, v in COURSE_NOISE.items()} for f in (0.1, 10.0)])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("world", NOISE_GRID,
                         ids=lambda w: ",".join(f"{k}={v:g}" for k, v in w.items()))
def test_noise_grid_runs_to_the_end(world, seed):
    ds = make_synthetic(SyntheticConfig(seed=seed, **world))
    result = pipeline.run(ds, Isam2Backend())
    assert result.steps == len(ds.frames) and not result.interrupted


def test_information_too_large_for_float64_is_one_line():
    """1e-30 m ranges (a setting now refused by [synthetic]; a file may still carry them)
    made iSAM2's system indeterminate where it reads its estimate, not in the update the
    QR fallback guards: a gtsam RuntimeError traceback."""
    import dataclasses

    import numpy as np

    ds = make_synthetic(SyntheticConfig(seed=0, sigma_r_m=1e-9))
    frames = [dataclasses.replace(f, observations=tuple(
        dataclasses.replace(o, covariance=np.diag([1e-60, 1e-4])) for o in f.observations))
        for f in ds.frames]
    ds = dataclasses.replace(ds, frames=frames)
    backend = Isam2Backend(Isam2Config())  # the default Cauchy kernel on sightings
    with pytest.raises(GraphSlamError, match="isam2: indeterminate linear system near x"):
        pipeline.run(ds, backend, max_steps=60)


def test_the_smallest_synthetic_noise_runs():
    """[synthetic] noise floors (MIN_SIGMA): a setting at the floor runs to the end."""
    from graphslam.sources.planar.synthetic import MIN_SIGMA

    with pytest.raises(ConfigError, match="sigma_r_m must be >= 1e-09"):
        SyntheticConfig(sigma_r_m=1e-320)
    result = _run({"sigma_r_m": MIN_SIGMA}, 0, "auto", max_steps=100)
    assert result.steps == 100
