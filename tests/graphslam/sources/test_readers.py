"""Tests of the dataset readers (graphslam.sources.planar.victoria_park / posegraph).

Noise interpretation is checked factor by factor against gtsam's own loaders (TORO
noise as gtsam's NoiseFormatTORO reads it: information, the one reader's reading).
"""

from __future__ import annotations

import functools
import math
import re

import gtsam
import numpy as np
import pytest

from slamcore.errors import InputError
from graphslam.sources.planar.posegraph import read_city10000, read_pose_graph
from graphslam.sources.posegraph_files import read_pose_graph_file, read_pose_graph_records
from graphslam.sources.planar.victoria_park import read_victoria_park, victoria_park_path
from slamcore.planar.records import ObservationKind

#: Relative tolerance when comparing our numbers with gtsam's (both parse the
#: same decimal text; the only differences are inversion round-off).
REL_TOL = 1e-9
#: Published optimum of w10000 with load2D's noise and a 1e-3 prior.
W10000_OPTIMUM = 144.867


def _edges(ds):
    """All relative-pose records of a pose-graph Dataset, in frame order."""
    out = []
    for f in ds.frames:
        if f.odometry is not None:
            out.append(f.odometry)
        out.extend(f.loop_closures)
    return out


def _between_factors(graph):
    return [graph.at(i) for i in range(graph.size())
            if isinstance(graph.at(i), gtsam.BetweenFactorPose2)]


def _edge_key(a, b):
    return (int(a), int(b))


def _assert_edges_match_gtsam(ds, graph):
    """Our edges and gtsam's BetweenFactorPose2s agree one to one: keys, value, covariance.

    Both sides are sorted by (from, to) with a stable sort, so repeated pairs
    keep their file order.
    """
    ours = _edges(ds)
    theirs = _between_factors(graph)
    assert len(ours) == len(theirs)
    k1 = np.array([(e.from_id, e.to_id) for e in ours], dtype=np.int64)
    k2 = np.array([tuple(f.keys()) for f in theirs], dtype=np.int64)
    o1 = np.lexsort((k1[:, 1], k1[:, 0]))
    o2 = np.lexsort((k2[:, 1], k2[:, 0]))
    np.testing.assert_array_equal(k1[o1], k2[o2])
    d1 = np.array([e.delta for e in ours])[o1]
    d2 = np.array([[m.x(), m.y(), m.theta()] for m in (f.measured() for f in theirs)])[o2]
    np.testing.assert_allclose(d1[:, :2], d2[:, :2], rtol=REL_TOL, atol=1e-12)
    assert np.max(np.abs(d1[:, 2] - d2[:, 2])) < 1e-12  # both wrapped to [-pi, pi)
    c1 = np.array([e.covariance for e in ours])[o1]
    c2 = np.array([f.noiseModel().covariance() for f in theirs])[o2]
    scale = np.max(np.abs(c2), axis=(1, 2), keepdims=True)
    assert np.all(np.abs(c1 - c2) <= REL_TOL * scale)


# ------------------------------------------------------------------- Victoria Park
@pytest.fixture(scope="module")
def victoria():
    return read_victoria_park(victoria_park_path())


def test_victoria_park_counts(victoria):
    ds = victoria
    assert ds.name == "victoria-park"
    assert len(ds.frames) == 6969
    obs = [o for f in ds.frames for o in f.observations]
    assert len(obs) == 3640
    assert len({o.landmark_id for o in obs}) == 151
    assert ds.frames[0].pose_id == 0 and ds.frames[0].odometry is None
    assert all(f.odometry is not None for f in ds.frames[1:])
    assert all(o.kind is ObservationKind.RANGE_BEARING for o in obs)
    assert all(o.pose_id == f.pose_id for f in ds.frames for o in f.observations)
    assert ds.source_path == victoria_park_path()
    assert not ds.has_timestamps and not ds.has_ground_truth
    np.testing.assert_array_equal(ds.prior_wTb, np.zeros(3))
    np.testing.assert_array_equal(ds.prior_covariance, np.eye(3) * 1e-6)
    # ids kept as in the file: landmark 5 sits between poses 4 and 6
    assert [f.pose_id for f in ds.frames[:6]] == [0, 1, 2, 3, 4, 6]
    assert ds.frames[5].odometry.from_id == 4


