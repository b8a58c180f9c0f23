"""Pruning of landmarks missed in the sensor's field (filters.landmark_existence, the EKF's and
FastSLAM's use of it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters.ekf_slam import EkfSlam
from filters.ekf_slam_config import EkfSlamConfig
from filters.ekf_slam_store import SlotStore
from filters.fastslam import FastSlam
from filters.fastslam_config import FastSlamConfig
from filters.fastslam_map import ParticleMaps
from filters.landmark_existence import MissedSightings
from slamcore.errors import GraphSlamError, MeasurementError
from slamcore.planar import geometry as models
from slamcore.planar.records import Observation, Odometry, SensorField

R = np.diag([0.05**2, math.radians(2.0) ** 2])
#: Positions agree this closely after a pure removal (float64 copies, no arithmetic).
EXACT_M = 0.0


def test_cusum_prunes_after_the_misses_alpha_allows_and_a_sighting_resets():
    # p = 0.5, alpha = 0.1: 0.5^3 = 0.125 > 0.1 >= 0.5^4, so the 4th miss in a row prunes
    ms = MissedSightings(0.5, 0.1)
    assert [ms.frame([], [7]) for _ in range(3)] == [[], [], []]
    assert ms.score(7) == pytest.approx(3 * math.log(2.0))
    assert ms.frame([7], []) == [] and ms.score(7) == 0.0  # seen: reset
    assert [ms.frame([], [7, 8]) for _ in range(4)] == [[], [], [], [7, 8]]
    assert ms.score(7) == 0.0  # forgotten once pruned


def test_cusum_seen_wins_over_missed_and_sure_sensor_prunes_at_once():
    ms = MissedSightings(1.0, 1e-3)
    assert ms.frame([3], [3]) == []  # an id in both lists was seen
    assert ms.frame([], [3]) == [3]  # a sensor that sees all its field: one miss is enough


@pytest.mark.parametrize("p, alpha", [(0.0, 0.1), (1.5, 0.1), (0.5, 0.0), (0.5, 1.0)])
def test_cusum_refuses_bad_probabilities(p, alpha):
    with pytest.raises(GraphSlamError):
        MissedSightings(p, alpha)


@pytest.mark.parametrize("args", [(0.0, 1.0, 0.5), (5.0, 0.0, 0.5), (5.0, 4.0, 0.5), (5.0, 1.0, 0.0),
                                  (5.0, 1.0, 1.1), (math.nan, 1.0, 0.5), (5.0, 1.0, 0.5, 0.0),
                                  (5.0, 1.0, 0.5, -math.inf), (5.0, 1.0, 0.5, 0.999)])
def test_sensor_field_refuses_bad_values(args):
    with pytest.raises(MeasurementError):
        SensorField(*args)


@pytest.mark.parametrize("args, names", [((math.nan, 1.0, 0.5), "max_range_m"), ((5.0, math.nan, 0.5), "half_fov_rad"),
                                         ((5.0, 1.0, math.nan), "detection_prob"),
                                         ((5.0, 1.0, 0.5, math.nan), "error_dof")])
def test_sensor_field_names_the_value_that_is_not_a_number(args, names):
    with pytest.raises(MeasurementError, match=names):
        SensorField(*args)


def test_removing_slots_marginalises_the_gaussian():
    rng = np.random.default_rng(3)
    M = 6
    n = 3 + 2 * M
    A = rng.standard_normal((n, n))
    P = A @ A.T + n * np.eye(n)
    x = rng.standard_normal(n)
    store = SlotStore(capacity=8)
    store.load(x, P, [10 + k for k in range(M)])
    store.remove_slots([1, 4])
    keep = [0, 1, 2] + [3 + 2 * k + j for k in (0, 2, 3, 5) for j in (0, 1)]
    np.testing.assert_allclose(store.x, x[keep], atol=EXACT_M)
    np.testing.assert_allclose(store.P, P[np.ix_(keep, keep)], atol=EXACT_M)
    assert store.ids == [10, 12, 13, 15]
    assert store.slot == {10: 0, 12: 1, 13: 2, 15: 3}
    np.testing.assert_allclose(store.m_first[1], x[7:9], atol=EXACT_M)
    assert not store.xbuf[store.n :].any() and not store.Pbuf[store.n :, :].any()


def _filter(field: SensorField | None, association: str = "unknown", alpha: float | None = 0.1) -> EkfSlam:
    """An EKF at the origin facing +x with three landmarks: ahead (kept by its
    sightings), ahead but never sighted again (a duplicate), and behind."""
    ekf = EkfSlam(EkfSlamConfig(association=association, prune_missed_alpha=alpha))
    x = np.array([0.0, 0.0, 0.0, 4.0, 0.0, 4.0, 2.0, -4.0, 0.0])
    P = np.diag([1e-6] * 3 + [1e-4] * 6)
    ekf.load_state(0, x, P, [0, 1, 2])
    ekf.set_sensor_field(field)
    return ekf


def _drive(ekf: EkfSlam, steps: int, known: bool = False) -> None:
    """``steps`` frames standing still, each sighting landmark 0 only."""
    first = ekf.estimate().pose_ids[-1] + 1
    for k in range(first, first + steps):
        ekf.predict(Odometry(k - 1, k, np.zeros(3), np.diag([1e-8, 1e-8, 1e-10])), k)
        z = models.observe(np.zeros(3), np.array([4.0, 0.0]))
        ekf.update([Observation(k, 0 if known else None, z, R)])


FIELD = SensorField(max_range_m=8.0, half_fov_rad=math.radians(45.0), detection_prob=0.5)


def test_ekf_prunes_the_landmark_missed_in_view_only():
    ekf = _filter(FIELD)
    _drive(ekf, 3)
    assert ekf.landmark_ids() == [0, 1, 2]  # three misses: 0.125 > alpha
    _drive(ekf, 1)
    assert ekf.landmark_ids() == [0, 2] and ekf.pruned_landmark_ids() == [1]
    assert ekf.state_vector().size == 7  # its rows are gone
    np.testing.assert_allclose(ekf.state_vector()[3:], [4.0, 0.0, -4.0, 0.0], atol=0.05)
    _drive(ekf, 20)
    assert ekf.landmark_ids() == [0, 2]  # behind the robot: never evidence against it


def test_ekf_an_unpaired_observation_in_its_gate_is_not_a_miss():
    # landmark 1 moved 6 cm from landmark 0: each sighting of (4, 0) falls in both
    # gates, so whichever the association leaves unpaired may have been seen
    ekf = _filter(FIELD)
    x = ekf.state_vector()
    x[5:7] = [4.0, 0.06]
    ekf.load_state(0, x, ekf.state_covariance(), [0, 1, 2])
    ekf.set_sensor_field(FIELD)
    _drive(ekf, 10)
    assert len(ekf.landmark_ids()) == 3 and ekf.pruned_landmark_ids() == []


def test_ekf_field_edge_needs_three_sigmas_to_spare():
    # landmark 1 sits 26.6 deg off the heading; a 27 deg field leaves no 3-sigma margin
    ekf = _filter(SensorField(8.0, math.radians(27.0), 0.5))
    _drive(ekf, 10)
    assert ekf.landmark_ids() == [0, 1, 2]


@pytest.mark.parametrize("field, association, alpha", [(None, "unknown", 0.1), (FIELD, "known", 0.1),
                                                       (FIELD, "unknown", None)])
def test_ekf_never_prunes_without_a_field_with_known_ids_or_when_off(field, association, alpha):
    ekf = _filter(field, association, alpha)
    _drive(ekf, 10, known=association == "known")
    assert ekf.landmark_ids() == [0, 1, 2] and ekf.pruned_landmark_ids() == []


def test_sources_state_their_field():
    from graphslam.sources.planar.mrclam import MrclamConfig
    from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic

    ds = make_synthetic(SyntheticConfig(n_landmarks=20, laps=1, fov_deg=90.0, sensor_range_m=6.0))
    assert ds.sensor_field == SensorField(6.0, math.radians(45.0), 1.0)
    field = MrclamConfig(
        field_range_m=5.0, field_half_fov_deg=30.0, detection_prob=0.2, sighting_error_dof=4.0
    ).sensor_field()
    assert field == SensorField(5.0, math.radians(30.0), 0.2, 4.0)
    assert ds.sensor_field.error_dof == math.inf  # simulated noise is Gaussian


def test_pipeline_hands_the_field_to_the_back_end_and_reports_pruning():
    from graphslam.pipelines import planar as pipeline
    from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic

    ds = make_synthetic(SyntheticConfig(seed=2))
    ekf = EkfSlam(EkfSlamConfig(association="unknown"))
    result = pipeline.run(ds, ekf)
    assert ekf._sensor_field == ds.sensor_field
    # seed 2's unknown-association run leaves duplicates that the sensor, which sees
    # all of its field, then misses (measured: 12 of them)
    assert result.landmarks_pruned == len(ekf.pruned_landmark_ids()) > 0
    metrics = pipeline.compute_metrics(result, with_graph_error=False)
    assert metrics.landmarks_pruned == result.landmarks_pruned
    assert not set(ekf.pruned_landmark_ids()) & set(result.estimate.landmark_ids.tolist())


# --- FastSLAM: one score per particle and landmark (filters.fastslam_particles) ----------


def test_pipeline_reports_the_landmarks_fastslam_pruned_from_every_particle():
    from graphslam.pipelines import planar as pipeline
    from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic

    fs = FastSlam(FastSlamConfig(association="unknown", n_particles=30, seed=0))
    result = pipeline.run(make_synthetic(SyntheticConfig(seed=2)), fs)
    # only landmarks gone from every particle count, a subset of the pairs pruned
    assert 0 < result.landmarks_pruned == len(fs.pruned_landmark_ids()) <= fs.particles.pruned
    assert pipeline.compute_metrics(result, with_graph_error=False).landmarks_pruned == result.landmarks_pruned
    assert not set(fs.pruned_landmark_ids()) & set(result.estimate.landmark_ids.tolist())


def _fastslam(field: SensorField | None, association: str = "unknown", alpha: float = 0.1) -> FastSlam:
    """FastSLAM 2.0 at the origin facing +x, having mapped from it a landmark ahead
    (4, 0) and one behind (-4, 0) in every particle; then a duplicate of the one ahead,
    (4, 2), sighted once."""
    fs = FastSlam(FastSlamConfig(association=association, prune_missed_alpha=alpha, n_particles=20, seed=1))
    fs.set_sensor_field(field)
    fs.initialize(0, np.zeros(3), np.diag([1e-8, 1e-8, 1e-10]))
    ahead, behind, dup = (models.observe(np.zeros(3), np.array(p)) for p in ([4.0, 0.0], [-4.0, 0.0], [4.0, 2.0]))
    ids = (0, 1) if association == "known" else (None, None)
    fs.update([Observation(0, ids[0], ahead, R), Observation(0, ids[1], behind, R)])
    fs.predict(Odometry(0, 1, np.zeros(3), np.diag([1e-8, 1e-8, 1e-10])), 1)
    fs.update([Observation(1, 2 if association == "known" else None, dup, R)])
    return fs


def _fs_drive(fs: FastSlam, steps: int, known: bool = False) -> None:
    """``steps`` frames standing still, each sighting the landmark ahead only."""
    first = int(fs.estimate().pose_ids[-1]) + 1
    for k in range(first, first + steps):
        fs.predict(Odometry(k - 1, k, np.zeros(3), np.diag([1e-8, 1e-8, 1e-10])), k)
        z = models.observe(np.zeros(3), np.array([4.0, 0.0]))
        fs.update([Observation(k, 0 if known else None, z, R)])


def _fs_map(fs: FastSlam) -> np.ndarray:
    """(M, 2) landmarks of the estimate, sorted by x then y."""
    m = np.asarray(fs.estimate().landmarks_w).reshape(-1, 2)
    return m[np.lexsort((m[:, 1], m[:, 0]))]


def test_fastslam_prunes_the_landmark_missed_in_view_only():
    fs = _fastslam(FIELD)
    assert len(_fs_map(fs)) == 3
    _fs_drive(fs, 3)
    assert len(_fs_map(fs)) == 3  # three misses: 0.125 > alpha
    _fs_drive(fs, 1)
    np.testing.assert_allclose(_fs_map(fs), [[-4.0, 0.0], [4.0, 0.0]], atol=0.05)
    assert fs.particles.pruned == fs.n_particles  # the duplicate, in every particle
    dup = fs.pruned_landmark_ids()
    assert len(dup) == 1 and dup[0] not in fs.estimate().landmark_ids.tolist()
    _fs_drive(fs, 20)
    assert len(_fs_map(fs)) == 2  # behind the robot: never evidence against it
    assert fs.pruned_landmark_ids() == dup


def test_fastslam_an_unpaired_observation_in_its_gate_is_not_a_miss():
    # a sighting of (4, 0.06) falls in the gates of both (4, 0) and the duplicate moved
    # there: whichever a particle leaves unpaired may have been seen
    fs = FastSlam(FastSlamConfig(association="unknown", prune_missed_alpha=0.1, n_particles=20, seed=1))
    fs.set_sensor_field(FIELD)
    fs.initialize(0, np.zeros(3), np.diag([1e-8, 1e-8, 1e-10]))
    near = [models.observe(np.zeros(3), np.array(p)) for p in ([4.0, 0.0], [4.0, 0.06])]
    fs.update([Observation(0, None, z, R) for z in near])
    _fs_drive(fs, 10)
    assert len(_fs_map(fs)) == 2 and fs.particles.pruned == 0


def test_fastslam_field_edge_needs_three_sigmas_to_spare():
    # the duplicate sits 26.6 deg off the heading; a 27 deg field leaves no 3-sigma margin
    fs = _fastslam(SensorField(8.0, math.radians(27.0), 0.5))
    _fs_drive(fs, 10)
    assert len(_fs_map(fs)) == 3 and fs.particles.pruned == 0


@pytest.mark.parametrize("field, association, alpha", [(None, "unknown", 0.1), (FIELD, "known", 0.1),
                                                       (FIELD, "unknown", 0.0)])
def test_fastslam_never_prunes_without_a_field_with_known_ids_or_when_off(field, association, alpha):
    fs = _fastslam(field, association, alpha)
    _fs_drive(fs, 10, known=association == "known")
    assert len(_fs_map(fs)) == 3 and fs.particles.pruned == 0 and fs.pruned_landmark_ids() == []


def test_fastslam_scores_follow_resampling_and_dropped_columns():
    maps = ParticleMaps(3, column_capacity=1)
    for lid in (10, 11, 12):  # the second and third columns grow the table
        c = maps.add_column(lid)
        maps.write(np.arange(3), c, np.zeros((3, 2)), np.broadcast_to(np.eye(2), (3, 2, 2)))
    maps.score[:] = [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [6.0, 7.0, 8.0]]
    maps.resample(np.array([2, 2, 0]))
    np.testing.assert_array_equal(maps.score, [[6.0, 7.0, 8.0], [6.0, 7.0, 8.0], [0.0, 1.0, 2.0]])
    gone = np.zeros((3, 3), dtype=bool)
    gone[:, 1] = True  # landmark 11 leaves every particle: its column goes
    maps.forget(gone)
    assert maps.drop_empty_columns() == 1
    assert maps.ids.tolist() == [10, 12]
    np.testing.assert_array_equal(maps.score, [[6.0, 8.0], [6.0, 8.0], [0.0, 2.0]])
    c = maps.add_column(13)  # a new column starts at score 0
    assert (maps.score[:, c] == 0.0).all()
