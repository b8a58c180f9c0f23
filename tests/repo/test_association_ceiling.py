"""The known-pose ceiling of benchmarks/bench_association_ceiling.py.

Its exact-odometry copy of the synthetic world must really pin the robot to
the true path, or the ceiling it reports would be a noisy run in disguise.
"""

from __future__ import annotations

import numpy as np

from slamcore.planar import geometry as models
from graphslam import registry
from graphslam.pipelines import planar as pipeline
from tests.benchmarks import load_benchmark

#: Position error (m) the near-noise-free odometry may leave over a whole run.
KNOWN_POSE_TOL_M = 1e-3


def _bench():
    return load_benchmark("bench_association_ceiling")


def test_exact_odometry_composes_to_the_true_path_and_the_ekf_stays_on_it():
    bench = _bench()
    ds = registry.load_dataset("synthetic", seed=0)
    exact = bench.with_exact_odometry(ds)
    x = exact.prior_wTb
    for f in exact.frames[1:]:
        x = models.compose(x, f.odometry.delta)
        assert np.linalg.norm(x[:2] - f.wTb_true[:2]) < KNOWN_POSE_TOL_M
    result = pipeline.run(exact, registry.make_backend("ekf", overrides={"association": "unknown"}))
    true = np.array([f.wTb_true for f in ds.frames])
    err = np.linalg.norm(result.estimate.wTb[:, :2] - true[:, :2], axis=1)
    assert err.max() < KNOWN_POSE_TOL_M
    # the noisy original is not pinned: the copy did change something
    noisy = pipeline.run(ds, registry.make_backend("ekf", overrides={"association": "unknown"}))
    assert np.abs(noisy.estimate.wTb[:, :2] - true[:, :2]).max() > 100 * KNOWN_POSE_TOL_M
