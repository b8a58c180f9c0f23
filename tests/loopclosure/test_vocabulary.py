"""Visual vocabularies: word recovery, tree vs brute force, IDF, save/load, bad files, determinism."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from slamcore.errors import ConfigError, GraphSlamError, InputError, NotFittedError, VocabularyError
from loopclosure.descriptor_distance import hamming_distances
from loopclosure.vocabulary import FlatVocabulary, VocabularyTree, load_vocabulary
from loopclosure.vocabulary_file import FORMAT_VERSION

#: Bits flipped between a parent and a child cluster centre (of 256) in the binary hierarchy.
CHILD_FLIP_BITS = 40
#: Bits flipped between a cluster centre and one of its descriptors.
POINT_FLIP_BITS = 4
#: k-means restarts in the recovery tests: one start can merge two clusters (a local optimum).
N_INIT = 5
#: Std of float points around their centre, in descriptor units (centres are ~100 apart).
FLOAT_POINT_STD = 0.5


def flip_bits(rng, packed: np.ndarray, n_bits: int) -> np.ndarray:
    """Copy of packed (D,) uint8 with n_bits distinct random bits flipped."""
    bits = np.unpackbits(packed).copy()
    idx = rng.choice(bits.size, n_bits, replace=False)
    bits[idx] ^= 1
    return np.packbits(bits)


def binary_hierarchy(seed=0, k=4, per_leaf=30):
    """Two-level clusters of 32-byte descriptors: k parents, k children each.

    Returns (descriptors (k*k*per_leaf, 32) uint8, true leaf label per row, leaf centres).
    """
    rng = np.random.default_rng(seed)
    parents = rng.integers(0, 256, size=(k, 32), dtype=np.uint8)
    leaves = np.stack([flip_bits(rng, p, CHILD_FLIP_BITS) for p in parents for _ in range(k)])
    x = np.stack([flip_bits(rng, c, POINT_FLIP_BITS) for c in leaves for _ in range(per_leaf)])
    labels = np.repeat(np.arange(len(leaves)), per_leaf)
    return x, labels, leaves


def float_hierarchy(seed=0, k=3, per_leaf=30, dim=8):
    rng = np.random.default_rng(seed)
    parents = rng.normal(0.0, 100.0, size=(k, dim))
    leaves = np.concatenate([p + rng.normal(0.0, 10.0, size=(k, dim)) for p in parents])
    x = np.concatenate([c + rng.normal(0.0, FLOAT_POINT_STD, size=(per_leaf, dim)) for c in leaves])
    return x.astype(np.float32), np.repeat(np.arange(len(leaves)), per_leaf), leaves


def assert_bijection(words: np.ndarray, labels: np.ndarray, n: int):
    """Every true cluster maps to one word, and distinct clusters to distinct words."""
    mapping = {}
    for lab in range(n):
        w = np.unique(words[labels == lab])
        assert w.size == 1, f"cluster {lab} split over words {w}"
        mapping[lab] = int(w[0])
    assert len(set(mapping.values())) == n


def fitted_tree(seed=0):
    x, labels, leaves = binary_hierarchy(seed)
    return VocabularyTree(branching=4, depth=2, seed=seed, n_init=N_INIT).fit(x), x, labels


# -- fitting -----------------------------------------------------------------------


def test_flat_recovers_binary_and_float_clusters():
    x, labels, leaves = binary_hierarchy()
    v = FlatVocabulary(n_words=16, seed=0, minibatch=False, n_init=N_INIT).fit(x)
    assert v.metric_ == "hamming" and v.centres_.dtype == np.uint8 and v.centres_.shape == (16, 32)
    assert_bijection(v.transform(x), labels, 16)
    xf, lf, _ = float_hierarchy()
    vf = FlatVocabulary(n_words=9, seed=0, minibatch=False, n_init=N_INIT).fit(xf)
    assert vf.metric_ == "euclidean" and vf.centres_.dtype == np.float32
    assert_bijection(vf.transform(xf), lf, 9)


def test_tree_recovers_binary_and_float_clusters_and_leaf_centres():
    v, x, labels = fitted_tree()
    assert v.n_words_ == 16 and v.children_.shape == (1 + 4 + 16, 4)
    words = v.transform(x)
    assert words.dtype == np.int64
    assert_bijection(words, labels, 16)
    # each word's centre is its cluster's true centre to within the point noise
    _, _, leaves = binary_hierarchy()
    for lab in range(16):
        w = words[labels == lab][0]
        assert hamming_distances(v.leaf_centres()[w:w + 1], leaves[lab:lab + 1])[0, 0] <= POINT_FLIP_BITS
    xf, lf, _ = float_hierarchy()
    vf = VocabularyTree(branching=3, depth=2, seed=0, n_init=N_INIT).fit(xf)
    assert vf.n_words_ == 9
    assert_bijection(vf.transform(xf), lf, 9)


def test_tree_descent_equals_brute_force_over_leaves():
    # depth 1: the tree is flat, so the descent must be the brute-force nearest leaf
    rng = np.random.default_rng(1)
    x = rng.integers(0, 256, size=(2000, 32), dtype=np.uint8)
    flat = VocabularyTree(branching=16, depth=1, seed=0).fit(x)
    brute = np.argmin(hamming_distances(x, flat.leaf_centres()), axis=1)
    assert np.array_equal(flat.transform(x), brute)
    # data with the tree's own cluster structure: descent finds the nearest leaf too
    v, xh, _ = fitted_tree()
    assert np.array_equal(v.transform(xh), np.argmin(hamming_distances(xh, v.leaf_centres()), axis=1))
    # (on unstructured data a greedy descent may differ from brute force: documented, not tested)


def test_quantisation_is_o_k_l_shaped_and_handles_empty():
    v, x, _ = fitted_tree()
    assert v.transform(np.zeros((0, 32), np.uint8)).shape == (0,)
    with pytest.raises(ValueError):
        v.transform(x[:, :16])
    with pytest.raises(ValueError):
        v.transform(x.astype(np.float32))


def test_bad_parameters_raise_config_error():
    x, _, _ = binary_hierarchy()
    for bad in (VocabularyTree(branching=1), VocabularyTree(depth=0), VocabularyTree(init="nope"),
                FlatVocabulary(n_words=0)):
        with pytest.raises(ConfigError):
            bad.fit(x)


# -- IDF ---------------------------------------------------------------------------


def test_idf_is_log_n_over_document_frequency():
    x, labels, _ = binary_hierarchy(per_leaf=8)
    # 4 images: cluster 0 in all four, cluster 1 in two, every other cluster in one
    images = [[] for _ in range(4)]
    for lab in range(16):
        rows = x[labels == lab]
        holders = range(4) if lab == 0 else (0, 1) if lab == 1 else (lab % 4,)
        for i in holders:
            images[i].append(rows)
    images = [np.concatenate(r) for r in images]
    v = VocabularyTree(branching=4, depth=2, seed=0, n_init=N_INIT).fit(images)
    w = v.transform(x)
    word_of = {lab: int(w[labels == lab][0]) for lab in range(16)}
    assert v.n_training_images_ == 4
    assert v.idf_[word_of[0]] == pytest.approx(0.0, abs=1e-12)
    assert v.idf_[word_of[1]] == pytest.approx(np.log(2.0), abs=1e-12)
    for lab in range(2, 16):
        assert v.idf_[word_of[lab]] == pytest.approx(np.log(4.0), abs=1e-12)
    # one (N, D) array: no image structure, uniform IDF
    assert np.array_equal(VocabularyTree(4, 2, seed=0).fit(x).idf_, np.ones(16))


# -- determinism and persistence ---------------------------------------------------


def test_same_seed_same_bits():
    x, _, _ = binary_hierarchy()
    a = VocabularyTree(4, 2, seed=3).fit(x)
    b = VocabularyTree(4, 2, seed=3).fit(x.copy())
    for name in ("centres_", "children_", "node_word_", "word_node_", "idf_"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    fa = FlatVocabulary(16, seed=3).fit(x)
    fb = FlatVocabulary(16, seed=3).fit(x)
    assert np.array_equal(fa.centres_, fb.centres_)


def _assert_same(a, b, names):
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
        else:
            assert x == y, name


def test_save_load_round_trip_is_bit_identical(tmp_path):
    v, x, _ = fitted_tree()
    path = tmp_path / "tree.vocab"  # no .npz suffix: the file is written at exactly this path
    v.save(path)
    assert path.is_file()
    for loaded in (VocabularyTree.load(path), load_vocabulary(path)):
        _assert_same(v, loaded, ["branching", "depth", "seed", "max_iter", "max_node_samples", "init", "n_init",
                                 "centres_", "children_", "node_word_", "word_node_", "metric_",
                                 "descriptor_dim_", "n_words_", "idf_", "n_training_images_"])
        assert np.array_equal(loaded.transform(x), v.transform(x))
    xf, _, _ = float_hierarchy()
    f = FlatVocabulary(9, seed=0).fit([xf[:100], xf[100:]])
    f.save(tmp_path / "flat.npz")
    g = FlatVocabulary.load(tmp_path / "flat.npz")
    _assert_same(f, g, ["n_words", "seed", "max_iter", "minibatch", "n_init", "centres_", "metric_",
                        "descriptor_dim_", "n_words_", "idf_", "n_training_images_"])


def test_bad_files_raise_input_error_naming_the_file(tmp_path):
    v, _, _ = fitted_tree()
    good = tmp_path / "good.npz"
    v.save(good)
    raw = good.read_bytes()
    cases = {}
    cases["missing.npz"] = None
    cases["truncated.npz"] = raw[: len(raw) // 2]
    cases["garbage.npz"] = b"this is not a vocabulary" * 10
    flipped = bytearray(raw)
    flipped[len(raw) // 2] ^= 0xFF  # inside the stored arrays: CRC or header check fails
    cases["flipped.npz"] = bytes(flipped)
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(InputError) as err:
            VocabularyTree.load(path)
        assert err.value.path == str(path) and str(path) in str(err.value), name
    # wrong version, wrong kind, missing field, inconsistent arrays
    with np.load(good) as z:
        data = {n: z[n] for n in z.files}

    def write(name, **changes):
        d = {**data, **changes}
        d = {n: a for n, a in d.items() if a is not None}
        path = tmp_path / name
        with open(path, "wb") as fh:
            np.savez(fh, **d)
        return path

    p = write("v99.npz", format_version=np.int64(FORMAT_VERSION + 98))
    with pytest.raises(InputError, match="version 99"):
        load_vocabulary(p)
    p = write("kind.npz")
    f = FlatVocabulary(16, seed=0).fit(binary_hierarchy()[0])
    f.save(p)
    with pytest.raises(InputError, match="not a VocabularyTree"):
        VocabularyTree.load(p)
    p = write("nofield.npz", idf=None)
    with pytest.raises(InputError, match="idf"):
        load_vocabulary(p)
    p = write("shape.npz", idf=data["idf"][:-1])
    with pytest.raises(InputError, match="inconsistent"):
        load_vocabulary(p)
    p = write("dtype.npz", centres=data["centres"].astype(np.float32))
    with pytest.raises(InputError, match="inconsistent"):
        load_vocabulary(p)
    p = write("child.npz", children=data["children"] + 100)
    with pytest.raises(InputError, match="inconsistent"):
        load_vocabulary(p)


def test_flat_seed_beyond_kmeans_range_is_refused_by_name():
    # scikit-learn's random_state takes 0 to 2**32 - 1: its own error was a traceback
    x = np.random.default_rng(0).integers(0, 256, (200, 32), dtype=np.uint8)
    with pytest.raises(ConfigError, match="seed must be an integer <= 4294967295"):
        FlatVocabulary(n_words=4, seed=2**32).fit(x)
    assert FlatVocabulary(n_words=4, seed=2**32 - 1).fit(x).n_words_ == 4


@pytest.mark.parametrize("name, content, what", [
    ("dbow3.yml.gz", gzip.compress(b"%YAML:1.0\nvocabulary:\n   k: 10\n", mtime=0), "gzip-compressed"),
    ("dbow3.yml", b"%YAML:1.0\nvocabulary:\n   k: 10\n", "YAML text"),
    ("ORBvoc.txt", b"10 6  0 0\n0 0 252 188 188 242 169 109 85 143 187 171\n", "text"),
], ids=["dbow3-gzip", "dbow3-yaml", "orb-slam-text"])  # bytes make ids that differ by worker (gzip's mtime)
def test_another_tools_vocabulary_is_named_not_called_damaged(tmp_path, name, content, what):
    """Tenth hostile pass: the DBoW3 vocabulary the desk data ships was "damaged or
    unreadable (BadZipFile)": a user learns nothing of what to do."""
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as err:
        load_vocabulary(path)
    message = str(err.value)
    assert f"not a graphslam vocabulary: the file is {what}" in message and "vocab train" in message
    assert "damaged" not in message


