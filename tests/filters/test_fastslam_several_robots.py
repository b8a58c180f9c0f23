"""FastSLAM with several robots in every particle (``--robot all``, issue 31 item 4).

Each particle holds every robot's latest pose; the parked ones must follow the
particles through resampling, a sighting of one robot by another weighs the
particles by its likelihood, and on a small three-robot world the filter must
agree with the dense joint EKF of ``test_ekf_several_robots``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters.fastslam import FastSlam
from filters.fastslam_config import FastSlamConfig
from filters.fastslam_particles import ParticleSet
from slamcore.errors import ConfigError, GraphSlamError, UnsupportedError
from slamcore.planar import geometry as models
from slamcore.planar.records import PoseSighting
from tests.filters.test_ekf_several_robots import PRIOR, R, STRIDE, _stream, feed

#: Weighted-mean position of 2000 particles against the joint EKF's estimate on the
#: three-robot world, metres: the largest over the poses (measured 0.016-0.020 m over
#: seeds 0-2) and the mean (measured 0.0057-0.0068 m; without the robots' sightings
#: of each other the particles drift to 0.015-0.024 m).
EKF_AGREEMENT_MAX_M = 0.05
EKF_AGREEMENT_MEAN_M = 0.012
#: Log-likelihood agreement, nats.
LOGL_TOL = 1e-9


def test_resampling_carries_the_parked_robots_with_their_particles():
    ps = ParticleSet(FastSlamConfig(n_particles=6, seed=0))
    ps.draw_initial(np.zeros(3), np.eye(3))
    ps.park_and_start(7, np.array([5.0, 0.0, 0.0]), np.eye(3))
    parked = ps.parked[7].copy()
    moving = ps.poses.copy()
    parents = ps.resample(np.array([0.0, 0.5, 0.0, 0.0, 0.5, 0.0]))
    np.testing.assert_array_equal(ps.parked[7], parked[parents])
    np.testing.assert_array_equal(ps.poses, moving[parents])
    ps.activate(7, 9)  # robot 7's poses move now; the other robot's are parked as 9
    np.testing.assert_array_equal(ps.poses, parked[parents])
    np.testing.assert_array_equal(ps.parked[9], moving[parents])


def test_a_sighting_weighs_each_particle_by_its_gaussian_likelihood():
    rng = np.random.default_rng(1)
    ps = ParticleSet(FastSlamConfig(n_particles=50, seed=1))
    a = rng.normal(0.0, 1.0, (50, 3))
    b = a + np.array([2.0, 1.0, 0.0]) + rng.normal(0.0, 0.3, (50, 3))
    z = np.array([2.2, 0.4])
    before = ps.logw.copy()
    ps.weigh_sighting(a, b, z, R)
    nu = models.innovation(z, models.observe(a, b[:, :2]))
    want = before - 0.5 * np.einsum("ni,ij,nj->n", nu, np.linalg.inv(R), nu)
    want -= 0.5 * math.log(np.linalg.det(2 * math.pi * R))
    want -= np.log(np.sum(np.exp(want - want.max()))) + want.max()
    np.testing.assert_allclose(ps.logw, want, atol=LOGL_TOL)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_several_robots_agree_with_the_joint_ekf(seed):
    # the EKF's trajectory is filtered: compare it with FastSLAM's filtered means
    fs = FastSlam(FastSlamConfig(n_particles=2000, seed=seed, trajectory="filtered"))
    ref = feed(fs, _stream(seed))
    est = fs.estimate()
    want = ref.trajectory()
    assert sorted(int(i) for i in est.pose_ids) == sorted(want)
    err = [np.linalg.norm(wTb[:2] - want[pid][:2]) for pid, wTb in zip(est.pose_ids.tolist(), est.wTb, strict=True)]
    assert max(err) < EKF_AGREEMENT_MAX_M, max(err)
    assert np.mean(err) < EKF_AGREEMENT_MEAN_M, np.mean(err)


def test_a_sighting_of_a_pose_no_particle_holds_is_refused():
    stream = _stream(0)[:8]
    fs = FastSlam(FastSlamConfig(n_particles=20, seed=0))
    fs.initialize(STRIDE, np.zeros(3), PRIOR)
    for _, pid, odo, seen, _ in stream[1:]:
        fs.predict(odo, pid)
    with pytest.raises(UnsupportedError, match="latest pose only"):
        fs.add_pose_sighting(PoseSighting(STRIDE, stream[-1][1], np.array([1.0, 0.1]), R))


def test_the_particle_count_is_per_robot():
    """``n_particles`` for each robot of the run: three robots, three times the particles,
    every one of them drawn, moved and weighed; one robot leaves the filter as built."""
    fs = FastSlam(FastSlamConfig(n_particles=20, seed=0))
    fs.set_robot_count(1)
    assert fs.n_particles == 20
    fs.set_robot_count(3)
    assert fs.n_particles == 60
    feed(fs, _stream(0)[:10])
    assert fs._particles.poses.shape == (60, 3) and fs._particles.logw.shape == (60,)
    assert all(p.shape == (60, 3) for p in fs._particles.parked.values())


def test_a_robot_count_the_filter_cannot_take_is_one_line():
    fs = FastSlam(FastSlamConfig(n_particles=400_000, seed=0))
    with pytest.raises(ConfigError, match="for each of 3 robots is 1200000 particles"):
        fs.set_robot_count(3)
    for bad in (0, -1, 2.5, True):
        with pytest.raises(GraphSlamError, match="positive integer"):
            fs.set_robot_count(bad)
    fs = FastSlam(FastSlamConfig(n_particles=5, seed=0))
    fs.initialize(STRIDE, np.zeros(3), PRIOR)
    with pytest.raises(GraphSlamError, match="after initialize"):
        fs.set_robot_count(2)


def test_the_pipeline_gives_fastslam_its_robot_count(shared_data):
    """``pipeline.run`` tells the back end how many robots the data holds, before the
    first particle is drawn: MRCLAM's five in one filter are 5 x 100 particles."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline
    from graphslam.sources.planar.mrclam import MrclamConfig
    from graphslam.sources.planar.mrclam_joint import read_mrclam_all

    ds = read_mrclam_all(shared_data / "mrclam6", MrclamConfig(all_robots=True))
    backend = registry.make_backend("fastslam2", overrides={"seed": 0})
    pipeline.run(ds, backend, max_steps=5)
    assert len(ds.agents) == 5 and backend.n_particles == 500
