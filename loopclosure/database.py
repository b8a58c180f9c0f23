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
can still lift into the answer (:meth:`BowDatabase.query`). The postings keep
their weights in float32 and the scan sums in float32 (a third less memory
read than float64, and twice the SIMD lanes): its scores are within a known
bound of the exact ones (:func:`_scan_error`), used as a margin by every
pruning test, and every image that may be in the answer is rescored in
float64 from the forward index, so answers and scores are the float64 ones.
Memory: about 20 bytes per stored (image, word) entry, both indexes together.

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

#: First query stage: the rarest, heaviest words up to this fraction of the query's postings,
#: after which theta is taken (on real-image vectors the best partial scores rescored
#: here already give the final k-th best score).
_FIRST_FRACTION = 1 / 32

#: Scan step between pruning checks, as a fraction of the query's postings.
_STEP_FRACTION = 1 / 32

#: Images of best partial score rescored for theta (at least max_results).
_THETA_ROWS = 32

#: Rescore once rescoring all candidates costs less than this many scan steps: past the
#: point where the bound falls below theta, the candidates drop by ~40 % a step on
#: real-image vectors, so a step is worth scanning while it saves more than it costs.
_STOP_STEPS = 2.5

#: Postings gathered per np.add.at in a query scan (see _scan): 512 KiB of buffers.
_CHUNK = 32_768

#: Slack on pruning comparisons, far above the float64 rounding of a sum of <= 1 weights.
_PRUNE_MARGIN = 1e-9

#: Fewer postings than this are scanned in one go: a pruning attempt (a partition of all
#: scores, a rescoring) costs about as much as scanning tens of thousands of postings.
_MIN_PRUNE = 400_000

#: Cost of rescoring one stored (word, weight) entry of a candidate's row, in "postings
#: scanned" units: both gathered in cache-sized groups, measured 5.9 and 6.2 ns at 20 000
#: real-image vectors with the floor run between queries (cold caches).
_RESCORE_COST = 1.0


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
    def empty(cls) -> BowVector:
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64))


