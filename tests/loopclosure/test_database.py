"""Bag-of-words database: DBoW2 L1 score, inverted-index query vs brute force, exclusions, KITTI."""

from __future__ import annotations

import numpy as np
import pytest

from slamcore.errors import ConfigError
from loopclosure.database import BowDatabase, BowVector
from loopclosure.vocabulary import FlatVocabulary, VocabularyTree
from tests.conftest import SHARED_DATA

#: Agreement of two computations of one score (float64 sums of <= a few thousand terms).
SCORE_TOL = 1e-12

N_WORDS = 500


class UniformVocabulary:
    """Stand-in fitted vocabulary for database tests that build BowVectors directly."""

    n_words_ = N_WORDS
    idf_ = np.ones(N_WORDS)

    def transform(self, descriptors):
        raise AssertionError("not used")


def random_bow(rng, n_words=N_WORDS, zipf=1.0, n_draws=60) -> BowVector:
    """Seeded sparse vector: words drawn from a Zipf-like law so postings overlap a lot."""
    p = 1.0 / np.arange(1, n_words + 1) ** zipf
    ids, counts = np.unique(rng.choice(n_words, n_draws, p=p / p.sum()), return_counts=True)
    w = counts * rng.uniform(0.5, 2.0, ids.size)
    return BowVector(ids, w / w.sum())


def dense(b: BowVector, n_words=N_WORDS) -> np.ndarray:
    v = np.zeros(n_words)
    v[b.word_ids] = b.weights
    return v


def brute_force_ranking(db_vectors, q, n_allowed):
    """(ids, scores) of images 0..n_allowed-1 with a positive L1 score, best first, ties by id."""
    n_words = max([N_WORDS] + [int(v.word_ids[-1]) + 1 for v in db_vectors[:n_allowed] if len(v)])
    n_words = max(n_words, int(q.word_ids[-1]) + 1 if len(q) else 0)
    qd = dense(q, n_words)
    s = np.array([1.0 - 0.5 * np.abs(dense(d, n_words) - qd).sum() if len(d) and len(q) else 0.0
                  for d in db_vectors[:n_allowed]])
    ids = np.flatnonzero(s > SCORE_TOL)
    order = np.lexsort((ids, -s[ids]))
    return ids[order], s[ids][order]


def filled_db(seed=0, n=300):
    rng = np.random.default_rng(seed)
    vectors = [random_bow(rng) for _ in range(n)]
    db = BowDatabase(UniformVocabulary())
    for i, v in enumerate(vectors):
        assert db.add(v) == i
    return db, vectors, rng


def test_bow_vector_invariants():
    with pytest.raises(ValueError):
        BowVector(np.array([2, 1]), np.array([0.5, 0.5]))       # not sorted
    with pytest.raises(ValueError):
        BowVector(np.array([1, 2]), np.array([0.5, 0.6]))       # not L1-normalised
    with pytest.raises(ValueError):
        BowVector(np.array([1, 2]), np.array([1.0, 0.0]))       # zero weight
    b = BowVector(np.array([1, 5]), np.array([0.25, 0.75]))
    assert b.word_ids.dtype == np.int64 and b.weights.dtype == np.float64
    with pytest.raises(ValueError):
        b.weights[0] = 1.0                                       # read-only


def test_score_is_the_l1_formula_and_its_inverted_index_form():
    rng = np.random.default_rng(0)
    db = BowDatabase(UniformVocabulary())
    for _ in range(200):
        a, b = random_bow(rng), random_bow(rng)
        l1 = 1.0 - 0.5 * np.abs(dense(a) - dense(b)).sum()
        common = np.intersect1d(a.word_ids, b.word_ids)
        aw, bw = dense(a)[common], dense(b)[common]
        inv = 0.5 * np.sum(np.abs(aw) + np.abs(bw) - np.abs(aw - bw))
        s = db.score(a, b)
        assert s == pytest.approx(l1, abs=SCORE_TOL) and s == pytest.approx(inv, abs=SCORE_TOL)
        assert 0.0 <= s <= 1.0 and s == pytest.approx(db.score(b, a), abs=SCORE_TOL)
    assert db.score(a, a) == pytest.approx(1.0, abs=SCORE_TOL)
    # disjoint vectors score 0
    assert db.score(BowVector([1], [1.0]), BowVector([2], [1.0])) == 0.0


