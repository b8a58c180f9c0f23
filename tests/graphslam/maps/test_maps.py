"""The map folder: save, load, save gives identical files; each refusal is one InputError."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graphslam.maps.files import check_camera, load_map, save_map
from graphslam.maps.spatial_map import SpatialMap, bow_csr
from loopclosure.database import BowDatabase
from loopclosure.vocabulary import FlatVocabulary
from slamcore.errors import InputError

FILES = ("map.json", "map.npz", "vocabulary.npz")


def random_map(n_kf: int = 6, n_lm: int = 20, per_kf: int = 8, seed: int = 0) -> SpatialMap:
    """A small map with every array filled (random but consistent)."""
    rng = np.random.default_rng(seed)
    desc = rng.integers(0, 256, (n_kf, 30, 32), dtype=np.uint8)
    vocab = FlatVocabulary(n_words=8, seed=0).fit(list(desc))
    db = BowDatabase(vocab)
    wTc = np.tile(np.eye(4), (n_kf, 1, 1))
    wTc[:, 0, 3] = np.arange(n_kf) * 0.5
    obs_kf = np.repeat(np.arange(n_kf), per_kf)
    obs_lm = rng.integers(0, n_lm, len(obs_kf))
    indptr, words, weights = bow_csr([db.bow(d) for d in desc])
    return SpatialMap(
        K=np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]), image_size=(640, 480),
        keyframe_ids=np.arange(n_kf, dtype=np.int64), keyframe_wTc=wTc,
        keyframe_cov=np.tile(np.eye(6) * 1e-4, (n_kf, 1, 1)),
        landmark_ids=np.arange(n_lm, dtype=np.int64) + 100, landmark_w=rng.normal(size=(n_lm, 3)),
        landmark_cov=np.tile(np.eye(3) * 1e-3, (n_lm, 1, 1)),
        landmark_desc=rng.integers(0, 256, (n_lm, 32), dtype=np.uint8),
        landmark_patch=rng.random((n_lm, 11, 11)).astype(np.float32),
        obs_keyframe=obs_kf.astype(np.int64), obs_landmark=obs_lm.astype(np.int64),
        obs_uv=rng.uniform(0, 400, (len(obs_kf), 2)),
        obs_desc=rng.integers(0, 256, (len(obs_kf), 32), dtype=np.uint8),
        bow_indptr=indptr, bow_words=words, bow_weights=weights, vocabulary=vocab,
        meta={"dataset": "test", "frames": "0:6"})


@pytest.fixture
def saved(tmp_path) -> Path:
    folder = tmp_path / "map"
    save_map(random_map(), folder)
    return folder


def test_round_trip_gives_identical_files_and_arrays(saved, tmp_path):
    smap = load_map(saved)
    again = tmp_path / "again"
    save_map(smap, again)
    for name in FILES:
        assert (saved / name).read_bytes() == (again / name).read_bytes(), name
    ref = random_map()
    for name in ("keyframe_wTc", "landmark_w", "obs_desc", "landmark_patch", "bow_weights"):
        np.testing.assert_array_equal(getattr(smap, name), getattr(ref, name))
    assert smap.meta == ref.meta and smap.image_size == (640, 480)
    k = 3
    assert np.array_equal(smap.bow(k).word_ids, ref.bow(k).word_ids)
    assert set(smap.keyframe_observations(k)) == set(np.flatnonzero(ref.obs_keyframe == k))


def test_saving_twice_gives_identical_files(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    save_map(random_map(), a)
    save_map(random_map(), b)
    # the vocabulary file of a fresh save is the vocabulary's own format (dated zip
    # entries); the map's arrays and description are byte-reproducible
    for name in ("map.json", "map.npz"):
        assert (a / name).read_bytes() == (b / name).read_bytes()


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize("name", FILES)
def test_missing_file_is_refused(saved, name):
    (saved / name).unlink()
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert name in one_line(e)


def test_missing_folder_is_refused(tmp_path):
    with pytest.raises(InputError) as e:
        load_map(tmp_path / "nowhere")
    assert "not found" in one_line(e)


@pytest.mark.parametrize("name", ["map.npz", "vocabulary.npz"])
def test_truncated_file_is_refused(saved, name):
    data = (saved / name).read_bytes()
    (saved / name).write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "damaged, truncated" in one_line(e)


def test_damaged_byte_is_refused(saved):
    data = bytearray((saved / "map.npz").read_bytes())
    data[len(data) // 3] ^= 0xFF
    (saved / "map.npz").write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "damaged" in one_line(e)


def test_damaged_json_is_refused(saved):
    text = (saved / "map.json").read_text()
    (saved / "map.json").write_text(text[: len(text) // 2])
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "damaged map.json" in one_line(e)


def _edit_json(folder: Path, **changes) -> None:
    doc = json.loads((folder / "map.json").read_text())
    doc.update(changes)
    (folder / "map.json").write_text(json.dumps(doc))


@pytest.mark.parametrize("sessions", [5, "abc", [1, 2]])
def test_sessions_not_a_list_of_tables_is_refused(saved, sessions):
    # a run extending the map (--map, --save-map) lists them: 5 was a TypeError after
    # the run, "abc" three sessions named by letters
    meta = json.loads((saved / "map.json").read_text())["meta"]
    _edit_json(saved, meta={**meta, "sessions": sessions})
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "sessions" in one_line(e) and "map.json" in one_line(e)


def test_map_json_given_for_the_folder_says_so(saved):
    with pytest.raises(InputError) as e:
        load_map(saved / "map.json")
    assert "is a file; a map is the folder" in one_line(e)


def test_newer_version_is_refused(saved):
    _edit_json(saved, version=2)
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "newer" in one_line(e)


def test_other_format_is_refused(saved):
    _edit_json(saved, format="something-else")
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "not a graphslam-map" in one_line(e)


def test_counts_that_disagree_are_refused(saved):
    doc = json.loads((saved / "map.json").read_text())
    doc["counts"]["landmarks"] += 1
    (saved / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "map.json says" in one_line(e)


def test_map_from_another_map_is_refused(saved, tmp_path):
    other = tmp_path / "other"
    save_map(random_map(seed=1), other)
    (saved / "map.npz").write_bytes((other / "map.npz").read_bytes())
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "from another map" in one_line(e)


def test_different_camera_is_refused(saved):
    smap = load_map(saved)
    check_camera(smap, smap.K, (640, 480), "seq")  # the same camera passes
    K = smap.K.copy()
    K[0, 0] += 1.0
    with pytest.raises(InputError) as e:
        check_camera(smap, K, (640, 480), "seq")
    assert "another camera" in one_line(e)
    with pytest.raises(InputError) as e:
        check_camera(smap, smap.K, (320, 240), "seq")
    assert "640x480" in one_line(e)


def test_inconsistent_arrays_are_refused_on_save(tmp_path):
    smap = random_map()
    smap.obs_landmark[0] = smap.n_landmarks  # points past the last landmark
    with pytest.raises(InputError):
        save_map(smap, tmp_path / "bad")


@pytest.mark.parametrize("size", [[640], [640, 480, 3], [0, 0], [640, -480], [640.5, 480], [True, 480], ["640", 480]])
def test_an_image_size_of_other_than_two_numbers_is_refused(saved, size):
    doc = json.loads((saved / "map.json").read_text())
    doc["camera"]["image_size"] = size
    (saved / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "damaged map.json (camera" in one_line(e) and "map.json" in one_line(e)


@pytest.mark.parametrize("distortion", [[-0.034], [0.1, 0.2], [float("nan")] * 5, {"k1": 1}, "abc"])
def test_a_distortion_opencv_cannot_take_is_refused_on_load(saved, distortion):
    """map.json is outside the arrays' checksum: an edited [-0.034] (k1 alone) ended in
    OpenCV's traceback when a localisation compared cameras (nineteenth hostile pass)."""
    meta = json.loads((saved / "map.json").read_text())["meta"]
    _edit_json(saved, meta={**meta, "distortion": distortion})
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "damaged map.json (camera distortion" in one_line(e)


