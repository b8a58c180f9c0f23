"""The state of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`) and its landmark slots.

:class:`SlotStore` owns the numbers that the filter's steps share: the state
``x = [x, y, theta, m1x, m1y, ...]`` and its covariance ``P`` in preallocated
buffers, the landmark slots (id of each slot, slot of each id), the
linearisation points of the observability-constrained Jacobian (the robot pose
predicted for this step and each landmark's first estimate), the BLAS downdate
bound to ``P``'s buffer and an upper bound on ``P``'s largest variance. It is a
part of its own because the filter (prediction, new landmarks, association)
and the correction of :mod:`filters.ekf_slam_correction` both read and write
it: each takes the store as an explicit argument instead of reaching into the
other's attributes, and the buffers, the slots and what is bound to the
buffers change together, only here.

Buffers: sized for ``cap`` landmarks and padded to
:func:`filters.ekf_slam_update.padded` (the downdate's padding); when a
landmark does not fit, :meth:`SlotStore.open_slot` doubles the capacity and
copies the used ``n x n`` block once (amortised O(1) copies per landmark). The
working ``x`` and ``P`` are the views ``xbuf[:n]`` and ``Pbuf[:n, :n]``;
entries beyond ``n`` are zero.

Several robots (``--robot all``): the state holds one pose per robot, the
latest of each. The robot that moves now is *active*, its pose at ``x[:3]``
where every step of the filter reads it; the others are *parked* after the
landmarks, ``x = [active, m1, ..., mM, parked_1, ..., parked_R]``
(:meth:`SlotStore.park_and_start`, :meth:`SlotStore.activate`). A parked pose
is a state entry like any other: every correction moves it through its
correlations, and nothing else touches it. The landmarks keep indices
``3 + 2 k`` (every step's indexing); a new landmark moves the parked poses
down by two entries.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from filters.ekf_slam_update import Rank2Downdate, padded
from slamcore.planar.geometry import wrap_angle


class SlotStore:
    """State vector, covariance and landmark slots of the EKF-SLAM (see the module docstring).

    Attributes:
        cap: landmarks the buffers hold before the next doubling.
        xbuf: (dim,) state buffer; ``xbuf[:n]`` is the state.
        Pbuf: (dim, dim) C-ordered covariance buffer; ``Pbuf[:n, :n]`` is ``P``.
        downdate: the in-place rank-2 downdate bound to ``Pbuf``
            (:class:`filters.ekf_slam_update.Rank2Downdate`).
        diag: view of ``Pbuf``'s diagonal (zero beyond ``n``).
        pmax_ub: upper bound of ``P``'s largest variance; whoever raises a
            variance raises it (:meth:`note_variances`), a downdate only lowers
            variances (the correction's noise floor relies on it).
        n: used state size, 3 + 2 M; 0 before the first pose.
        ids: landmark id of each slot; slot: slot of each landmark id.
        m_first: first estimate (2,) of each slot's landmark (OC).
        x_pred: robot pose predicted for this step (OC).
        parked_ids: pose id of each parked pose, in state order (several robots).
        parked_pred: ``x_pred`` of each parked pose, restored when it is activated.
    """

    def __init__(self, capacity: int):
        self.cap = int(capacity)
        self._pose_cap = 0  # parked poses the buffers hold
        dim = padded(3 + 2 * self.cap)  # the downdate's padding fits (filters.ekf_slam_update)
        self.xbuf = np.zeros(dim)
        self.Pbuf = np.zeros((dim, dim))
        self._bind()
        self.pmax_ub = math.inf
        self.n = 0
        self.ids: list[int] = []
        self.slot: dict[int, int] = {}
        self.m_first: list[np.ndarray] = []
        self.x_pred = np.zeros(3)
        self.parked_ids: list[int] = []
        self.parked_pred: list[np.ndarray] = []

    def _bind(self) -> None:
        """The BLAS downdate and the diagonal view bound to the current ``Pbuf``."""
        self.downdate = Rank2Downdate(self.Pbuf)
        self.diag = self.Pbuf.reshape(-1)[:: self.Pbuf.shape[0] + 1]

    @property
    def x(self) -> np.ndarray:
        """The state, a view (n,)."""
        return self.xbuf[: self.n]

    @property
    def P(self) -> np.ndarray:
        """The covariance, a view (n, n)."""
        return self.Pbuf[: self.n, : self.n]

    def start(self, wTb: np.ndarray, cov: np.ndarray) -> None:
        """Hold only the robot pose ``wTb`` (3,) with covariance ``cov`` (empty store)."""
        self.n = 3
        self.xbuf[:3] = wTb
        self.xbuf[2] = wrap_angle(wTb[2])
        self.Pbuf[:3, :3] = cov
        self.x_pred = self.xbuf[:3].copy()

    def load(self, x: np.ndarray, P: np.ndarray, ids: Sequence[int]) -> None:
        """Hold the state ``x`` (3 + 2M,), ``P`` and landmark ids ``ids`` (empty store,
        capacity at least M); the loaded state is taken as both predicted pose and
        first estimates (OC)."""
        M = len(ids)
        self.n = x.size
        self.xbuf[: self.n] = x
        self.xbuf[2] = wrap_angle(x[2])
        self.Pbuf[: self.n, : self.n] = P
        self.x_pred = self.xbuf[:3].copy()
        self.m_first = [self.xbuf[3 + 2 * k : 5 + 2 * k].copy() for k in range(M)]
        self.ids = list(ids)
        self.slot = {lid: k for k, lid in enumerate(self.ids)}

    def open_slot(self, lid: int, m: np.ndarray) -> int:
        """Append landmark ``lid`` at position ``m`` (2,) as its first estimate; its slot.

        Doubles the capacity first when the buffers are full. The caller
        fills the new rows and columns of ``P`` (zero until then) and raises
        :attr:`pmax_ub` with their variances.
        """
        if len(self.ids) >= self.cap:
            self._grow(2 * self.cap, self._pose_cap)
        n = 3 + 2 * len(self.ids)
        if self.parked_ids:
            self._move_parked(n, n + 2)
        self.xbuf[n : n + 2] = m
        self.m_first.append(self.xbuf[n : n + 2].copy())
        slot = len(self.ids)
        self.ids.append(lid)
        self.slot[lid] = slot
        self.n += 2
        return slot

    def _move_parked(self, start: int, to: int) -> None:
        """Move the parked poses' entries (from ``start`` to ``n``) of ``x`` and ``P`` to
        begin at ``to`` instead; the entries between are left zero. O(n^2)."""
        n, shift = self.n, to - start
        idx = np.r_[0:start, to : n + shift]
        x = self.xbuf[:n].copy()
        P = self.Pbuf[:n, :n].copy()
        size = max(n, n + shift)
        self.xbuf[:size] = 0.0
        self.Pbuf[:size, :size] = 0.0
        self.xbuf[idx] = x
        self.Pbuf[np.ix_(idx, idx)] = P

    def parked_index(self, k: int) -> int:
        """State index of parked pose ``k``'s first entry."""
        return 3 + 2 * len(self.ids) + 3 * k

    def park_and_start(self, active_id: int, wTb: np.ndarray, cov: np.ndarray) -> None:
        """Park the active pose (id ``active_id``) after the others and make ``wTb`` (3,)
        the active pose, with covariance ``cov`` (3, 3) and no correlation with the
        rest of the state (a robot's start, known independently of it)."""
        if len(self.parked_ids) >= self._pose_cap:
            self._grow(self.cap, max(2, 2 * self._pose_cap))
        n, x, P = self.n, self.xbuf, self.Pbuf
        P[n : n + 3, :n] = P[:3, :n]
        P[:n, n : n + 3] = P[:n, :3]
        P[n : n + 3, n : n + 3] = P[:3, :3]
        x[n : n + 3] = x[:3]
        self.parked_ids.append(int(active_id))
        self.parked_pred.append(self.x_pred.copy())
        self.n = n + 3
        P[:3, : self.n] = 0.0
        P[: self.n, :3] = 0.0
        P[:3, :3] = cov
        x[:3] = wTb
        x[2] = wrap_angle(float(wTb[2]))
        self.x_pred = x[:3].copy()
        self.note_variances(*np.diagonal(cov).tolist())

    def activate(self, k: int, active_id: int) -> int:
        """Swap parked pose ``k`` with the active pose (id ``active_id``, parked in its
        place); returns the id of the pose now active. O(n^2)."""
        n, j = self.n, self.parked_index(k)
        perm = np.arange(n)
        perm[0:3], perm[j : j + 3] = np.arange(j, j + 3), np.arange(3)
        self.xbuf[:n] = self.xbuf[perm]
        self.Pbuf[:n, :n] = self.Pbuf[np.ix_(perm, perm)]
        now = self.parked_ids[k]
        self.parked_ids[k] = int(active_id)
        self.x_pred, self.parked_pred[k] = self.parked_pred[k], self.x_pred
        return now

    def remove_slots(self, slots: Sequence[int]) -> None:
        """Drop the landmarks of ``slots`` from the state: marginalise them out of the
        Gaussian, which is deleting their rows and columns of ``x`` and ``P``. The
        remaining landmarks keep their order and move down to fill the gaps; the
        freed entries of the buffers are zeroed. O(n^2)."""
        drop = set(slots)
        if not drop:
            return
        keep = [k for k in range(len(self.ids)) if k not in drop]
        parked = list(range(3 + 2 * len(self.ids), self.n))
        idx = np.array([0, 1, 2] + [3 + 2 * k + j for k in keep for j in (0, 1)] + parked)
        x = self.xbuf[idx]
        P = self.Pbuf[np.ix_(idx, idx)]
        n_old, self.n = self.n, idx.size
        self.xbuf[:n_old] = 0.0
        self.Pbuf[:n_old, :n_old] = 0.0
        self.xbuf[: self.n] = x
        self.Pbuf[: self.n, : self.n] = P
        self.ids = [self.ids[k] for k in keep]
        self.m_first = [self.m_first[k] for k in keep]
        self.slot = {lid: k for k, lid in enumerate(self.ids)}

    def _grow(self, cap: int, pose_cap: int) -> None:
        dim = padded(3 + 2 * cap + 3 * pose_cap)
        n = self.n
        xbuf = np.zeros(dim)
        xbuf[:n] = self.xbuf[:n]
        Pbuf = np.zeros((dim, dim))
        Pbuf[:n, :n] = self.Pbuf[:n, :n]
        self.xbuf, self.Pbuf, self.cap, self._pose_cap = xbuf, Pbuf, cap, pose_cap
        self._bind()

    def note_variances(self, *variances: float) -> None:
        """Raise :attr:`pmax_ub` to cover ``variances`` (variances just raised in ``P``)."""
        self.pmax_ub = max(self.pmax_ub, *variances)

    def landmark_marginals(self) -> np.ndarray:
        """(M, 2, 2) marginal covariance of each slot's landmark."""
        M = len(self.ids)
        i = 3 + 2 * np.arange(M)
        P = self.Pbuf
        out = np.empty((M, 2, 2))
        out[:, 0, 0] = P[i, i]
        out[:, 0, 1] = P[i, i + 1]
        out[:, 1, 0] = P[i + 1, i]
        out[:, 1, 1] = P[i + 1, i + 1]
        return out