@pytest.mark.parametrize("exclude_recent", [0, 7])
def test_query_equals_brute_force_ranking(exclude_recent):
    db, vectors, rng = filled_db()
    n_allowed = len(vectors) - exclude_recent
    for _ in range(30):
        q = random_bow(rng)
        ids, scores = brute_force_ranking(vectors, q, n_allowed)
        for k in (1, 10, 1000):
            got = db.query(q, max_results=k, exclude_recent=exclude_recent)
            assert len(got) == min(k, ids.size)
            got_ids = np.array([i for i, _ in got])
            got_s = np.array([s for _, s in got])
            np.testing.assert_allclose(got_s, scores[:len(got)], rtol=0, atol=SCORE_TOL)
            # same ids, except where two scores are equal within rounding
            distinct = np.r_[np.diff(scores[:len(got)]) < -SCORE_TOL, True]
            distinct &= np.r_[True, np.diff(scores[:len(got)]) < -SCORE_TOL]
            assert np.array_equal(got_ids[distinct], ids[:len(got)][distinct])
            assert all(i < n_allowed for i in got_ids)


class WideVocabulary(UniformVocabulary):
    n_words_ = 2000
    idf_ = np.ones(2000)


def test_query_prunes_exactly_on_a_large_database(monkeypatch):
    # Many images, a Zipf word law and IDF-like weights (frequent words weigh little):
    # the pruned path runs (tried at any size here), and it must stay exact.
    import loopclosure.database

    monkeypatch.setattr(loopclosure.database, "_MIN_PRUNE", 0)
    rng = np.random.default_rng(5)
    n_words, draws = 2000, 200
    p = 1.0 / np.arange(1, n_words + 1)
    p /= p.sum()
    idf = np.log(1.0 / (1.0 - (1.0 - p) ** draws))  # expected log(N / document frequency)

    def bow():
        ids, counts = np.unique(rng.choice(n_words, draws, p=p), return_counts=True)
        w = counts * idf[ids]
        return BowVector(ids[w > 0], w[w > 0] / w[w > 0].sum())

    db = BowDatabase(WideVocabulary())
    vectors = [bow() for _ in range(3000)]
    for v in vectors:
        db.add(v)
    skipped = 0
    for _ in range(10):
        q = vectors[int(rng.integers(len(vectors)))]
        ids, scores = brute_force_ranking(vectors, q, len(vectors))
        scanned = count_scanned(db)
        got = db.query(q, max_results=5)
        np.testing.assert_allclose([s for _, s in got], scores[:5], rtol=0, atol=SCORE_TOL)
        assert got[0][1] == pytest.approx(1.0, abs=SCORE_TOL)
        skipped += len(q) - sum(scanned)
    assert skipped, "the pruned path was never taken: the test does not exercise it"


def count_scanned(db: BowDatabase) -> list[int]:
    """A list that the next queries of ``db`` fill with the number of words each scan reads."""
    scanned: list[int] = []
    original = db._scan
    db._scan = lambda scores, words, *a, **kw: scanned.append(len(words)) or original(scores, words, *a, **kw)
    return scanned


def test_query_equals_the_sparse_floor_on_real_image_vectors(shared_data):
    # Real ORB words (the loop detector's ORB, the shipped vocabulary) of 6 real images,
    # replicated to 3000 images as bench_vocabulary.py does: the pruned query must give
    # the floor's top 10, ids in order and scores to SCORE_TOL, with and without exclusions.
    from frontend.image import load_gray
    from frontend.orb import OrbDetector
    from loopclosure.detector import LoopDetectorConfig
    from loopclosure.shipped import load_shipped_vocabulary
    from tests.benchmarks import load_benchmark

    bench = load_benchmark("bench_vocabulary")
    paths = (sorted((shared_data / "kitti07" / "image_0").glob("*.png"))[:150:40]
             + sorted((shared_data / "lund_door" / "images").glob("*.JPG"))[:1]
             + sorted((shared_data / "slambook2_desk" / "images").glob("*.png"))[:1])
    vocab = load_shipped_vocabulary()
    orb = OrbDetector(LoopDetectorConfig().orb)
    words = [vocab.transform(orb.detect(load_gray(p)).descriptors) for p in paths]
    db = BowDatabase(vocab)
    replicas = [db.bow_from_words(w) for w in bench.replica_words(words, 3000, seed=3)]
    for v in replicas:
        db.add(v)
    floor, _ = bench.sparse_floor(replicas, vocab.n_words_)
    scanned = count_scanned(db)
    for w in words:
        q = db.bow_from_words(w)
        for exclude in (0, 1000):
            got = db.query(q, 10, exclude_recent=exclude)
            want = floor(q, 10) if exclude == 0 else \
                bench.sparse_floor(replicas[:-exclude], vocab.n_words_)[0](q, 10)
            assert [i for i, _ in got] == [i for i, _ in want]
            np.testing.assert_allclose([s for _, s in got], [s for _, s in want],
                                       rtol=0, atol=SCORE_TOL)
    assert sum(scanned) < sum(len(db.bow_from_words(w)) for w in words) * 2, \
        "every word was scanned: the pruned path is not exercised"


