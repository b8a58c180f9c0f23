"""Progress off a terminal: a line every few seconds, not silence (issue 35's interface list)."""

from __future__ import annotations

import io

from graphslam.pipelines import progress as pr
from graphslam.pipelines.progress import ProgressLines, progress


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_a_line_every_interval_and_a_last_one():
    out, clock = io.StringIO(), Clock()
    bar = ProgressLines(total=100, desc="isam2 on synthetic", unit="step", file=out,
                        interval_s=10.0, clock=clock)
    for k in range(100):
        clock.t += 0.25  # 4 steps a second: a line every 40 steps
        bar.update(1)
        if k == 50:
            bar.set_postfix(closures=3)
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 3, lines
    assert lines[0].startswith("isam2 on synthetic: 40/100 step (40 %); 4 step/s; about 15 s left")
    assert lines[1].endswith("closures=3")
    assert lines[2].startswith("isam2 on synthetic: 100/100 step (100 %)") and "25 s" in lines[2]


def test_short_work_prints_nothing_and_iteration_counts():
    out, clock = io.StringIO(), Clock()
    bar = ProgressLines(range(5), desc="loops", unit="img", file=out, clock=clock)
    assert list(bar) == [0, 1, 2, 3, 4] and bar.n == 5 and bar.total == 5
    bar.close()
    assert out.getvalue() == ""


def test_the_factory_picks_by_terminal(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    assert isinstance(progress(total=3, file=io.StringIO()), ProgressLines)
    assert not isinstance(progress(total=3, file=Tty()), ProgressLines)
    silent = progress(range(3), enabled=False)
    assert list(silent) == [0, 1, 2]


def test_a_logged_run_shows_its_progress(tmp_path, capsys, monkeypatch):
    from graphslam.cli.main import main

    monkeypatch.setattr(pr, "PROGRESS_LINE_INTERVAL_S", 0.0)  # a line a step
    assert main(["run", "--dataset", "synthetic", "--max-steps", "30", "--rerun", "off",
                 "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err.splitlines()
    steps = [line for line in err if line.startswith("isam2 on synthetic: ")]
    assert len(steps) >= 30 and "/30 step" in steps[0]
