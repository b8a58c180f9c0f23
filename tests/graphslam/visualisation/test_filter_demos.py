"""The course's filter demos in Rerun (issue 19 item 5): the EKF correlation image,
FastSLAM's particle cloud, ESS and resampling events, read back from the recording."""

from __future__ import annotations

import numpy as np
import pytest

from filters.fastslam import FastSlam
from filters.fastslam_config import FastSlamConfig
from graphslam import registry
from graphslam.pipelines import planar as pipeline
from graphslam.visualisation.filter_state import (
    FilterStateLogger, correlation_matrix, entity_image, mean_off_diagonal,
)
from graphslam.visualisation.planar import RunRecorder
from tests.recordings import entity_rows, points2d, scalars, tensors

#: Float32 storage of logged values (correlations are dimensionless, poses in metres).
FLOAT32_TOL = 1e-6
POSITION_TOL_M = 1e-4
#: Steps between a re-sighting after this many unseen steps and the ESS minimum.
REVISIT_GAP_STEPS = 100
LOOP_WINDOW_STEPS = 5
#: First steps, where the first landmarks make mean |rho| jump from 0.
SETTLE_STEPS = 10


def _record(tmp_path, backend_name, steps, every, overrides=None):
    """Run ``steps`` of the seeded synthetic world into a recording; (path, backend, dataset)."""
    dataset = registry.load_dataset("synthetic", seed=0)
    backend = registry.make_backend(backend_name, overrides=overrides or {})
    path = tmp_path / "run.rrd"
    rec = RunRecorder.open("save", path)
    rec.start(dataset, steps)
    result = pipeline.run(dataset, backend, max_steps=steps, on_step=rec.hook(backend.name, every),
                          with_covariances=True)
    rec.finish(backend.name, result)
    rec.close()
    return path, backend, dataset


def _loop_closure_step(dataset) -> int:
    """First step that re-sights a landmark unseen for :data:`REVISIT_GAP_STEPS` (truth)."""
    last = {}
    for k, frame in enumerate(dataset.frames):
        for lid in frame.true_landmark_ids or ():
            if lid in last and k - last[lid] > REVISIT_GAP_STEPS:
                return k
            last[lid] = k
    raise AssertionError("the default synthetic world has no loop")


def test_correlation_matrix_and_entity_image_by_brute_force():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((9, 9))
    P = A @ A.T + 0.1 * np.eye(9)  # pose (3) + 3 landmarks (2 each)
    rho = correlation_matrix(P)
    i, j = 1, 6
    assert rho[i, j] == pytest.approx(P[i, j] / np.sqrt(P[i, i] * P[j, j]), abs=FLOAT32_TOL)
    assert np.allclose(np.diag(rho), 1.0)
    blocks = [range(0, 3), range(3, 5), range(5, 7), range(7, 9)]
    expect = np.array([[max(abs(rho[a, b]) for a in ra for b in rb) for rb in blocks]
                       for ra in blocks])
    a = np.abs(rho)
    assert np.allclose(entity_image(a), expect, atol=FLOAT32_TOL)
    # above max_side entities, consecutive pairs share a cell by the same maximum
    halved = entity_image(a, max_side=2)
    assert halved.shape == (2, 2)
    assert halved[0, 1] == pytest.approx(expect[:2, 2:].max(), abs=FLOAT32_TOL)
    B = rng.standard_normal((11, 11))  # 5 entities in tiles of 3: the last tile padded
    b = np.abs(correlation_matrix(B @ B.T))
    full = entity_image(b)
    tiles = entity_image(b, max_side=2)
    assert tiles.shape == (2, 2)
    assert tiles[0, 1] == pytest.approx(full[:3, 3:].max(), abs=FLOAT32_TOL)
    assert tiles[1, 1] == pytest.approx(1.0)
    off = ~np.eye(9, dtype=bool)
    assert mean_off_diagonal(a) == pytest.approx(a[off].mean())
    with pytest.raises(ValueError, match="not 3 \\+ 2"):
        entity_image(a[:8, :8])


def test_entity_image_puts_other_robots_poses_last():
    """The EKF with several robots: ``[pose, m1, m2, parked pose]``, four entities."""
    rng = np.random.default_rng(4)
    A = rng.standard_normal((10, 10))
    a = np.abs(correlation_matrix(A @ A.T + 0.1 * np.eye(10)))
    blocks = [range(0, 3), range(3, 5), range(5, 7), range(7, 10)]
    expect = np.array([[max(a[i, j] for i in ra for j in rb) for rb in blocks] for ra in blocks])
    assert np.allclose(entity_image(a, parked_poses=1), expect, atol=FLOAT32_TOL)
    with pytest.raises(ValueError, match="not 3 \\+ 2 x landmarks \\+ 2 x 3"):
        entity_image(a, parked_poses=2)


def test_ekf_recording_has_the_correlation_image(tmp_path):
    steps, every = 61, 15  # the last step (60) is a logged one
    path, ekf, _ = _record(tmp_path, "ekf", steps, every)
    images = tensors(path, "/filter/ekf/correlation")
    assert [s for s, _ in images] == list(range(0, steps, every))
    last_step, last = images[-1]
    assert last.shape == (1 + ekf.num_landmarks,) * 2 and ekf.num_landmarks > 5
    for _, image in images:
        assert image.min() >= 0.0 and image.max() <= 1.0
        assert np.allclose(np.diag(image), 1.0)
    # the recording holds the filter's own state at that step
    a = np.abs(correlation_matrix(ekf.state_covariance()))
    assert np.allclose(last, entity_image(a), atol=FLOAT32_TOL)
    s, mean_abs = scalars(path, "/plots/ekf/mean_abs_correlation")
    assert list(s) == [s for s, _ in images]
    assert mean_abs[-1] == pytest.approx(mean_off_diagonal(a), abs=FLOAT32_TOL)


