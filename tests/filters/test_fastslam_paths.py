"""FastSLAM's particle paths (filters.fastslam_paths): each particle's path read back
through the resamplings, coalesced rows, the memory bound, and the estimate built on them."""

from __future__ import annotations

import numpy as np
import pytest

from filters import fastslam_paths
from filters.fastslam import FastSlam
from filters.fastslam_config import FastSlamConfig
from filters.fastslam_math import low_variance_resample
from filters.fastslam_paths import ParticlePaths
from graphslam import registry
from graphslam.pipelines import planar as pipeline
from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic
from slamcore.errors import GraphSlamError
from tests.filters.test_fastslam import loop_world

#: Paths are copies of recorded poses: they must come back to the bit.
EXACT = 0.0


def _brute_force(seed: int, n: int, steps: int, concentrate: bool):
    """Random poses and resamplings fed to ParticlePaths beside an explicit (N, T, 3)
    history that is permuted at every resampling (what the store must reproduce)."""
    rng = np.random.default_rng(seed)
    store = ParticlePaths(n)
    full = np.zeros((n, 0, 3))
    for row in range(steps):
        poses = rng.normal(size=(n, 3))
        full = np.concatenate([full, poses[:, None]], axis=1)
        store.record(row, poses)
        if rng.random() < 0.3:  # a refresh of the same row (a parked robot, a sighting)
            poses = rng.normal(size=(n, 3))
            full[:, row] = poses
            store.record(row, poses)
        if rng.random() < 0.5:
            w = rng.random(n) ** (8 if concentrate else 1)
            parents = low_variance_resample(w / w.sum(), rng)
            full = full[parents]
            store.resampled(parents)
    return store, full