def test_victoria_park_matches_load2d(victoria):
    graph, _ = gtsam.load2D(victoria_park_path())
    odo = {f.odometry.to_id: f.odometry for f in victoria.frames[1:]}
    obs = [o for f in victoria.frames for o in f.observations]
    n_between = n_br = 0
    obs_iter = iter(obs)
    for i in range(graph.size()):
        f = graph.at(i)
        if isinstance(f, gtsam.BetweenFactorPose2):
            a, b = f.keys()
            e = odo[b]
            assert (e.from_id, e.to_id) == (a, b)
            m = f.measured()
            np.testing.assert_allclose(e.delta, [m.x(), m.y(), m.theta()], rtol=REL_TOL,
                                       atol=1e-15)
            np.testing.assert_allclose(np.sqrt(np.diag(e.covariance)),
                                       f.noiseModel().sigmas(), rtol=REL_TOL)
            np.testing.assert_allclose(e.covariance, f.noiseModel().covariance(),
                                       rtol=REL_TOL, atol=1e-18)
            n_between += 1
        else:
            assert isinstance(f, gtsam.BearingRangeFactor2D)
            o = next(obs_iter)  # load2D keeps file order, so do we
            pose_key, lm_key = f.keys()
            assert pose_key == o.pose_id
            assert lm_key == gtsam.symbol_shorthand.L(o.landmark_id)
            m = f.measured()
            assert o.z[0] == pytest.approx(m.range(), rel=REL_TOL)
            assert o.z[1] == pytest.approx(m.bearing().theta(), rel=REL_TOL, abs=1e-15)
            bearing_sigma, range_sigma = f.noiseModel().sigmas()
            np.testing.assert_allclose(np.sqrt(np.diag(o.covariance)),
                                       [range_sigma, bearing_sigma], rtol=REL_TOL)
            assert o.covariance[0, 1] == 0.0
            n_br += 1
    assert n_between == 6968 and n_br == 3640
    assert next(obs_iter, None) is None


def test_victoria_park_landmark_for_older_pose(tmp_path):
    p = tmp_path / "vp.txt"
    p.write_text("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\n"
                 "ODOMETRY 1 2 1 0 0 0.01 0 0 0.01 0 0.01\n"
                 "LANDMARK 1 7 3 4 0.4 0 0.4\n")
    ds = read_victoria_park(p)
    assert len(ds.frames[1].observations) == 1 and not ds.frames[2].observations
    o = ds.frames[1].observations[0]
    assert o.z[0] == pytest.approx(5.0) and o.z[1] == pytest.approx(math.atan2(4, 3))
    np.testing.assert_allclose(o.covariance, np.diag([0.4, 0.04]))


@pytest.mark.parametrize("text, line, words", [
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0\n", 1, "tokens"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nLANDMARK 1 5 x 1 0.4 0 0.4\n", 2,
     "not a number"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\n\n# c\nLANDMARK 1 5 nan 1 0.4 0 0.4\n", 4,
     "not finite"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nLANDMARK 3 5 1 1 0.4 0 0.4\n", 2,
     "does not exist"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nODOMETRY 2 3 1 0 0 0.01 0 0 0.01 0 0.01\n",
     2, "does not exist"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 -0.01 0 0.01\n", 1, "positive definite"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nLANDMARK 1 5 1 1 0 0 0.4\n", 2,
     "positive definite"),
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nGPS 1 2 3\n", 2, "unknown tag"),
    # longer than int() converts (4300 digits): refused, not a ValueError
    ("ODOMETRY 0 1 1 0 0 0.01 0 0 0.01 0 0.01\nLANDMARK 1 " + "5" * 5000 + " 1 1 0.4 0 0.4\n",
     2, "out of range"),
])
def test_victoria_park_bad_lines(tmp_path, text, line, words):
    p = tmp_path / "bad_vp.txt"
    p.write_text(text)
    with pytest.raises(InputError) as info:
        read_victoria_park(p)
    assert info.value.line == line
    assert info.value.path == str(p)
    msg = str(info.value)
    assert f"bad_vp.txt:{line}" in msg and words in msg


# ------------------------------------------------------------------------ w10000
@pytest.fixture(scope="module")
def w10000_path():
    return gtsam.findExampleDataFile("w10000.graph")


@pytest.fixture(scope="module")
def w10000(w10000_path):
    return read_pose_graph(w10000_path, fmt="toro")