class BowDatabase:
    """Images as BoW vectors behind an inverted index (see the module docstring).

    ``BowDatabase(vocabulary)``: ``vocabulary`` is a fitted FlatVocabulary
    or VocabularyTree (anything with ``transform``, ``idf_`` and
    ``n_words_``). Image ids are 0, 1, 2... in insertion order.
    """

    def __init__(self, vocabulary) -> None:
        if not all(hasattr(vocabulary, a) for a in ("transform", "idf_", "n_words_")):
            raise ConfigError("BowDatabase needs a fitted vocabulary (transform, idf_, n_words_)")
        self.vocabulary = vocabulary
        self._idf = np.asarray(vocabulary.idf_, dtype=np.float64)
        self._n_words = int(vocabulary.n_words_)
        # Inverted index: per word, postings [0, _count[w]) of image ids (int32) and
        # weights (float32, for the scan only); arrays are allocated on a word's first
        # posting and doubled when full.
        self._post_ids: list[np.ndarray | None] = [None] * self._n_words
        self._post_wts: list[np.ndarray | None] = [None] * self._n_words
        self._count = np.zeros(self._n_words, dtype=np.int64)
        self._capacity = np.zeros(self._n_words, dtype=np.int64)
        # Views of each word's filled postings, remade for the words a query scans that
        # were added to since (stale): slicing 2 x 400 lists a query cost 0.2 ms.
        self._ids_view: list = [None] * self._n_words
        self._wts_view: list = [None] * self._n_words
        self._stale = np.ones(self._n_words, dtype=bool)
        # Forward index (each image's row of words and weights, rows end to end, image i
        # in [_row_ptr[i], _row_ptr[i + 1])): candidates are rescored from their rows.
        self._row_words = np.empty(0, dtype=np.int32)
        self._row_wts = np.empty(0, dtype=np.float64)
        self._row_ptr = np.zeros(1, dtype=np.int64)
        self._scan_ids = np.empty(0, dtype=np.intp)  # query scan buffers (see _scan)
        self._scan_wts = np.empty(0, dtype=np.float32)
        self._rescore_wts = np.empty(0, dtype=np.float64)
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
        raw = np.asarray(words).reshape(-1)
        if raw.size and raw.dtype.kind not in "iu":  # 1.7 was truncated to word 1
            raise ValueError(f"word ids must be integers, got {raw.dtype}")
        words = raw.astype(np.int64)
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
            raise ValueError(
                f"word id {int(bow.word_ids[-1])} outside the vocabulary ({self._n_words} words)"
            )

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
            wts = np.empty(cap, dtype=np.float32)
            n = int(self._count[w])
            if n:
                ids[:n] = self._post_ids[w][:n]
                wts[:n] = self._post_wts[w][:n]
            self._post_ids[w], self._post_wts[w] = ids, wts
            self._ids_view[w] = self._wts_view[w] = None  # (stale below) frees the old arrays
            self._capacity[w] = cap
        post_ids, post_wts = self._post_ids, self._post_wts
        for w, n, x in zip(words.tolist(), slots.tolist(), bow.weights.tolist(), strict=True):
            post_ids[w][n] = image
            post_wts[w][n] = x
        self._count[words] += 1
        self._stale[words] = True
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

    def query(
        self, bow: BowVector, max_results: int = 10, exclude_recent: int = 0
    ) -> list[tuple[int, float]]:
        """Best matches of ``bow``: [(image id, score)], best first (ties: lower id first).

        Only images sharing at least one word with ``bow`` (score > 0) are
        returned, at most ``max_results`` of them; the ``exclude_recent``
        most recently added images are never returned. Scores are exact
        (equal to :meth:`score` up to float64 rounding): the float32 scan
        only selects which images are rescored in float64.

        Exact "max-score" pruning of text retrieval (Turtle & Flood 1995): the
        query's words are scanned through the inverted index in order of
        weight per posting (rare, heavy words first), accumulating
        ``min(q_w, d_w)`` per image. The words not yet scanned can add at
        most ``B = sum of their q_w`` to any image. After a first stage the
        best partial scores are rescored exactly from the forward index,
        giving ``theta``, a lower bound of the final k-th best score; the
        scan then jumps to where ``B < theta``, and from there only images
        with ``partial + B >= theta`` can still be in the answer. Once
        rescoring those few is cheaper than scanning on (a cost model in
        postings scanned), they are rescored and the rest is never read.
        The frequent words' long posting lists are thus the ones skipped: the
        exact counterpart of a stop list of frequent words (Sivic &
        Zisserman, "Video Google", ICCV 2003), which would change scores.
        """
        k, n_allowed = self._check_query(bow, max_results, exclude_recent)
        if k == 0 or n_allowed <= 0 or bow.word_ids.size == 0:
            return []
        plan = self._plan(bow)
        if plan is None:
            return []
        words, lengths, q, dense_q, bound_after, cum = plan
        total = int(cum[-1])
        scores = np.zeros(self._n_images, dtype=np.float32)
        eps = _scan_error(len(words))
        row_len = self._row_ptr[self._n_images] / self._n_images
        m = min(n_allowed, max(k, _THETA_ROWS))
        if total > _MIN_PRUNE and n_allowed >= k and m * row_len * _RESCORE_COST < total / 4:
            found = self._pruned(scores, plan, k, m, n_allowed, row_len, eps)
            if found is not None:
                return found
        else:
            self._scan(scores, words, lengths, q)
        allowed = scores[:n_allowed]
        cand = np.flatnonzero(allowed > 0.0)
        if cand.size > k:  # the k best and all within the scan's error of them, exactly
            kth = np.partition(allowed[cand], cand.size - k)[cand.size - k]
            cand = cand[allowed[cand] >= kth - 2 * eps]
        return _best(cand, self._rescore(cand, dense_q), k)

    def _plan(self, bow: BowVector):
        """The query's words present in the index, in scan order, with their bounds, or None.

        (words, lengths, q, dense q, bound_after, cumulated lengths):
        ``bound_after[e]`` is the most the words e, e+1, ... can still add to any image.
        """
        lengths = self._count[bow.word_ids]
        present = lengths > 0
        if not present.any():
            return None
        q_all, words_all, lengths = bow.weights[present], bow.word_ids[present], lengths[present]
        order = np.argsort(-q_all / lengths, kind="stable")  # most weight per posting first
        words, lengths, q = words_all[order].tolist(), lengths[order], q_all[order]
        dense_q = np.zeros(self._n_words, dtype=np.float64)
        dense_q[words_all] = q_all
        bound_after = np.r_[np.cumsum(q[::-1])[::-1], 0.0]
        return words, lengths, q, dense_q, bound_after, np.cumsum(lengths)

    def _pruned(self, scores, plan, k: int, m: int, n_allowed: int, row_len: float, eps: float):
        """The pruned scan of :meth:`query`: its answer, or None with ``scores`` complete."""
        words, lengths, q, dense_q, bound_after, cum = plan
        margin = _PRUNE_MARGIN + eps
        total, n_q = int(cum[-1]), len(words)
        step = max(1, int(total * _STEP_FRACTION))
        neg_bound = -bound_after  # increasing, for searchsorted
        end = min(n_q, int(np.searchsorted(cum, total * _FIRST_FRACTION, side="left")) + 1)
        self._scan(scores, words[:end], lengths[:end], q[:end])
        exact = np.full(n_allowed, np.nan)  # exact scores rescored so far (NaN: not yet)
        theta, refreshed = self._theta(scores[:n_allowed], k, m, dense_q, exact), False
        while end < n_q:
            bound = bound_after[end]
            nxt = int(np.searchsorted(cum, int(cum[end - 1]) + step, side="left")) + 1
            if theta > bound + margin:
                if not refreshed:  # partial scores are better now: a tighter theta, once
                    theta, refreshed = max(theta, self._theta(scores[:n_allowed], k, m, dense_q, exact)), True
                cand = np.flatnonzero(scores[:n_allowed] >= theta - bound - margin)
                left = total - int(cum[end - 1])
                if cand.size * row_len * _RESCORE_COST <= min(left, _STOP_STEPS * step):
                    return _best(cand, self._exact(cand, dense_q, exact), k)
            else:  # no image can be ruled out before the bound falls below theta: jump there
                nxt = max(nxt, int(np.searchsorted(neg_bound, margin - theta, side="right")))
            nxt = min(nxt, n_q)
            self._scan(scores, words[end:nxt], lengths[end:nxt], q[end:nxt])
            end = nxt
        return None

    def _theta(self, allowed: np.ndarray, k: int, m: int, dense_q: np.ndarray, exact: np.ndarray) -> float:
        """A lower bound of the final k-th best score: the k-th best exact score of the
        ``m`` (>= k) images of best partial score."""
        top = np.sort(np.argpartition(allowed, allowed.size - m)[allowed.size - m :])
        return float(np.partition(self._exact(top, dense_q, exact), m - k)[m - k])

    def _exact(self, ids: np.ndarray, dense_q: np.ndarray, exact: np.ndarray) -> np.ndarray:
        """Exact scores of the sorted image ids ``ids``, rescoring only those ``exact``
        does not hold yet (NaN) and keeping them there."""
        need = ids[np.isnan(exact[ids])]
        if need.size:
            exact[need] = self._rescore(need, dense_q)
        return exact[ids]

    def _check_query(self, bow: BowVector, max_results, exclude_recent) -> tuple[int, int]:
        """(k, number of images allowed) after checking the arguments (ConfigError)."""
        if isinstance(max_results, bool) or not isinstance(max_results, (int, np.integer)) or max_results < 0:
            raise ConfigError(f"max_results must be an integer >= 0, got {max_results!r}")
        if (
            isinstance(exclude_recent, bool)
            or not isinstance(exclude_recent, (int, np.integer))
            or exclude_recent < 0
        ):
            raise ConfigError(f"exclude_recent must be an integer >= 0, got {exclude_recent!r}")
        self._check_words(bow)
        return int(max_results), self._n_images - int(exclude_recent)

    def _scan(self, scores: np.ndarray, words: list[int], lengths: np.ndarray, q: np.ndarray) -> None:
        """Add to ``scores`` the sum over ``words`` of min(q_w, d_w), from whole posting lists.

        The words go in groups of about ``_CHUNK`` postings, each gathered into small
        buffers kept between queries (from the cached views of the lists: no slicing
        per word), clipped at the query weights in one call and added by one
        ``np.add.at``: the buffers stay in the core's cache (one gather of a whole
        stage went through memory: 8.7 against 5.8 ns a posting at 20 000 real-image
        vectors); ``add.at`` makes no dense result per group, where ``bincount`` (one
        float per image) cost 5 % more a query. ``scores`` is float32, as the weights.
        """
        ns = lengths.tolist()
        q32 = q.astype(np.float32)  # as np.minimum rounds a Python float against float32
        self._refresh_views(words)
        starts = np.cumsum(lengths) - lengths
        group = starts // _CHUNK  # each word goes with the group of its first posting
        cuts = [0, *(np.flatnonzero(np.diff(group)) + 1).tolist(), len(ns)]
        big = int(np.max(np.add.reduceat(lengths, cuts[:-1]))) if len(ns) else 0
        self._reserve(big)
        ids_view, wts_view = self._ids_view, self._wts_view
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            n = int(starts[b - 1] - starts[a]) + ns[b - 1]
            ids, wts = self._scan_ids[:n], self._scan_wts[:n]
            chunk = words[a:b]
            np.concatenate([ids_view[w] for w in chunk], out=ids, casting="same_kind")
            np.concatenate([wts_view[w] for w in chunk], out=wts)
            np.minimum(wts, np.repeat(q32[a:b], lengths[a:b]), out=wts)
            np.add.at(scores, ids, wts)

    def _refresh_views(self, words: list[int]) -> None:
        """Remake the stale words' views of their filled postings."""
        w = np.array(words, dtype=np.intp)
        stale = w[self._stale[w]]
        if stale.size:
            for v, m in zip(stale.tolist(), self._count[stale].tolist(), strict=True):
                self._ids_view[v] = self._post_ids[v][:m]
                self._wts_view[v] = self._post_wts[v][:m]
            self._stale[stale] = False

    def _reserve(self, n: int) -> None:
        """Room for ``n`` entries in the (ids, weights) buffers of scan and rescoring."""
        if n > self._scan_ids.size:
            self._scan_ids = np.empty(n, dtype=np.intp)
            self._scan_wts = np.empty(n, dtype=np.float32)
            self._rescore_wts = np.empty(n, dtype=np.float64)

    def _rescore(self, cand: np.ndarray, dense_q: np.ndarray) -> np.ndarray:
        """(len(cand),) exact scores of the image ids ``cand`` from their rows.

        Rows are summed in word order, as the floor sums them, in groups of about
        ``_CHUNK`` entries gathered into the scan's buffers (cache-sized, as in
        :meth:`_scan`); word ids are widened to intp while gathered, since ``take``
        would convert int32 indices in a pass of its own.
        """
        out = np.zeros(cand.size, dtype=np.float64)
        ptr = self._row_ptr
        starts, ends = ptr[cand].tolist(), ptr[cand + 1].tolist()
        i = 0
        while i < len(starts):
            j, n = i, 0
            while j < len(starts) and (n == 0 or n + ends[j] - starts[j] <= _CHUNK):
                n += ends[j] - starts[j]
                j += 1
            if n:
                self._rescore_rows(out, i, starts[i:j], ends[i:j], n, dense_q)
            i = j
        return out

    def _rescore_rows(self, out, first: int, starts: list, ends: list, n: int, dense_q) -> None:
        """out[first + r] = exact score of the row [starts[r], ends[r]), n entries in all."""
        self._reserve(n)
        words, contrib = self._scan_ids[:n], self._rescore_wts[:n]
        spans = [(s, e) for s, e in zip(starts, ends, strict=True) if e > s]
        np.concatenate([self._row_words[s:e] for s, e in spans], out=words, casting="same_kind")
        np.concatenate([self._row_wts[s:e] for s, e in spans], out=contrib)
        np.minimum(dense_q.take(words), contrib, out=contrib)
        lens = np.array(ends) - np.array(starts)
        filled = np.flatnonzero(lens)  # reduceat needs non-empty rows
        out[first + filled] = np.add.reduceat(contrib, (np.cumsum(lens) - lens)[filled])


def _scan_error(n_words: int) -> float:
    """Largest error of a float32 scan score over ``n_words`` query words: each term
    min(q_w, d_w) <= 1 is rounded once to float32 (weights) and the running sum, <= 1,
    once per addition: at most (n + 2) units of 2**-24, doubled for slack."""
    return (n_words + 2) * 2.0**-23


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
    return [(int(i), float(min(1.0, s))) for i, s in zip(ids[order], scores[order], strict=True)]
