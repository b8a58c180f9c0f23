"""``benchmarks/bench_filter_seeds.py --victoria-park`` (issue 17 item 4)."""

from __future__ import annotations

import json

import pytest

from tests.benchmarks import load_benchmark

#: A prefix of Victoria Park short enough for a test, long enough to see landmarks.
STEPS = 40


def test_victoria_park_writes_the_spread_per_filter(tmp_path, capsys):
    bench = load_benchmark("bench_filter_seeds")
    out = tmp_path / "vp.json"
    assert bench.main(["--victoria-park", "--seeds", "0", "1", "--max-steps", str(STEPS),
                       "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["max_steps"] == STEPS
    assert got["ekf_rms_m"] > 0.0  # the EKF is not the iSAM2 solution it is measured against
    for backend in ("fastslam1", "fastslam2"):
        per_seed = got[backend]["rms_m"]
        assert sorted(per_seed) == ["0", "1"]
        assert got[backend]["worst_m"] == max(per_seed.values())
        assert min(per_seed.values()) <= got[backend]["median_m"] <= got[backend]["worst_m"]
        for seed in got[backend]["seeds_above_goal"]:
            assert per_seed[str(seed)] > bench.VP_EKF_RATIO * got["ekf_rms_m"]
    assert "first 40 steps" in capsys.readouterr().out


def test_max_steps_needs_victoria_park():
    bench = load_benchmark("bench_filter_seeds")
    with pytest.raises(SystemExit):
        bench.main(["--seeds", "0", "--max-steps", "10"])


@pytest.mark.parametrize("argv", [["--from", "1", "--to", "0"],
                                  ["--victoria-park", "--seeds", "0", "--max-steps", "1"]])
def test_bad_ranges_are_refused_before_any_run(argv):
    with pytest.raises(SystemExit):
        load_benchmark("bench_filter_seeds").main(argv)
