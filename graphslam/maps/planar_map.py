"""A 2-D landmark map that outlives the run: landmark ids, positions and 2x2 covariances.

:class:`PlanarMap` is what ``graphslam run --save-map`` writes after a 2-D run
(synthetic world, Victoria Park) and ``graphslam run --map`` localises against
(:mod:`graphslam.maps.files` writes and reads it, ``kind = "planar"``).
Conventions of :mod:`slamcore.planar.records`: positions ``[x_m, y_m]`` in the
world frame of the run that built the map, covariances in m^2. Only each
landmark's own 2x2 marginal is kept (the cross-covariances between landmarks
are not saved: O(L^2), and a localising filter treats the map's landmarks as
independent).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from graphslam.sources.posegraph_files import TRANSLATION_MAX_M
from graphslam.sources.tokens import MAX_ID
from slamcore.errors import InputError
from slamcore.planar.records import Estimate

#: Arrays of a 2-D map and their trailing shapes and dtypes (the first axis is L).
ARRAYS: dict[str, tuple[tuple[int, ...], str]] = {
    "landmark_ids": ((), "int64"),
    "landmark_xy": ((2,), "float64"),
    "landmark_cov": ((2, 2), "float64"),
}
#: Largest asymmetry a saved 2x2 covariance may have, relative to its largest entry.
COV_SYMMETRY_RTOL = 1e-9
#: Largest landmark variance read, m^2: a standard deviation of the largest
#: position read (TRANSLATION_MAX_M); beyond it the landmark is no information,
#: and its inverse (the filter's information) underflows.
VARIANCE_MAX_M2 = TRANSLATION_MAX_M**2


@dataclass(eq=False)
class PlanarMap:
    """A saved 2-D landmark map (module docstring); L landmarks.

    Attributes:
        landmark_ids: (L,) int64 ids, as the dataset names its landmarks.
        landmark_xy: (L, 2) positions, metres.
        landmark_cov: (L, 2, 2) marginal covariances, m^2 (symmetric positive definite).
        meta: JSON-ready description (dataset, steps, back end, configuration).
    """

    landmark_ids: np.ndarray
    landmark_xy: np.ndarray
    landmark_cov: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def n_landmarks(self) -> int:
        return int(len(self.landmark_ids))

    def counts(self) -> dict:
        return {"landmarks": self.n_landmarks}

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in ARRAYS}

    def check(self, where) -> None:
        """InputError naming ``where`` on a wrong shape or dtype, a repeated id, a
        non-finite value or a covariance that is not symmetric positive definite."""
        n = self.n_landmarks
        for name, (tail, dtype) in ARRAYS.items():
            a = getattr(self, name)
            if a.dtype != np.dtype(dtype) or a.shape != (n, *tail):
                raise InputError(
                    f"map array {name} has shape {a.shape} and dtype {a.dtype}, "
                    f"expected ({n}, {', '.join(map(str, tail))}) {dtype}",
                    where,
                )
        if len(np.unique(self.landmark_ids)) != n:
            raise InputError("map landmark ids are not distinct", where)
        if not (np.all(np.isfinite(self.landmark_xy)) and np.all(np.isfinite(self.landmark_cov))):
            raise InputError("map landmarks hold non-finite values", where)
        self._check_ranges(where)
        C = self.landmark_cov
        scale = np.maximum(np.abs(C).max(axis=(1, 2), initial=0.0), 1e-300)
        asym = np.abs(C[:, 0, 1] - C[:, 1, 0]) / scale if n else np.zeros(0)
        det = C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] * C[:, 1, 0]
        bad = np.flatnonzero((asym > COV_SYMMETRY_RTOL) | (C[:, 0, 0] <= 0) | (det <= 0))
        if bad.size:
            raise InputError(
                f"map covariance of landmark {int(self.landmark_ids[bad[0]])} is not "
                "symmetric positive definite",
                where,
            )

    def _check_ranges(self, where) -> None:
        """Ids and values the readers of pose graphs would accept: a landmark id
        from 0 to below 2**62 (gtsam keys; the filters' id arithmetic), positions
        within TRANSLATION_MAX_M, variances within VARIANCE_MAX_M2. Beyond them
        a map loaded fine and then overflowed the filter's algebra."""
        ids = self.landmark_ids
        bad = np.flatnonzero((ids < 0) | (ids >= MAX_ID))
        if bad.size:
            raise InputError(f"map landmark id {int(ids[bad[0]])} is outside 0 to 2**62 - 1", where)
        far = np.flatnonzero(np.any(np.abs(self.landmark_xy) > TRANSLATION_MAX_M, axis=1))
        if far.size:
            raise InputError(f"map landmark {int(ids[far[0]])} lies beyond {TRANSLATION_MAX_M:.0e} m", where)
        wide = np.flatnonzero(np.any(np.abs(self.landmark_cov) > VARIANCE_MAX_M2, axis=(1, 2)))
        if wide.size:
            raise InputError(
                f"map covariance of landmark {int(ids[wide[0]])} exceeds {VARIANCE_MAX_M2:.0e} m^2", where
            )


def map_from_estimate(estimate: Estimate, meta: dict) -> PlanarMap:
    """The map of a finished run's estimate (landmark covariances required), sorted by id."""
    if estimate.landmark_covariances is None:
        raise InputError("the run has no landmark covariances to save", "--save-map")
    order = np.argsort(estimate.landmark_ids, kind="stable")
    cov = np.asarray(estimate.landmark_covariances, dtype=np.float64)[order]
    return PlanarMap(
        np.asarray(estimate.landmark_ids, dtype=np.int64)[order].copy(),
        np.asarray(estimate.landmarks_w, dtype=np.float64)[order].copy(),
        0.5 * (cov + np.swapaxes(cov, 1, 2)),
        meta,
    )
