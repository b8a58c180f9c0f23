"""The shared benchmark timer alternates candidates and reports medians (issue 20 item 1)."""

from __future__ import annotations

import sys
import time

import pytest

from tests.conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))

import timing  # noqa: E402

#: Sleep-based timings on a loaded machine overshoot, never undershoot.
SLEEP_S = 0.002
OVERSHOOT_S = 0.02


def test_alternate_rotates_order_and_runs_setup_untimed():
    calls: list[str] = []
    fresh = []
    cands = {"a": lambda: calls.append("a"), "b": lambda: calls.append("b"),
             "c": lambda: calls.append("c")}
    out = timing.alternate(cands, repeats=3, warmup=1,
                           setup={"b": lambda: (fresh.append(1), time.sleep(SLEEP_S))})
    assert calls[:3] == ["a", "b", "c"]           # warm-up
    assert calls[3:] == ["a", "b", "c", "b", "c", "a", "c", "a", "b"]
    assert len(fresh) == 4                         # warm-up + 3 repeats
    assert all(len(t.samples_s) == 3 for t in out.values())
    # b's setup sleeps but is not timed
    assert out["b"].median_s < SLEEP_S


def test_median_not_best_of():
    out = timing.alternate({"s": lambda: time.sleep(SLEEP_S)}, repeats=5, warmup=0)
    t = out["s"]
    assert SLEEP_S <= t.median_s < SLEEP_S + OVERSHOOT_S
    assert t.median_s == pytest.approx(sorted(t.samples_s)[2])
    assert t.p25_s <= t.median_s <= t.p75_s


def test_summary_ratio_and_target():
    rec = timing.summary("x", 1.5, 1.0, target=1.2, floor="plain numpy", command="python b.py")
    assert rec["ratio"] == pytest.approx(1.5) and rec["meets_target"] is False
    assert timing.summary("y", 1.0, 1.0, target=None, floor="f", command="c")["meets_target"] is None


def test_bad_repeats_refused():
    with pytest.raises(ValueError):
        timing.alternate({"a": lambda: None}, repeats=0)


def test_blas_threads_pins_and_restores():
    from threadpoolctl import threadpool_info

    before = [p["num_threads"] for p in threadpool_info()]
    with timing.blas_threads(1):
        assert all(p["num_threads"] == 1 for p in threadpool_info())
    assert [p["num_threads"] for p in threadpool_info()] == before


def test_table_rows_from_summaries_and_missing_listed(tmp_path):
    import json

    import table

    (tmp_path / "a.json").write_text(json.dumps({"summary": timing.summary(
        "A", 0.0012, 0.001, target=1.1, floor="plain numpy", command="python benchmarks/a.py")}))
    (tmp_path / "b.json").write_text(json.dumps({"summaries": [timing.summary(
        "B1", 2.0, 1.0, target=None, floor="f", command="c")]}))
    (tmp_path / "c.json").write_text(json.dumps({"no": "summary"}))
    rows, missing = table.summaries(tmp_path)
    assert [s["name"] for _, s in rows] == ["A", "B1"] and missing == ["c"]
    text = table.render(rows, missing)
    assert "| 1.20 | 1.1 | **no** |" in text and "1.2 ms" in text and "c." in text


def test_readme_table_is_current():
    """The README's targets table is what the committed results give (re-run benchmarks/table.py)."""
    import table

    assert table.update(check=True), "benchmarks/README.md table is stale: python benchmarks/table.py"