def test_fastslam_recording_has_cloud_ess_and_resampling(tmp_path):
    n, steps = 40, 120
    path, fs, _ = _record(tmp_path, "fastslam1", steps, 10, {"n_particles": n})
    clouds = points2d(path, "/world/fastslam1/particles")
    assert [s for s, _ in clouds] == list(range(steps))
    assert all(c.shape == (n, 2) for _, c in clouds)
    assert np.allclose(clouds[-1][1], fs.particle_poses[:, :2], atol=POSITION_TOL_M)
    s, ess = scalars(path, "/plots/fastslam1/ess")
    assert list(s) == list(range(steps))
    assert np.all(ess > 0.0) and np.all(ess <= n + FLOAT32_TOL)
    assert ess[-1] == pytest.approx(fs.step_ess())
    events = entity_rows(path, "/plots/fastslam1/resampling", "TextLog:text")
    assert len(events) == fs.resample_count > 0
    # a resampling happens exactly when the ESS fell below the configured fraction
    resampled = {step for step, _ in events}
    below = {int(k) for k, e in zip(s, ess) if e < fs.config.resample_ess_fraction * n}
    assert resampled == below


def test_fastslam_accessors_follow_the_filter_state():
    dataset = registry.load_dataset("synthetic", seed=0)
    fs = FastSlam(FastSlamConfig(n_particles=30, seed=1))
    frames = dataset.frames[:200]
    fs.initialize(frames[0].pose_id, dataset.prior_wTb, dataset.prior_covariance)
    seen_resampling = seen_plain = False
    for frame in frames[1:]:
        fs.predict(frame.odometry, frame.pose_id)
        count = fs.resample_count
        assert not fs.resampled_this_step()  # no decision yet at this pose
        fs.update(frame.observations)
        w = fs.weights
        if fs.resampled_this_step():
            seen_resampling = True
            assert fs.resample_count == count + 1 and np.allclose(w, 1.0 / 30)
            assert fs.step_ess() < fs.config.resample_ess_fraction * 30
        else:
            seen_plain = True
            assert fs.step_ess() == pytest.approx(1.0 / np.sum(w * w))
    assert seen_resampling and seen_plain
    poses = fs.particle_poses
    poses[:] = 0.0  # a copy: the filter's cloud is untouched
    assert np.any(fs.particle_poses != 0.0)


def test_loop_closure_shows_in_the_logged_series(tmp_path):
    """Default synthetic world (it loops once): FastSLAM's ESS is lowest of the run
    at the loop closure, with a resampling there; the EKF's mean |rho| rises."""
    steps = 480
    path, _, dataset = _record(tmp_path, "fastslam1", steps, 60)
    closure = _loop_closure_step(dataset)
    s, ess = scalars(path, "/plots/fastslam1/ess")
    assert abs(int(s[np.argmin(ess)]) - closure) <= LOOP_WINDOW_STEPS
    events = [k for k, _ in entity_rows(path, "/plots/fastslam1/resampling", "TextLog:text")]
    assert any(abs(k - closure) <= LOOP_WINDOW_STEPS for k in events)
    path, _, _ = _record(tmp_path, "ekf", steps, 1)
    s, mean_abs = scalars(path, "/plots/ekf/mean_abs_correlation")
    early = mean_abs[(s > 0) & (s <= closure // 4)].mean()
    assert mean_abs[-1] > early + 0.1
    # past the first landmarks, the largest one-step rise is the closure's
    later = s[1:] > SETTLE_STEPS
    assert abs(int(s[1:][later][np.argmax(np.diff(mean_abs)[later])]) - closure) \
        <= LOOP_WINDOW_STEPS


def test_filter_state_logger_batches_fastslam_and_ignores_other_backends():
    sent = []
    log = type("FakeLog", (), {"send_particles": lambda self, b, series, c, style:
                               sent.append(series),
                               "log_correlation": lambda self, b, snap: sent.append(snap)})()
    logger = FilterStateLogger(log, "other", every=1)
    logger(0, None, object())  # iSAM2, a localiser: no filter state to show
    logger.flush()
    assert sent == []
    dataset = registry.load_dataset("synthetic", seed=0)
    fs = FastSlam(FastSlamConfig(n_particles=10, seed=1))
    fs.initialize(dataset.frames[0].pose_id, dataset.prior_wTb, dataset.prior_covariance)
    logger = FilterStateLogger(log, "fastslam1", every=1)
    steps = FilterStateLogger.FLUSH_STEPS + 3
    for k in range(steps):
        logger(k, 0.1 * k, fs)
    assert [len(s.steps) for s in sent] == [FilterStateLogger.FLUSH_STEPS]
    logger.flush()
    assert [len(s.steps) for s in sent] == [FilterStateLogger.FLUSH_STEPS, 3]
    assert list(sent[1].steps) == list(range(FilterStateLogger.FLUSH_STEPS, steps))
    assert sent[1].positions.shape == (3, 10, 2) and sent[1].stamps_s[-1] == pytest.approx(
        0.1 * (steps - 1))
