"""The landmark-slot store of :class:`filters.mono_ekf.MonoEkf`: which track sits in which
slot of the state vector, and the landmarks' lifetime rules.

:class:`LandmarkSlots` owns everything about the landmarks except their numbers:
each slot's track id, parametrisation and counters (frames unseen, consecutive
misses), the per-slot offsets, kinds and padded state indices the filter's
algebra gathers with, the track id -> slot lookup, the track ids banned from
re-initialisation and the last estimates of forgotten Euclidean landmarks. The
filter owns the Gaussian (``x``, ``P``) and the camera; the store never keeps
them: the methods that change the state layout take ``(x, P)`` and return the
new pair, so the layout and the slots change in one call and cannot drift apart.
It is separate so that the slot layout has one owner with explicit methods,
instead of the filter's attributes shared with a mixin. The rules are the
filter's module docstring's steps 3 and 4; the state surgery is
:mod:`filters.mono_ekf_map`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from filters import landmark_params as lp
from filters.mono_ekf_map import (
    augment_with_landmarks,
    euclidean_conversion,
    euclidean_points,
    farthest_candidates,
    inverse_distances,
    linear_enough,
    transform_state,
    undetermined_depths,
)

__all__ = ["LandmarkRecord", "LandmarkSlots"]


@dataclass
class LandmarkRecord:
    """Bookkeeping of one landmark in the state (the parameters live in ``X``)."""

    track_id: int
    kind: int
    unseen: int = 0  # consecutive frames out of view
    misses: int = 0  # consecutive frames in view but not found or rejected
    prior_var_rho: float = 0.0  # the inverse distance's prior variance, 1/m^2 (0: Euclidean)


class LandmarkSlots:
    """The landmarks of a state ``X = [R, L1 ... Ln]`` (robot block of ``rdim`` entries),
    in state order (see the module docstring).

    Read-only views, rebuilt whenever the slots change: ``records`` (the
    :class:`LandmarkRecord` of each slot), ``ids`` (k,) int64 track ids, ``off``
    (k,) first state index, ``kinds`` (k,) parametrisations, ``idx`` (k, 7)
    padded state indices (padding repeats the first index), ``slot`` (track
    id -> slot), ``retired`` (track id -> last Euclidean estimate of a
    forgotten landmark).
    """

    def __init__(self, rdim: int):
        self._rdim = rdim
        self.records: list[LandmarkRecord] = []
        self._banned: set[int] = set()  # deleted: never initialised again
        self.retired: dict[int, np.ndarray] = {}
        self._reindex()

    def __len__(self) -> int:
        return len(self.records)

    def _reindex(self) -> None:
        """Offsets, kinds and padded index rows (k, 7) of the landmarks in state order."""
        sizes = np.array([lp.SIZE[lm.kind] for lm in self.records], dtype=np.int64)
        self.off = (
            self._rdim + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
            if len(sizes)
            else np.zeros(0, dtype=np.int64)
        )
        self.kinds = np.array([lm.kind for lm in self.records], dtype=np.int64)
        cols = np.arange(lp.PAD)
        # padding columns repeat the landmark's first index; their Jacobian columns are zero
        self.idx = (
            np.where(cols[None, :] < sizes[:, None], self.off[:, None] + cols[None, :], self.off[:, None])
            if len(sizes)
            else np.zeros((0, lp.PAD), np.int64)
        )
        self.ids = np.array([lm.track_id for lm in self.records], dtype=np.int64)
        self.slot = {lm.track_id: i for i, lm in enumerate(self.records)}

    # ------------------------------------------------------------ lifetime

    def count_frame(
        self, x: np.ndarray, visible, observed, accepted, rejected, max_misses: int, forget_frames: int
    ) -> tuple[dict, int, int]:
        """Update the counters after a frame (step 4 of the filter); returns the slots to
        drop ``{slot: None}`` and how many of them were deleted and forgotten.

        A deleted landmark's track id is banned; a forgotten Euclidean one keeps
        its estimate (``x``) in ``retired``.
        """
        drop: dict = {}
        deleted = forgotten = 0
        for i, lm in enumerate(self.records):
            if not visible[i] and not observed[i]:
                lm.unseen += 1
            else:
                lm.unseen = 0
            if accepted[i]:
                lm.misses = 0
            elif rejected[i] or (visible[i] and not observed[i]):
                lm.misses += 1
            if lm.misses >= max_misses:
                self._banned.add(lm.track_id)
                self.retired.pop(lm.track_id, None)
                deleted += 1
                drop[i] = None
            elif lm.unseen >= forget_frames:
                forgotten += 1
                drop[i] = None
                if lm.kind == lp.EUCLIDEAN:  # converged: keep it in the output map
                    o = self.off[i]
                    self.retired[lm.track_id] = x[o : o + 3].copy()
        return drop, deleted, forgotten

    def candidates(
        self, ids: np.ndarray, uv_px: np.ndarray, known: np.ndarray, image_size: tuple[int, int], room: int
    ) -> np.ndarray:
        """Rows of ``ids`` (step 3 of the filter) to become landmarks: at most ``room``
        unknown (``~known``), not banned tracks inside the image, chosen greedily
        farthest from the known tracks' pixels and from each other."""
        W, H = image_size
        cand = [
            r
            for r in np.flatnonzero(~known)
            if int(ids[r]) not in self._banned
            and -0.5 <= uv_px[r, 0] < W - 0.5
            and -0.5 <= uv_px[r, 1] < H - 0.5
        ]
        if not cand:
            return np.zeros(0, dtype=np.int64)
        # greedy farthest-point choice: spread new points away from mapped ones
        picked = farthest_candidates(uv_px[cand], uv_px[known], min(room, len(cand)))
        return np.array([cand[j] for j in picked], dtype=np.int64)

    # ------------------------------------------------------ state layout

    def append(
        self,
        x: np.ndarray,
        P: np.ndarray,
        track_ids: np.ndarray,
        kind: int,
        init: tuple,
        var: float,
        sigma_rho: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(x', P')`` with new landmarks of parametrisation ``kind`` in new slots at the
        end; ``init``: ``(L, G_pose, G_uv, G_rho)`` of
        :func:`filters.landmark_params.init_landmarks`, ``var`` the pixel variance
        (:func:`filters.mono_ekf_map.augment_with_landmarks`)."""
        L, G_pose, G_uv, G_rho = init
        x, P = augment_with_landmarks(x, P, L, G_pose, G_uv, G_rho, var, sigma_rho)
        prior = float(sigma_rho) ** 2 if kind != lp.EUCLIDEAN else 0.0
        self.records.extend(LandmarkRecord(int(t), kind, prior_var_rho=prior) for t in track_ids)
        self._reindex()
        return x, P

    def transform(self, x: np.ndarray, P: np.ndarray, changes: dict) -> tuple[np.ndarray, np.ndarray]:
        """``(x', P')`` with the slots in ``changes`` dropped (value None) or converted to
        Euclidean (value ``(p_w, J)``; :func:`filters.mono_ekf_map.transform_state`);
        converted landmarks move to the end of the state."""
        x, P = transform_state(x, P, self.off, self.kinds, changes)
        recs = self.records
        moved = [
            LandmarkRecord(recs[i].track_id, lp.EUCLIDEAN, recs[i].unseen, recs[i].misses)
            for i, ch in changes.items()
            if ch is not None
        ]
        self.records = [lm for i, lm in enumerate(recs) if i not in changes] + moved
        self._reindex()
        return x, P

    # --------------------------------------------------- reading the state

    def linear_enough(self, x: np.ndarray, P: np.ndarray, threshold: float, exclude=()) -> dict:
        """``{slot: (p_w (3,), J (3, s))}`` of the landmarks linear enough to become
        Euclidean (:func:`filters.mono_ekf_map.linear_enough`)."""
        return linear_enough(x, P, self.idx, self.kinds, threshold, exclude)

    def conversions(self, x: np.ndarray, track_ids) -> dict:
        """``{slot: (p_w, J)}`` converting the given tracks to Euclidean whatever their
        linearity; unknown ids, Euclidean landmarks and ``rho <= 0`` are skipped."""
        changes = {}
        for t in track_ids:
            i = self.slot.get(int(t))
            ch = None if i is None else euclidean_conversion(x, self.idx, self.kinds, i)
            if ch is not None:
                changes[i] = ch
        return changes

    def inverse_distances(self, x: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """Inverse distances (1/m) of ``slots`` from the camera position ``x[0:3]``."""
        return inverse_distances(x, self.idx[slots], self.kinds[slots])

    def euclidean_landmarks(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Track ids and Euclidean points (m) of the landmarks with ``rho > 0``."""
        if not self.records:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        p_w, ok = euclidean_points(x, self.idx, self.kinds)
        return self.ids[ok], p_w[ok]

    def undetermined_count(self, x: np.ndarray, P: np.ndarray) -> int:
        """How many of :meth:`euclidean_landmarks` have a depth not yet measured
        (:func:`~filters.mono_ekf_map.undetermined_depths`, against their priors)."""
        if not self.records:
            return 0
        prior = np.array([lm.prior_var_rho for lm in self.records])
        return int(np.sum(undetermined_depths(x, P, self.idx, self.kinds, prior)))
