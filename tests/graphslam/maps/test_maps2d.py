"""2-D landmark maps: ``run --save-map`` and localisation-only ``run --map`` (issue 18, item 5).

Save, load, save gives identical files; every refusal is one line; a
localisation-only run keeps the map's landmarks exactly where the map put them
and localises no worse than SLAM on the same steps.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graphslam.cli.main import main
from graphslam.maps.files import load_map, load_planar_map, save_map, save_planar_map
from graphslam.maps.planar_map import PlanarMap
from slamcore.errors import InputError
from tests.graphslam.maps.test_maps import random_map

#: Steps of the short synthetic run (150 s of driving, 0.4 of a lap).
STEPS = "150"
#: How much worse than SLAM on the same steps a localisation-only run may be, metres.
#: Its map comes from that very SLAM run, so it should match it; the margin covers
#: the localiser's own noise model (measured: isam2 0.0015 m worse, 0.4511 against
#: 0.4496 m; ekf 0.025 m better, 0.3932 against 0.4181 m).
ATE_TOLERANCE_M = 0.05
RUN = ["run", "--max-steps", STEPS, "--rerun", "off", "--quiet"]
FILES = ("map.json", "map.npz")


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_line_error(capsys, *argv) -> str:
    rc, _, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("graphslam: error:"), err
    return lines[0]


def small_map(n: int = 12, seed: int = 0) -> PlanarMap:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 2, 2)) * 0.1
    cov = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(2)
    return PlanarMap(np.arange(n, dtype=np.int64) * 3 + 5, rng.normal(size=(n, 2)) * 20, cov,
                     {"dataset": "synthetic", "steps": 10})


@pytest.fixture
def saved(tmp_path) -> Path:
    folder = tmp_path / "map"
    save_planar_map(small_map(), folder)
    return folder


# --------------------------------------------------------------------------- the files

def test_round_trip_gives_identical_files(saved, tmp_path):
    pmap = load_planar_map(saved)
    again = tmp_path / "again"
    save_planar_map(pmap, again)
    for name in FILES:
        assert (saved / name).read_bytes() == (again / name).read_bytes(), name
    ref = small_map()
    assert np.array_equal(pmap.landmark_ids, ref.landmark_ids)
    assert np.array_equal(pmap.landmark_xy, ref.landmark_xy)
    assert np.array_equal(pmap.landmark_cov, ref.landmark_cov)
    doc = json.loads((saved / "map.json").read_text())
    assert (doc["format"], doc["version"], doc["kind"]) == ("graphslam-map", 1, "planar")
    assert doc["counts"] == {"landmarks": 12}


def test_run_map_round_trip(tmp_path, capsys):
    folder, again = tmp_path / "map", tmp_path / "again"
    rc, out, err = run_cli(capsys, *RUN, "--out", str(tmp_path / "slam"), "--save-map", str(folder))
    assert rc == 0, err
    assert "map in" in out
    pmap = load_planar_map(folder)
    assert pmap.meta["dataset"] == "synthetic" and pmap.meta["steps"] == int(STEPS)
    assert pmap.meta["config"]["isam2"]["polish"] is True and pmap.meta["world"]["seed"] == 0
    assert pmap.landmark_cov.shape == (pmap.n_landmarks, 2, 2) and pmap.n_landmarks > 10
    save_planar_map(pmap, again)
    for name in FILES:
        assert (folder / name).read_bytes() == (again / name).read_bytes(), name
    # landmarks.csv keeps its own format; the map holds the same positions
    rows = np.loadtxt(tmp_path / "slam" / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    assert np.allclose(rows[np.argsort(rows[:, 0]), 1:], pmap.landmark_xy, atol=1e-6)


def _edit_json(folder: Path, **changes) -> None:
    doc = json.loads((folder / "map.json").read_text())
    doc.update(changes)
    (folder / "map.json").write_text(json.dumps(doc))


def _refusal(folder, loader=load_planar_map) -> str:
    with pytest.raises(InputError) as e:
        loader(folder)
    text = str(e.value)
    assert "\n" not in text
    return text


def test_truncated_arrays_are_refused(saved):
    data = (saved / "map.npz").read_bytes()
    (saved / "map.npz").write_bytes(data[: len(data) // 2])
    assert "damaged, truncated" in _refusal(saved)


def test_damaged_byte_is_refused(saved):
    data = bytearray((saved / "map.npz").read_bytes())
    data[len(data) // 2] ^= 0x55
    (saved / "map.npz").write_bytes(bytes(data))
    assert "damaged" in _refusal(saved)


def test_damaged_json_is_refused(saved):
    text = (saved / "map.json").read_text()
    (saved / "map.json").write_text(text[: len(text) // 3])
    assert "damaged map.json" in _refusal(saved)


def test_newer_version_is_refused(saved):
    _edit_json(saved, version=2)
    assert "newer" in _refusal(saved)


def test_missing_files_are_refused(saved, tmp_path):
    assert "not found" in _refusal(tmp_path / "nowhere")
    (saved / "map.npz").unlink()
    assert "map.npz" in _refusal(saved)


def test_counts_that_disagree_are_refused(saved):
    _edit_json(saved, counts={"landmarks": 13})
    assert "map.json says" in _refusal(saved)


def test_3d_map_given_to_a_2d_run_and_the_reverse_are_refused(saved, tmp_path):
    spatial = tmp_path / "spatial"
    save_map(random_map(), spatial)
    assert "3-D map" in _refusal(spatial, load_planar_map)
    assert "2-D landmark map" in _refusal(saved, load_map)


def test_bad_covariance_is_refused_on_save(tmp_path):
    pmap = small_map()
    pmap.landmark_cov[3] = [[1.0, 0.0], [0.0, -1.0]]
    with pytest.raises(InputError) as e:
        save_planar_map(pmap, tmp_path / "bad")
    assert "landmark 14" in str(e.value)
    pmap = small_map()
    pmap.landmark_ids[1] = pmap.landmark_ids[0]
    with pytest.raises(InputError):
        save_planar_map(pmap, tmp_path / "bad")


# --------------------------------------------------------------------------- localisation

def _ate(folder: Path) -> float:
    return json.loads((folder / "metrics.json").read_text())["ate_rmse_m"]


@pytest.mark.parametrize("backend", ["isam2", "ekf"])
def test_localisation_keeps_the_map_fixed_and_localises(backend, tmp_path, capsys):
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline
    from graphslam.pipelines.planar_maps import load_run_map, localiser

    folder = tmp_path / "map"
    slam, loc = tmp_path / "slam", tmp_path / "loc"
    assert run_cli(capsys, *RUN, "--backend", backend, "--out", str(slam),
                   "--save-map", str(folder))[0] == 0
    rc, out, err = run_cli(capsys, *RUN, "--backend", backend, "--out", str(loc),
                           "--map", str(folder))
    assert rc == 0, err
    metrics = json.loads((loc / "metrics.json").read_text())
    assert metrics["localisation_only"] is True and metrics["map"] == str(folder)
    assert metrics["association"]["unused"] == 0  # every observation was of a map landmark
    assert _ate(loc) <= _ate(slam) + ATE_TOLERANCE_M, (_ate(loc), _ate(slam))
    # the estimate's landmarks are the map's, to the bit, after every step
    dataset = registry.load_dataset("synthetic")
    pmap = load_run_map(folder, dataset, None)
    be = localiser(backend, pmap, None, {})
    moved = []

    def check(k, frame, b):
        if k % 25 == 0:
            est = b.estimate()
            moved.append(not np.array_equal(est.landmarks_w, pmap.landmark_xy))
    result = pipeline.run(dataset, be, max_steps=int(STEPS), on_step=check, with_covariances=True)
    est = result.estimate
    assert moved and not any(moved)
    assert np.array_equal(est.landmark_ids, pmap.landmark_ids)
    assert np.array_equal(est.landmarks_w, pmap.landmark_xy)
    assert np.array_equal(est.landmark_covariances, pmap.landmark_cov)
    assert be.unmapped_count == 0


@pytest.mark.parametrize("backend", ["isam2", "ekf"])
def test_landmarks_not_in_the_map_are_not_added(backend, tmp_path, capsys):
    folder, loc = tmp_path / "map", tmp_path / "loc"
    assert run_cli(capsys, "run", "--max-steps", "60", "--rerun", "off", "--quiet", "--out",
                   str(tmp_path / "slam"), "--save-map", str(folder))[0] == 0
    rc, _, err = run_cli(capsys, *RUN, "--backend", backend, "--out", str(loc), "--map", str(folder))
    assert rc == 0, err
    metrics = json.loads((loc / "metrics.json").read_text())
    pmap = load_planar_map(folder)
    assert metrics["landmarks"] == pmap.n_landmarks
    assert metrics["unmapped_observations"] > 0  # steps 60-150 see landmarks the map lacks
    rows = np.loadtxt(loc / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    assert np.array_equal(rows[:, 0].astype(np.int64), pmap.landmark_ids)


def test_refusals_on_the_command_line(tmp_path, capsys):
    folder = tmp_path / "map"
    assert run_cli(capsys, *RUN, "--out", str(tmp_path / "slam"), "--save-map", str(folder))[0] == 0
    out = ["--out", str(tmp_path / "x")]
    assert "fastslam1 cannot localise" in one_line_error(
        capsys, *RUN, *out, "--backend", "fastslam1", "--map", str(folder))
    assert "another synthetic world" in one_line_error(
        capsys, *RUN, *out, "--seed", "1", "--map", str(folder))
    assert "adds no landmark" in one_line_error(
        capsys, *RUN, *out, "--map", str(folder), "--save-map", str(tmp_path / "m2"))
    assert "built on 'synthetic'" in one_line_error(
        capsys, "run", "--dataset", "victoria-park", "--max-steps", "5", "--rerun", "off",
        "--quiet", *out, "--map", str(folder))
    data = (folder / "map.npz").read_bytes()
    (folder / "map.npz").write_bytes(data[:100])
    assert "truncated" in one_line_error(capsys, *RUN, *out, "--map", str(folder))


#: Mean pose NEES (3 dof, expected 3) a consistent localiser stays under on one run.
NEES_MEAN_MAX = 4.0


def test_ekf_localiser_is_consistent_when_the_map_errors_are_independent():
    """The Schmidt filter carries the map's covariances: on a map whose landmarks are
    the truth plus independent 0.3 m errors (what block-diagonal covariances
    describe) its pose NEES averages about 3 (measured 2.37), and it localises
    better than dead reckoning by far."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    ds = registry.load_dataset("synthetic", seed=3)
    ids = np.array(sorted(ds.landmarks_true), dtype=np.int64)
    sigma_m = 0.3
    xy = np.array([ds.landmarks_true[i] for i in ids])
    xy = xy + np.random.default_rng(1).normal(size=xy.shape) * sigma_m
    be = registry.make_localiser("ekf", ids, xy, np.tile(np.eye(2) * sigma_m ** 2, (len(ids), 1, 1)))
    result = pipeline.run(ds, be, with_covariances=True)
    m = pipeline.compute_metrics(result, with_graph_error=False)
    pipeline.add_nees(result, m)
    assert 1.0 < m.nees_mean < NEES_MEAN_MAX, m.nees_mean
    assert m.ate_rmse_m < 0.2 * m.odometry_ate_rmse_m
    assert np.array_equal(result.estimate.landmarks_w, xy)


def test_ekf_localisation_on_a_map_of_another_place_says_so():
    """Tenth hostile pass: on a map moved 50 m the localiser gated out every sighting (the
    estimate dead reckoning, 'unmapped observations 0') and said nothing."""
    from graphslam import registry
    from graphslam.pipelines import planar as pipeline

    ds = registry.load_dataset("synthetic", seed=3)
    ids = np.array(sorted(ds.landmarks_true), dtype=np.int64)
    xy = np.array([ds.landmarks_true[i] for i in ids]) + 50.0
    be = registry.make_localiser("ekf", ids, xy, np.tile(np.eye(2) * 0.01, (len(ids), 1, 1)))
    result = pipeline.run(ds, be)
    m = pipeline.compute_metrics(result, with_graph_error=False)
    assert result.observations_rejected == result.observations > 0
    assert any("100 %) were rejected by the back end's gate" in w for w in m.warnings or [])