def test_exclude_recent_and_self_query():
    db, vectors, _ = filled_db(n=50)
    for i in (0, 17, 49):
        best = db.query(vectors[i], max_results=3)
        assert best[0][0] == i and best[0][1] == pytest.approx(1.0, abs=SCORE_TOL)
    # the most recent images are never returned, however good
    for excl in (1, 10, 50, 80):
        got = db.query(vectors[49], max_results=100, exclude_recent=excl)
        assert all(i < 50 - excl for i, _ in got)
    assert db.query(vectors[49], exclude_recent=50) == []
    assert db.query(vectors[3], max_results=0) == []
    with pytest.raises(ConfigError):
        db.query(vectors[3], exclude_recent=-1)


def test_empty_vectors():
    db, vectors, _ = filled_db(n=20)
    empty = BowVector.empty()
    assert len(empty) == 0 and db.bow(np.zeros((0, 32), np.uint8)).word_ids.size == 0
    assert db.query(empty) == []
    assert db.score(empty, vectors[0]) == 0.0 and db.score(empty, empty) == 0.0
    assert db.add(empty) == 20 and len(db) == 21
    assert all(i != 20 for i, _ in db.query(vectors[0], max_results=100))
    assert BowDatabase(UniformVocabulary()).query(vectors[0]) == []


def test_bow_is_tf_idf_l1_normalised():
    rng = np.random.default_rng(2)
    centres = rng.normal(0.0, 100.0, size=(8, 4))
    lab = np.repeat(np.arange(8), 30)
    x = (centres[lab] + rng.normal(0.0, 0.5, size=(lab.size, 4))).astype(np.float32)
    # cluster 0 in every image (IDF 0), the others in one or two images
    images = [x[np.isin(lab, c)] for c in ([0, 1, 2, 3], [0, 3, 4, 5], [0, 5, 6, 7])]
    voc = FlatVocabulary(n_words=8, seed=0, minibatch=False, n_init=5).fit(images)
    db = BowDatabase(voc)
    d = x[rng.choice(lab.size, 57, replace=False)]
    b = db.bow(d)
    words = voc.transform(d)
    expect = np.bincount(words, minlength=8) / words.size * voc.idf_
    expect /= expect.sum()
    assert np.all(np.diff(b.word_ids) > 0) and np.all(b.weights > 0)
    np.testing.assert_allclose(dense(b, 8), expect, rtol=0, atol=SCORE_TOL)
    zero_idf = np.flatnonzero(voc.idf_ == 0.0)
    assert zero_idf.size == 1 and zero_idf[0] in words and zero_idf[0] not in b.word_ids
    assert b.weights.sum() == pytest.approx(1.0, abs=SCORE_TOL)


# -- real images ------------------------------------------------------------------

#: Query frames: none inserted, each at most 3 frames (a few metres) from an inserted one.
KITTI_QUERIES = (2, 33, 48, 71, 88, 119, 142, 157)
KITTI = SHARED_DATA / "kitti07" / "image_0"


@pytest.fixture(scope="module")
def kitti_descriptors():
    if not KITTI.is_dir():
        pytest.skip(f"KITTI 07 frames not found at {KITTI}")
    from frontend.image import load_gray
    from frontend.orb import OrbDetector

    det = OrbDetector(cell_size_px=0, n_features=500)
    files = sorted(KITTI.glob("*.png"))[:160]
    if len(files) < 160:
        pytest.skip(f"fewer than 160 KITTI 07 frames in {KITTI}")
    needed = set(range(0, 160, 5)) | set(KITTI_QUERIES)
    return {i: det.detect(load_gray(files[i])).descriptors for i in sorted(needed)}


def test_kitti_frame_ranks_its_nearest_inserted_frame_first(kitti_descriptors):
    d = kitti_descriptors
    # vocabulary from frames that are neither inserted nor queried
    voc = VocabularyTree(branching=8, depth=3, seed=0).fit([d[i] for i in range(5, 160, 10)])
    db = BowDatabase(voc)
    inserted = list(range(0, 160, 10))
    for i in inserted:
        db.add(db.bow(d[i]))
    for f in KITTI_QUERIES:
        nearest = min(inserted, key=lambda i: abs(i - f))
        got = db.query(db.bow(d[f]), max_results=3)
        assert inserted[got[0][0]] == nearest, (f, [(inserted[i], s) for i, s in got])


