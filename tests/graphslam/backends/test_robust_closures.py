"""Robust loop closures: wrong closures must not wreck the map."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graphslam.pipelines import planar as pipeline
from slamcore.errors import ConfigError
from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
from slamcore.planar.records import LoopClosure
from tests.worlds import square_world

#: A run with false closures must stay this close (RMS position) to the clean run.
ROBUST_TOL_M = 0.05
#: ... while a plain Gaussian back end is pulled at least this far off.
DAMAGE_M = 0.5


def with_false_closures(ds, n, seed):
    """Add ``n`` closures between random far-apart poses claiming they coincide."""
    rng = np.random.default_rng(seed)
    frames = list(ds.frames)
    cov = np.diag([0.01, 0.01, 0.001])
    for _ in range(n):
        j = int(rng.integers(20, len(frames)))
        i = int(rng.integers(0, j - 10))
        lc = LoopClosure(i, j, np.zeros(3), cov, source="injected-false")
        frames[j] = dataclasses.replace(frames[j], loop_closures=frames[j].loop_closures + (lc,))
    return dataclasses.replace(ds, frames=frames)


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a.wTb[:, :2] - b.wTb[:, :2]) ** 2, axis=1))))


@pytest.mark.parametrize("config", [
    Isam2Config(loop_closure_kernel="cauchy"),
    Isam2Config(loop_closure_kernel="huber", polish_method="gnc"),
    Isam2Config(polish_method="gnc"),
], ids=["cauchy", "huber+gnc", "gnc"])
def test_false_closures_do_not_wreck_the_map(config):
    clean_ds = square_world(seed=11, loop_closure=True)
    bad_ds = with_false_closures(clean_ds, 5, seed=2)
    clean = pipeline.run(clean_ds, Isam2Backend(config)).estimate
    robust = pipeline.run(bad_ds, Isam2Backend(config)).estimate
    plain = pipeline.run(bad_ds, Isam2Backend(Isam2Config())).estimate
    assert rms(plain, clean) > DAMAGE_M  # the injected closures really are harmful
    assert rms(robust, clean) < ROBUST_TOL_M


def test_kernel_config_validation():
    with pytest.raises(ConfigError):
        Isam2Config(loop_closure_kernel="tukeyy")
    with pytest.raises(ConfigError):
        Isam2Config(polish_method="dogleg")
    with pytest.raises(ConfigError):
        Isam2Config(loop_closure_kernel_k=0)
