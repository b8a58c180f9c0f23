"""The final error of a run that associated its own landmarks (unknown ids) is taken
over the graph as the run paired it: it was n/a (the data's ids name no landmark of the
estimate), so the chi-square test of the final cost never ran on such runs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from graphslam import registry
from graphslam.backends.gtsam_convert import graph_cost
from graphslam.evaluation.planar import majority_truth
from graphslam.pipelines import planar as pipeline
from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic
from slamcore.planar.records import Estimate

#: Relative agreement of two evaluations of one gtsam graph error (summation order).
COST_RTOL = 1e-9


@pytest.fixture(scope="module")
def world():
    # sparse landmarks and a sharp sensor: every sighting the run uses is paired right
    return make_synthetic(SyntheticConfig(seed=0, n_landmarks=40, sigma_r_m=0.05, sigma_phi_deg=1.0))


def test_an_unknown_id_run_has_the_final_error_of_the_graph_it_paired(world):
    result = pipeline.run(world, registry.make_backend("isam2", overrides={"association": "unknown"}))
    m = pipeline.compute_metrics(result)
    assert result.paired and m.final_error is not None
    # independent of the pairing record: the data's own graph over the sightings the
    # run used (in stream order beside result.associations), at the estimate with its
    # landmarks renamed to the true ids their sightings are of; every used sighting is
    # of its landmark's true id here, so the two graphs are one
    pairs = iter(result.associations)
    frames = []
    for frame in world.frames:
        used = tuple(o for o in frame.observations if next(pairs)[1] is not None)
        frames.append(replace(frame, observations=used))
    true_of = majority_truth(result.associations)
    assert all(true_of[got] == true for true, got in result.associations if got is not None)
    est = result.estimate
    renamed = Estimate(
        pose_ids=est.pose_ids,
        wTb=est.wTb,
        landmark_ids=np.array([true_of[int(i)] for i in est.landmark_ids]),
        landmarks_w=est.landmarks_w,
    )
    own, _ = graph_cost(replace(world, frames=tuple(frames)), renamed)
    assert m.final_error == pytest.approx(own, rel=COST_RTOL)


def test_a_known_id_run_keeps_every_sighting_in_its_final_error(world):
    """With the data's ids nothing is re-paired: a sighting a gate turned away still
    counts in the final error, as before."""
    result = pipeline.run(world, registry.make_backend("isam2"))
    assert result.paired == {}
    m = pipeline.compute_metrics(result)
    assert m.final_error == pytest.approx(graph_cost(world, result.estimate)[0], rel=COST_RTOL)


def test_sightings_an_unknown_id_run_left_unused_leave_its_final_error():
    """The default world: sightings held on iSAM2's provisional list, or given a landmark
    no longer in the estimate, are out of the graph; the others count under the id the
    run gave them (its pairings in stream order, kept apart from ``paired``)."""
    world = make_synthetic(SyntheticConfig(seed=0))
    result = pipeline.run(world, registry.make_backend("isam2", overrides={"association": "unknown"}))
    kept = set(result.estimate.landmark_ids.tolist())
    given = iter(got for _, got in result.associations)
    frames = []
    for frame in world.frames:
        obs = tuple(replace(o, landmark_id=next(given)) for o in frame.observations)
        frames.append(replace(frame, observations=tuple(o for o in obs if o.landmark_id in kept)))
    unused = len(result.associations) - sum(len(f.observations) for f in frames)
    assert unused > 0  # the case this test is for
    own, _ = graph_cost(replace(world, frames=tuple(frames)), result.estimate)
    assert pipeline.compute_metrics(result).final_error == pytest.approx(own, rel=COST_RTOL)
