"""The 2-D pose-graph readers' bulk path gives what their line-by-line loop gives.

``graphslam.sources.planar.bulk.read_se2_lines`` parses a whole valid file at
once; the loop (forced here by making the bulk path decline) is the reference.
Every record must be equal bit for bit, and every refusal must still be the
loop's, with its line.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from graphslam.sources.planar import bulk, posegraph
from slamcore.errors import InputError

#: Ids at or above this do not fit a gtsam symbol key (the readers' limit).
LIMIT = posegraph.SYMBOL_INDEX_LIMIT
#: Pose-graph files of the gtsam wheel (w100_30.g2o and the two 3-D ones are refused, the
#: same way by both paths).
GTSAM_FILES = ("w10000.graph", "w100.graph", "noisyToyGraph.txt", "toyExample.g2o",
               "w100_30.g2o", "example_with_vertices.g2o", "pose2example.txt")


def _loop_only(monkeypatch):
    monkeypatch.setattr(posegraph, "read_se2_lines", lambda *a, **k: None)


def _read(path, monkeypatch, bulk_path: bool, **kw):
    """(dataset or None, InputError message or None) through one path."""
    with monkeypatch.context() as m:
        if not bulk_path:
            _loop_only(m)
        try:
            return posegraph.read_pose_graph(path) if not kw else posegraph.read_toro(path, **kw), None
        except InputError as exc:
            return None, str(exc)


def _assert_same(a, b):
    assert a.name == b.name and a.source_path == b.source_path
    assert [f.pose_id for f in a.frames] == [f.pose_id for f in b.frames]
    for fa, fb in zip(a.frames, b.frames):
        pairs = [(fa.odometry, fb.odometry)] if fa.odometry or fb.odometry else []
        assert len(fa.loop_closures) == len(fb.loop_closures)
        for ea, eb in pairs + list(zip(fa.loop_closures, fb.loop_closures)):
            assert (ea.from_id, ea.to_id) == (eb.from_id, eb.to_id)
            assert type(ea.from_id) is int and type(ea.to_id) is int
            assert ea.delta.tobytes() == eb.delta.tobytes()  # bit for bit
            assert ea.covariance.tobytes() == eb.covariance.tobytes()
            assert type(ea) is type(eb)


@pytest.mark.parametrize("name", GTSAM_FILES)
def test_gtsam_files_same_both_ways(name, monkeypatch):
    path = gtsam.findExampleDataFile(name)
    fast, fast_err = _read(path, monkeypatch, bulk_path=True)
    slow, slow_err = _read(path, monkeypatch, bulk_path=False)
    assert fast_err == slow_err
    if slow is not None:
        _assert_same(fast, slow)


def test_bulk_path_reads_w10000():
    """The bulk path itself accepts w10000 (else the test above compares the loop with itself)."""
    path = gtsam.findExampleDataFile("w10000.graph")
    edges, pose_lines = bulk.read_se2_lines(path, "VERTEX2", "EDGE2", ("EQUIV",), "auto", LIMIT)
    assert len(edges) == 64311 and len(pose_lines) == 10000
    assert max(abs(e[3][2]) for e in edges) <= np.pi  # angles such as -3.15858 wrapped


_EDGES = ["EDGE2 +0 1 1.5 0.25 3.2",  # '+' id, angle past pi
          "EDGE2 2 1 -1 0.5 -3.5",  # edge written backwards
          "EDGE2 0 2 0.5 -0.1 0.7"]
#: Positive-definite off-diagonal noise numbers in each layout (TORO's, g2o's).
_NOISE = {"toro": ["40 2 35 30 1 3", "60 1 50 40 3 2", "45 0 35 55 2 1"],
          "g2o": ["40 2 1 30 3 35", "60 1 3 50 2 40", "45 0 1 35 2 55"]}


@pytest.mark.parametrize("fmt", posegraph.NOISE_FORMATS[1:])
def test_every_noise_format_same(tmp_path, monkeypatch, fmt):
    """Off-diagonal noise (covariance and information, both layouts), CRLF line ends,
    comments and blank lines (the line numbers must not move), vertex lines."""
    p = tmp_path / "g.graph"
    text = "# header\r\n\r\nVERTEX2 0 0 0 0\r\nVERTEX2 1 1 0 0\r\nVERTEX2 2 2 0 0\r\n"
    noise = _NOISE["toro" if fmt in ("graph", "toro") else "g2o"]
    edges = [f"{e} {v}" for e, v in zip(_EDGES, noise)]
    p.write_bytes((text + "\r\n".join(edges) + "\r\nEQUIV 0 1\r\n").encode())
    fast, fast_err = _read(p, monkeypatch, True, noise_format=fmt)
    slow, slow_err = _read(p, monkeypatch, False, noise_format=fmt)
    assert fast_err is None and slow_err is None
    _assert_same(fast, slow)
    assert bulk.read_se2_lines(p, "VERTEX2", "EDGE2", ("EQUIV",), fmt, LIMIT) is not None


@pytest.mark.parametrize("text", [
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nBR 1 5 0.1 2.0 0.01 0.1\n",  # a landmark line
    "EDGE2 1 0 1 0 0 1 0 1 1 0\n",  # a token short
    "EDGE2 1 0 1 zero 0 1 0 1 1 0 0\n",
    "EDGE2 1 0 1 nan 0 1 0 1 1 0 0\n",
    "EDGE2 1 -0 1 0 0 1 0 1 1 0 0\n",  # not an id as parse_id reads one
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 1 0 1 0 0 1 0 1 1 0 0\nVERTEX2 0 0 0 0\nVERTEX2 0 0 0 0\n",
    f"EDGE2 {LIMIT} 0 1 0 0 1 0 1 1 0 0\n",
    "EDGE2 1 0 1 0 0 1 2 1 1 0 0\n",  # noise matches neither auto layout
    "EDGE3 1 0 1 0 0 1 0 1 1 0 0\n",
])
def test_bulk_declines_what_the_loop_must_decide(tmp_path, text):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    assert bulk.read_se2_lines(p, "VERTEX2", "EDGE2", ("EQUIV",), "auto", LIMIT) is None


def test_information_not_positive_definite_declined(tmp_path, monkeypatch):
    p = tmp_path / "bad.g2o"
    p.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n")
    assert bulk.read_se2_lines(p, "VERTEX_SE2", "EDGE_SE2", ("FIX",), "g2o", LIMIT) is None
    with pytest.raises(InputError, match="positive definite") as info:
        posegraph.read_g2o(p)
    assert info.value.line == 1


def test_refusals_after_reading_keep_their_line(tmp_path, monkeypatch):
    """Checks made on the records (here, a pose gap) name the same line either way."""
    p = tmp_path / "gap.graph"
    p.write_text("# c\nEDGE2 1 0 1 0 0 1 0 1 1 0 0\n\nEDGE2 3 0 1 0 0 1 0 1 1 0 0\n")
    assert bulk.read_se2_lines(p, "VERTEX2", "EDGE2", ("EQUIV",), "auto", LIMIT) is not None
    fast, fast_err = _read(p, monkeypatch, True)
    slow, slow_err = _read(p, monkeypatch, False)
    assert fast is None and fast_err == slow_err and f"{Path(p).name}:4" in fast_err
