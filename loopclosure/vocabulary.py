"""Visual vocabularies: descriptors -> visual word ids, with IDF weights.

Two scikit-learn style estimators (parameters stored unchanged by
``__init__``, ``fit`` returns ``self``, learned attributes end in ``_``):

- :class:`FlatVocabulary`: one k-means over all training descriptors,
  quantisation by brute force over the ``n_words`` centres.
- :class:`VocabularyTree`: hierarchical k-means (Nistér & Stewénius, CVPR
  2006): k-means with ``k = branching`` at every node, recursively, down to
  ``depth`` levels; quantisation descends the tree, O(k L) distance
  computations per descriptor, vectorised over all descriptors of an image
  level by level.

Every k-means is ``sklearn.cluster.KMeans`` (or ``MiniBatchKMeans`` for a
large flat vocabulary).

Metric, chosen from the descriptor dtype at fit time and stored in
``metric_``:

- ``uint8`` descriptors (ORB/BRIEF, 32 bytes = 256 bits) are binary:
  k-means runs on the unpacked bits (0/1 floats), each centre is then
  re-binarised by majority (threshold 0.5) and packed back to uint8, and
  assignment is by Hamming distance (popcount of XOR). During tree training
  the descriptors of a node are re-assigned to the binarised centres by
  Hamming distance before the recursion, so training partitions and
  query-time descent agree.
- any float dtype: squared Euclidean distance to float32 centres.

Ties in distance go to the lowest centre (child) index, in training and in
quantisation alike.

IDF: ``fit`` accepts either a list of per-image descriptor arrays (preferred:
``idf_[w] = log(N_images / n_images_containing_w)`` as in DBoW2, so a word
present in every training image weighs 0, and a word seen in no training
image is counted as seen once, so it gets the largest weight
``log(N_images)``) or one (N, D) array (no image structure: ``idf_`` is
uniform, all ones).

Persistence: ``save(path)`` writes ONE ``.npz`` file (exactly ``path``, no
suffix added) holding ``format_version``, ``kind``, the parameters and the
learned arrays; ``load(path)`` (class method, or :func:`load_vocabulary` for
either kind) returns arrays identical to the saved ones (same dtype, same
bits) and raises :class:`slamcore.errors.InputError` naming the file when it
is missing, damaged, truncated, of another format version, of another kind or
internally inconsistent.

Beside the estimators: :mod:`loopclosure.descriptor_distance` (metrics and
distances), :mod:`loopclosure.vocabulary_training` (steps shared by both
``fit``) and :mod:`loopclosure.vocabulary_file` (the file format).
"""

from __future__ import annotations

import numpy as np

from loopclosure.descriptor_distance import check_query, metric_for, nearest_centre, popcount_sum
from loopclosure.vocabulary_file import (
    flat_arrays,
    read_kind,
    read_npz,
    restore_flat,
    restore_tree,
    save_npz,
    tree_arrays,
)
from loopclosure.vocabulary_training import (
    KMEANS_SEED_MAX,
    as_training_set,
    centres_from_kmeans,
    check_int,
    idf_from_images,
    kmeans_features,
    n_distinct_at_least,
    one_thread,
)
from slamcore.errors import ConfigError, InputError, NotFittedError, VocabularyError, quote


def _kmeans():
    """scikit-learn's ``(KMeans, MiniBatchKMeans)``, imported on first training only:
    loading a vocabulary needs no scikit-learn (about 1 s of imports). Training calls
    it before :func:`one_thread`, so the thread limit sees sklearn's OpenMP and BLAS
    (a library loaded inside the limit would run unlimited, and k-means sums in
    another order: other centres)."""
    from sklearn.cluster import KMeans, MiniBatchKMeans

    return KMeans, MiniBatchKMeans


def _require_fitted(vocabulary) -> None:
    """NotFittedError (scikit-learn's kind) instead of the AttributeError of a learned
    attribute not yet there."""
    if not hasattr(vocabulary, "metric_"):
        raise NotFittedError(f"{type(vocabulary).__name__} is not fitted: call fit() or load() first")