@pytest.mark.parametrize("distortion", [[], [0.0] * 4, [0.1, -0.2, 0.0, 0.0, 0.01]])
def test_a_distortion_opencv_takes_is_kept(saved, distortion):
    meta = json.loads((saved / "map.json").read_text())["meta"]
    _edit_json(saved, meta={**meta, "distortion": distortion})
    assert load_map(saved).meta["distortion"] == distortion


def test_a_singular_camera_matrix_is_refused_on_load(saved):
    """K of zeros: numpy's "Singular matrix" traceback when a localisation compared cameras."""
    doc = json.loads((saved / "map.json").read_text())
    doc["camera"]["K"] = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]
    (saved / "map.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        load_map(saved)
    assert "camera K is no pinhole matrix" in one_line(e)


def test_a_whole_image_size_written_as_floats_is_kept(saved):
    doc = json.loads((saved / "map.json").read_text())
    doc["camera"]["image_size"] = [640.0, 480.0]
    (saved / "map.json").write_text(json.dumps(doc))
    assert load_map(saved).image_size == (640, 480)


def test_a_map_with_a_repeated_landmark_id_is_refused_on_save(tmp_path):
    """The arrays were checked for shape and range only: a repeated id (or NaN pixels)
    was saved and loaded (nineteenth hostile pass, rebuilt with its checksum)."""
    smap = random_map()
    smap.landmark_ids[1] = smap.landmark_ids[0]
    with pytest.raises(InputError) as e:
        save_map(smap, tmp_path / "bad")
    assert "landmark_ids repeats an id" in one_line(e)


def test_a_map_with_non_finite_pixels_is_refused_on_save(tmp_path):
    smap = random_map()
    smap.obs_uv[3, 1] = np.nan
    with pytest.raises(InputError) as e:
        save_map(smap, tmp_path / "bad")
    assert "obs_uv holds non-finite values" in one_line(e)


def test_a_joined_map_repeats_keyframe_ids_and_is_kept(tmp_path):
    """Two sessions both start at frame 0: keyframe ids repeat by design."""
    from graphslam.maps.merge import merge_maps

    a = random_map()
    b = random_map(seed=1)
    b.vocabulary = a.vocabulary
    joined = merge_maps(a, b)
    save_map(joined, tmp_path / "joined")
    assert load_map(tmp_path / "joined").n_keyframes == 2 * a.n_keyframes