def test_w10000_counts(w10000, w10000_path):
    ds = w10000
    assert len(ds.frames) == 10000
    assert [f.pose_id for f in ds.frames] == list(range(10000))
    assert len(_edges(ds)) == 64311
    assert ds.frames[0].odometry is None
    assert all(f.odometry is not None for f in ds.frames[1:])
    # direction kept as in the file: "EDGE2 1 0 ..."
    assert (ds.frames[1].odometry.from_id, ds.frames[1].odometry.to_id) == (1, 0)
    for f in ds.frames:
        for lc in f.loop_closures:
            assert max(lc.from_id, lc.to_id) == f.pose_id and lc.source == "dataset"


def test_w10000_matches_load2d(w10000, w10000_path):
    graph, _ = gtsam.load2D(w10000_path)
    _assert_edges_match_gtsam(w10000, graph)


def _graph_from_records(ds, prior_sigma=1e-3):
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(ds.frames[0].pose_id, gtsam.Pose2(0, 0, 0),
                                     gtsam.noiseModel.Isotropic.Sigma(3, prior_sigma)))
    for e in _edges(ds):
        graph.add(gtsam.BetweenFactorPose2(
            e.from_id, e.to_id, gtsam.Pose2(*e.delta),
            gtsam.noiseModel.Gaussian.Covariance(np.asarray(e.covariance))))
    return graph


@pytest.mark.slow
def test_w10000_optimum(w10000, w10000_path):
    _, initial = gtsam.load2D(w10000_path)
    graph = _graph_from_records(w10000)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    assert graph.error(result) == pytest.approx(W10000_OPTIMUM, rel=1e-3)


# ---------------------------------------------------- noise formats, synthetic
#: Noise numbers positive definite in g2o layout [[v1 v2 v3], [v2 v4 v5], [v3 v5 v6]]
_G2O_NOISE = [(40, 2, 3, 30, 1, 50), (60, 1, 2, 50, 3, 40), (45, 0, 1, 35, 2, 55)]
#: ... and in TORO layout [[v1 v2 v5], [v2 v3 v6], [v5 v6 v4]]
_TORO_NOISE = [(40, 2, 35, 30, 1, 3), (60, 1, 50, 40, 3, 2), (45, 0, 35, 55, 2, 1)]


def _write_graph(tmp_path, tag, suffix, noise):
    p = tmp_path / f"g{suffix}"
    lines = [f"{tag} {a} {b} 1 0.1 0.05 " + " ".join(map(str, v))
             for (a, b), v in zip([(0, 1), (1, 2), (0, 2)], noise)]
    p.write_text("\n".join(lines) + "\n")
    return p


def test_toro_noise_is_information_as_load2d_reads_it_with_noise_format_toro(tmp_path):
    # was parametrised over gtsam's four noise formats: the one reader reads TORO's six
    # numbers as the format defines them (information), whatever the back end (issue 36)
    p = _write_graph(tmp_path, "EDGE2", ".graph", _TORO_NOISE)
    graph, _ = gtsam.load2D(str(p), None, 0, False, True, gtsam.NoiseFormat.NoiseFormatTORO)
    _assert_edges_match_gtsam(read_pose_graph(p, fmt="toro"), graph)


def test_g2o_matches_readg2o(tmp_path):
    p = _write_graph(tmp_path, "EDGE_SE2", ".g2o", _G2O_NOISE)
    # gtsam's parser stops at the first line it does not know (FIX), so FIX goes last
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
                 + p.read_text() + "FIX 0\n")
    graph, _ = gtsam.readG2o(str(p), False)
    ds = read_pose_graph(p, fmt="g2o")
    assert [f.pose_id for f in ds.frames] == [0, 1, 2]
    assert len(ds.frames[2].loop_closures) == 1
    _assert_edges_match_gtsam(ds, graph)
    _assert_edges_match_gtsam(read_pose_graph(p), graph)


def test_toro_numbers_load2d_refuses_are_read_as_the_batch_reader_reads_them(tmp_path):
    # was: refused as gtsam.load2D's automatic noise format refuses them; the one reader
    # reads them in TORO's order as information, here not positive definite (issue 36)
    p = _write_graph(tmp_path, "EDGE2", ".graph", _G2O_NOISE)
    ds = read_pose_graph(p)
    batch = read_pose_graph_file(p)
    assert batch.n_information_fixed == 3 and "3 edges' information" in ds.notes[0]
    np.testing.assert_allclose([np.linalg.inv(e.covariance) for e in _edges(ds)],
                               batch.information, rtol=1e-9)
    with pytest.raises(InputError, match="not positive definite") as info:
        read_pose_graph(p, information_fix="refuse", fmt="toro")
    assert info.value.line == 1


def _information_by_edge(ds):
    return {(e.from_id, e.to_id): np.linalg.inv(e.covariance) for e in _edges(ds)}


