"""Landmark maps shared between FastSLAM particles, copy-on-write (numpy only).

Every particle owns one 2-D EKF (mean (2,), covariance (2, 2)) per landmark it
knows. After resampling most particles are copies of a few parents, so storing
``(N, L, 2)`` means per particle and copying them on every resampling would cost
O(N L) floats per step. Instead:

- a **pool** of landmark-EKF records, ``pool_mean (P, 2)`` and ``pool_cov (P, 2, 2)``,
  is append-only: a record is never modified once written;
- each particle holds a row of an **index table** ``table (N, L)`` of int32
  pointers into the pool (``-1``: the particle does not know that landmark).
  Column ``c`` is one landmark slot, whose external id is ``ids[c]``.

Costs:

- resampling copies only the table rows: N x L int32 (N=1000, L=150: 600 kB),
  no landmark record is copied;
- an update of one landmark for ``n`` particles appends ``n`` records and
  repoints ``n`` table cells (copy-on-write: particles that shared the old
  record keep it unchanged), O(n);
- records nobody points to any more are reclaimed by mark-and-compact when the
  pool is full: live records are found with ``np.unique`` over the table,
  O(N L log(N L)), and moved to the front; the pool doubles only if it is still
  more than half full afterwards, so compaction is amortised O(1) per write and
  memory stays within ~4x the live records.
- columns no particle points to any more (landmarks only dead particles had)
  can be dropped with :meth:`ParticleMaps.drop_empty_columns`.

Beside each record the pool keeps the time of the latest sighting the record took in
and the sensor that made it (``pool_seen``, ``pool_sensor``): a sighting correlated in
time with that one carries less new information, and FastSLAM weighs it so
(:func:`filters.fastslam_update.weight_shares`). They travel with the record through
resampling and compaction, as its mean does.

Beside each pointer the table keeps a float: the landmark's missed-sighting score in
that particle (:mod:`filters.landmark_existence`, ``[fastslam] prune_missed_alpha``),
resampled and dropped with it; :meth:`ParticleMaps.forget` removes a landmark from some
particles.
"""

from __future__ import annotations

import numpy as np

#: The pool's per-record arrays: ``(name, trailing shape, dtype, fill, reset on allocate)``.
#: ``pool_mean`` (2,) and ``pool_cov`` (2, 2): the landmark EKF, written by the caller;
#: ``pool_seen``: time of the latest sighting the record took in, s (-inf: none with a
#: time), and ``pool_sensor``: the sensor that made it (-1: none stated), for sightings
#: correlated in time; ``pool_misread_since``: time of the first of the sightings in a row
#: that the record's particles all took as misread ids, s (NaN: its latest sighting was
#: taken in; :meth:`filters.fastslam_particles.ParticleSet._restart_misread_records`).
_POOL: tuple[tuple[str, tuple[int, ...], type, float, bool], ...] = (
    ("pool_mean", (2,), np.float64, 0.0, False),
    ("pool_cov", (2, 2), np.float64, 0.0, False),
    ("pool_seen", (), np.float64, -np.inf, True),
    ("pool_sensor", (), np.int32, -1, True),
    ("pool_misread_since", (), np.float64, np.nan, True),
)


