"""The fixed costs of ``graphslam run`` removed for issue 20 item 2, each kept honest.

- the Victoria Park reader's one-pass path gives the very records of the
  line-by-line path (which is kept for naming bad lines);
- the bulk record constructors refuse what the one-by-one constructors refuse;
- the parser and the 2-D run path import no scipy.stats / scipy.spatial;
- gtsam values are read out in one call with the same numbers as key by key;
- a recording made in a second process is a valid recording, and a failure
  there is reported by ``close``.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from slamcore.errors import GraphSlamError, MeasurementError
from slamcore.planar.records import (
    Observation, Odometry, odometry_batch, range_bearing_batch,
)
from tests.conftest import ROOT


def _same_records(a, b) -> None:
    assert [f.pose_id for f in a.frames] == [f.pose_id for f in b.frames]
    for fa, fb in zip(a.frames, b.frames):
        assert (fa.odometry is None) == (fb.odometry is None)
        if fa.odometry is not None:
            oa, ob = fa.odometry, fb.odometry
            assert (oa.from_id, oa.to_id) == (ob.from_id, ob.to_id)
            assert oa.delta.tobytes() == ob.delta.tobytes()
            assert oa.covariance.tobytes() == ob.covariance.tobytes()
            assert not oa.delta.flags.writeable and not oa.covariance.flags.writeable
        assert len(fa.observations) == len(fb.observations)
        for x, y in zip(fa.observations, fb.observations):
            assert (x.pose_id, x.landmark_id, x.kind) == (y.pose_id, y.landmark_id, y.kind)
            assert x.z.tobytes() == y.z.tobytes()
            assert x.covariance.tobytes() == y.covariance.tobytes()


def test_victoria_park_one_pass_reads_the_records_line_by_line_reads(monkeypatch):
    from graphslam.sources.planar import victoria_park as vp

    path = vp.victoria_park_path()
    fast = vp.read_well_formed(path)
    assert fast is not None and len(fast.frames) == 6969
    monkeypatch.setattr(vp, "read_well_formed", lambda _path, _name=None: None)
    _same_records(fast, vp.read_victoria_park(path))


@pytest.mark.parametrize("line", [
    "LANDMARK 1 7 1.0 2.0 0.5 0 0.5",  # a pose created only on the next line
    "ODOMETRY 0 1 0.1 0 0 nan 0 0 0.01 0 0.01",
    "ODOMETRY 0 1 0.1 0 0 -1 0 0 0.01 0 0.01",  # not positive definite
    "LANDMARK 0 7 0 0 0.5 0 0.5",  # zero range
    "ODOMETRY 0 1 0.1 0 0 0.01 0 0 0.01 0",  # a token short
])
def test_victoria_park_bad_input_leaves_the_one_pass_reader(tmp_path, line):
    from graphslam.sources.planar.victoria_park import read_well_formed

    good = "ODOMETRY 0 1 0.1 0 0 0.01 0 0 0.01 0 0.01\n"
    path = tmp_path / "vp.txt"
    path.write_text(line + "\n" + good if line.startswith("LANDMARK 1") else good + line + "\n")
    assert read_well_formed(path) is None


def test_bulk_records_refuse_what_single_records_refuse():
    cov3, cov2 = np.eye(3) * 0.01, np.diag([0.5, 0.05])
    built = odometry_batch([0, 1], [1, 2], [[1, 0, 0], [2, 0, 0.1]], [cov3, cov3])
    single = Odometry(1, 2, [2, 0, 0.1], cov3)
    assert built[1].delta.tobytes() == single.delta.tobytes() and built[1].to_id == 2
    seen = range_bearing_batch([3], [9], [[4.0, 0.2]], [cov2])[0]
    assert seen.z.tobytes() == Observation(3, 9, [4.0, 0.2], cov2).z.tobytes()
    asym = np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    for deltas, covs in [([[np.inf, 0, 0]], [cov3]), ([[0, 0, 0]], [-cov3]), ([[0, 0, 0]], [asym])]:
        with pytest.raises(MeasurementError, match="row 0"):
            odometry_batch([0], [1], deltas, covs)
        with pytest.raises(MeasurementError):
            Odometry(0, 1, deltas[0], covs[0])
    with pytest.raises(MeasurementError, match="range must be positive"):
        range_bearing_batch([0, 0], [1, 2], [[1.0, 0], [0.0, 0]], [cov2, cov2])
    assert odometry_batch([], [], np.zeros((0, 3)), np.zeros((0, 3, 3))) == []


def test_parser_and_planar_run_modules_do_not_import_scipy():
    """scipy.stats alone cost each run 0.3-0.6 s before any work (issue 20)."""
    code = ("import sys; from graphslam.cli.main import build_parser; build_parser(); "
            "import graphslam.pipelines.planar, graphslam.evaluation.planar, "
            "graphslam.evaluation.trajectory, graphslam.cli.run.planar, "
            # a recording's both processes (the run's imports the filters for their demos)
            "graphslam.visualisation.planar, graphslam.visualisation.filter_state; "
            "print(sorted(m for m in sys.modules if m.startswith(('scipy.stats', "
            "'scipy.spatial'))))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == "[]"


def test_values_read_in_one_call_equal_key_by_key():
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from graphslam.backends.gtsam_convert import values_to_estimate

    values = gtsam.Values()
    rng = np.random.default_rng(0)
    ids = [7, 3, 12, 0]  # not sorted: the estimate keeps this order
    for i in ids:
        values.insert(X(i), gtsam.Pose2(*rng.normal(size=3)))
    for j in (5, 2):
        values.insert(L(j), rng.normal(size=2))
    est = values_to_estimate(values, ids, [5, 2])
    for i, row in zip(ids, est.wTb):
        p = values.atPose2(X(i))
        assert row.tolist() == [p.x(), p.y(), p.theta()]
    assert est.landmarks_w.tolist() == [values.atPoint2(L(5)).tolist(),
                                        values.atPoint2(L(2)).tolist()]
    assert values_to_estimate(values, [12, 3], []).wTb.tolist() == est.wTb[[2, 1]].tolist()
    with pytest.raises(RuntimeError):  # an id that is not there is an error, as key by key
        values_to_estimate(values, [99], [])


def test_recording_in_a_second_process_is_valid_and_failures_are_reported(tmp_path):
    from graphslam.visualisation.background import BackgroundLog
    from graphslam.visualisation.planar import PlanarLog
    from graphslam.visualisation.recording import find_viewer

    path = tmp_path / "bg.rrd"
    log = BackgroundLog(PlanarLog, "save", path, None)
    poses = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    log.log_pose_columns("isam2", list(range(5)), None, poses)
    log.set_step(4)
    log.log_pose_uncertainty("isam2", poses[-1], np.eye(3))
    log.close()
    assert path.stat().st_size > 0
    exe = find_viewer()
    if exe is not None:
        done = subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    broken = BackgroundLog(PlanarLog, "no-such-mode", tmp_path / "x.rrd", None)
    broken.set_step(0)
    with pytest.raises(GraphSlamError, match="recording failed: ConfigError"):
        broken.close()


def test_long_runs_record_in_a_second_process_and_the_recording_verifies(tmp_path, monkeypatch):
    """The run's own recorder in background mode (runs of 1000 steps and more): same
    snapshots as in one process, a file ``rerun rrd verify`` accepts."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline
    from graphslam.visualisation.background import BackgroundLog
    from graphslam.visualisation.planar import RunRecorder
    from graphslam.visualisation.recording import find_viewer

    dataset = registry.load_dataset("synthetic")
    recorders = {}
    for background in (False, True):
        path = tmp_path / f"run-{background}.rrd"
        rec = RunRecorder.open("save", path, background=background)
        assert isinstance(rec.log, BackgroundLog) is background
        calls = []
        log = rec.log

        class Counting:  # counts what the recorder asks of its log, in either process
            def __getattr__(self, name):
                calls.append(name)
                return getattr(log, name)

        rec.log = Counting()
        rec.start(dataset, 60)
        backend = registry.make_backend("isam2")
        result = pipeline.run(dataset, backend, max_steps=60, on_step=rec.hook("isam2", every=7),
                              with_covariances=True)
        rec.finish("isam2", result)
        rec.close()
        recorders[background] = calls
        exe = find_viewer()
        if exe is not None:
            done = subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True)
            assert done.returncode == 0, done.stderr
    assert recorders[True] == recorders[False]
    assert recorders[True].count("log_estimate") == 60 // 7 + 1 + 1  # snapshots and the end
    # read back: the second process (which leaves by os._exit once the file is closed)
    # wrote every row the run's own process writes
    from tests.recordings import entity_rows

    for entity, component, rows in (("/world/isam2/pose", "Arrows2D:origins", 61),  # and the end
                                    ("/world/isam2/trajectory", "LineStrips2D:strips", 10),
                                    ("/world/isam2/landmarks", "Points2D:positions", 9),  # none at 0
                                    ("/world/isam2/landmark_ellipses", "LineStrips2D:strips", 1),
                                    ("/plots/isam2/pose_sigma_m", "Scalars:scalars", 10)):
        logged = {bg: entity_rows(tmp_path / f"run-{bg}.rrd", entity, component)
                  for bg in (False, True)}
        assert len(logged[True]) == rows, entity
        assert logged[True] == logged[False], entity


