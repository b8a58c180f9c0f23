"""The 3-D back-end contract (slamcore.spatial.backend.VisualBackend), written once
and run on every visual back end of the registry, as
tests/graphslam/backends/test_backend_contract.py does for the 2-D ones.

On a seeded synthetic world (points around a circular route, noisy odometry and
pixels: tests/graphslam/backends/test_isam2_visual.make_world) every back end must
give an estimate of the documented shapes, predictions the measured pixels fall inside, a run
repeatable to the bit, a result better than its odometry (measured on seed 1,
30 frames: iSAM2 0.025 m, the EKF 0.064 m, odometry 0.116 m), and capability
flags that say what its methods do. Each back end is built as a visual run with
odometry builds it, the scene's nearest depth included: with the EKF's own 1 m
prior instead of the scene's 2.8 m it ends at 0.358 m, worse than the odometry.
"""

from __future__ import annotations

import numpy as np
import pytest

from graphslam import registry
from graphslam.backend_table import VISUAL_COMPARE_BACKENDS
from slamcore.errors import UnsupportedError
from slamcore.spatial.backend import VisualBackend
from slamcore.spatial.records import PixelObservations, PoseClosure
from tests.graphslam.backends.test_isam2_visual import (
    K, SIGMA_PX, SIZE, dead_reckoning, make_world, position_rmse,
)

#: Frames of the contract run (a half circle: landmarks re-observed over many frames).
N_FRAMES = 30
#: Of the landmarks a back end predicts, the share whose measured pixel lies inside
#: the 99.9 % gate of its innovation covariance (chi-square, 2 dof: 13.8). A
#: consistent back end has 0.999 in expectation; filters linearise, so the bound
#: leaves room (measured on seed 1: iSAM2 247 of 247, the EKF 343 of 344, both
#: parametrisations).
INSIDE_GATE_MIN = 0.95
CHI2_2DOF_999 = 13.8155
#: |R^T R - I| of an estimated rotation (float64 after many compositions).
ROTATION_TOL = 1e-6

#: name -> (back end, config overrides): every registered visual back end, the EKF once
#: per landmark parametrisation; a new back end of the registry must appear here.
ENTRIES = dict(VISUAL_COMPARE_BACKENDS)


def test_every_registered_visual_backend_runs_the_contract():
    assert {backend for backend, _ in ENTRIES.values()} == set(registry.VISUAL_BACKENDS)


@pytest.fixture(scope="module")
def world():
    return make_world(seed=1, n_frames=60)


def nearest_depth_m(world) -> float:
    """The world's nearest depth as a sequence states it (the 1st percentile of the
    in-view depths, as graphslam.sources.spatial.synthetic_images does)."""
    from slamcore.spatial.geometry import invert_pose

    depths = []
    for wTc, (ids, _) in zip(world["wTc"], world["obs"]):
        cTw = invert_pose(wTc)
        depths.append((world["points"][ids] @ cTw[:3, :3].T + cTw[:3, 3])[:, 2])
    return float(np.percentile(np.concatenate(depths), 1))


def make(entry: str, world=None) -> VisualBackend:
    """The back end as a visual run with odometry builds it (graphslam.pipelines.spatial
    .backend_overrides: what a run hands each back end, the scene's nearest depth
    included, then the entry's own settings)."""
    from graphslam.pipelines.spatial import backend_overrides

    name, overrides = ENTRIES[entry]
    depth = None if world is None else nearest_depth_m(world)
    run_overrides = backend_overrides(name, "sequence", nearest_depth_m=depth)
    return registry.make_visual_backend(name, overrides={**run_overrides, **overrides})


def run(entry: str, world, n: int = N_FRAMES, on_predictions=None) -> VisualBackend:
    backend = make(entry, world)
    backend.initialize(0, world["wTc"][0], np.zeros((6, 6)), K, SIZE)
    backend.update(PixelObservations(*world["obs"][0], SIGMA_PX))
    for k in range(1, n):
        backend.predict(k, world["odo"][k - 1], world["cov"])
        predictions = backend.predict_observations()
        if on_predictions is not None:
            on_predictions(k, predictions)
        backend.update(PixelObservations(*world["obs"][k], SIGMA_PX))
    return backend