def load_vocabulary(path) -> FlatVocabulary | VocabularyTree:
    """Load a vocabulary of either kind from ``path`` (InputError when bad)."""
    data = read_npz(path)
    found = {
        "FlatVocabulary": (FlatVocabulary, restore_flat),
        "VocabularyTree": (VocabularyTree, restore_tree),
    }.get(data["kind"])
    if found is None:
        raise InputError(f"unknown vocabulary kind {quote(data['kind'])}", path)
    cls, restore = found
    return restore(cls, data, path)


# ----------------------------------------------------------------------------
# flat vocabulary


class FlatVocabulary:
    """One k-means over the training descriptors: ``n_words`` visual words.

    Parameters:
        n_words: number of clusters (visual words).
        seed: random seed of k-means (a fit repeats to the bit for one seed).
        max_iter: k-means iterations (epochs for MiniBatchKMeans).
        minibatch: use MiniBatchKMeans (faster on large sets) instead of KMeans.
        n_init: k-means restarts, the best (lowest inertia) kept; more
            restarts make a merged pair of clusters less likely.

    Learned attributes: ``centres_`` ((n_words, D) uint8 packed bits for
    binary, float32 otherwise), ``metric_`` ("hamming"|"euclidean"),
    ``n_words_``, ``descriptor_dim_`` (D: bytes for binary, floats
    otherwise), ``idf_`` ((n_words,) float64), ``n_training_images_`` (0
    when fitted on one array).
    """

    kind = "FlatVocabulary"

    def __init__(
        self, n_words: int = 1000, seed: int = 0, max_iter: int = 50, minibatch: bool = True, n_init: int = 1
    ):
        self.n_words = n_words
        self.seed = seed
        self.max_iter = max_iter
        self.minibatch = minibatch
        self.n_init = n_init

    def fit(self, descriptors) -> FlatVocabulary:
        """Learn the words from an (N, D) array or a list of per-image (N_i, D) arrays."""
        _kmeans()  # before one_thread(): see _kmeans
        n_words = check_int("n_words", self.n_words, 1)
        max_iter = check_int("max_iter", self.max_iter, 1)
        seed = check_int("seed", self.seed, 0, KMEANS_SEED_MAX)
        n_init = check_int("n_init", self.n_init, 1)
        x, images = as_training_set(descriptors)
        metric = metric_for(x.dtype)
        if not n_distinct_at_least(x, n_words):
            raise VocabularyError(f"{x.shape[0]} descriptors hold fewer than {n_words} distinct ones")
        feats = kmeans_features(x, metric)
        if self.minibatch:
            km = _kmeans()[1](
                n_clusters=n_words,
                random_state=seed,
                batch_size=max(1024, 3 * n_words),
                n_init=n_init,
                max_iter=max_iter,
            )
        else:
            km = _kmeans()[0](n_clusters=n_words, random_state=seed, n_init=n_init, max_iter=max_iter)
        with one_thread():
            km.fit(feats)
        self.centres_ = centres_from_kmeans(km.cluster_centers_, metric)
        self.metric_ = metric
        self.descriptor_dim_ = int(x.shape[1])
        self.n_words_ = n_words
        words = None if images is None else [self.transform(d) for d in images]
        self.idf_, self.n_training_images_ = idf_from_images(words, self.n_words_)
        return self

    def transform(self, descriptors: np.ndarray) -> np.ndarray:
        """(N, D) descriptors -> (N,) int64 word ids (nearest centre, lowest id on ties)."""
        _require_fitted(self)
        d = check_query(descriptors, self.metric_, self.descriptor_dim_)
        return nearest_centre(d, self.centres_, self.metric_)

    def save(self, path) -> None:
        """Write one .npz file at exactly ``path`` (:mod:`loopclosure.vocabulary_file`)."""
        _require_fitted(self)
        save_npz(path, self.kind, flat_arrays(self))

    @classmethod
    def load(cls, path) -> FlatVocabulary:
        """Read a file written by :meth:`save`; InputError naming the file when it is bad."""
        return restore_flat(cls, read_kind(path, cls.kind), path)


# ----------------------------------------------------------------------------
# vocabulary tree