# -- pruned query: exactness against brute force ------------------------------------

def zipf_idf_bow(rng, n_words=2000, used=1500, draws=200):
    """Vector over the first ``used`` words, Zipf-drawn, IDF-like weights (frequent words
    weigh little): the shape under which the pruned query skips the long lists."""
    p = 1.0 / np.arange(1, used + 1)
    p /= p.sum()
    idf = np.log(1.0 / (1.0 - (1.0 - p) ** draws))
    ids, counts = np.unique(rng.choice(used, draws, p=p), return_counts=True)
    w = counts * idf[ids]
    return BowVector(ids[w > 0], w[w > 0] / w[w > 0].sum())


def assert_same_ranking(got, vectors, q, n_allowed, k):
    ids, scores = brute_force_ranking(vectors, q, n_allowed)
    assert len(got) == min(k, ids.size)
    got_ids, got_s = np.array([i for i, _ in got], dtype=int), np.array([s for _, s in got])
    np.testing.assert_allclose(got_s, scores[:len(got)], rtol=0, atol=SCORE_TOL)
    # same ids wherever the scores are not equal to rounding (exact ties: lower id first,
    # checked on duplicated vectors below)
    distinct = np.r_[np.diff(scores[:len(got)]) < -SCORE_TOL, True]
    distinct &= np.r_[True, np.diff(scores[:len(got)]) < -SCORE_TOL]
    assert np.array_equal(got_ids[distinct], ids[:len(got)][distinct])
    assert len(set(got_ids.tolist())) == len(got) and all(i < n_allowed for i in got_ids)


@pytest.fixture
def pruning_everywhere(monkeypatch):
    """Prune at any database size, with scan and rescoring groups of a few lists or rows."""
    import loopclosure.database

    monkeypatch.setattr(loopclosure.database, "_MIN_PRUNE", 0)
    monkeypatch.setattr(loopclosure.database, "_CHUNK", 700)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruned_query_equals_brute_force_with_ties_exclusions_and_growth(pruning_everywhere, seed):
    rng = np.random.default_rng(seed)
    db = BowDatabase(WideVocabulary())
    vectors = [zipf_idf_bow(rng) for _ in range(1500)]
    for v in vectors:
        db.add(v)
    scanned, pruned = count_scanned(db), 0
    for round_ in range(2):  # the second round after the database grew by 500 images
        n = len(vectors)
        stored = np.unique(np.concatenate([v.word_ids for v in vectors]))
        for _ in range(6):
            q = vectors[int(rng.integers(n))] if rng.random() < 0.5 else zipf_idf_bow(rng)
            for k, exclude in ((1, 0), (10, 0), (10, 300), (25, n - 40), (3000, 0)):
                del scanned[:]
                got = db.query(q, max_results=k, exclude_recent=exclude)
                assert_same_ranking(got, vectors, q, n - exclude, k)
                pruned += sum(scanned) < np.isin(q.word_ids, stored).sum()
            assert db.query(q, max_results=0) == []
        grown = [zipf_idf_bow(rng) for _ in range(500)]
        for v in grown:
            db.add(v)
        vectors += grown
    assert pruned >= 20, f"only {pruned} of 60 queries skipped words: the pruned path is not exercised"


def test_pruned_query_is_exact_when_it_scans_every_word(pruning_everywhere, monkeypatch):
    # When rescoring never pays (the cost model told so), the pruned scan reads every
    # word and the query ranks its complete scores: exact still, with exclusions.
    import loopclosure.database

    monkeypatch.setattr(loopclosure.database, "_STOP_STEPS", 0.0)
    rng = np.random.default_rng(11)
    db = BowDatabase(WideVocabulary())
    vectors = [zipf_idf_bow(rng) for _ in range(1500)]
    for v in vectors:
        db.add(v)
    scanned = count_scanned(db)
    for _ in range(6):
        q = vectors[int(rng.integers(len(vectors)))] if rng.random() < 0.5 else zipf_idf_bow(rng)
        for k, exclude in ((1, 0), (10, 0), (10, 300), (25, len(vectors) - 40)):
            del scanned[:]
            got = db.query(q, max_results=k, exclude_recent=exclude)
            assert_same_ranking(got, vectors, q, len(vectors) - exclude, k)
            assert len(scanned) > 1, "the pruned path was not taken"


