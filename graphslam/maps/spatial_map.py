"""A visual map that outlives the run: keyframes, landmarks, what saw what, bag of words.

:class:`SpatialMap` is the record ``graphslam run --save-map`` builds
(:mod:`graphslam.pipelines.mapping`) and ``graphslam localize`` reads
(:mod:`graphslam.pipelines.localize`); :mod:`graphslam.maps.files` writes and
reads it. Conventions of :mod:`slamcore.spatial.backend`: ``wTc`` (4, 4) maps
camera points to world points, pose covariances are (6, 6) ``[rho, phi]`` of a
right perturbation, pixels ``[u, v]`` with pixel centres at integers.

Each observation keeps the ORB descriptor computed at its pixel in its
keyframe: a relocalising camera is matched against the descriptors of the
keyframes place recognition retrieved (what the landmarks looked like from
near there), not against one descriptor per landmark from far away.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from loopclosure.database import L1_NORM_TOL, BowVector
from slamcore.errors import InputError

if TYPE_CHECKING:  # loading a map imports the vocabulary module only when it reads one
    from loopclosure.vocabulary import FlatVocabulary, VocabularyTree

#: Arrays of a map and their trailing shapes and dtypes (the first axis is a count).
ARRAYS: dict[str, tuple[tuple[int, ...], str]] = {
    "keyframe_ids": ((), "int64"),
    "keyframe_wTc": ((4, 4), "float64"),
    "keyframe_cov": ((6, 6), "float64"),
    "landmark_ids": ((), "int64"),
    "landmark_w": ((3,), "float64"),
    "landmark_cov": ((3, 3), "float64"),
    "landmark_desc": ((32,), "uint8"),
    "obs_keyframe": ((), "int64"),
    "obs_landmark": ((), "int64"),
    "obs_uv": ((2,), "float64"),
    "obs_desc": ((32,), "uint8"),
    "bow_indptr": ((), "int64"),
    "bow_words": ((), "int64"),
    "bow_weights": ((), "float64"),
}
#: Which count each array's first axis is (``bow_indptr`` has keyframes + 1 rows).
COUNTS = {"keyframe": "keyframes", "landmark": "landmarks", "obs": "observations"}


#: A map covariance's smallest eigenvalue may be negative by this share of its largest
#: (round-off of the marginals, 1e-16 relative, far inside), not more.
COV_EIGEN_TOL = 1e-8


@dataclass(eq=False)
class SpatialMap:
    """A saved visual map (module docstring). K keyframes, L landmarks, O observations.

    Attributes:
        K: (3, 3) intrinsics; image_size: ``(W, H)`` pixels.
        keyframe_ids: (K,) frame index of each keyframe in the sequence that built it.
        keyframe_wTc, keyframe_cov: (K, 4, 4) poses and (K, 6, 6) covariances.
        landmark_ids: (L,) track ids; landmark_w (L, 3) metres; landmark_cov (L, 3, 3) m^2.
        landmark_desc: (L, 32) uint8 ORB descriptor at the landmark's first observation.
        landmark_patch: (L, p, p) float32 patch the tracker followed it with (p odd).
        obs_keyframe, obs_landmark: (O,) indices into the keyframes and the landmarks.
        obs_uv: (O, 2) pixels; obs_desc: (O, 32) ORB descriptors there.
        bow_indptr, bow_words, bow_weights: every keyframe's bag-of-words vector as
            CSR rows (keyframe ``k`` is ``[indptr[k], indptr[k + 1])``).
        vocabulary: the fitted vocabulary the vectors were made with.
        meta: JSON-ready description (dataset, frames, back end, configuration).
        vocabulary_bytes: the vocabulary file as read (written back verbatim).
    """

    K: np.ndarray
    image_size: tuple[int, int]
    keyframe_ids: np.ndarray
    keyframe_wTc: np.ndarray
    keyframe_cov: np.ndarray
    landmark_ids: np.ndarray
    landmark_w: np.ndarray
    landmark_cov: np.ndarray
    landmark_desc: np.ndarray
    landmark_patch: np.ndarray
    obs_keyframe: np.ndarray
    obs_landmark: np.ndarray
    obs_uv: np.ndarray
    obs_desc: np.ndarray
    bow_indptr: np.ndarray
    bow_words: np.ndarray
    bow_weights: np.ndarray
    vocabulary: FlatVocabulary | VocabularyTree
    meta: dict = field(default_factory=dict)
    vocabulary_bytes: bytes | None = None

    @property
    def n_keyframes(self) -> int:
        return int(len(self.keyframe_ids))

    @property
    def n_landmarks(self) -> int:
        return int(len(self.landmark_ids))

    @property
    def n_observations(self) -> int:
        return int(len(self.obs_keyframe))

    def counts(self) -> dict:
        return {
            "keyframes": self.n_keyframes,
            "landmarks": self.n_landmarks,
            "observations": self.n_observations,
            "bow_entries": int(len(self.bow_words)),
            "patch_px": int(self.landmark_patch.shape[1]) if self.landmark_patch.ndim == 3 else 0,
        }

    def bow(self, k: int) -> BowVector:
        """Keyframe ``k``'s bag-of-words vector."""
        a, b = int(self.bow_indptr[k]), int(self.bow_indptr[k + 1])
        return BowVector(self.bow_words[a:b], self.bow_weights[a:b])

    def keyframe_observations(self, k: int) -> np.ndarray:
        """Indices of the observations made in keyframe ``k``."""
        return self._obs_by_keyframe()[k]

    def _obs_by_keyframe(self) -> list[np.ndarray]:
        cache = getattr(self, "_obs_cache", None)
        if cache is None:
            order = np.argsort(self.obs_keyframe, kind="stable")
            bounds = np.searchsorted(self.obs_keyframe[order], np.arange(self.n_keyframes + 1))
            cache = [order[bounds[k] : bounds[k + 1]] for k in range(self.n_keyframes)]
            self._obs_cache = cache
        return cache

    def check(self, where) -> None:
        """InputError naming ``where`` when arrays disagree in shape, dtype or index range."""
        n = {
            "keyframes": self.n_keyframes,
            "landmarks": self.n_landmarks,
            "observations": self.n_observations,
        }
        for name, (tail, dtype) in ARRAYS.items():
            a = getattr(self, name)
            rows = n.get(COUNTS.get(name.split("_")[0], ""), None)
            if name == "bow_indptr":
                rows = self.n_keyframes + 1
            if name in ("bow_words", "bow_weights"):
                rows = len(self.bow_words)
            if a.dtype != np.dtype(dtype) or a.shape[1:] != tail or (rows is not None and len(a) != rows):
                raise InputError(
                    f"map array {name} has shape {a.shape} and dtype {a.dtype}, "
                    f"expected ({rows}, {', '.join(map(str, tail))}) {dtype}",
                    where,
                )
        p = self.landmark_patch
        if p.ndim != 3 or len(p) != self.n_landmarks or p.shape[1] != p.shape[2]:
            raise InputError(f"map array landmark_patch has shape {p.shape}", where)
        if self.n_observations and (
            self.obs_keyframe.min() < 0
            or self.obs_keyframe.max() >= self.n_keyframes
            or self.obs_landmark.min() < 0
            or self.obs_landmark.max() >= self.n_landmarks
        ):
            raise InputError("map observations index keyframes or landmarks that do not exist", where)
        ip = self.bow_indptr
        if len(ip) and (ip[0] != 0 or ip[-1] != len(self.bow_words) or np.any(np.diff(ip) < 0)):
            raise InputError("map bag-of-words rows (bow_indptr) are inconsistent", where)
        w = self.bow_words
        if len(w) and (w.min() < 0 or w.max() >= self.vocabulary.n_words_):
            raise InputError(
                f"map bag-of-words word ids outside the vocabulary's {self.vocabulary.n_words_} words", where
            )
        for name in ("keyframe_wTc", "landmark_w", "obs_uv", "bow_weights", "keyframe_cov", "landmark_cov"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise InputError(f"map array {name} holds non-finite values", where)
        # landmarks are looked up by id (a joined map renumbers them; keyframe ids are
        # per session and may repeat): a repeated id kept one of its landmarks unsaid
        if len(np.unique(self.landmark_ids)) != self.n_landmarks:
            raise InputError("map array landmark_ids repeats an id", where)
        self._check_geometry(where)
        self._check_bow_rows(where)

    def _check_geometry(self, where) -> None:
        """InputError unless keyframe poses are rigid, positions within
        ``TRANSLATION_MAX_M`` and covariances symmetric with no negative variance
        (thirteenth hostile pass: rotations scaled by 2, a bottom row [1 2 3 0] and
        positions times 1e160 loaded, and a joined map carried them on)."""
        from graphslam.evaluation.matching import RIGID_TOL
        from graphslam.sources.posegraph_files import TRANSLATION_MAX_M
        from slamcore.spatial.geometry import non_rigid_rows

        T = self.keyframe_wTc
        bad = np.flatnonzero(non_rigid_rows(T, RIGID_TOL))
        if bad.size:
            raise InputError(f"map keyframe {int(self.keyframe_ids[bad[0]])} is not a rigid pose", where)
        for name, xyz in (("keyframe", T[:, :3, 3]), ("landmark", self.landmark_w)):
            far = np.flatnonzero(np.any(np.abs(xyz) > TRANSLATION_MAX_M, axis=1))
            if far.size:
                raise InputError(f"map {name} {int(far[0])} lies beyond {TRANSLATION_MAX_M:.0e} m", where)
        for name in ("keyframe_cov", "landmark_cov"):
            C = getattr(self, name)
            diag = np.diagonal(C, axis1=1, axis2=2)
            if np.any(diag < 0.0) or np.any(np.abs(C - np.swapaxes(C, 1, 2)) > 1e-9 * (1.0 + np.abs(C))):
                raise InputError(
                    f"map array {name} holds a covariance that is not symmetric or has a negative variance",
                    where,
                )
            # a correlation beyond 1 (hostile pass 24: localize.csv then carried covariances
            # with negative eigenvalues): negative beyond round-off of the largest
            w = np.linalg.eigvalsh(0.5 * (C + np.swapaxes(C, 1, 2))) if len(C) else np.zeros((0, 1))
            bad = np.flatnonzero(w[:, 0] < -COV_EIGEN_TOL * np.maximum(np.abs(w[:, -1]), 1e-300))
            if bad.size:
                raise InputError(
                    f"map array {name} holds a covariance that is not positive semi-definite (row "
                    f"{int(bad[0])}, smallest eigenvalue {w[bad[0], 0]:.3g}): a correlation beyond 1",
                    where,
                )

    def _check_bow_rows(self, where) -> None:
        """InputError unless every keyframe's row is a :class:`BowVector` (word ids
        increasing, weights > 0 summing to 1): :meth:`bow` raised ValueError."""
        w, wts, ip = self.bow_words, self.bow_weights, self.bow_indptr
        if not len(w):
            return
        starts = ip[:-1][np.diff(ip) > 0]
        inside = np.ones(len(w) - 1, dtype=bool)  # consecutive entries of one row
        inside[starts[1:] - 1] = False
        sums = np.add.reduceat(wts, starts)  # empty rows hold nothing: each segment is a row
        if np.any(wts <= 0) or np.any(np.abs(sums - 1.0) > L1_NORM_TOL) or np.any(np.diff(w)[inside] <= 0):
            raise InputError(
                "map bag-of-words rows are not normalised vectors (word ids "
                "increasing, weights > 0 summing to 1)",
                where,
            )


def bow_csr(vectors: list[BowVector]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(indptr (K+1,), words (nnz,), weights (nnz,))`` of a list of BoW vectors."""
    lengths = np.array([len(v) for v in vectors], dtype=np.int64)
    indptr = np.r_[0, np.cumsum(lengths)].astype(np.int64)
    words = np.concatenate([v.word_ids for v in vectors]) if vectors else np.zeros(0, np.int64)
    weights = np.concatenate([v.weights for v in vectors]) if vectors else np.zeros(0)
    return indptr, words.astype(np.int64), weights.astype(np.float64)