class VocabularyTree:
    """Hierarchical k-means vocabulary (Nistér & Stewénius 2006).

    Parameters:
        branching: k of every node's k-means.
        depth: number of levels L; at most ``branching ** depth`` words.
        seed: random seed (each node's k-means gets a seed drawn from it in a
            fixed breadth-first order, so a fit repeats to the bit).
        max_iter: Lloyd iterations of each node's k-means.
        max_node_samples: a node with more training descriptors runs its
            k-means on a seeded random subsample of this size; all its
            descriptors are then assigned to the nearest centre (k-means on
            10 centres does not need 200 000 points, and this bounds the
            training time of the top levels).
        init: ``"k-means++"`` or ``"random"``, the KMeans initialisation.
        n_init: k-means restarts per node, the best (lowest inertia) kept.

    A node with fewer than ``branching`` distinct training descriptors (or at
    depth L) becomes a leaf, so words may sit at different depths and
    ``n_words_`` can be below ``branching ** depth``.

    Quantisation is a greedy descent (nearest child at every level), as in
    Nistér & Stewénius and DBoW2: it is not guaranteed to give the leaf
    nearest to the descriptor over all leaves. It does when depth = 1 (the
    tree is then flat), and in practice when the data has the tree's
    cluster structure; on real descriptors the two differ for a fraction of
    descriptors, which is the accepted price of O(k L) quantisation.

    Learned attributes (nodes numbered breadth first, root = 0 without a
    centre):
        ``centres_``: (n_nodes, D) node centres (packed uint8 or float32; row
        0 unused, zeros), ``children_``: (n_nodes, branching) int32 child node
        ids, -1 where absent, ``node_word_``: (n_nodes,) int32 word id of each
        leaf, -1 for inner nodes, ``word_node_``: (n_words,) int32 node of
        each word, ``metric_``, ``descriptor_dim_``, ``n_words_``, ``idf_``,
        ``n_training_images_``.
    """

    kind = "VocabularyTree"

    def __init__(
        self,
        branching: int = 10,
        depth: int = 4,
        seed: int = 0,
        max_iter: int = 20,
        max_node_samples: int = 5000,
        init: str = "random",
        n_init: int = 1,
    ):
        # Defaults measured on 200 000 KITTI ORB descriptors, k=10, L=4 (one
        # thread, loaded machine): random init + 5000 samples per node trains in
        # 24 s; k-means++ took 51 s for 0.7 % lower mean Hamming distortion
        # (54.3 vs 54.7 bits), and 20 000 samples took 34 s for no gain.
        self.branching = branching
        self.depth = depth
        self.seed = seed
        self.max_iter = max_iter
        self.max_node_samples = max_node_samples
        self.init = init
        self.n_init = n_init

    # -- training --------------------------------------------------------------

    def _check_params(self) -> tuple[int, int, int, int, int]:
        k = check_int("branching", self.branching, 2)
        depth = check_int("depth", self.depth, 1)
        seed = check_int("seed", self.seed, 0)
        max_iter = check_int("max_iter", self.max_iter, 1)
        max_samples = check_int("max_node_samples", self.max_node_samples, k)
        check_int("n_init", self.n_init, 1)
        if self.init not in ("k-means++", "random"):
            raise ConfigError(f"init must be 'k-means++' or 'random', got {self.init!r}")
        return k, depth, seed, max_iter, max_samples

    def _node_centres(
        self, pts: np.ndarray, metric: str, seed: int, k: int, max_iter: int, max_samples: int
    ) -> np.ndarray | None:
        """k centres for one node's descriptors, or None when it must be a leaf."""
        if pts.shape[0] > max_samples:
            pick = np.random.default_rng(seed).choice(pts.shape[0], max_samples, replace=False)
            pts = pts[np.sort(pick)]
        if not n_distinct_at_least(pts, k):
            return None
        km = _kmeans()[0](
            n_clusters=k, init=self.init, n_init=int(self.n_init), max_iter=max_iter, random_state=seed
        )
        km.fit(kmeans_features(pts, metric))
        return centres_from_kmeans(km.cluster_centers_, metric)

    def fit(self, descriptors) -> VocabularyTree:
        """Learn the tree from an (N, D) array or a list of per-image (N_i, D) arrays."""
        _kmeans()  # before one_thread(): see _kmeans
        k, depth, seed, max_iter, max_samples = self._check_params()
        x, images = as_training_set(descriptors)
        metric = metric_for(x.dtype)
        if metric == "euclidean":
            x = x.astype(np.float32, copy=False)
        with one_thread():
            self._grow(x, metric, k, depth, seed, max_iter, max_samples)
        self.metric_ = metric
        self.descriptor_dim_ = int(x.shape[1])
        self.n_words_ = int(self.word_node_.size)
        words = None if images is None else [self.transform(d) for d in images]
        self.idf_, self.n_training_images_ = idf_from_images(words, self.n_words_)
        return self

    def _grow(
        self, x: np.ndarray, metric: str, k: int, depth: int, seed: int, max_iter: int, max_samples: int
    ) -> None:
        """Build the tree breadth first; sets centres_, children_, node_word_, word_node_."""
        rng = np.random.default_rng(seed)
        centres = [np.zeros(x.shape[1], dtype=x.dtype)]
        children: list[list[int]] = [[-1] * k]
        # breadth-first queue of (node id, level, indices of its descriptors)
        queue = [(0, 0, np.arange(x.shape[0]))]
        head = 0
        while head < len(queue):
            node, level, idx = queue[head]
            head += 1
            node_seed = int(rng.integers(2**31 - 1))  # drawn for leaves too: fixed order
            if level >= depth or idx.size < k:
                continue
            pts = x[idx]
            c = self._node_centres(pts, metric, node_seed, k, max_iter, max_samples)
            if c is None:
                continue
            # Re-assign with the same metric and tie rule as transform(), so the
            # descriptors that built a child are those that descend into it.
            labels = nearest_centre(pts, c, metric)
            for j in range(k):
                child = len(centres)
                centres.append(c[j])
                children.append([-1] * k)
                children[node][j] = child
                queue.append((child, level + 1, idx[labels == j]))
        self.centres_ = np.stack(centres).astype(x.dtype)
        self.children_ = np.asarray(children, dtype=np.int32)
        is_leaf = (self.children_ < 0).all(axis=1)
        self.node_word_ = np.full(self.children_.shape[0], -1, dtype=np.int32)
        self.word_node_ = np.flatnonzero(is_leaf).astype(np.int32)
        self.node_word_[self.word_node_] = np.arange(self.word_node_.size, dtype=np.int32)

    # -- quantisation ------------------------------------------------------------

    def transform(self, descriptors: np.ndarray) -> np.ndarray:
        """(N, D) descriptors -> (N,) int64 word ids, by descending the tree.

        At every level all descriptors still at an inner node are compared
        with that node's (at most ``branching``) children at once and move to
        the nearest (lowest child index on ties); O(branching * depth)
        distances each.
        """
        _require_fitted(self)
        d = check_query(descriptors, self.metric_, self.descriptor_dim_)
        n = d.shape[0]
        node = np.zeros(n, dtype=np.int64)
        if n == 0 or self.node_word_[0] >= 0:  # the root alone is the only word
            return node
        active = np.arange(n)
        big = np.iinfo(np.int32).max if self.metric_ == "hamming" else np.inf
        while active.size:
            child = self.children_[node[active]]  # (M, k)
            valid = child >= 0
            c = self.centres_[np.where(valid, child, 0)]  # (M, k, D)
            x = d[active][:, None, :]
            if self.metric_ == "hamming":
                dist = popcount_sum(np.bitwise_xor(x, c))
            else:
                diff = x - c
                dist = np.einsum("mkd,mkd->mk", diff, diff)
            dist[~valid] = big
            best = child[np.arange(active.size), np.argmin(dist, axis=1)]
            node[active] = best
            active = active[self.node_word_[best] < 0]
        return self.node_word_[node].astype(np.int64)

    def leaf_centres(self) -> np.ndarray:
        """(n_words, D) centre of every word, in word id order."""
        _require_fitted(self)
        return self.centres_[self.word_node_]

    # -- persistence -------------------------------------------------------------

    def save(self, path) -> None:
        """Write one .npz file at exactly ``path`` (:mod:`loopclosure.vocabulary_file`)."""
        _require_fitted(self)
        save_npz(path, self.kind, tree_arrays(self))

    @classmethod
    def load(cls, path) -> VocabularyTree:
        """Read a file written by :meth:`save`; InputError naming the file when it is bad."""
        return restore_tree(cls, read_kind(path, cls.kind), path)