@pytest.mark.parametrize("concentrate", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_every_particles_path_is_its_history_through_the_resamplings(seed, concentrate):
    store, full = _brute_force(seed, n=12, steps=300, concentrate=concentrate)
    for p in range(12):
        np.testing.assert_allclose(store.path(p, full.shape[1]), full[p], rtol=0, atol=EXACT)


def test_coalesced_rows_keep_one_pose_and_the_paths_are_unchanged():
    store, full = _brute_force(0, n=12, steps=300, concentrate=True)
    before = [store.path(p, 300) for p in range(12)]
    store.compact()
    # lineages meet within a few resamplings: far fewer rows than 300 keep all 12 poses
    assert store.nbytes < 300 * 12 * 3 * 8 / 4
    for p in range(12):
        np.testing.assert_array_equal(store.path(p, 300), before[p])


def test_a_store_that_outgrows_its_bound_gives_up(monkeypatch):
    monkeypatch.setattr(fastslam_paths, "MAX_PATH_BYTES", 10 * 4 * 3 * 8)
    store = ParticlePaths(4)
    for row in range(64):  # no resampling: nothing coalesces
        store.record(row, np.zeros((4, 3)))
    assert store.given_up and store.nbytes == 0
    with pytest.raises(GraphSlamError, match="given up"):
        store.path(0, 64)


def test_a_filter_whose_paths_gave_up_reports_its_means_and_says_so(monkeypatch):
    monkeypatch.setattr(fastslam_paths, "MAX_PATH_BYTES", 1000)
    ds = loop_world(seed=1)
    cfg = dict(n_particles=30, seed=0, resample_ess_fraction=0.0)
    gave_up = FastSlam(FastSlamConfig(**cfg))
    pipeline.run(ds, gave_up)
    means = FastSlam(FastSlamConfig(**cfg, trajectory="filtered"))
    pipeline.run(ds, means)
    np.testing.assert_array_equal(gave_up.estimate().wTb, means.estimate().wTb)
    assert any("weighted mean" in note for note in gave_up.numerical_recoveries())
    assert means.numerical_recoveries() == []


def test_a_filter_whose_pairings_gave_up_scores_each_steps_pairing_and_says_so(monkeypatch):
    """Unknown ids: past the bound the pairing store gives up as the path store does; the
    run is then scored with each step's best particle's pairing, and says so."""
    monkeypatch.setattr(fastslam_paths, "MAX_PATH_BYTES", 1000)
    ds = loop_world(seed=1)
    slam = FastSlam(FastSlamConfig(n_particles=30, seed=0, resample_ess_fraction=0.0, association="unknown"))
    result = pipeline.run(ds, slam)
    assert slam.final_associations() is None
    assert any("pairings outgrew" in note and "best particle" in note for note in slam.numerical_recoveries())
    m = pipeline.compute_metrics(result, with_graph_error=False)
    assert m.association is not None and m.association.accuracy is not None


@pytest.mark.parametrize("version", [1, 2])
def test_the_estimate_is_the_best_particles_path_and_map(version):
    ds = loop_world(seed=1)
    b = FastSlam(FastSlamConfig(version=version, n_particles=50, seed=3))
    pipeline.run(ds, b)
    est = b.estimate()
    assert b.resample_count > 0
    np.testing.assert_array_equal(b.current_pose(), est.wTb[-1])
    # the particle whose pose ends the path holds the estimate's map
    best = np.flatnonzero((b.particle_poses == est.wTb[-1]).all(axis=1))
    assert best.size >= 1
    ids, means, _ = b.maps.landmarks_of(int(best[0]))
    np.testing.assert_array_equal(est.landmark_ids, ids)
    np.testing.assert_array_equal(est.landmarks_w, means)
    assert len(est.wTb) == len(ds.frames)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_path_beats_the_per_step_means_where_a_loop_closes(seed):
    """The default synthetic world drives a loop: the resampling at its closure keeps the
    paths that fit the map again; the per-step means keep the drift before it."""
    ds = make_synthetic(SyntheticConfig(seed=seed))
    ate = {}
    for mode in ("path", "filtered"):
        r = pipeline.run(ds, registry.make_backend("fastslam2", overrides={"trajectory": mode}))
        ate[mode] = pipeline.compute_metrics(r, with_graph_error=False).ate_rmse_m
    assert ate["path"] < 0.6 * ate["filtered"], ate


def test_paths_repeat_to_the_bit():
    ds = loop_world(seed=2)
    runs = [pipeline.run(ds, FastSlam(FastSlamConfig(n_particles=40, seed=5))).estimate.wTb for _ in range(2)]
    np.testing.assert_array_equal(runs[0], runs[1])


def test_a_lineage_of_rows_of_any_width_follows_the_resamplings():
    """A scan's landmark ids (N, K), K varying by row, come back as the ancestor's."""
    rng = np.random.default_rng(3)
    n = 9
    store = ParticlePaths(n)
    full: list[np.ndarray] = []  # per row (N, K), permuted at every resampling
    for row in range(200):
        ids = rng.integers(0, 50, size=(n, 1 + row % 4)).astype(float)
        full.append(ids)
        store.record(row, ids)
        if rng.random() < 0.5:
            w = rng.random(n) ** 8
            parents = low_variance_resample(w / w.sum(), rng)
            full = [f[parents] for f in full]
            store.resampled(parents)
    store.compact()
    for p in range(n):
        got = store.lineage(p, range(200))
        for row in range(200):
            np.testing.assert_array_equal(got[row], full[row][p])


@pytest.mark.parametrize("version", [1, 2])
def test_unknown_ids_are_scored_as_the_estimates_particle_paired_them(version):
    """final_associations is the best particle's own pairing history: every pairing
    names a landmark of its map or one it dropped, and the estimate's landmarks are
    each paired at least once (its map was built from those sightings)."""
    backend = FastSlam(
        FastSlamConfig(version=version, n_particles=30, association="unknown", resample_ess_fraction=1.0)
    )  # lineages that differ
    res = pipeline.run(make_synthetic(), backend, max_steps=150)
    pairs = backend.final_associations()
    assert pairs is not None and len(pairs) == len(res.associations)
    assert backend.resample_count > 0
    used = set(pairs.values())
    assert set(res.estimate.landmark_ids.tolist()) <= used
    assert used - set(res.estimate.landmark_ids.tolist()) <= set(backend.pruned_landmark_ids())
