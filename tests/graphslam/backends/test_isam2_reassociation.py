"""Re-association at the end of an iSAM2 run without landmark ids (isam2_unknown)."""

from __future__ import annotations

import numpy as np

from graphslam import registry
from graphslam.backends.planar.isam2_unknown import reassign_scan
from graphslam.evaluation import planar as metrics
from graphslam.pipelines import planar as pipeline
from slamcore.planar.geometry import observe
from slamcore.planar.records import Observation
from tests.filters.test_fastslam import loop_world

#: Range and bearing sigmas of the sightings below (MRCLAM-like), metres and radians.
SIGMA_R_M, SIGMA_B_RAD = 0.1, 0.01
R = np.diag([SIGMA_R_M**2, SIGMA_B_RAD**2])
#: 99.9 % gate on two degrees of freedom (the back end's default association_gate_prob).
GATE_D2 = 13.8


def _sights(wTb, points, now):
    """One scan's sightings of ``points`` (noise-free), each held by landmark ``now[k]``."""
    return [
        (lid, 100 + k, Observation(0, None, observe(wTb, p), R), None)
        for k, (p, lid) in enumerate(zip(points, now, strict=True))
    ]


def test_two_swapped_sightings_go_back_to_the_landmarks_that_explain_them():
    wTb = np.zeros(3)
    positions = {7: np.array([4.0, 0.1]), 8: np.array([4.0, -0.1]), 9: np.array([-3.0, 2.0])}
    sights = _sights(wTb, [positions[7], positions[8]], now=[8, 7])
    assert sorted(reassign_scan(sights, wTb, positions, GATE_D2)) == [(0, 7), (1, 8)]


def test_a_sighting_that_fits_where_it_is_stays():
    wTb = np.array([1.0, -2.0, 0.4])
    positions = {7: np.array([4.0, 0.1]), 8: np.array([4.0, -0.1])}
    sights = _sights(wTb, [positions[7], positions[8]], now=[7, 8])
    assert reassign_scan(sights, wTb, positions, GATE_D2) == []


def test_a_sighting_never_moves_outside_the_gate():
    """A sighting 1 m from where its landmark is (10 range sigmas): nothing else near,
    so it stays, however badly it fits."""
    wTb = np.zeros(3)
    positions = {7: np.array([5.0, 0.0]), 8: np.array([0.0, 5.0])}
    sights = _sights(wTb, [np.array([6.0, 0.0])], now=[7])
    assert reassign_scan(sights, wTb, positions, GATE_D2) == []
    # ... and goes to a landmark inside the gate when there is one
    positions[9] = np.array([6.02, 0.0])
    assert reassign_scan(sights, wTb, positions, GATE_D2) == [(0, 9)]


def test_a_landmark_takes_at_most_one_sighting_of_a_scan():
    """Two sightings both nearest landmark 7: the joint assignment gives 7 to one and
    leaves the other where it is."""
    wTb = np.zeros(3)
    positions = {7: np.array([4.0, 0.0]), 8: np.array([4.0, 0.3]), 9: np.array([4.0, -0.3])}
    near7 = [np.array([4.0, 0.02]), np.array([4.0, -0.02])]
    moves = reassign_scan(_sights(wTb, near7, now=[8, 9]), wTb, positions, GATE_D2)
    assert [to for _, to in moves] == [7]


def _unknown_run(**overrides):
    ds = loop_world(seed=2, known_ids=False)
    backend = registry.make_backend("isam2", overrides={"association": "unknown", **overrides})
    return backend, pipeline.run(ds, backend)


def test_the_run_scores_the_pairings_the_estimate_rests_on():
    """Every scored observation's final landmark is one of the estimate's, the
    re-association is reported, and on a world of well-apart landmarks the pairing is
    right (as the unknown-id FastSLAM test asks of it)."""
    backend, res = _unknown_run()
    final = backend.final_associations()
    assert final and set(final.values()) <= set(res.estimate.landmark_ids.tolist())
    m = pipeline.compute_metrics(res, with_graph_error=False)
    assert m.sightings_reassociated is not None and m.reassociation_settled is True
    assert metrics.association_accuracy(res.associations).accuracy >= 0.98


def test_no_passes_leave_the_pairings_as_decided():
    backend, res = _unknown_run(reassociation_passes=0)
    assert backend.reassociation() is None
    m = pipeline.compute_metrics(res, with_graph_error=False)
    assert m.sightings_reassociated is None and m.reassociation_settled is None


def test_known_ids_have_no_final_pairings_to_report():
    backend = registry.make_backend("isam2")
    assert backend.final_associations() is None and backend.reassociation() is None