@pytest.mark.parametrize("name", ["w20000.txt", "w100.graph", "example.graph"])
def test_a_toro_file_gets_the_same_information_streamed_or_solved_whole(name):
    """A filter run streams the frames (registry.load_dataset), a batch run solves the
    graph (registry.load_pose_graph): the same matrices. w20000 is the wheel file whose
    numbers load2D read as a covariance; example.graph has landmark lines, which only
    the frame stream reads (the batch side is then the reader with landmarks)."""
    from graphslam import registry

    path = gtsam.findExampleDataFile(name)
    frames = _information_by_edge(registry.load_dataset(path))
    graph = (read_pose_graph_records(path, landmarks=True)[0] if name == "example.graph"
             else registry.load_pose_graph(path))
    assert len(frames) == graph.n_edges
    for (a, b), info in zip(graph.edges.tolist(), graph.information):
        np.testing.assert_allclose(frames[(a, b)], info, rtol=1e-12, atol=1e-12)


def test_a_bad_line_is_refused_once_with_file_and_line_by_the_one_reader(tmp_path, monkeypatch):
    """Both paths refuse a bad line with the one reader's message, naming file and line,
    and the frame stream adds no parsing of its own (the reader runs once)."""
    from graphslam.sources import posegraph_files

    p = tmp_path / "bad.graph"
    p.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\n# c\nEDGE2 0 1 1 0 zero 1 0 1 1 0 0\n")
    calls = []
    real = posegraph_files.iter_lines
    monkeypatch.setattr(posegraph_files, "iter_lines", lambda path: calls.append(path) or real(path))
    messages = []
    for read in (read_pose_graph, read_pose_graph_file):
        with pytest.raises(InputError) as info:
            read(p)
        assert (info.value.path, info.value.line) == (str(p), 4)
        messages.append(str(info.value))
    assert len(calls) == 2  # once a path: the bulk path declined, the line loop named it
    assert messages[0] == messages[1] == f"{p}:4: 'zero' is not a number (decimal ASCII digits)"
    assert "\n" not in messages[0]


