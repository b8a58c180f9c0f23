"""The config gates (``Validated.GATES``) say the truth: a setting a gate calls unread
in some mode changes nothing in that mode, bit for bit (the warning would otherwise be
a new silent wrong answer). Run on the 2-D back ends and the loop verifier."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphslam import registry
from graphslam.pipelines import planar as pipeline
from slamcore.config import ConfigFile
from tests.worlds import square_world

#: (back end, the mode that turns the gate off, the gated settings moved far from their
#: defaults, known ids): the run must be bit-identical to the one without the moves.
PLANAR = [
    ("isam2", {"polish": False},
     {"polish_max_iterations": 1, "polish_method": "gnc", "polish_relative_error_tol": 0.5,
      "polish_absolute_error_tol": 0.5, "gate_polish_rounds": 0}, True),
    ("isam2", {"loop_closure_gate": 0.0},
     {"gate_window": 1, "gate_min_support": 9, "gate_scale_from_data": False, "gate_polish_rounds": 0}, True),
    ("isam2", {"loop_closure_gate": 16.27, "polish_method": "gnc"}, {"gate_polish_rounds": 0}, True),
    ("isam2", {"loop_closure_kernel": "none"}, {"loop_closure_kernel_k": 0.05}, True),
    ("isam2", {"observation_kernel": "none"}, {"observation_kernel_k": 0.05}, True),
    ("isam2", {}, {"association_gate_prob": 0.5, "confirm_sightings": 9, "reassociation_passes": 0},
     True),
    ("ekf", {"association": "unknown", "jcbb_objective": "count"},
     {"new_landmark_density_per_m2": 0.9, "detection_prob": 0.1}, False),
    ("ekf", {}, {"prune_missed_alpha": 0.5}, True),
    ("fastslam2", {}, {"new_landmark_mahalanobis_sq": 1.0, "new_landmark_log_likelihood": -50.0,
                       "prune_missed_alpha": 0.5, "pair_scans_jointly": True}, True),
]


def _estimate(name, settings, known_ids):
    backend = registry.make_backend(name, config=ConfigFile(data={}), overrides=settings)
    ds = square_world(seed=5, loop_closure=True, known_ids=known_ids)
    return pipeline.run(ds, backend).estimate


@pytest.mark.parametrize("name,mode,moved,known_ids", PLANAR, ids=lambda v: str(v)[:40])
def test_a_gated_setting_changes_nothing_where_its_gate_is_off(name, mode, moved, known_ids):
    settings = registry.backend_settings(name, ConfigFile(data={}), {**mode, **moved})
    assert set(moved) <= set(settings.inert_settings()), "the gate no longer calls them unread"
    base = _estimate(name, mode, known_ids)
    other = _estimate(name, {**mode, **moved}, known_ids)
    assert np.array_equal(base.wTb, other.wTb)
    assert np.array_equal(base.landmarks_w, other.landmarks_w)


def test_the_gated_settings_do_act_where_their_gate_is_on():
    """The same moves with the polish on change the estimate: the test above can fail."""
    moved = {"polish_max_iterations": 1, "polish_relative_error_tol": 0.5, "polish_absolute_error_tol": 0.5}
    base = _estimate("isam2", {}, True)
    other = _estimate("isam2", moved, True)
    assert not np.array_equal(base.wTb, other.wTb)


def test_the_forward_scale_changes_nothing_without_the_coverage_test():
    from frontend.orb import OrbDetector
    from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images
    from loopclosure.verify import GeometricVerifier, VerifyConfig

    seq = make_synthetic_images(SyntheticImagesConfig(width=320, height=240, fx=250, fy=250,
                                                      cx=159.5, cy=119.5, n_frames=120))
    orb = OrbDetector(cell_size_px=0, n_features=500)
    a, b = orb.detect(seq.load(2)), orb.detect(seq.load(5))
    K = seq.K
    for mode in ({"min_coverage": 0.0}, {"model": "fundamental"}):
        assert "max_forward_scale" in VerifyConfig(**mode, max_forward_scale=5.0).inert_settings()
        one, two = (GeometricVerifier(VerifyConfig(**mode, max_forward_scale=s)).verify(
            a.xy_px, a.descriptors, b.xy_px, b.descriptors, None if "model" in mode else K) for s in (1.2, 5.0))
        assert (one.accepted, one.reason, one.n_inliers, one.coverage) == (
            two.accepted, two.reason, two.n_inliers, two.coverage)
    # the decisive share waives the coverage tests: nothing to waive without them
    assert "decisive_share" in VerifyConfig(min_coverage=0.0, decisive_share=0.5).inert_settings()
    assert "decisive_share" not in VerifyConfig(decisive_share=0.5).inert_settings()


#: (back end, the file's settings, those of them said to do nothing): visual runs of
#: 20 synthetic frames with and without the settings said unread, the same bytes.
VISUAL = [
    ("isam2", '[tracker]\nmax_hamming = 3\n[isam2_visual]\nseed = 77\nloop_closure_kernel = "huber"\n'
     'loop_closure_kernel_k = 0.1\n[isam2_visual.mono]\nmin_pnp_inliers = 50\n',
     "[tracker]\n", ["[tracker] max_hamming", "[isam2_visual] seed, mono",
                     "[isam2_visual] loop_closure_kernel, loop_closure_kernel_k"]),
    ("ekf", '[mono_ekf]\nrobot_model = "odometry"\ncv_sigma_accel_mps2 = 9.0\nransac = false\n'
     'ransac_inlier_sigmas = 0.5\nseed = 4\n[tracker]\ndetector = "orb"\nfollow_min_score = 0.1\n[harris]\nk = 0.2\n',
     '[mono_ekf]\nrobot_model = "odometry"\nransac = false\n[tracker]\ndetector = "orb"\n',
     ["[mono_ekf] cv_sigma_accel_mps2", "[mono_ekf] ransac_inlier_sigmas, seed",
      "[tracker] follow_min_score", "[harris] k"]),
    ("ekf", '[tracker]\ndetector = "fpga"\n[active_search]\nmin_score = 0.99\nsubpixel = false\n'
     'predict_appearance = true\n', '[tracker]\ndetector = "fpga"\n',
     ["[active_search] min_score, subpixel, predict_appearance"]),
    ("ekf", '[tracker]\ndetector = "orb"\n[active_search]\nmin_score = 0.99\nmin_patch_std = 50.0\n',
     '[tracker]\ndetector = "orb"\n', ["[active_search] min_score, min_patch_std"]),
]


@pytest.mark.parametrize("backend,with_text,without_text,said", VISUAL, ids=["isam2", "mono_ekf", "fpga_search", "orb_search"])
def test_visual_settings_said_unread_change_no_byte(tmp_path, capsys, backend, with_text, without_text, said):
    from graphslam.cli.main import main

    out = {}
    for name, text in (("with", with_text), ("without", without_text)):
        (tmp_path / f"{name}.toml").write_text(text)
        assert main(["run", "--dataset", "synthetic-images", "--backend", backend, "--max-steps", "20",
                     "--rerun", "off", "--quiet", "--config", str(tmp_path / f"{name}.toml"),
                     "--out", str(tmp_path / name)]) == 0
        out[name] = capsys.readouterr().err
    assert (tmp_path / "with" / "trajectory.tum").read_bytes() == (tmp_path / "without" / "trajectory.tum").read_bytes()
    lines = [line for line in out["with"].splitlines() if "did nothing" in line]
    assert len(lines) == len(said) and all(any(s in line for line in lines) for s in said), out["with"]
    assert "did nothing" not in out["without"]


GRAPH = "noisyToyGraph.txt"  # gtsam's 2-D g2o example: 4 poses, a closure

#: (solver flags, the file's [posegraph] settings that solver does not read, what is said)
POSEGRAPH = [
    (["--backend", "batch"], 'relinearize_threshold = 0.9\nrelinearize_skip = 3\npolish = false\n',
     "[posegraph] relinearize_threshold, relinearize_skip, polish"),
    (["--backend", "isam2", "--no-polish"], 'init = "odometry"\n', "[posegraph] init"),
    (["--backend", "batch"], 'toro_noise = "sqrt_information"\n', "[posegraph] toro_noise"),
]


@pytest.mark.parametrize("flags,text,said", POSEGRAPH, ids=["batch", "isam2-unpolished", "g2o"])
def test_pose_graph_settings_said_unread_change_no_byte(tmp_path, capsys, flags, text, said):
    """The [posegraph] settings a solve does not read (iSAM2's under batch, the polish's
    start with no polish, the TORO convention on a g2o file) ran silent; now they are
    said, and the trajectory is the same bytes without them."""
    from graphslam.cli.main import main
    import gtsam

    err = {}
    for name, body in (("with", text), ("without", "")):
        (tmp_path / f"{name}.toml").write_text("[posegraph]\n" + body)
        assert main(["run", "--dataset", gtsam.findExampleDataFile(GRAPH), *flags, "--rerun", "off", "--quiet",
                     "--config", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / name)]) == 0
        err[name] = capsys.readouterr().err
    assert (tmp_path / "with" / "trajectory.tum").read_bytes() == (tmp_path / "without" / "trajectory.tum").read_bytes()
    assert f"{said} did nothing" in err["with"] and "did nothing" not in err["without"]
    said_in_file = json.loads((tmp_path / "with" / "metrics.json").read_text())["provenance"]["did_nothing"]
    assert any(f"{said} did nothing" in line for line in said_in_file)


def test_init_with_an_unpolished_isam2_solve_is_refused(tmp_path, capsys):
    from graphslam.cli.main import main
    import gtsam

    assert main(["run", "--dataset", gtsam.findExampleDataFile(GRAPH), "--backend", "isam2", "--no-polish",
                 "--init", "lago", "--rerun", "off", "--quiet", "--out", str(tmp_path / "o")]) == 2
    assert "--init starts the batch polish" in capsys.readouterr().err
    assert not (tmp_path / "o" / "trajectory.tum").exists()


def test_synthetic_signatures_are_said_to_do_nothing_in_a_run(tmp_path, capsys):
    """Every synthetic observation has its landmark id, so no back end reads a signature:
    ``signature_count = 3`` (many landmarks sharing one) ran the same bits, silent."""
    from graphslam.cli.main import main

    out = {}
    for name, body in (("with", "[synthetic]\nsignature_count = 3\n"), ("without", "[synthetic]\n")):
        (tmp_path / f"{name}.toml").write_text(body)
        assert main(["run", "--dataset", "synthetic", "--backend", "ekf", "--max-steps", "30", "--rerun", "off",
                     "--quiet", "--config", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / name)]) == 0
        out[name] = capsys.readouterr().err
    assert (tmp_path / "with" / "trajectory.tum").read_bytes() == (tmp_path / "without" / "trajectory.tum").read_bytes()
    assert "[synthetic] signature_count did nothing" in out["with"] and "did nothing" not in out["without"]


def test_the_ekfs_unknown_association_keys_are_said_to_do_nothing_under_known_ids(tmp_path, capsys):
    """Under known ids the EKF's gate and JCBB act only on sightings without an id; every
    sighting of a run had one, and ``gate_chi2_prob = 0.5`` ran the same bits, silent
    (fifteenth hostile pass). Under unknown ids the same key acts and is not marked."""
    from graphslam.cli.main import main

    key = "[ekf]\ngate_chi2_prob = 0.5\njcbb_max_nodes = 0\n"
    out = {}
    for name, body in (("with", key), ("without", "[ekf]\n"), ("unknown", key + 'association = "unknown"\n')):
        (tmp_path / f"{name}.toml").write_text(body)
        assert main(["run", "--dataset", "synthetic", "--backend", "ekf", "--max-steps", "40", "--rerun", "off",
                     "--quiet", "--config", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / name)]) == 0
        out[name] = capsys.readouterr().err
    assert (tmp_path / "with" / "trajectory.tum").read_bytes() == (tmp_path / "without" / "trajectory.tum").read_bytes()
    assert "[ekf] gate_chi2_prob, jcbb_max_nodes did nothing" in out["with"]
    assert "did nothing" not in out["without"] and "gate_chi2_prob" not in out["unknown"]
