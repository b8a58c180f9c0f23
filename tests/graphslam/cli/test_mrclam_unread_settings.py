"""The MRCLAM reader's settings of the sensor field and of the sightings' correlation in
time are said to do nothing under a back end that does not read them (hostile pass 18:
``detection_prob`` under iSAM2, ``sighting_error_dof`` under known ids without truth,
the correlation under FastSLAM without ``temper_correlated`` changed nothing, unsaid)."""

from __future__ import annotations

import pytest

from graphslam.cli.main import main
from tests.graphslam.sources.test_mrclam_fifteenth import cut

SETTINGS = "[mrclam]\nsighting_error_dof = 4.0\ndetection_prob = 0.1\ncorrelation_time_s = 3.0\n"


@pytest.fixture(scope="module")
def folder(shared_data, tmp_path_factory):
    return cut(shared_data / "mrclam6", tmp_path_factory.mktemp("m") / "cut", end_s=40.0)


@pytest.fixture(scope="module")
def no_truth(shared_data, tmp_path_factory):
    return cut(
        shared_data / "mrclam6",
        tmp_path_factory.mktemp("m") / "cut",
        end_s=40.0,
        edits={"Robot1_Groundtruth.dat": lambda rows: None},
    )


def _said(capsys, tmp_path, folder, backend: str, extra: str = "") -> set[str]:
    config = tmp_path / "c.toml"
    config.write_text(SETTINGS + extra)
    code = main(["run", "--dataset", str(folder), "--backend", backend, "--config", str(config),
                 "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 0
    err = capsys.readouterr().err
    return {k for k in ("sighting_error_dof", "detection_prob", "correlation_time_s")
            if f"[mrclam] {k} did nothing" in err}


@pytest.mark.parametrize(
    "backend, extra, inert",
    [
        ("isam2", "", {"detection_prob"}),
        ("isam2", '[isam2]\nassociation = "unknown"\n', {"detection_prob"}),
        ("ekf", "", {"detection_prob"}),
        ("ekf", '[ekf]\nassociation = "unknown"\n', set()),
        ("fastslam2", '[fastslam]\nassociation = "unknown"\nprune_missed_alpha = 0.0\n', {"detection_prob"}),
        ("fastslam2", "[fastslam]\ntemper_correlated = false\n", {"detection_prob", "correlation_time_s"}),
    ],
)
def test_what_the_back_end_does_not_read_is_said(capsys, tmp_path, folder, backend, extra, inert):
    assert _said(capsys, tmp_path, folder, backend, extra) == inert


def test_the_error_tail_under_known_ids_is_said_only_without_truth(capsys, tmp_path, no_truth):
    """With truth the reader's check of the sightings against it reads the tail."""
    assert _said(capsys, tmp_path, no_truth, "isam2") == {"sighting_error_dof", "detection_prob"}
    # FastSLAM weighs its particles by the tail's law, known ids or not
    assert "sighting_error_dof" not in _said(capsys, tmp_path, no_truth, "fastslam2")


@pytest.mark.parametrize(
    "backends, extra, inert",
    [
        # iSAM2 weighs the sightings' correlation that FastSLAM without tempering leaves
        (["isam2", "fastslam2"], "[fastslam]\ntemper_correlated = false\n", {"detection_prob"}),
        (["isam2", "ekf"], '[ekf]\nassociation = "unknown"\n', set()),
    ],
)
def test_compare_says_what_none_of_its_back_ends_reads(capsys, tmp_path, folder, backends, extra, inert):
    """compare marked none of them (hostile pass 18 left it open): a setting is said to do
    nothing there when no back end of the comparison reads it."""
    config = tmp_path / "c.toml"
    config.write_text(SETTINGS + extra)
    code = main(["compare", "--dataset", str(folder), "--backends", *backends, "--config", str(config),
                 "--out", str(tmp_path / "out"), "--rerun", "off", "--in-process"])
    assert code == 0
    err = capsys.readouterr().err
    said = {k for k in ("sighting_error_dof", "detection_prob", "correlation_time_s")
            if f"[mrclam] {k} did nothing" in err}
    assert said == inert