@pytest.mark.parametrize("text, line, words", [
    ("VERTEX2 0 0 0 0\nEDGE2 1 0 1 0 0 1 0 1 1 0\n", 2, "tokens"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 2 1 1 zero 0 1 0 1 1 0 0\n", 2, "not a number"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\n\n# c\nEDGE2 2 1 1 0 inf 1 0 1 1 0 0\n", 4, "not finite"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 2 1 NaN 0 0 1 0 1 1 0 0\n", 2, "not finite"),
    ("VERTEX2 1.5 0 0 0\n", 1, "not an integer"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 3 2 1 0 0 1 0 1 1 0 0\n"
     "EDGE2 3 1 1 0 0 1 0 1 1 0 0\n", 2, "no edge to pose 1"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 3 0 1 0 0 1 0 1 1 0 0\n", 2, "pose 2 is missing"),
    # was "unknown tag": the one reader knows EDGE3 (TORO 3-D) and refuses the mix (issue 36)
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE3 2 1 1 0 0 1 0 1 1 0 0\n", 2, "EDGE3 in a 2-D toro file"),
    ("EDGE2 1 1 1 0 0 1 0 1 1 0 0\n", 1, "itself"),
    ("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 2 " + "7" * 5000 + " 1 0 0 1 0 1 1 0 0\n", 2,
     "larger than 2**56 - 1"),  # the frame-stream reader's bound: ids become symbol keys
])
def test_toro_bad_lines(tmp_path, text, line, words):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    with pytest.raises(InputError) as info:
        read_pose_graph(p, fmt="toro")
    assert info.value.line == line and info.value.path == str(p)
    assert f"bad.graph:{line}" in str(info.value) and words in str(info.value)


def test_an_edge_from_a_pose_to_itself_is_left_out_and_said(tmp_path):
    # was refused: the one reader leaves such edges out and counts them, as the batch
    # solvers always did (issue 36); leading zeros past int()'s 4300 digits: the id is 1
    p = tmp_path / "self.graph"
    p.write_text("EDGE2 1 0 1 0 0 1 0 1 1 0 0\nEDGE2 1 " + "0" * 4999 + "1 1 0 0 1 0 1 1 0 0\n")
    ds = read_pose_graph(p, fmt="toro")
    assert len(ds.frames) == 2 and not ds.frames[1].loop_closures
    assert ds.notes == ("1 edges from a pose to itself left out (lines 2): they constrain "
                        "nothing",)


@pytest.mark.parametrize("reader", [read_victoria_park, functools.partial(read_pose_graph, fmt="toro"),
                                    functools.partial(read_pose_graph, fmt="g2o"), read_pose_graph])
def test_missing_file(tmp_path, reader):
    p = tmp_path / "nope.txt"
    with pytest.raises(InputError) as info:
        reader(p)
    assert "nope.txt" in str(info.value) and info.value.line is None


def test_read_pose_graph_unknown_content(tmp_path):
    p = tmp_path / "x.dat"
    p.write_text("# hi\nPOINT 1 2\n")
    with pytest.raises(InputError) as info:
        read_pose_graph(p)
    assert info.value.line == 2


# ----------------------------------------------------------------------- city10000
def test_city10000():
    ds = read_city10000()
    assert ds.name == "city10000"
    assert len(ds.frames) == 10000 and ds.has_ground_truth
    ids, wTb = ds.ground_truth()
    assert wTb.shape == (10000, 3) and ids[0] == 0 and ids[-1] == 9999
    n_lines = sum(1 for line in open(gtsam.findExampleDataFile("T1_city10000_04.txt"))
                  if line.strip())
    assert len(_edges(ds)) == n_lines
    sig = np.sqrt(np.diag(ds.frames[1].odometry.covariance))
    np.testing.assert_allclose(sig, [1 / 30, 1 / 30, 1 / 100])
    # first hypothesis kept: line 2 is "EDGE2 1 1 2 0 1 0.999423 0.016409 -0.005213"
    np.testing.assert_allclose(ds.frames[2].odometry.delta, [0.999423, 0.016409, -0.005213])


def test_city10000_truth_count_mismatch(tmp_path):
    g = tmp_path / "c.txt"
    g.write_text("EDGE2 0 1 1 0 1 1 0 0\nEDGE2 1 1 2 0 2 1 0 0 5 5 5\n")
    gt = tmp_path / "gt.txt"
    gt.write_text("0 0 0\n1 0 0\n")
    with pytest.raises(InputError) as info:
        read_city10000(g, gt)
    assert "gt.txt" in str(info.value)
    gt.write_text("0 0 0\n1 0 0\n2 0 0\n")
    ds = read_city10000(g, gt)
    np.testing.assert_allclose(ds.frames[2].odometry.delta, [1, 0, 0])
    g.write_text("EDGE2 0 1 1 0 2 1 0 0\n")
    with pytest.raises(InputError) as info:
        read_city10000(g, gt)
    assert info.value.line == 1 and "c.txt:1" in str(info.value)


@pytest.mark.parametrize("token, words", [
    ("12", None), ("+12", None), ("0007", None),
    ("-3", "out of range: negative"), ("3.0", "not an integer"), ("1e3", "not an integer"),
    ("１２", "not an integer"), (str(2**62 + 1), "larger than 2**62"),
])
def test_one_id_parser_for_every_line_reader(token, words):
    """graphslam.sources.tokens.parse_id: the pose-graph, TORO/g2o frame-stream and
    Victoria Park readers all read ids with it, so they refuse alike."""
    from graphslam.sources.tokens import MAX_KEY_ID, parse_id
    from slamcore.errors import InputError

    if words is None:
        assert parse_id(token, "f", 3) == int(token)
        return
    with pytest.raises(InputError, match=re.escape(words)):
        parse_id(token, "f", 3)
    with pytest.raises(InputError, match="out of range: larger than 2\\*\\*56 - 1"):
        parse_id(str(2**56), "f", 3, limit=MAX_KEY_ID)


def test_the_posegraph_section_reaches_a_streamed_file(tmp_path):
    """``[posegraph] toro_noise`` is read for a filter's frame stream as for batch: a
    file whose TORO numbers are the square root of the information gets the squared
    information in both."""
    from graphslam import registry

    path = tmp_path / "g.graph"
    path.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 2 0 2 2 0 0\n")
    cfg = tmp_path / "c.toml"
    cfg.write_text('[posegraph]\ntoro_noise = "sqrt_information"\n')
    streamed = registry.load_dataset(str(path), config=str(cfg))
    whole = registry.load_pose_graph(path, "sqrt_information")
    info = np.linalg.inv(streamed.frames[1].odometry.covariance)
    np.testing.assert_allclose(info, whole.information[0], rtol=1e-12)
    default = registry.load_dataset(str(path))
    assert not np.allclose(np.linalg.inv(default.frames[1].odometry.covariance), info)
