"""Landmark bookkeeping of :class:`filters.mono_ekf.MonoEkf`: which landmarks to add,
convert to Euclidean or drop, and the state changes that do it.

A mixin (its own module to keep the filter's under the project's size): it
reads and writes the filter's state ``_x``, ``_P``, its landmark list
``_lms`` and their offsets, and calls the pure functions of
:mod:`filters.mono_ekf_map`. The rules are the filter's module docstring's
steps 3 and 4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from filters import landmark_params as lp
from filters.mono_ekf_map import (augment_with_landmarks, euclidean_points, farthest_candidates,
                                  inverse_distances, linear_enough, transform_state)

__all__ = ["LandmarkRecord", "MapBookkeeping"]


@dataclass
class LandmarkRecord:
    """Bookkeeping of one landmark in the state (the parameters live in ``X``)."""

    track_id: int
    kind: int
    unseen: int = 0  # consecutive frames out of view
    misses: int = 0  # consecutive frames in view but not found or rejected


class MapBookkeeping:
    """Map management methods of :class:`filters.mono_ekf.MonoEkf`."""

    def _manage_map(self, visible, observed, accepted, rejected) -> dict:
        """Update the landmarks' counters; returns ``{slot: None}`` of those to drop."""
        c = self.config
        drop = {}
        for i, lm in enumerate(self._lms):
            if not visible[i] and not observed[i]:
                lm.unseen += 1
            else:
                lm.unseen = 0
            if accepted[i]:
                lm.misses = 0
            elif rejected[i] or (visible[i] and not observed[i]):
                lm.misses += 1
            if lm.misses >= c.max_consecutive_misses:
                self._banned.add(lm.track_id)
                self._retired.pop(lm.track_id, None)
                self._stats["deleted"] += 1
                drop[i] = None
            elif lm.unseen >= c.forget_unseen_frames:
                self._stats["forgotten"] += 1
                drop[i] = None
                if lm.kind == lp.EUCLIDEAN:  # converged: keep it in the output map
                    o = self._off[i]
                    self._retired[lm.track_id] = self._x[o:o + 3].copy()
        return drop

    def _reparametrise(self, exclude=()) -> dict:
        """``{slot: (p_w (3,), J (3, s))}`` of the landmarks linear enough to become Euclidean."""
        conv = linear_enough(self._x, self._P, self._idx, self._kinds,
                             self.config.linearity_threshold, exclude)
        self._stats["reparametrised"] += len(conv)
        return conv

    def _transform(self, changes: dict) -> None:
        """Drop (value None) or convert to Euclidean (value ``(p_w, J)``) the landmark slots
        in ``changes`` (:func:`filters.mono_ekf_map.transform_state`); converted
        landmarks move to the end of the state."""
        self._x, self._P = transform_state(self._x, self._P, self._off, self._kinds, changes)
        moved = [LandmarkRecord(self._lms[i].track_id, lp.EUCLIDEAN, self._lms[i].unseen,
                           self._lms[i].misses) for i, ch in changes.items() if ch is not None]
        self._lms = [lm for i, lm in enumerate(self._lms) if i not in changes] + moved
        self._reindex()
        self._version += 1

    def _initialise(self, ids: np.ndarray, uv_px: np.ndarray, known: np.ndarray,
                    var: float) -> np.ndarray:
        """New landmarks from unknown tracks (undelayed); returns their track ids."""
        c = self.config
        none = np.zeros(0, dtype=np.int64)
        room = min(c.max_init_per_frame, c.max_landmarks - len(self._lms))
        if room <= 0:
            return none
        W, H = self._image_size
        cand = [r for r in np.flatnonzero(~known) if int(ids[r]) not in self._banned
                and -0.5 <= uv_px[r, 0] < W - 0.5 and -0.5 <= uv_px[r, 1] < H - 0.5]
        if not cand:
            return none
        # greedy farthest-point choice: spread new points away from mapped ones
        picked = farthest_candidates(uv_px[cand], uv_px[known], min(room, len(cand)))
        rows = np.array([cand[j] for j in picked], dtype=np.int64)
        kind = self._kind0
        rho0, sigma_rho = self._depth_prior()
        L, G_pose, G_uv, G_rho = lp.init_landmarks(kind, self._K_inv, self._x[0:3], self._x[3:7],
                                                   uv_px[rows], rho0)
        self._x, self._P = augment_with_landmarks(self._x, self._P, L, G_pose, G_uv, G_rho, var,
                                                  sigma_rho)
        self._lms.extend(LandmarkRecord(int(ids[r]), kind) for r in rows)
        self._reindex()
        self._version += 1
        self._stats["initialised"] += len(rows)
        return ids[rows].astype(np.int64)

    def _depth_prior(self) -> tuple[float, float]:
        """``(rho0, sigma_rho)`` (1/m) of this frame's new landmarks (``depth_prior``)."""
        c = self.config
        if c.depth_prior == "fixed" or not self._lms:
            return c.rho0, c.sigma_rho
        uv, hz, _, _ = self._observe(np.arange(len(self._lms)), jacobians=False)
        vis = self._in_view(uv, hz)
        inv = inverse_distances(self._x, self._idx[vis], self._kinds[vis])
        rho0 = float(np.median(inv)) if len(inv) else 0.0
        if not rho0 > 0:  # nothing in view, or only points at infinity: no map unit here
            return c.rho0, c.sigma_rho
        return rho0, 0.5 * max(rho0, float(inv.max()) - rho0)

    def _euclidean_landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """Track ids and Euclidean points (m) of the state's landmarks with ``rho > 0``."""
        if not self._lms:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        p_w, ok = euclidean_points(self._x, self._idx, self._kinds)
        ids = np.array([lm.track_id for lm in self._lms], dtype=np.int64)
        return ids[ok], p_w[ok]
