"""The visual pipeline and ``graphslam run`` on image sequences, end to end.

A test-double back end (perfect predictions from ground truth) checks the
wiring; the real back ends run when their modules are present.
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

from slamcore.spatial.geometry import invert_pose, so3_exp
from frontend.tracking import Tracker
from frontend.tracking_config import TrackerConfig
from graphslam.pipelines import spatial as vp
from graphslam.cli.main import main
from slamcore.config import ConfigFile, from_dict
from slamcore.errors import ConfigError, GraphSlamError, UnsupportedError
from graphslam.sources.spatial.sequence import ImageSequence
from graphslam.sources.spatial import synthetic_images as si
from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
from slamcore.spatial.records import PixelPredictions, VisualEstimate
from slamcore.spatial.backend import VisualBackend
from slamcore.spatial.geometry import rotation_to_quaternion
from tests.conftest import ROOT, SHARED_DATA

QVGA = dict(width=320, height=240, fx=250.0, fy=250.0, cx=159.5, cy=119.5)
KITTI07 = SHARED_DATA / "kitti07"


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_images(SyntheticImagesConfig(**QVGA, n_frames=300))


class TruthBackend(VisualBackend):
    """Test double: maps a track from the true depth under its first pixel, predicts
    it exactly from the true pose (S = 3 px sigma), and reports the odometry-composed
    poses as its estimate. Records every call."""

    name = "truth"

    def __init__(self, seq, has_motion_model=False):
        self.seq = seq
        self.has_motion_model = has_motion_model
        self.calls: list[tuple] = []
        self.points: dict[int, np.ndarray] = {}
        self.observed: list[np.ndarray] = []

    def initialize(self, frame_id, wTc, covariance, K, image_size):
        self.calls.append(("initialize", frame_id))
        self.k = frame_id
        self.poses = [np.asarray(wTc)]
        self.ids = [frame_id]
        assert np.allclose(K, self.seq.K) and tuple(image_size) == tuple(self.seq.image_size)

    def predict(self, frame_id, odometry, covariance):
        self.calls.append(("predict", frame_id, None if odometry is None else odometry.copy()))
        self.k = frame_id
        # without odometry, its "motion model" is the truth scaled by 2 (a monocular scale)
        if odometry is None:
            T = self.seq.wTc_true[frame_id].copy()
            t0 = self.seq.wTc_true[0, :3, 3]
            T[:3, 3] = t0 + 2.0 * (T[:3, 3] - t0)
            self.poses.append(T)
        else:
            self.poses.append(self.poses[-1] @ odometry)
        self.ids.append(frame_id)

    def predict_observations(self):
        self.calls.append(("predict_observations", self.k))
        ids = sorted(self.points)
        if not ids:
            return PixelPredictions(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        uv, z = self.seq.project(self.k, np.array([self.points[i] for i in ids]))
        W, H = self.seq.image_size
        ok = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        return PixelPredictions(np.array(ids, np.int64)[ok], uv[ok],
                                np.tile(9.0 * np.eye(2), (int(ok.sum()), 1, 1)))

    def update(self, observations):
        self.calls.append(("update", self.k, len(observations)))
        self.observed.append(observations.track_ids.copy())
        depth = self.seq.render(self.k)[1]
        T = self.seq.wTc_true[self.k]
        for tid, uv in zip(observations.track_ids, observations.uv_px):
            if int(tid) in self.points or len(self.points) >= 60:
                continue
            z = float(depth[int(round(uv[1])), int(round(uv[0]))])
            if np.isfinite(z):
                p_c = np.linalg.inv(self.seq.K) @ [uv[0], uv[1], 1.0] * z
                self.points[int(tid)] = T[:3, :3] @ p_c + T[:3, 3]

    def estimate(self):
        ids = sorted(self.points)
        return VisualEstimate(np.array(self.ids, np.int64), np.array(self.poses), np.array(ids, np.int64),
                              np.array([self.points[i] for i in ids]).reshape(-1, 3), None,
                              {"mapped": len(ids)})


def test_pipeline_drives_the_backend_frame_by_frame(seq):
    backend = TruthBackend(seq)
    result = vp.run(seq, backend, Tracker(TrackerConfig(), follow_unmapped=False), max_frames=12)
    assert result.frames == 12 and not result.interrupted and result.odometry == "sequence"
    kinds = [c[0] for c in backend.calls]
    assert kinds[:2] == ["initialize", "update"]
    assert kinds[2:] == ["predict", "predict_observations", "update"] * 11
    # odometry k-1 -> k is the sequence's own
    for c in backend.calls:
        if c[0] == "predict":
            assert np.array_equal(c[2], seq.odometry[c[1] - 1])
    assert np.array_equal(result.estimate.frame_ids, np.arange(12))
    # with exact predictions the landmarks are found again by active search
    assert np.mean(result.tracking["found"][1:]) > 5
    assert np.array_equal(result.estimate.wTc[0], seq.wTc_true[0])


def test_metrics_state_alignment_and_compare_to_odometry(seq):
    result = vp.run(seq, TruthBackend(seq), Tracker(TrackerConfig(), follow_unmapped=False),
                    max_frames=10)
    m = vp.compute_metrics(result, seed=0).to_dict()
    # the double reports the odometry chain, so its ATE is the odometry's
    assert m["ate_rmse_m"] == pytest.approx(m["odometry_ate_rmse_m"], rel=1e-9)
    assert m["ate_rmse_m"] > 0 and m["alignment"] == "se3" and m["frames"] == 10
    assert m["path_length_m"] == pytest.approx(
        np.sum(np.linalg.norm(np.diff(seq.wTc_true[:10, :3, 3], axis=0), axis=1)))
    assert m["rpe"]["n"] == 9 and m["backend_stats"] == {"mapped": m["landmarks"]}
    assert m["tracking"]["found_per_frame"] > 0


def test_no_odometry_needs_a_motion_model_and_gives_sim3(seq):
    tracker = Tracker(TrackerConfig(), follow_unmapped=False)
    with pytest.raises(UnsupportedError, match="motion model"):
        vp.run(seq, TruthBackend(seq), tracker, config=vp.VisualRunConfig(odometry="none"),
               max_frames=3)
    backend = TruthBackend(seq, has_motion_model=True)
    result = vp.run(seq, backend, Tracker(TrackerConfig(), follow_unmapped=False),
                    config=vp.VisualRunConfig(odometry="none"), max_frames=4)
    assert all(c[2] is None for c in backend.calls if c[0] == "predict")
    m = vp.compute_metrics(result).to_dict()
    assert m["alignment"] == "sim3" and m["ate"]["alignment"] == "sim3"
    assert m["ate"]["scale"] == pytest.approx(0.5, rel=0.01) and m["ate_rmse_m"] < 0.01
    assert m["odometry_ate_rmse_m"] is None


def test_sequence_odometry_missing_is_a_clear_error(seq):
    plain = ImageSequence("folder", seq.image_paths, None, seq.K, None, None, seq.image_size)
    with pytest.raises(GraphSlamError, match="no odometry"):
        vp.resolve_odometry(plain, "sequence")
    with pytest.raises(GraphSlamError, match="no ground truth"):
        vp.resolve_odometry(plain, "derived")
    assert vp.resolve_odometry(seq, "auto")[0] == "sequence"


def test_auto_never_derives_odometry_from_the_truth(seq):
    """A sequence read with its truth (KITTI's poses.txt, EuRoC, TUM) ran by default on
    odometry made from the very truth it was scored against: the camera alone now."""
    kitti_like = ImageSequence("kitti", seq.image_paths, None, seq.K, None, seq.wTc_true, seq.image_size)
    assert kitti_like.wTc_true is not None
    assert vp.resolve_odometry(kitti_like, "auto")[:2] == ("none", None)
    assert vp.resolve_odometry(kitti_like, "derived")[0] == "derived"  # when asked for


def _straight(n, step_m=1.0):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 2, 3] = step_m * np.arange(n)
    return T


def test_derived_odometry_has_the_stated_noise():
    gt = _straight(4001, step_m=0.5)
    cfg = vp.OdometryNoiseConfig(sigma_t_per_m=0.02, sigma_r_deg=0.1, seed=4)
    odo, cov = vp.derive_odometry(gt, cfg)
    rel = invert_pose(gt[:-1]) @ gt[1:]
    err = invert_pose(rel) @ odo
    # 2 % of 0.5 m = 0.01 m per axis; 0.1 deg per axis; 12000 draws -> ~1 % sampling error
    assert np.std(err[:, :3, 3]) == pytest.approx(0.01, rel=0.05)
    angles = np.array([np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)) for R in err[:, :3, :3]])
    rms_axis = np.sqrt(np.mean(angles**2) / 3)
    assert np.degrees(rms_axis) == pytest.approx(0.1, rel=0.05)
    assert np.allclose(cov[0], np.diag([0.01**2] * 3 + [np.radians(0.1) ** 2] * 3))
    # a still camera keeps the floor
    _, cov0 = vp.derive_odometry(_straight(3, 0.0), cfg)
    assert cov0[0, 0, 0] == pytest.approx(cfg.min_sigma_t_m**2)


def test_derived_odometry_is_seeded():
    gt = _straight(20)
    a, _ = vp.derive_odometry(gt, vp.OdometryNoiseConfig(seed=1))
    b, _ = vp.derive_odometry(gt, vp.OdometryNoiseConfig(seed=1))
    c, _ = vp.derive_odometry(gt, vp.OdometryNoiseConfig(seed=2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


# --------------------------------------------------------------------------- settings

def _refused(cls, key, value, words):
    """``cls`` built in code and from a dict refuses ``key = value`` naming section.key."""
    for build in (lambda: cls(**{key: value}), lambda: from_dict(cls, {key: value})):
        with pytest.raises(ConfigError) as e:
            build()
        assert str(e.value).startswith(f"{cls.SECTION}.{key}") and words in str(e.value), \
            str(e.value)


@pytest.mark.parametrize("key, value, words", [
    ("sigma_t_per_m", -0.01, "must be >= 0.0"),
    ("sigma_t_per_m", "2 %", "expected a number"),
    ("min_sigma_t_m", 0.0, "must be > 0.0"),  # a zero covariance cannot weigh a factor
    ("sigma_r_deg", 0, "must be > 0.0"),
    ("sigma_r_deg", float("inf"), "finite"),
    # third hostile pass: --odometry-noise 1e308 1e308 drew an infinite rotation (a traceback)
    ("sigma_r_deg", 1e308, "<= 180.0"),
    ("sigma_t_per_m", 1e308, "<= 100.0"),
    ("min_sigma_t_m", 1e308, "<= 1000.0"),
    ("seed", -1, "must be >= 0"),
    ("seed", 1.5, "expected an integer"),
])
def test_odometry_noise_config_refuses_bad_values(key, value, words):
    _refused(vp.OdometryNoiseConfig, key, value, words)


@pytest.mark.parametrize("key, value, words", [
    ("odometry", "gps", "must be one of ['auto', 'sequence', 'derived', 'none']"),
    ("odometry", None, "must be one of"),
    ("prior_sigma_t_m", 0.0, "must be > 0.0"),
    ("prior_sigma_r_deg", "tiny", "expected a number"),
    ("prior_sigma_t_m", 100.0, "<= 1.0"),  # iSAM2's system was indeterminate at frame 1
    ("prior_sigma_r_deg", 1e4, "<= 90.0"),
])
def test_visual_run_config_refuses_bad_values(key, value, words):
    _refused(vp.VisualRunConfig, key, value, words)
    from graphslam.pipelines.common import ODOMETRY_MODES

    assert ODOMETRY_MODES == ("auto", "sequence", "derived", "none")


@pytest.mark.parametrize("key, value, words", [
    ("width", 8, "must be >= 16"),
    ("width", si.MAX_IMAGE_SIDE_PX + 1, f"<= {si.MAX_IMAGE_SIDE_PX}"),  # what a camera gives
    ("height", 240.5, "expected an integer"),
    ("n_frames", 1, "must be >= 2"),
    ("n_frames", si.MAX_FRAMES + 1, f"<= {si.MAX_FRAMES}"),  # O(n^2) revisit search, render time
    ("n_frames", "300", "expected a number"),
    ("fx", 1e-12, ">= 1.0"),  # hung the renderer: the bounds of an intrinsics file
    ("fy", 2e6, "<= 1000000.0"),
    ("cx", -1e12, ">= -100000.0"),  # as an intrinsics file's principal point
    ("fx", 0.0, "must be >= 1.0"),
    ("laps", -1.0, "must be > 0.0"),
    ("room_length_m", si.MAX_ROOM_M * 10, f"<= {si.MAX_ROOM_M}"),  # surfaces per frame
    ("texture", "marble", "must be one of ['procedural', 'balbianello']"),
    ("texture_px_per_m", 1e4, "texels"),  # memory: 5e10 texels for the default room
    ("texture_px_per_m", 1e200, "texels"),  # its square overflows: OverflowError before
    ("pixel_noise_sigma", -1.0, "must be >= 0.0"),
    ("near_m", 0.0, "must be > 0.0"),
    ("revisit_min_gap_frames", 0, "must be >= 1"),
    ("corner_radius_m", 3.0, "must be <= half of path_length_m"),  # cross-field
    ("path_width_m", 10.0, "must fit in room_width_m"),  # cross-field
    ("camera_height_m", 3.5, "must be < room_height_m"),  # cross-field
])
def test_synthetic_images_config_refuses_bad_values(key, value, words):
    _refused(SyntheticImagesConfig, key, value, words)


def test_synthetic_images_config_error_names_file_and_line(tmp_path):
    path = tmp_path / "big.toml"
    path.write_text("[synthetic_images]\nseed = 2\nn_frames = 1e9\n")
    with pytest.raises(ConfigError) as e:
        ConfigFile.read(path).section(SyntheticImagesConfig)
    assert (e.value.path, e.value.line) == (str(path), 3)
    assert "synthetic_images.n_frames must be >= 2 and <= 100000" in str(e.value)


def test_ctrl_c_stops_between_frames_and_keeps_the_estimate(seq):
    def on_frame(k, image, tracking, backend):
        if k == 4:
            os.kill(os.getpid(), signal.SIGINT)

    result = vp.run(seq, TruthBackend(seq), Tracker(TrackerConfig(), follow_unmapped=False),
                    max_frames=20, on_frame=on_frame)
    assert result.interrupted and result.frames == 5
    assert len(result.estimate.frame_ids) == 5 and len(result.odometry_wTc) == 5


def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        R = so3_exp(rng.normal(0, 2.0, 3))
        qx, qy, qz, qw = rotation_to_quaternion(R[None])[0]
        R2 = np.array([
            [1 - 2 * (qy**2 + qz**2), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)],
            [2 * (qx * qy + qw * qz), 1 - 2 * (qx**2 + qz**2), 2 * (qy * qz - qw * qx)],
            [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx**2 + qy**2)]])
        assert np.allclose(R, R2, atol=1e-12)


# --------------------------------------------------------------------------- real back ends

@pytest.mark.parametrize("name", ["isam2", "ekf"])
def test_real_backends_against_odometry_on_a_short_sequence(seq, name):
    """iSAM2 beats odometry; the EKF stays within 1.5x of it (no divergence)."""
    from graphslam import registry

    backend = registry.make_visual_backend(name)
    tracker = Tracker(TrackerConfig(), follow_unmapped=backend.needs_track_history)
    result = vp.run(seq, backend, tracker, max_frames=40)
    m = vp.compute_metrics(result).to_dict()
    assert result.frames == 40 and m["landmarks"] > 5
    # iSAM2 must beat odometry already; the EKF (20 landmarks, QVGA pixels twice
    # as coarse, 5 m of path) is about at par here and must at least not diverge
    bound = 1.0 if name == "isam2" else 1.5
    assert m["ate_rmse_m"] < bound * m["odometry_ate_rmse_m"]


# --------------------------------------------------------------------------- command line

def _config(tmp_path, extra=""):
    path = tmp_path / "qvga.toml"
    keys = "\n".join(f"{k} = {v}" for k, v in QVGA.items())
    path.write_text(f"[synthetic_images]\n{keys}\n{extra}")
    return path


def test_cli_synthetic_images_writes_outputs(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["run", "--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "20",
               "--config", str(_config(tmp_path)), "--out", str(out), "--quiet"])
    assert rc == 0
    stdout = capsys.readouterr().out
    assert "SE(3)-aligned" in stdout and f"outputs in {out}" in stdout
    m = json.loads((out / "metrics.json").read_text())
    for key in ("dataset", "backend", "frontend", "frames", "landmarks", "ate_rmse_m", "alignment",
                "odometry_ate_rmse_m", "rpe", "path_length_m", "wall_s", "frames_per_s",
                "interrupted", "backend_stats"):
        assert key in m, key
    assert m["frames"] == 20 and m["backend"] == "ekf" and m["frontend"] == "harris"
    assert "reparametrised" in m["backend_stats"]
    rows = [r for r in (out / "trajectory.tum").read_text().splitlines() if not r.startswith("#")]
    assert len(rows) == 20 and rows[0].startswith("0 ")  # stamps 0.1 s apart, from 0
    assert (out / "landmarks.csv").read_text().startswith("id,x,y,z\n")
    assert (out / "run.rrd").stat().st_size > 10_000


def test_cli_same_seed_same_bits(tmp_path, capsys):
    cfg = _config(tmp_path)
    outs = []
    for i in range(2):
        out = tmp_path / f"o{i}"
        assert main(["run", "--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "8",
                     "--frontend", "fpga", "--config", str(cfg), "--out", str(out), "--quiet",
                     "--rerun", "off", "--seed", "3"]) == 0
        outs.append(out)
    for f in ("trajectory.tum", "landmarks.csv"):
        assert (outs[0] / f).read_bytes() == (outs[1] / f).read_bytes()


@pytest.mark.skipif(not KITTI07.is_dir(), reason="KITTI 07 not in ../shared/data")
def test_cli_kitti_with_derived_odometry(tmp_path, capsys):
    out = tmp_path / "k"
    assert main(["run", "--dataset", str(KITTI07), "--backend", "ekf", "--max-steps", "6",
                 "--odometry", "derived", "--odometry-noise", "0.05", "0.2", "--out", str(out),
                 "--quiet", "--rerun", "off"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 6 and m["odometry"] == "derived"
    noise = m["odometry_noise"]
    assert noise["sigma_t_per_m"] == 0.05 and noise["sigma_r_deg_per_frame"] == 0.2
    assert m["ate_rmse_m"] is not None
    second = (out / "trajectory.tum").read_text().splitlines()[2]
    assert second.split()[0] == "0.1038752"  # KITTI's own times.txt stamp (1.038752e-01), not the frame id
    _ = capsys.readouterr()


#: KITTI 07 frames 0-159, derived odometry (default seed), benchmarks/kitti07_visual.toml:
#: each back end's ATE at most this share of the odometry's (issue 5). Measured 0.46
#: (iSAM2) and 0.49 (EKF); seeds 0-3 average 0.52 and 0.55 (the global scale the
#: odometry sets is unobservable by a monocular camera: seeds differ).
KITTI_ATE_SHARE = 0.5


@pytest.mark.slow
@pytest.mark.skipif(not KITTI07.is_dir(), reason="KITTI 07 not in ../shared/data")
@pytest.mark.parametrize("backend", ["isam2", "ekf"])
def test_kitti07_vision_beats_derived_odometry(tmp_path, capsys, backend):
    out = tmp_path / backend
    assert main(["run", "--dataset", str(KITTI07), "--backend", backend, "--odometry", "derived",
                 "--config", str(ROOT / "benchmarks" / "kitti07_visual.toml"), "--out", str(out),
                 "--quiet", "--rerun", "off"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 160
    print(f"{backend}: ATE {m['ate_rmse_m']:.4f} m, odometry {m['odometry_ate_rmse_m']:.4f} m")
    assert m["ate_rmse_m"] <= KITTI_ATE_SHARE * m["odometry_ate_rmse_m"]
    _ = capsys.readouterr()


def _one_line_error(capsys, argv, *fragments):
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("graphslam: error:"), err
    for f in fragments:
        assert f in err[0]


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    _one_line_error(capsys, ["run", "--dataset", str(empty), "--out", str(tmp_path / "o")], str(empty))
    _one_line_error(capsys, ["run", "--dataset", "synthetic-images", "--backend", "fastslam1"],
                    "image sequences")
    # iSAM2 set to track by the camera alone, handed odometry
    camera = _config(tmp_path, '[isam2_visual]\nrobot_model = "constant_velocity"\n')
    _one_line_error(capsys, ["run", "--dataset", "synthetic-images", "--odometry", "sequence",
                             "--backend", "isam2", "--config", str(camera),
                             "--out", str(tmp_path / "o2")], "tracks by the camera alone, and this run has odometry")
    _one_line_error(capsys, ["run", "--dataset", "synthetic", "--frontend", "orb"], "image sequences only")
    _one_line_error(capsys, ["run", "--dataset", "synthetic-images", "--max-steps", "0"], "--max-steps")
    bad = _config(tmp_path, "[tracker]\ndetector = \"sift\"\n")
    _one_line_error(capsys, ["run", "--dataset", "synthetic-images", "--config", str(bad),
                             "--out", str(tmp_path / "o3")], "tracker.detector")


def test_rerun_recording_of_a_visual_run_is_written(seq, tmp_path):
    from graphslam.visualisation.spatial import VisualRecorder

    path = tmp_path / "v.rrd"
    rec = VisualRecorder.open("save", path)
    rec.start(seq, 5)
    result = vp.run(seq, TruthBackend(seq), Tracker(TrackerConfig(), follow_unmapped=False),
                    max_frames=5, on_frame=rec.hook("truth"))
    rec.finish("truth", result)
    rec.close()
    assert path.stat().st_size > 10_000
    data = path.read_bytes()
    for entity in (b"world/truth/camera/image/ellipses", b"world/truth/camera/image/matches",
                   b"world/truth/landmarks", b"world/ground_truth/camera", b"world/truth/trajectory"):
        assert entity in data, entity


def test_cli_ctrl_c_writes_what_was_estimated(tmp_path, capsys, monkeypatch):
    original = Tracker.track

    def track(self, image, predictions=None):
        if self._frame == 2:  # Ctrl-C while frame 3 is being processed
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, image, predictions)

    monkeypatch.setattr(Tracker, "track", track)
    out = tmp_path / "o"
    rc = main(["run", "--dataset", "synthetic-images", "--backend", "ekf", "--max-steps", "20",
               "--config", str(_config(tmp_path)), "--out", str(out), "--quiet", "--rerun", "off"])
    assert rc == 130
    assert "interrupted" in capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["interrupted"] is True and m["frames"] == 4
    rows = [r for r in (out / "trajectory.tum").read_text().splitlines() if not r.startswith("#")]
    assert len(rows) == 4
