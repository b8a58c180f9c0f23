"""Progress of a pose-graph solve (graphslam.pipelines.progress.SolveProgress): the
default run on RRR's NewCollege went 40 s and more without a word."""

from __future__ import annotations

import io

from graphslam.pipelines import posegraph as pipeline
from graphslam.pipelines.progress import PROGRESS_LINE_INTERVAL_S, SolveProgress


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_off_a_terminal_a_line_every_interval():
    out, clock = io.StringIO(), _Clock()
    tracker = SolveProgress(file=out, clock=clock)
    for k in range(1, 40):
        clock.t = k
        tracker("lm", k)
    lines = out.getvalue().splitlines()
    assert len(lines) == int(39 // PROGRESS_LINE_INTERVAL_S)
    assert lines[0] == f"solving: batch LM iteration 10, {PROGRESS_LINE_INTERVAL_S:.0f} s"
    clock.t = 60
    tracker("init")
    assert out.getvalue().splitlines()[-1] == "solving: Shonan averaging, 60 s"  # a wait: no count


def test_on_a_terminal_the_line_is_drawn_in_place_and_cleared():
    out, clock = _Terminal(), _Clock()
    tracker = SolveProgress(file=out, clock=clock)
    clock.t = 1.0
    tracker("step", 7)
    assert out.getvalue() == "\rsolving: iSAM2 update 7, 1 s"
    tracker.close()
    assert out.getvalue().endswith("\r" + " " * len("solving: iSAM2 update 7, 1 s") + "\r")
    assert "\n" not in out.getvalue()


def test_quiet_says_nothing():
    out, clock = io.StringIO(), _Clock()
    tracker = SolveProgress(enabled=False, file=out, clock=clock)
    clock.t = 100.0
    tracker("lm", 3)
    tracker.close()
    assert out.getvalue() == ""


def test_a_solve_tells_its_points(tmp_path):
    lines = [f"VERTEX_SE2 {i} {i} 0 0" for i in range(20)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0.01 100 0 0 100 0 100" for i in range(19)]
    lines += ["EDGE_SE2 0 19 19.5 0 0.2 100 0 0 100 0 100"]
    path = tmp_path / "g.g2o"
    path.write_text("\n".join(lines) + "\n")
    from graphslam import registry

    graph = registry.load_pose_graph(str(path), "auto", "nearest")
    told = []
    pipeline.run(graph, "batch", progress=lambda point, step: told.append(point))
    assert {"lm", "certificate"} <= set(told), sorted(set(told))
