"""The paths of FastSLAM's particles (:class:`filters.fastslam.FastSlam`): each particle's
poses at every step, through the resamplings that copied it.

A FastSLAM particle is a sample of the whole path, and its landmark map is conditioned on
that path (Montemerlo et al., FastSLAM, AAAI 2002, Sec. 3): the trajectory that goes with
the map of the highest-weight particle is that particle's path, not the weighted mean of
each step's cloud. The mean is a filter's estimate: it is never revised, so where a loop
closes (the resampling keeps the particles whose paths fit the map again) the poses before
the closure keep their drift, and where the weights jump between modes the mean jumps with
them (the default synthetic world, known ids, ``graphslam run --backend fastslam2
--seed S`` for S = 0-4: ATE 0.36-0.65 m for the best particle's path against 0.93-1.46 m
for the means; FastSLAM 1.0 0.31-0.80 m against 0.58-1.94 m).

Storage: each history row keeps the (N, 3) particle poses it was last recorded with and
the resampling generation they belong to; each resampling keeps its parents (N,). A
particle's path is read backwards through the parents (its ancestor in every older
generation). Resampling makes the lineages coalesce: once every living particle descends
from one particle of a generation, the rows of that generation and older ones hold one
pose each for all living particles, and :meth:`ParticlePaths.compact` keeps only that
pose and drops the parents behind it. Memory is then N x 3 floats per row (and N indices
per resampling) since the last coalescence, not per row of the run. A filter that never
resamples never coalesces: past :data:`MAX_PATH_BYTES` the store gives up
(:attr:`ParticlePaths.given_up`) and the filter reports the weighted means instead, and
says so.
"""

from __future__ import annotations

import numpy as np

from slamcore.errors import GraphSlamError

__all__ = ["MAX_PATH_BYTES", "ParticlePaths"]

#: Most bytes the rows not yet coalesced and their parents may take (1 GiB: 100 particles
#: over 450 000 steps without a resampling, 10 000 particles over 4 500).
MAX_PATH_BYTES = 1 << 30
#: Rows recorded between two attempts to coalesce (amortises the walk through the parents).
_COMPACT_EVERY = 64


class ParticlePaths:
    """Per-row particle poses and the resampling ancestry (module docstring).

    Args:
        n_particles: N.
    """

    def __init__(self, n_particles: int):
        self.n_particles = int(n_particles)
        self.generation = 0  # resamplings so far
        # row -> (poses (N, 3) or one pose (3,) shared by every living particle, generation)
        self._rows: dict[int, tuple[np.ndarray, int]] = {}
        self._full: set[int] = set()  # rows still holding (N, 3)
        # parents of resampling g + 1 at index g - _base (older ones dropped by compact)
        self._parents: list[np.ndarray] = []
        self._base = 0
        self._bytes = 0  # the full rows' and the kept parents'
        self._since_compact = 0
        #: True once the rows not yet coalesced and their parents outgrew
        #: :data:`MAX_PATH_BYTES`: the store then holds nothing and :meth:`path` refuses.
        self.given_up = False

    def record(self, row: int, poses: np.ndarray) -> None:
        """History row ``row`` holds ``poses`` (N, 3) (copied), of the current generation."""
        if self.given_up:
            return
        if row in self._full:
            self._bytes -= self._rows[row][0].nbytes
        arr = np.array(poses, dtype=np.float64)
        self._rows[row] = (arr, self.generation)
        self._full.add(row)
        self._bytes += arr.nbytes
        self._since_compact += 1
        if self._since_compact >= _COMPACT_EVERY or self._bytes > MAX_PATH_BYTES:
            self.compact()

    def resampled(self, parents: np.ndarray) -> None:
        """A resampling made particle ``i`` a copy of ``parents[i]``."""
        if self.given_up:
            return
        kept = np.asarray(parents, dtype=np.intp).copy()
        self._parents.append(kept)
        self._bytes += kept.nbytes
        self.generation += 1

    def _ancestors(self, particle: int, newest: int) -> dict[int, int]:
        """Generation -> index of the ancestor of ``particle`` (an index of generation
        ``newest``), for ``newest`` and every older kept generation."""
        out = {newest: int(particle)}
        for g in range(newest, self._base, -1):
            out[g - 1] = int(self._parents[g - 1 - self._base][out[g]])
        return out

    def path(self, particle: int, n_rows: int) -> np.ndarray:
        """(n_rows, 3) the poses of ``particle``'s path at rows ``0 .. n_rows - 1``
        (:meth:`lineage`, which refuses once the store gave up)."""
        return np.array(self.lineage(particle, range(n_rows))).reshape(n_rows, 3)

    def lineage(self, particle: int, rows) -> list[np.ndarray]:
        """Each of ``rows`` as ``particle``'s ancestors recorded it: row ``r`` recorded
        (N, ...) gives that row's (...) entry of the ancestor (any trailing shape: poses
        (3,), or a scan's landmark ids (K,))."""
        if self.given_up:
            raise GraphSlamError("particle paths were given up (MAX_PATH_BYTES)")
        ancestor = self._ancestors(particle, self.generation)
        out = []
        for row in rows:
            kept, g = self._rows[row]
            full = row in self._full
            out.append(kept[ancestor[g]] if full else kept)
        return out

    @property
    def nbytes(self) -> int:
        """Bytes held by rows not yet coalesced and the parents kept for them."""
        return self._bytes

    def compact(self) -> None:
        """Coalesce: the rows of the newest generation whose living lineages all meet in
        one particle, and older rows, keep that particle's pose; the parents before that
        generation go. Gives up past :data:`MAX_PATH_BYTES`."""
        self._since_compact = 0
        idx = np.arange(self.n_particles, dtype=np.intp)  # the living lineages, walked back
        meet = None
        for g in range(self.generation, self._base - 1, -1):
            if np.all(idx == idx[0]):
                meet = g
                break
            if g > self._base:
                idx = self._parents[g - 1 - self._base][idx]
        if meet is not None:
            ancestor = self._ancestors(int(idx[0]), meet)
            for row in [r for r in self._full if self._rows[r][1] <= meet]:
                poses, g = self._rows[row]
                self._rows[row] = (poses[ancestor[g]].copy(), g)
                self._bytes -= poses.nbytes
                self._full.discard(row)
            for dropped in self._parents[: meet - self._base]:
                self._bytes -= dropped.nbytes
            self._parents = self._parents[meet - self._base :]
            self._base = meet
        if self._bytes > MAX_PATH_BYTES:
            self.given_up = True
            self._rows.clear()
            self._full.clear()
            self._parents.clear()
            self._bytes = 0
