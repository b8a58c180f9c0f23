"""The pose-graph reader's bulk path gives what its line-by-line loop gives.

``graphslam.sources.posegraph_bulk.read_in_bulk`` parses a whole valid file at
once; the loop of ``graphslam.sources.posegraph_files`` (forced here by making the
bulk path decline) is the reference. Every array must be equal bit for bit, and
every refusal must still be the loop's, with its line. The frame streams of
``graphslam.sources.planar.posegraph`` convert that one reader's graph, so they
are checked through it.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from graphslam.sources import builtin_posegraphs, posegraph_bulk, posegraph_files
from graphslam.sources.planar import posegraph
from graphslam.sources.posegraph_files import TAGS
from graphslam.sources.tokens import MAX_ID, MAX_KEY_ID
from slamcore.errors import InputError

#: Pose-graph files of the gtsam wheel, 2-D and 3-D (example_with_vertices.g2o is refused,
#: the same way by both paths; example.graph has landmark lines, read by the loop alone).
GTSAM_FILES = ("w10000.graph", "w100.graph", "w20000.txt", "noisyToyGraph.txt", "toyExample.g2o",
               "w100_30.g2o", "example_with_vertices.g2o", "pose2example.txt", "example.graph",
               "sphere2500.txt", "pose3example-offdiagonal.txt", "Klaus3.g2o")


def _read(path, monkeypatch, bulk_path: bool, **kw):
    """((graph, sightings) or None, InputError message or None) through one path."""
    with monkeypatch.context() as m:
        if not bulk_path:
            m.setattr(posegraph_files, "read_in_bulk", lambda *a, **k: None)
        try:
            return posegraph_files.read_pose_graph_records(path, landmarks=True, **kw), None
        except InputError as exc:
            return None, str(exc)


def _assert_same(a, b):
    for name, va in vars(a).items():
        vb = getattr(b, name)
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype and va.shape == vb.shape, name
            assert va.tobytes() == vb.tobytes(), name  # bit for bit
        else:
            assert va == vb, name


@pytest.mark.parametrize("name", GTSAM_FILES)
@pytest.mark.parametrize("toro_noise", ["information", "sqrt_information"])
def test_gtsam_files_same_both_ways(name, toro_noise, monkeypatch):
    path = gtsam.findExampleDataFile(name)
    fast, fast_err = _read(path, monkeypatch, True, toro_noise=toro_noise)
    slow, slow_err = _read(path, monkeypatch, False, toro_noise=toro_noise)
    assert fast_err == slow_err
    if slow is not None:
        _assert_same(fast[0], slow[0])
        _assert_same(fast[1], slow[1])


def test_bulk_path_reads_w10000():
    """The bulk path itself accepts w10000 (else the test above compares the loop with itself)."""
    lines = posegraph_bulk.read_in_bulk(gtsam.findExampleDataFile("w10000.graph"), TAGS,
                                        MAX_KEY_ID)
    assert lines is not None and lines.kind == ("toro", 2, "angle")
    assert len(lines.edges) == 64311 and len(lines.vertex_ids) == 10000


_EDGES = ["EDGE2 +0 1 1.5 0.25 3.2",  # '+' id, angle past pi
          "EDGE2 2 1 -1 0.5 -3.5",  # edge written backwards
          "EDGE2 0 2 0.5 -0.1 0.7"]
#: Positive-definite off-diagonal numbers in TORO's order, one in g2o's diagonal pattern,
#: one not positive definite (replaced).
_NOISE = ["40 2 35 30 1 3", "60 0 0 50 0 40", "45 0 1 1 30 0"]


@pytest.mark.parametrize("information_fix", ["nearest", "isotropic"])
def test_every_layout_same(tmp_path, monkeypatch, information_fix):
    """Both TORO layouts, a replaced matrix, CRLF line ends, comments and blank lines (the
    line numbers must not move), vertex, EQUIV and FIX lines, a self-edge."""
    p = tmp_path / "g.graph"
    text = "# header\r\n\r\nVERTEX2 0 0 0 0\r\nVERTEX2 1 1 0 0\r\nVERTEX2 2 2 0 0\r\n"
    edges = [f"{e} {v}" for e, v in zip(_EDGES, _NOISE)] + ["EDGE2 1 1 0 0 0 1 0 1 1 0 0"]
    p.write_bytes((text + "\r\n".join(edges) + "\r\nEQUIV 0 1\r\nFIX 0\r\n").encode())
    fast, fast_err = _read(p, monkeypatch, True, information_fix=information_fix)
    slow, slow_err = _read(p, monkeypatch, False, information_fix=information_fix)
    assert fast_err is None and slow_err is None
    _assert_same(fast[0], slow[0])
    assert fast[0].n_information_fixed == 1 and fast[0].self_edge_lines.tolist() == [9]
    assert posegraph_bulk.read_in_bulk(p, TAGS, MAX_ID) is not None


@pytest.mark.parametrize("text", [
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nBR 1 5 0.1 2.0 0.01 0.1\n",  # a landmark line
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE3 2 1 1 0 0 1 0 1 1 0 0\n",  # two kinds
    "EDGE2 1 0 1 0 0 1 0 1 1 0\n",  # a token short
    "EDGE2 1 0 1 zero 0 1 0 1 1 0 0\n",
    "EDGE2 1 0 1 nan 0 1 0 1 1 0 0\n",
    "EDGE2 1 0 1_0 0 0 1 0 1 1 0 0\n",  # float() takes it, g2o does not
    "EDGE2 1 -0 1 0 0 1 0 1 1 0 0\n",  # not an id as parse_id reads one
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nVERTEX2 0 0 0 0\nVERTEX2 0 0 0 0\n",
    f"EDGE2 {MAX_KEY_ID + 1} 0 1 0 0 1 0 1 1 0 0\n",
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nFIX\n",
    "EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEQUIV 0\n",
    "VERTEX2 0 0 0 0\n# no edge\n",
])
def test_bulk_declines_what_the_loop_must_decide(tmp_path, text):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    lines = posegraph_bulk.read_in_bulk(p, TAGS, MAX_KEY_ID)
    # a vertex-only file is well formed: the assembly, common to both paths, refuses it
    assert lines is None or not len(lines.edges)


def test_poses_out_of_range_go_to_the_loop(tmp_path, monkeypatch):
    """Lines the bulk path parses but whose poses the loop refuses: the loop's line."""
    p = tmp_path / "far.g2o"
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 2e9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    assert posegraph_bulk.read_in_bulk(p, TAGS, MAX_ID) is not None
    fast, fast_err = _read(p, monkeypatch, True)
    slow, slow_err = _read(p, monkeypatch, False)
    assert fast is None and fast_err == slow_err and f"{p.name}:2:" in fast_err