@pytest.mark.parametrize("make", [FlatVocabulary, VocabularyTree])
def test_unfitted_vocabulary_says_so_in_the_family_and_as_sklearn_does(make):
    with pytest.raises(NotFittedError, match="not fitted") as err:
        make().transform(np.zeros((2, 32), np.uint8))
    # scikit-learn's NotFittedError is both; code that caught those keeps working
    assert isinstance(err.value, GraphSlamError) and isinstance(err.value, ValueError)
    assert isinstance(err.value, AttributeError)


@pytest.mark.parametrize("make", [lambda: FlatVocabulary(n_words=3), lambda: VocabularyTree(branching=2, depth=2)])
def test_fit_refuses_nan_and_inf_descriptors(make):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 8)).astype(np.float32)
    for bad in (np.full_like(x, np.nan), np.vstack([x, np.full((1, 8), np.inf, np.float32)])):
        # the tree fitted all-NaN descriptors into one word; sklearn's own ValueError otherwise
        with pytest.raises(VocabularyError, match="finite"):
            make().fit(bad)


def test_fit_errors_are_of_the_family_and_value_errors():
    with pytest.raises(VocabularyError) as err:
        FlatVocabulary(n_words=10).fit(np.zeros((3, 32), np.uint8))
    assert isinstance(err.value, GraphSlamError) and isinstance(err.value, ValueError)