def test_pruned_query_breaks_exact_ties_by_lower_id(pruning_everywhere):
    rng = np.random.default_rng(7)
    db = BowDatabase(WideVocabulary())
    vectors = [zipf_idf_bow(rng) for _ in range(1200)]
    # the query's own vector at 4 ids, a second vector at 3 ids: exact ties at 1 and below
    q, other = vectors[5], zipf_idf_bow(rng)
    for i in (40, 300, 301, 999):
        vectors[i] = q
    for i in (41, 500, 800):
        vectors[i] = other
    for v in vectors:
        db.add(v)
    got = db.query(q, max_results=4)
    assert [i for i, _ in got] == [5, 40, 300, 301]
    assert all(s == pytest.approx(1.0, abs=SCORE_TOL) for _, s in got)
    assert db.query(q, max_results=1) == [(5, got[0][1])]
    got = db.query(other, max_results=10)
    assert [i for i, _ in got[:3]] == [41, 500, 800]
    assert_same_ranking(got, vectors, other, len(vectors), 10)


def test_query_words_absent_from_the_database(pruning_everywhere):
    rng = np.random.default_rng(3)
    db = BowDatabase(WideVocabulary())
    vectors = [zipf_idf_bow(rng) for _ in range(800)]  # words 0..1499 only
    for v in vectors:
        db.add(v)
    absent = BowVector(np.arange(1600, 1610), np.full(10, 0.1))
    assert db.query(absent) == []
    base = zipf_idf_bow(rng)
    mixed_ids = np.r_[base.word_ids, np.arange(1700, 1720)]
    mixed = BowVector(mixed_ids, np.r_[base.weights * 0.5, np.full(20, 0.5 / 20)])
    for k in (1, 10):
        assert_same_ranking(db.query(mixed, max_results=k), vectors, mixed, len(vectors), k)


def near_ties(rng, n_near=30, step=1e-9):
    """A query and ``n_near`` images whose scores against it are 1 - i * step (i = 1..n):
    apart by far more than float64 rounding, by far less than float32 resolves near 1."""
    q = zipf_idf_bow(rng)
    near = []
    for i in range(1, n_near + 1):
        w = q.weights.copy()
        w[0] += 2 * i * step  # L1 distance 4 i step after renormalising: score 1 - 2 i step
        near.append(BowVector(q.word_ids, w / w.sum()))
    return q, near


@pytest.mark.parametrize("pruned", [False, True])
def test_scores_closer_than_float32_resolves_rank_exactly(request, pruned):
    # The scan sums in float32 (half the memory traffic); the answer's order and scores
    # come from float64 rescoring of every image within the scan's error bound.
    if pruned:
        request.getfixturevalue("pruning_everywhere")
    rng = np.random.default_rng(3)
    q, near = near_ties(rng)
    vectors = [zipf_idf_bow(rng) for _ in range(1200)]
    for i, v in zip(rng.permutation(len(vectors))[:len(near)], near):
        vectors[int(i)] = v
    db = BowDatabase(WideVocabulary())
    for v in vectors:
        db.add(v)
    for k in (1, 10, 30):
        got = db.query(q, max_results=k)
        assert_same_ranking(got, vectors, q, len(vectors), k)
        exact = [float(db.score(q, vectors[i])) for i, _ in got]
        # the float64 scores (float32 would be off by up to 6e-8 here)
        np.testing.assert_allclose([s for _, s in got], exact, rtol=0, atol=SCORE_TOL)


def test_float32_scan_error_is_within_its_bound():
    import loopclosure.database as D

    rng = np.random.default_rng(5)
    vectors = [zipf_idf_bow(rng) for _ in range(800)]
    db = BowDatabase(WideVocabulary())
    for v in vectors:
        db.add(v)
    for _ in range(10):
        q = zipf_idf_bow(rng)
        words, lengths, qs, _, _, _ = db._plan(q)
        scan = np.zeros(len(db), dtype=np.float32)
        db._scan(scan, words, lengths, qs)
        exact = np.array([db.score(q, v) for v in vectors])
        assert np.abs(scan - exact).max() <= D._scan_error(len(words))


@pytest.mark.parametrize("pruned", [False, True])
def test_add_and_query_in_turn_as_a_slam_loop_does(request, pruned):
    # Each add makes its words' cached posting views stale (and may reallocate the
    # lists); every query must still read every posting added before it.
    if pruned:
        request.getfixturevalue("pruning_everywhere")
    rng = np.random.default_rng(13)
    db = BowDatabase(WideVocabulary())
    vectors = []
    for i in range(400):
        v = zipf_idf_bow(rng)
        db.add(v)
        vectors.append(v)
        if i % 7 == 0:
            q = vectors[int(rng.integers(len(vectors)))] if rng.random() < 0.5 else zipf_idf_bow(rng)
            assert_same_ranking(db.query(q, max_results=5), vectors, q, len(vectors), 5)