def test_pose_graph_edges_checked_in_bulk_equal_one_by_one(monkeypatch):
    import graphslam.sources.planar.posegraph as pg

    fast = pg.read_city10000()
    monkeypatch.setattr(pg, "edge_records", pg.edge_records_one_by_one)
    slow = pg.read_city10000()
    for fa, fb in zip(fast.frames, slow.frames, strict=True):
        recs = [r for r in (fa.odometry, *fa.loop_closures) if r is not None]
        again = [r for r in (fb.odometry, *fb.loop_closures) if r is not None]
        assert [(type(r), r.from_id, r.to_id, r.delta.tobytes(), r.covariance.tobytes())
                for r in recs] == [(type(r), r.from_id, r.to_id, r.delta.tobytes(),
                                    r.covariance.tobytes()) for r in again]


@pytest.mark.parametrize("name", ["isam2", "ekf"])
def test_landmark_covariances_alone_equal_those_of_the_full_estimate(name):
    """What the recording asks for at the end instead of every pose marginal."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    backend = registry.make_backend(name)
    pipeline.run(registry.load_dataset("synthetic"), backend, max_steps=40)
    full = backend.estimate(with_covariances=True).landmark_covariances
    alone = backend.landmark_covariances()
    assert len(full) > 0 and np.array_equal(alone, full)


def test_failed_background_recording_is_a_warning_not_a_lost_run(capsys):
    """A recording process that fails (here: its log cannot be built) is reported at
    close as one warning line; close_recorder returns False so the run goes on to its
    map and summary instead of ending in an error after its files were written."""
    from graphslam.cli.out_folder import close_recorder
    from graphslam.visualisation.background import BackgroundLog

    log = BackgroundLog(int, "not a number")   # int("not a number") raises in the child
    log.anything(1, 2)                          # calls after the failure are dropped
    assert close_recorder(log) == "broken"
    assert "recording failed" in capsys.readouterr().err