def test_refusals_after_reading_keep_their_line(tmp_path, monkeypatch):
    """Checks made on the records (here, a pose gap in a frame stream) name the same line
    either way."""
    p = tmp_path / "gap.graph"
    p.write_text("# c\nEDGE2 1 0 1 0 0 1 0 1 1 0 0\n\nEDGE2 3 0 1 0 0 1 0 1 1 0 0\n")
    assert posegraph_bulk.read_in_bulk(p, TAGS, MAX_KEY_ID) is not None
    errors = []
    for bulk_path in (True, False):
        with monkeypatch.context() as m:
            if not bulk_path:
                m.setattr(posegraph_files, "read_in_bulk", lambda *a, **k: None)
            with pytest.raises(InputError) as info:
                posegraph.read_pose_graph(p, fmt="toro")
            errors.append(str(info.value))
    assert errors[0] == errors[1] and f"{Path(p).name}:4:" in errors[0]


def test_city10000_same_both_ways(monkeypatch):
    path = gtsam.findExampleDataFile("T1_city10000_04.txt")
    fast = builtin_posegraphs._city10000_in_bulk(path)
    assert fast is not None
    monkeypatch.setattr(builtin_posegraphs, "_city10000_in_bulk", lambda path: None)
    slow = builtin_posegraphs._city10000_edges(path)
    for a, b in zip(fast, slow, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