@pytest.fixture(params=sorted(ENTRIES))
def entry(request):
    return request.param


def test_is_a_visual_backend(entry):
    backend = make(entry)
    assert isinstance(backend, VisualBackend)
    assert isinstance(backend.name, str) and backend.name


def test_estimate_has_the_documented_shapes_and_beats_odometry(entry, world):
    estimate = run(entry, world).finalize()
    n = N_FRAMES
    np.testing.assert_array_equal(estimate.frame_ids, np.arange(n))
    assert estimate.wTc.shape == (n, 4, 4) and np.all(np.isfinite(estimate.wTc))
    R = estimate.wTc[:, :3, :3]
    assert np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max() < ROTATION_TOL
    assert estimate.landmark_ids.dtype.kind == "i"
    assert len(np.unique(estimate.landmark_ids)) == len(estimate.landmark_ids) > 0
    assert estimate.landmarks_w.shape == (len(estimate.landmark_ids), 3)
    assert np.all(np.isfinite(estimate.landmarks_w))
    if estimate.current_covariance is not None:
        cov = estimate.current_covariance
        assert cov.shape == (6, 6) and np.allclose(cov, cov.T)
        assert np.linalg.eigvalsh(cov).min() > 0
    truth = world["wTc"][:n]
    assert position_rmse(estimate.wTc, truth) < position_rmse(dead_reckoning(world)[:n], truth)


def test_predictions_are_consistent_with_the_measurements(entry, world):
    inside, total = [0], [0]

    def check(k, p):
        n = len(p.track_ids)
        assert p.uv_px.shape == (n, 2) and p.S_px2.shape == (n, 2, 2)
        assert np.all(np.isfinite(p.uv_px)) and np.all(np.isfinite(p.S_px2))
        if n:
            assert np.linalg.eigvalsh(p.S_px2).min() > 0
        ids, uv = world["obs"][k]
        measured = dict(zip(ids.tolist(), uv))
        for tid, z, S in zip(p.track_ids.tolist(), p.uv_px, p.S_px2):
            if tid in measured:
                e = measured[tid] - z
                inside[0] += float(e @ np.linalg.solve(S, e)) <= CHI2_2DOF_999
                total[0] += 1

    run(entry, world, on_predictions=check)
    assert total[0] > 100
    assert inside[0] / total[0] >= INSIDE_GATE_MIN


def test_repeatable_to_the_bit(entry, world):
    a, b = run(entry, world, n=12).finalize(), run(entry, world, n=12).finalize()
    np.testing.assert_array_equal(a.wTc, b.wTc)
    np.testing.assert_array_equal(a.landmark_ids, b.landmark_ids)
    np.testing.assert_array_equal(a.landmarks_w, b.landmarks_w)


def test_capability_flags_say_what_the_methods_do(entry, world):
    backend = run(entry, world, n=8)
    if backend.has_motion_model:
        backend.predict(8, None, None)
        backend.update(PixelObservations(*world["obs"][8], SIGMA_PX))
    else:
        with pytest.raises(UnsupportedError):
            backend.predict(8, None, None)
    closure = PoseClosure(0, 7, np.linalg.inv(world["wTc"][0]) @ world["wTc"][7],
                          np.diag([1e-4] * 3 + [1e-6] * 3))
    if backend.supports_loop_closures:
        backend.add_loop_closure(closure)
        ids = np.asarray(world["obs"][2][0][:5], np.int64)
        assert backend.landmarks_in_frame(2, ids).shape == (5, 3)
    else:
        with pytest.raises(UnsupportedError):
            backend.add_loop_closure(closure)
        with pytest.raises(UnsupportedError):
            backend.landmarks_in_frame(2, np.zeros(1, np.int64))
    if not backend.supports_sequential_search:
        with pytest.raises(UnsupportedError):
            backend.correct_and_repredict(np.zeros(0, np.int64), np.zeros((0, 2)),
                                          np.zeros(0, np.int64))
    assert np.all(np.isfinite(backend.finalize().wTc))
