"""The mapped landmarks of the visual iSAM2 back end, one slot each.

A part of :class:`graphslam.backends.spatial.isam2.VisualIsam2Backend` that owns its
state: the slot of each mapped track id and, indexed by slot, numpy caches of what
each landmark needs per frame without asking iSAM2 (the last position read, when it
was read, how often it was seen, its latest pixel sigma, the index of its latest
frame). It is its own part because these arrays must stay consistent with each
other and with the slot index as landmarks come (grown by doubling) and go (the
later slots shift down); :meth:`LandmarkSlots.add` and :meth:`LandmarkSlots.drop`
are the only places that change their shape.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LandmarkSlots"]


class LandmarkSlots:
    """Slot per mapped track id and the per-slot caches; the first ``n`` rows are live.

    Attributes:
        slot: track id -> slot (row of the arrays).
        ids: track id of each slot, in slot order.
        pos: (capacity, 3) last position read (pre-selection of those in view only).
        read: the back end's estimate epoch of that read (-1: not read yet).
        nobs: pixels seen.
        sigma: latest pixel standard deviation seen.
        last: index in the back end's frame list of the latest pixel.
        n: landmarks mapped (live slots).
    """

    def __init__(self) -> None:
        self.slot: dict[int, int] = {}
        self.ids: list[int] = []
        self.pos = np.zeros((0, 3))
        self.read = np.zeros(0, dtype=np.int64)
        self.nobs = np.zeros(0, dtype=np.int64)
        self.sigma = np.zeros(0)
        self.last = np.zeros(0, dtype=np.int64)
        self.n = 0

    def __len__(self) -> int:
        return self.n

    def __contains__(self, tid: object) -> bool:
        return tid in self.slot

    def add(self, tid: int, point: np.ndarray, nobs: int, sigma: float, last: int) -> None:
        """Map track ``tid`` at ``point`` in the next slot, its position not yet read
        from iSAM2 (a pending initial value: read again once iSAM2 has it)."""
        if self.n == len(self.pos):  # grow by doubling: amortised O(1)
            cap = max(64, 2 * self.n)
            self.pos = np.resize(self.pos, (cap, 3))
            self.nobs = np.resize(self.nobs, cap)
            self.sigma = np.resize(self.sigma, cap)
            self.last = np.resize(self.last, cap)
            self.read = np.resize(self.read, cap)
        s = self.n
        self.slot[tid] = s
        self.ids.append(tid)
        self.pos[s], self.nobs[s], self.sigma[s] = point, nobs, sigma
        self.last[s] = last
        self.read[s] = -1
        self.n += 1

    def drop(self, tid: int) -> None:
        """Forget landmark ``tid``: its slot is removed and the later ones shift down."""
        s, n = self.slot.pop(tid), self.n
        for arr in (self.pos, self.nobs, self.sigma, self.last, self.read):
            arr[s : n - 1] = arr[s + 1 : n].copy()
        del self.ids[s]
        for t in self.ids[s:]:
            self.slot[t] -= 1
        self.n -= 1
