"""Bag-of-words image database: TF-IDF vectors, DBoW2's L1 score, inverted index.

An image's descriptors are quantised by a fitted vocabulary
(:class:`loopclosure.vocabulary.FlatVocabulary` or
:class:`loopclosure.vocabulary.VocabularyTree`) into a sparse
:class:`BowVector`: for every word ``w`` present, ``tf_w * idf_w`` with
``tf_w = count_w / n_descriptors``, then L1-normalised (weights sum to 1).
Words of zero IDF (present in every training image) carry no information and
are left out, so every stored weight is > 0.

Score (DBoW2's L1 score, Gálvez-López & Tardós, "Bags of binary words for
fast place recognition in image sequences", IEEE T-RO 2012)::

    s(a, b) = 1 - 0.5 * || a - b ||_1          a, b L1-normalised, s in [0, 1]

Because both vectors sum to 1 and words outside the intersection contribute
``|a_w|`` or ``|b_w|`` alone::

    s(a, b) = 0.5 * sum over common words w of (|a_w| + |b_w| - |a_w - b_w|)
            = sum over common words w of min(a_w, b_w)          (weights > 0)

so a query only needs the postings of its own words. The inverted index
keeps, for every word, a growable array of (image id, weight) postings, and
the forward index every image's row of (word, weight); a query scans the
postings of its rarest, heaviest words, adding ``min(q_w, d_w)`` per image,
and rescores from the forward index the few images that the words left
can still lift into the answer (:meth:`BowDatabase.query`). Memory: about
24 bytes per stored (image, word) entry, both indexes together.

An empty vector (an image without descriptors, or whose words all have zero
IDF) cannot be L1-normalised; its score against anything is 0 (the
common-word sum is empty), and it matches nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamcore.errors import ConfigError

#: Allowed |sum(weights) - 1| of a BowVector (float64 rounding of a normalised sum).
L1_NORM_TOL = 1e-9

#: First capacity of a word's posting arrays; they double when full.
_INITIAL_CAPACITY = 8

#: Query scan stages: fractions of the query's postings after which pruning is tried
#: (finer where, on real-image vectors, the candidates collapse: 20-40 % of the postings).
_SCAN_FRACTIONS = (1 / 16, 1 / 8, 3 / 16, 1 / 4, 5 / 16, 3 / 8, 1 / 2, 5 / 8, 3 / 4)

#: Slack on pruning comparisons, far above the float64 rounding of a sum of <= 1 weights.
_PRUNE_MARGIN = 1e-9

#: Fewer postings than this are scanned in one go: a pruning attempt (a partition of all
#: scores, a rescoring) costs about as much as scanning tens of thousands of postings.
_MIN_PRUNE = 400_000

#: Cost of rescoring one stored (word, weight) entry of a candidate's row, in "postings
#: scanned" units: measured 2-8 equally fast at 20 000 real-image vectors, 4 kept.
_RESCORE_COST = 4.0

#: Candidates up to this many are rescored row by row (a scipy.sparse row slice costs ~100 us).
_FEW_ROWS = 32


@dataclass(frozen=True, eq=False)
class BowVector:
    """Sparse TF-IDF vector, L1-normalised (weights sum to 1) unless empty.

    Attributes:
        word_ids: (K,) int64 word ids, sorted, unique.
        weights: (K,) float64 weights, > 0, summing to 1 (K = 0: empty vector).

    Both arrays are read-only; construction checks these invariants
    (ValueError otherwise).
    """

    word_ids: np.ndarray
    weights: np.ndarray

    def __post_init__(self):
        ids = np.array(self.word_ids, dtype=np.int64, copy=True).reshape(-1)
        wts = np.array(self.weights, dtype=np.float64, copy=True).reshape(-1)
        if ids.shape != wts.shape:
            raise ValueError(f"word_ids {ids.shape} and weights {wts.shape} differ in length")
        if ids.size:
            if np.any(np.diff(ids) <= 0) or ids[0] < 0:
                raise ValueError("word_ids must be sorted, unique and >= 0")
            if not np.all(np.isfinite(wts)) or np.any(wts <= 0.0):
                raise ValueError("weights must be finite and > 0")
            if abs(wts.sum() - 1.0) > L1_NORM_TOL:
                raise ValueError(f"weights must sum to 1 (L1-normalised), sum is {wts.sum()!r}")
        ids.setflags(write=False)
        wts.setflags(write=False)
        object.__setattr__(self, "word_ids", ids)
        object.__setattr__(self, "weights", wts)

    def __len__(self) -> int:
        return int(self.word_ids.size)

    @classmethod
    def empty(cls) -> "BowVector":
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64))


class BowDatabase:
    """Images as BoW vectors behind an inverted index (see the module docstring).

    ``BowDatabase(vocabulary)``: ``vocabulary`` is a fitted FlatVocabulary
    or VocabularyTree (anything with ``transform``, ``idf_`` and
    ``n_words_``). Image ids are 0, 1, 2... in insertion order.
    """

    def __init__(self, vocabulary):
        if not all(hasattr(vocabulary, a) for a in ("transform", "idf_", "n_words_")):
            raise ConfigError("BowDatabase needs a fitted vocabulary (transform, idf_, n_words_)")
        self.vocabulary = vocabulary
        self._idf = np.asarray(vocabulary.idf_, dtype=np.float64)
        self._n_words = int(vocabulary.n_words_)
        # Inverted index: per word, postings [0, _count[w]) of image ids and weights;
        # arrays are allocated on a word's first posting and doubled when full.
        self._post_ids: list[np.ndarray | None] = [None] * self._n_words
        self._post_wts: list[np.ndarray | None] = [None] * self._n_words
        self._count = np.zeros(self._n_words, dtype=np.int64)
        self._capacity = np.zeros(self._n_words, dtype=np.int64)
        # Forward index (each image's row of words and weights, rows end to end, image i
        # in [_row_ptr[i], _row_ptr[i + 1])): candidates are rescored from their rows.
        self._row_words = np.empty(0, dtype=np.int32)
        self._row_wts = np.empty(0, dtype=np.float64)
        self._row_ptr = np.zeros(1, dtype=np.int64)
        self._scan_ids = np.empty(0, dtype=np.intp)  # query scan buffers (see _scan)
        self._scan_wts = np.empty(0, dtype=np.float64)
        self._n_images = 0

    def __len__(self) -> int:
        return self._n_images

    # -- vectors -----------------------------------------------------------------

    def bow(self, descriptors: np.ndarray) -> BowVector:
        """(N, D) descriptors of one image -> its L1-normalised TF-IDF BowVector.

        N = 0 gives the empty vector.
        """
        d = np.asarray(descriptors)
        if d.size == 0:
            return BowVector.empty()
        return self.bow_from_words(self.vocabulary.transform(d))

    def bow_from_words(self, words: np.ndarray) -> BowVector:
        """(N,) word ids of one image's descriptors (as ``vocabulary.transform`` gives
        them) -> its L1-normalised TF-IDF BowVector; N = 0 gives the empty vector."""
        words = np.asarray(words, dtype=np.int64).reshape(-1)
        if words.size == 0:
            return BowVector.empty()
        if words.min() < 0 or words.max() >= self._n_words:
            raise ValueError(f"word ids must be in [0, {self._n_words})")
        ids, counts = np.unique(words, return_counts=True)
        w = counts / words.size * self._idf[ids]
        keep = w > 0.0  # zero-IDF words carry no information (and weights must be > 0)
        ids, w = ids[keep], w[keep]
        if ids.size == 0:
            return BowVector.empty()
        return BowVector(ids, w / w.sum())

    def score(self, a: BowVector, b: BowVector) -> float:
        """DBoW2's L1 score ``1 - 0.5 * ||a - b||_1`` in [0, 1]; 0 when either is empty.

        Computed as the sum over common words of ``min(a_w, b_w)``, equal for
        L1-normalised vectors (module docstring).
        """
        _, ia, ib = np.intersect1d(a.word_ids, b.word_ids, assume_unique=True, return_indices=True)
        if ia.size == 0:
            return 0.0
        return float(min(1.0, np.minimum(a.weights[ia], b.weights[ib]).sum()))

    # -- inverted index ----------------------------------------------------------

    def _check_words(self, bow: BowVector) -> None:
        if not isinstance(bow, BowVector):
            raise TypeError(f"expected a BowVector, got {type(bow).__name__}")
        if bow.word_ids.size and bow.word_ids[-1] >= self._n_words:
            raise ValueError(f"word id {int(bow.word_ids[-1])} outside the vocabulary "
                             f"({self._n_words} words)")

    def add(self, bow: BowVector) -> int:
        """Insert one image; returns its id (0, 1, 2... in insertion order)."""
        self._check_words(bow)
        image = self._n_images
        words = bow.word_ids
        slots = self._count[words]
        # Grow the (few) full posting arrays first, so the fill loop below is plain stores.
        for w in words[slots == self._capacity[words]].tolist():
            cap = max(_INITIAL_CAPACITY, 2 * int(self._capacity[w]))
            ids = np.empty(cap, dtype=np.int32)
            wts = np.empty(cap, dtype=np.float64)
            n = int(self._count[w])
            if n:
                ids[:n] = self._post_ids[w][:n]
                wts[:n] = self._post_wts[w][:n]
            self._post_ids[w], self._post_wts[w] = ids, wts
            self._capacity[w] = cap
        post_ids, post_wts = self._post_ids, self._post_wts
        for w, n, x in zip(words.tolist(), slots.tolist(), bow.weights.tolist()):
            post_ids[w][n] = image
            post_wts[w][n] = x
        self._count[words] += 1
        self._append_row(bow)
        self._n_images = image + 1
        return image

    def _append_row(self, bow: BowVector) -> None:
        """Append ``bow`` to the forward index (arrays doubled when full)."""
        start = int(self._row_ptr[self._n_images])
        end = start + len(bow)
        if end > self._row_words.size:
            cap = max(end, 2 * self._row_words.size, 1024)
            self._row_words = _grown(self._row_words, cap, start)
            self._row_wts = _grown(self._row_wts, cap, start)
        if self._n_images + 2 > self._row_ptr.size:
            self._row_ptr = _grown(self._row_ptr, 2 * self._row_ptr.size, self._n_images + 1)
        self._row_words[start:end] = bow.word_ids
        self._row_wts[start:end] = bow.weights
        self._row_ptr[self._n_images + 1] = end

    def query(self, bow: BowVector, max_results: int = 10,
              exclude_recent: int = 0) -> list[tuple[int, float]]:
        """Best matches of ``bow``: [(image id, score)], best first (ties: lower id first).

        Only images sharing at least one word with ``bow`` (score > 0) are
        returned, at most ``max_results`` of them; the ``exclude_recent``
        most recently added images are never returned. Scores are exact
        (equal to :meth:`score` up to float rounding).

        Exact "max-score" pruning of text retrieval (Turtle & Flood 1995): the
        query's words are scanned through the inverted index in order of
        weight per posting (rare, heavy words first), accumulating
        ``min(q_w, d_w)`` per image. The words not yet scanned can add at
        most ``B = sum of their q_w`` to any image. After each stage the
        ``max_results`` best partial scores are rescored exactly from the
        forward index, giving ``theta``, a lower bound of the final k-th
        best score; only images with ``partial + B >= theta`` can still be
        in the answer, and once rescoring those few is cheaper than
        scanning the rest, they are rescored and the rest is never read.
        The frequent words' long posting lists are thus the ones skipped: the
        exact counterpart of a stop list of frequent words (Sivic &
        Zisserman, "Video Google", ICCV 2003), which would change scores.
        """
        k, n_allowed = self._check_query(bow, max_results, exclude_recent)
        if k == 0 or n_allowed <= 0 or bow.word_ids.size == 0:
            return []
        lengths = self._count[bow.word_ids]
        present = lengths > 0
        if not present.any():
            return []
        q_all, words_all, lengths = bow.weights[present], bow.word_ids[present], lengths[present]
        order = np.argsort(-q_all / lengths, kind="stable")  # most weight per posting first
        words, lengths, q = words_all[order].tolist(), lengths[order], q_all[order]
        dense_q = np.zeros(self._n_words, dtype=np.float64)
        dense_q[words_all] = q_all
        # bound_after[e]: largest score the words e, e+1, ... can still add to any image.
        bound_after = np.r_[np.cumsum(q[::-1])[::-1], 0.0]
        cum = np.cumsum(lengths)
        total = int(cum[-1])
        row_len = self._row_ptr[self._n_images] / self._n_images
        stops = sorted({int(np.searchsorted(cum, total * f, side="left")) + 1
                        for f in _SCAN_FRACTIONS} - {len(words)}) if total > _MIN_PRUNE else []
        scores = np.zeros(self._n_images, dtype=np.float64)
        start, theta = 0, 0.0
        for end in stops:
            self._scan(scores, words[start:end], lengths[start:end], q[start:end])
            start = end
            allowed = scores[:n_allowed]
            if np.count_nonzero(allowed) < k:
                continue  # fewer than k images seen: any unseen one may still enter
            top = np.argpartition(allowed, n_allowed - k)[n_allowed - k:]
            theta = max(theta, float(np.min(self._rescore(top, dense_q))))
            bound = bound_after[end]
            if theta <= bound + _PRUNE_MARGIN:
                continue  # an image not seen yet could still reach the top k
            cand = np.flatnonzero(allowed + bound >= theta - _PRUNE_MARGIN)
            if cand.size * row_len * _RESCORE_COST < total - int(cum[end - 1]):
                return _best(cand, self._rescore(cand, dense_q), k)
        self._scan(scores, words[start:], lengths[start:], q[start:])
        allowed = scores[:n_allowed]
        cand = np.flatnonzero(allowed > 0.0)
        return _best(cand, allowed[cand], k)

    def _check_query(self, bow: BowVector, max_results, exclude_recent) -> tuple[int, int]:
        """(k, number of images allowed) after checking the arguments (ConfigError)."""
        if isinstance(max_results, bool) or not isinstance(max_results, (int, np.integer)) \
                or max_results < 0:
            raise ConfigError(f"max_results must be an integer >= 0, got {max_results!r}")
        if isinstance(exclude_recent, bool) or not isinstance(exclude_recent, (int, np.integer)) \
                or exclude_recent < 0:
            raise ConfigError(f"exclude_recent must be an integer >= 0, got {exclude_recent!r}")
        self._check_words(bow)
        return int(max_results), self._n_images - int(exclude_recent)

    def _scan(self, scores: np.ndarray, words: list[int], lengths: np.ndarray, q: np.ndarray) -> None:
        """Add to ``scores`` the sum over ``words`` of min(q_w, d_w), from whole posting lists.

        A few numpy calls per stage, whatever its number of words; the
        postings are gathered into buffers kept between queries (fresh pages
        for arrays of a million postings cost more than the additions).
        """
        n = int(lengths.sum())
        if n > self._scan_ids.size:
            self._scan_ids = np.empty(2 * n, dtype=np.intp)
            self._scan_wts = np.empty(2 * n, dtype=np.float64)
        ids, wts = self._scan_ids[:n], self._scan_wts[:n]
        ns = lengths.tolist()
        np.concatenate([self._post_ids[w][:m] for w, m in zip(words, ns)], out=ids, casting="same_kind")
        np.concatenate([self._post_wts[w][:m] for w, m in zip(words, ns)], out=wts)
        np.minimum(wts, np.repeat(q, lengths), out=wts)
        scores += np.bincount(ids, weights=wts, minlength=scores.size)

    def _rescore(self, cand: np.ndarray, dense_q: np.ndarray) -> np.ndarray:
        """(len(cand),) exact scores of the sorted image ids ``cand`` from their rows."""
        if cand.size <= _FEW_ROWS:  # row by row: cheaper than building a sparse matrix
            ptr = self._row_ptr
            return np.array([np.minimum(dense_q[self._row_words[ptr[i]:ptr[i + 1]]],
                                        self._row_wts[ptr[i]:ptr[i + 1]]).sum()
                             for i in cand.tolist()], dtype=np.float64)
        import scipy.sparse as sp  # only when a query prunes: loading the database needs none

        n = self._n_images
        ptr = self._row_ptr[: n + 1]
        nnz = int(ptr[-1])
        rows = sp.csr_matrix((self._row_wts[:nnz], self._row_words[:nnz], ptr),
                             shape=(n, self._n_words), copy=False)[cand]
        out = np.zeros(cand.size, dtype=np.float64)
        filled = np.flatnonzero(np.diff(rows.indptr) > 0)  # reduceat needs non-empty rows
        if filled.size:
            contrib = np.minimum(dense_q[rows.indices], rows.data)
            out[filled] = np.add.reduceat(contrib, rows.indptr[filled])
        return out


def _grown(a: np.ndarray, capacity: int, keep: int) -> np.ndarray:
    """A copy of ``a`` with room for ``capacity`` items, its first ``keep`` kept."""
    out = np.empty(capacity, dtype=a.dtype)
    out[:keep] = a[:keep]
    return out


def _best(ids: np.ndarray, scores: np.ndarray, k: int) -> list[tuple[int, float]]:
    """The k best (id, score) with score > 0, best first, ties by lower id."""
    keep = scores > 0.0
    ids, scores = ids[keep], scores[keep]
    if ids.size > k:
        # Keep everything tied with the k-th best so that ties resolve by id below.
        kth = np.partition(scores, ids.size - k)[ids.size - k]
        keep = scores >= kth
        ids, scores = ids[keep], scores[keep]
    order = np.lexsort((ids, -scores))[:k]
    return [(int(i), float(min(1.0, s))) for i, s in zip(ids[order], scores[order])]
