"""Steps shared by the two vocabulary estimators' ``fit``: parameter and
training-set checks, k-means in one thread, centres, IDF weights.

Binary descriptors are clustered as unpacked bits (0/1 floats) and each
centre re-binarised by majority (:func:`centres_from_kmeans`); float ones as
float32.
"""

from __future__ import annotations

import numpy as np

# threadpoolctl is a dependency of scikit-learn (installed with it), used here
# only to pin k-means to one thread: see one_thread.
from threadpoolctl import threadpool_limits

from loopclosure.descriptor_distance import beyond_float32
from slamcore.errors import ConfigError, VocabularyError


def one_thread():
    """Context pinning OpenMP and BLAS to one thread during a fit.

    Why: (1) scikit-learn's k-means reduces per-thread partial sums, so its
    result depends on the thread count in the last bits; pinned, a seed gives
    the same vocabulary on any machine. (2) The tree runs ~1000 small k-means;
    threads do not help them, and on a shared, loaded machine the thread
    barriers made training 3-8x slower (measured: 10 000-word tree from
    200 000 ORB descriptors, 184 s with the default 2 threads vs 24 s pinned,
    load average 9 on 2 cores).
    """
    return threadpool_limits(limits=1)


#: Largest k-means seed: scikit-learn's ``random_state`` (numpy's RandomState) takes 0 to 2**32 - 1.
KMEANS_SEED_MAX = 2**32 - 1


def check_int(name: str, value, lo: int, hi: int | None = None) -> int:
    """``value`` as an int in ``[lo, hi]`` (ConfigError naming the parameter otherwise)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise ConfigError(f"{name} must be an integer >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ConfigError(f"{name} must be an integer <= {hi}, got {value!r}")
    return int(value)


def as_training_set(descriptors) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Return (all descriptors stacked (N, D), per-image list or None)."""
    if isinstance(descriptors, np.ndarray):
        if descriptors.ndim != 2 or descriptors.shape[0] == 0:
            raise VocabularyError(
                f"descriptors must be a non-empty (N, D) array, got shape {descriptors.shape}"
            )
        return _finite(descriptors), None
    images = [np.asarray(d) for d in descriptors]
    if not images:
        raise VocabularyError("no images to fit")
    if any(d.ndim != 2 for d in images if d.size > 0):
        raise VocabularyError("every image must hold an (N, D) array")
    # An image without descriptors still counts in N_images for the IDF.
    full = [d for d in images if d.size > 0]
    if not full:
        raise VocabularyError("no descriptors to fit")
    if len({d.shape[1] for d in full}) != 1 or len({d.dtype for d in full}) != 1:
        raise VocabularyError("every image must hold descriptors of one width D and one dtype")
    return _finite(np.concatenate(full, axis=0)), images


def _finite(x: np.ndarray) -> np.ndarray:
    """``x`` unless float with NaN or inf: scikit-learn refused those with its own words,
    and all-NaN rows made one word (NaN rows are all 'the same')."""
    if x.dtype.kind == "f" and not np.isfinite(x).all():
        raise VocabularyError("training descriptors must be finite (NaN or inf found)")
    # k-means runs in float32 (kmeans_features): finite float64 beyond its range became inf
    # there, and scikit-learn's own ValueError (twentieth hostile pass)
    if x.dtype.kind == "f" and beyond_float32(x):
        raise VocabularyError("training descriptors must be within float32's range (k-means runs in float32)")
    return x


def kmeans_features(x: np.ndarray, metric: str) -> np.ndarray:
    """Points in the space where k-means runs: unpacked bits (0/1) or float32."""
    if metric == "hamming":
        return np.unpackbits(x, axis=1).astype(np.float32)
    return x.astype(np.float32, copy=False)


def centres_from_kmeans(centres: np.ndarray, metric: str) -> np.ndarray:
    """k-means centres -> vocabulary centres: majority bits packed to uint8, or float32."""
    if metric == "hamming":
        return np.packbits(centres >= 0.5, axis=1)
    return centres.astype(np.float32)


def n_distinct_at_least(x: np.ndarray, k: int) -> bool:
    """True when x (N, D) holds at least k distinct rows (k-means needs k)."""
    if x.shape[0] < k:
        return False
    rows = np.ascontiguousarray(x).view(np.dtype((np.void, x.dtype.itemsize * x.shape[1])))
    return np.unique(rows[:, 0]).size >= k


def idf_from_images(word_lists: list[np.ndarray] | None, n_words: int) -> tuple[np.ndarray, int]:
    """(n_words,) float64 IDF and the number of training images (0 = uniform IDF)."""
    if word_lists is None:
        return np.ones(n_words, dtype=np.float64), 0
    df = np.zeros(n_words, dtype=np.int64)
    for w in word_lists:
        df[np.unique(w)] += 1
    n_docs = len(word_lists)
    return np.log(n_docs / np.maximum(df, 1)), n_docs
