"""The numpy floor of ``benchmarks/bench_fastslam.py`` is a correct FastSLAM (issue 17 item 5).

Its speed ratio only means something if the floor does the same filtering as
ours: same draws in the same order, same estimate to round-off.
"""

from __future__ import annotations

import json

import pytest

from tests.benchmarks import load_benchmark

#: Steps of the seeded simulated run (about 10 observations a step, new landmarks and resamplings).
STEPS = 30
#: Particles: enough for several resamplings, few enough for a test.
PARTICLES = 50


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("bench_fastslam")


@pytest.fixture(scope="module")
def run(bench):
    return bench.simulated_run(150, STEPS, seed=0)


@pytest.mark.parametrize("version", [1, 2])
def test_floor_estimate_equals_ours_to_round_off(bench, run, version):
    ours = bench.FastSlam(bench.FastSlamConfig(version=version, n_particles=PARTICLES, seed=3))
    bench.run_backend(run, ours)
    floor = bench.run_floor(run, bench.FloorFastSlam(version, PARTICLES, seed=3))
    assert ours.resample_count > 0  # resampling is part of what is compared
    assert bench.floor_agreement_m(ours, floor) <= bench.FLOOR_AGREEMENT_M


@pytest.mark.parametrize("version", [1, 2])
def test_agreement_check_sees_a_different_filter(bench, run, version):
    """Other draws give another estimate, far beyond the tolerance: the check can fail."""
    ours = bench.FastSlam(bench.FastSlamConfig(version=version, n_particles=PARTICLES, seed=3))
    bench.run_backend(run, ours)
    floor = bench.run_floor(run, bench.FloorFastSlam(version, PARTICLES, seed=4))
    assert bench.floor_agreement_m(ours, floor) > 1000 * bench.FLOOR_AGREEMENT_M


def test_summaries_carry_the_fastslam_target(bench, tmp_path):
    out = tmp_path / "fs.json"
    assert bench.main(["--quick", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert {(s["version"], s["n_particles"]) for s in got["summaries"]} == {
        (v, n) for v in (1, 2) for n in (10, 100)}
    for s in got["summaries"]:
        assert s["target"] == bench.timing.TARGETS["fastslam"]
        assert s["ratio"] == pytest.approx(s["ours"] / s["floor_value"])
    assert all(r["agreement_m"] <= bench.FLOOR_AGREEMENT_M for r in got["vs_particles"])