class ParticleMaps:
    """Per-particle landmark EKFs in a shared append-only pool.

    Args:
        n_particles: N.
        pool_capacity: initial number of pool records (grows by doubling).
        column_capacity: initial number of landmark columns (grows by doubling).
    """

    # the per-record arrays of _POOL, made in __init__ and grown by _reserve
    pool_mean: np.ndarray
    pool_cov: np.ndarray
    pool_seen: np.ndarray
    pool_sensor: np.ndarray
    pool_misread_since: np.ndarray

    def __init__(self, n_particles: int, pool_capacity: int = 1024, column_capacity: int = 16):
        self.n_particles = int(n_particles)
        for name, shape, dtype, fill, _ in _POOL:
            setattr(self, name, np.full((max(pool_capacity, 1), *shape), fill, dtype=dtype))
        self.pool_size = 0
        self._table = np.full((self.n_particles, max(column_capacity, 1)), -1, dtype=np.int32)
        self._score = np.zeros(self._table.shape)
        self.n_cols = 0
        self._ids: list[int] = []
        self._col_of: dict[int, int] = {}
        self.compactions = 0

    # ----------------------------------------------------------------- columns
    @property
    def table(self) -> np.ndarray:
        """(N, L) int32 pointers into the pool (a view; -1 = unknown landmark)."""
        return self._table[:, : self.n_cols]

    @property
    def score(self) -> np.ndarray:
        """(N, L) missed-sighting score of each particle's landmark (a view; module docstring)."""
        return self._score[:, : self.n_cols]

    @property
    def ids(self) -> np.ndarray:
        """(L,) external landmark id of each column."""
        return np.array(self._ids, dtype=np.int64)

    def column(self, landmark_id: int) -> int | None:
        """Column of ``landmark_id``, or None."""
        return self._col_of.get(landmark_id)

    def add_column(self, landmark_id: int) -> int:
        """Column for ``landmark_id`` (created empty if new)."""
        c = self._col_of.get(landmark_id)
        if c is not None:
            return c
        if self.n_cols == self._table.shape[1]:
            grown = np.full((self.n_particles, 2 * self._table.shape[1]), -1, dtype=np.int32)
            grown[:, : self.n_cols] = self._table[:, : self.n_cols]
            self._table = grown
            score = np.zeros(grown.shape)
            score[:, : self.n_cols] = self._score[:, : self.n_cols]
            self._score = score
        c = self.n_cols
        self.n_cols += 1
        self._ids.append(int(landmark_id))
        self._col_of[int(landmark_id)] = c
        return c

    def drop_empty_columns(self) -> int:
        """Remove columns no particle points to; returns how many were dropped."""
        keep = np.flatnonzero((self.table >= 0).any(axis=0))
        dropped = self.n_cols - keep.size
        if dropped:
            kept = self._table[:, keep]
            self._table[:, : keep.size] = kept
            self._table[:, keep.size :] = -1
            kept_score = self._score[:, keep]
            self._score[:, : keep.size] = kept_score
            self._score[:, keep.size :] = 0.0
            self._ids = [self._ids[c] for c in keep]
            self._col_of = {lid: c for c, lid in enumerate(self._ids)}
            self.n_cols = keep.size
        return dropped

    # ---------------------------------------------------------------- records
    def pointers(self, particles: np.ndarray, col: int) -> np.ndarray:
        """(n,) pool indices of landmark ``col`` for ``particles`` (-1 = unknown)."""
        return self._table[particles, col]

    def get(self, particles: np.ndarray, col: int) -> tuple[np.ndarray, np.ndarray]:
        """Means (n, 2) and covariances (n, 2, 2) of landmark ``col`` (must be known)."""
        p = self._table[particles, col]
        if np.any(p < 0):
            raise KeyError(f"landmark column {col} unknown to some particles")
        return self.pool_mean[p], self.pool_cov[p]

    def write(self, particles: np.ndarray, col, mean: np.ndarray, cov: np.ndarray) -> None:
        """Give ``particles`` new records for landmark ``col`` (copy-on-write)."""
        if np.size(particles) == 0:
            return
        sl = self.allocate(np.asarray(particles), col)
        self.pool_mean[sl] = mean
        self.pool_cov[sl] = cov

    def allocate(self, particles: np.ndarray, cols) -> slice:
        """Point ``table[particles, cols]`` (broadcast together, C order) at fresh records
        and return their pool slice, for the caller to fill (copy-on-write: read the old
        records first, compaction may move them)."""
        shape = np.broadcast_shapes(np.shape(particles), np.shape(cols))
        n = int(np.prod(shape))
        self._reserve(n)
        start = self.pool_size
        self._table[particles, cols] = np.arange(start, start + n, dtype=np.int32).reshape(shape)
        self.pool_size = start + n
        for name, _, _, fill, reset in _POOL:
            if reset:  # the caller fills the mean and covariance
                getattr(self, name)[start : start + n] = fill
        return slice(start, start + n)

    def resample(self, parents: np.ndarray) -> None:
        """Particle ``i`` becomes a copy of ``parents[i]``: copies table rows only."""
        self._table[:, : self.n_cols] = self._table[parents, : self.n_cols]
        self._score[:, : self.n_cols] = self._score[parents, : self.n_cols]

    def forget(self, mask: np.ndarray) -> None:
        """The particles lose the landmarks where ``mask`` (N, L) is True (their records stay
        in the pool for the particles that share them; compaction reclaims the rest)."""
        t = self._table[:, : self.n_cols]
        t[mask] = -1
        self._score[:, : self.n_cols][mask] = 0.0

    def landmarks_of(self, particle: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ids (M,), means (M, 2), covs (M, 2, 2))`` known to one particle."""
        row = self._table[particle, : self.n_cols]
        cols = np.flatnonzero(row >= 0)
        p = row[cols]
        return self.ids[cols], self.pool_mean[p].copy(), self.pool_cov[p].copy()

    def live_count(self) -> int:
        """Distinct pool records referenced by some particle."""
        t = self.table
        return int(np.unique(t[t >= 0]).size)

    # -------------------------------------------------------------- internals
    def _reserve(self, n: int) -> None:
        cap = self.pool_mean.shape[0]
        if self.pool_size + n <= cap:
            return
        self.compact()
        live = self.pool_size
        cap_needed = live + n
        if cap_needed > cap or live > cap // 2:
            new_cap = cap
            while new_cap < cap_needed or live > new_cap // 2:
                new_cap *= 2
            for name, shape, dtype, fill, _ in _POOL:
                grown = np.full((new_cap, *shape), fill, dtype=dtype)
                grown[:live] = getattr(self, name)[:live]
                setattr(self, name, grown)

    def compact(self) -> None:
        """Mark-and-compact: keep only referenced records, at the front, in order."""
        t = self._table[:, : self.n_cols]
        valid = t >= 0
        live, inverse = np.unique(t[valid], return_inverse=True)
        for name, *_ in _POOL:
            column = getattr(self, name)
            column[: live.size] = column[live]
        t[valid] = inverse.astype(np.int32)
        self.pool_size = int(live.size)
        self.compactions += 1
