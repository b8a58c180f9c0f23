"""Active search: look for each landmark only inside its innovation ellipse.

Seed 003, section 4.4. After the filter's prediction every landmark is
projected into the image with an innovation covariance ``S`` (2x2, px^2); the
observation must lie, with probability ``gate_probability``, in the ellipse

    (z - z_hat)^T S^-1 (z - z_hat) <= gamma,   gamma = chi2_2dof(p) = -2 ln(1 - p)

(9.21 for p = 0.99: for 2 degrees of freedom the chi-square quantile is exact
in closed form). Landmarks are searched largest ellipse first (``sqrt(det S)``,
proportional to the area: their observation brings the most information), and
at most ``max_corrections`` are searched per frame, a hard bound on the time;
``max_found`` stops the search once a back end's per-frame correction budget
is found (the others would not be used).

Two orders (``ActiveSearchConfig.order``):

* ``"batch"``: every ellipse comes from the one prediction of the frame and the
  back end corrects with all the matches at once, after the search.
* ``"sequential"`` (RT-SLAM): the largest ellipse is searched, the back end
  corrects with its match at once, and the landmarks still to search are
  re-predicted from the corrected state (their ellipses shrink) and re-sorted;
  the next is searched inside its new ellipse, up to the caps. With
  ``ransac_every = n`` (the paper's RT-SLAM variant, section 5.1: "one
  correction in two by one-point RANSAC" is n = 2, RT-SLAM's
  ``N_UPDATES_RANSAC``), the first ``ceil(cap / n)`` matches (``cap`` the
  back end's correction budget) are found in their predicted ellipses and
  handed over together, for the back end's one-point RANSAC; the rest
  follow one by one. The back end is reached through the ``repredict``
  callback of :meth:`ActiveSearch.search_with`.

Two modes (``ActiveSearchConfig.mode``):

* ``"zncc"`` (software, RT-SLAM): the stored patch (``patch_size_px`` square,
  from the previous image) is correlated (zero-mean normalised
  cross-correlation, ``cv2.matchTemplate(TM_CCOEFF_NORMED)`` on the ellipse's
  bounding box) and the best score among the integer pixels inside the
  ellipse is accepted if ``>= min_score``; image windows whose standard
  deviation is below ``min_patch_std`` grey levels are never accepted (ZNCC is
  undefined on flat windows). Optional sub-pixel refinement by a parabola
  through the 3 scores around the peak on each axis. Optional appearance
  prediction: the patch is warped, from the previous image or from a larger
  patch cut around the point, by a per-landmark affine map of pixel offsets
  (previous -> current, e.g.
  :func:`slamcore.spatial.camera.plane_induced_affine`; the tracker's are
  those of :mod:`frontend.appearance`) before correlation.
* ``"nearest"`` (hardware, the FPGA variant): among the current frame's Harris
  points (:class:`frontend.features.Features`), the one nearest to the
  prediction in Mahalanobis distance and inside the ellipse is taken. Points are
  not exclusive (two landmarks may take the same point), as in the paper.

Pixels "searched" by a landmark are the integer pixels inside its ellipse (and
inside the image, where a patch fits for ZNCC); the image fraction reported is
the union of these pixels over the frame, divided by ``H * W`` (the sum, which
counts overlaps twice, is reported as well).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from frontend.active_search_config import ActiveSearchConfig
from frontend.features import Features
from frontend.image import check_gray
from frontend.search_matchers import (
    Matcher,
    NearestMatcher,
    ZnccMatcher,
    checked_points,
    ellipse_pixels,
    inv2,
)
from slamcore.config import with_overrides
from slamcore.errors import ConfigError, InputError, MeasurementError

# the settings (frontend.active_search_config) and the matchers (frontend.search_matchers)
# live in their own modules; import them from there
__all__ = ["ActiveSearchResult", "ActiveSearch", "Repredict"]


@dataclass(frozen=True, eq=False)
class ActiveSearchResult:
    """Outcome of one frame's active search, per landmark (N = number of predictions).

    Attributes:
        order: (M,) indices of the searched landmarks, in search order (largest ellipse first).
        searched: (N,) bool.
        found: (N,) bool, a match was accepted.
        uv: (N, 2) measured pixel position ``[u, v]``, NaN where not found.
        score: (N,) best ZNCC in the ellipse (zncc mode, even if rejected) or
            the Harris response of the chosen point (nearest mode); NaN if none.
        d2: (N,) Mahalanobis squared distance of ``uv`` to the prediction; NaN if not found.
        pixels: (N,) integer pixels evaluated inside the ellipse (0 if not searched).
        image_fraction: union of the searched pixels / (H W).
        image_fraction_sum: sum of ``pixels`` / (H W) (overlaps counted twice).
        skipped: (N,) bool, searchable but left unsearched because the search
            stopped (``max_corrections`` searched or ``max_found`` found); None
            for a result made without a search (no prediction).
        z, S: (N, 2), (N, 2, 2) the ellipse each landmark was searched in: the
            predictions, or in sequential order the re-predictions (the caller's
            arrays are not changed: hostile pass 24 found the tracker recording the
            first prediction for zncc and nearest searches); None without a search.
    """

    order: np.ndarray
    searched: np.ndarray
    found: np.ndarray
    uv: np.ndarray
    score: np.ndarray
    d2: np.ndarray
    pixels: np.ndarray
    image_fraction: float
    image_fraction_sum: float
    skipped: np.ndarray | None = None
    z: np.ndarray | None = None
    S: np.ndarray | None = None

    @property
    def n_found(self) -> int:
        return int(self.found.sum())


#: Sequential order's link to the back end: ``repredict(found, uv, pending) ->
#: (z (P, 2), S (P, 2, 2))``: correct with the landmarks ``found`` (M,) (indices
#: into the predictions) measured at ``uv`` (M, 2) px, and return the new
#: predictions and innovation covariances of the landmarks ``pending`` (P,).
Repredict = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _checked_predictions(predictions, S) -> tuple[np.ndarray, np.ndarray]:
    """``(z (N, 2), S (N, 2, 2))`` as float64 copies (the sequential order re-predicts them
    in place, and the caller's arrays are the caller's); InputError / MeasurementError
    if malformed. An array of another shape is refused, not reshaped: (2, N) read as
    (N, 2) scrambles the points."""
    z = checked_points(predictions, "predictions")
    S = np.array(S, dtype=np.float64)
    n = len(z)
    if S.shape != (n, 2, 2):
        raise InputError(f"{n} predictions need ({n}, 2, 2) covariances, got shape {S.shape}")
    finite = np.all(np.isfinite(S.reshape(n, 4)), axis=1)
    Sf = S[finite]
    if (
        np.any(np.abs(Sf[:, 0, 1] - Sf[:, 1, 0]) > 1e-9 * (1 + np.abs(Sf[:, 0, 1])))
        or np.any(Sf[:, 0, 0] <= 0)
        or np.any(np.linalg.det(Sf) <= 0)
    ):
        raise MeasurementError("innovation covariances must be symmetric positive definite")
    return z, S


class ActiveSearch:
    """Active search for one frame at a time (see the module docstring).

    ``ActiveSearch(config)`` or ``ActiveSearch(max_corrections=10, ...)``.
    """

    def __init__(self, config: ActiveSearchConfig | None = None, **overrides):
        self.config = with_overrides(config or ActiveSearchConfig(), overrides, ActiveSearchConfig)

    # ------------------------------------------------------------------ ordering

    def search_order(self, predictions: np.ndarray, S: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Candidate landmark indices, largest ellipse (``sqrt(det S)``) first, ties by index.

        Drops predictions that are not finite, lie outside the image, or whose
        ellipse is larger than ``max_half_extent_px``. The cap is applied by
        :meth:`search` (a landmark whose ellipse has no usable pixel does not use it).
        """
        H, W = shape
        z = predictions
        ok = np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(S.reshape(len(S), 4)), axis=1)
        ok &= (z[:, 0] >= -0.5) & (z[:, 0] <= W - 0.5) & (z[:, 1] >= -0.5) & (z[:, 1] <= H - 0.5)
        g = self.config.gate
        half = np.sqrt(g * np.maximum(np.maximum(S[:, 0, 0], S[:, 1, 1]), 0.0))
        ok &= half <= self.config.max_half_extent_px
        size = np.sqrt(np.maximum(np.linalg.det(S), 0.0))
        idx = np.flatnonzero(ok)
        return idx[np.argsort(-size[idx], kind="stable")]

    # ------------------------------------------------------------------ search

    def search(
        self,
        image: np.ndarray,
        predictions: np.ndarray,
        S: np.ndarray,
        *,
        patches: np.ndarray | None = None,
        prev_image: np.ndarray | None = None,
        prev_xy: np.ndarray | None = None,
        affine: np.ndarray | None = None,
        features: Features | None = None,
        max_found: int | None = None,
        source_patches: np.ndarray | None = None,
        repredict: Repredict | None = None,
    ) -> ActiveSearchResult:
        """Search the landmarks predicted at ``predictions`` (N, 2) with covariances ``S`` (N, 2, 2).

        ``image``: current (H, W) uint8 frame. zncc mode needs ``patches``
        (N, p, p) or ``prev_image`` + ``prev_xy`` (N, 2) (patches are cut there);
        appearance prediction needs ``affine`` (N, 2, 2) and either
        ``prev_image`` + ``prev_xy`` or ``source_patches`` (N, q, q), q odd >= p,
        centred on the points (:class:`ZnccMatcher`); without ``affine`` it is
        off. nearest mode needs ``features`` (the current frame's points).
        ``max_found``: stop once this many landmarks are found (a back end that
        corrects at most that many per frame, largest ellipses first, would not
        use the others: paper section 4.4); ``None`` or 0: no such stop. The
        config's ``max_corrections`` still caps the landmarks searched.
        ``repredict``: the sequential order's link to the back end
        (:meth:`search_with`).
        """
        image = check_gray(image)
        z, S = _checked_predictions(predictions, S)
        if max_found is not None and (
            isinstance(max_found, bool) or not isinstance(max_found, (int, np.integer)) or max_found < 0
        ):  # -1 searched nothing, without a word
            raise InputError(f"max_found must be None or an integer >= 0, got {max_found!r}")
        matcher: ZnccMatcher | NearestMatcher
        if self.config.mode != "nearest":  # None: zncc
            matcher = ZnccMatcher(
                self.config,
                image,
                len(z),
                patches=patches,
                prev_image=prev_image,
                prev_xy=prev_xy,
                affine=affine,
                source_patches=source_patches,
            )
        else:
            matcher = NearestMatcher(self.config, z, features)
        return self.search_with(
            image.shape, z, S, matcher, margin=matcher.margin, max_found=max_found, repredict=repredict
        )

    def search_with(
        self,
        shape: tuple[int, int],
        z: np.ndarray,
        S: np.ndarray,
        matcher: Matcher,
        *,
        margin: int = 0,
        max_found: int | None = None,
        repredict: Repredict | None = None,
    ) -> ActiveSearchResult:
        """The search loop shared by every mode: ``matcher`` (see :data:`Matcher`) looks
        inside each ellipse, largest first, within the caps (:meth:`search`).

        ``shape``: ``(H, W)`` of the image; ``z`` (N, 2) and ``S`` (N, 2, 2)
        float64, already checked; ``margin``: pixels of every edge an ellipse
        pixel must keep (half the patch for ZNCC).

        ``repredict`` (:data:`Repredict`), with ``order = "sequential"``: each
        match (the first :meth:`ActiveSearchConfig.first_batch` together) goes
        to the back end at once, and the landmarks not searched yet are
        re-predicted and re-sorted. ``z`` and ``S`` are then updated in place:
        they end up holding the ellipse each landmark was searched in (the
        matcher reads them).
        """
        if repredict is not None and self.config.order != "sequential":
            raise ConfigError("active_search: a back-end link (repredict) needs order = 'sequential'")
        H, W = shape
        n = len(z)
        searched, found, skipped = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
        uv, score, d2 = np.full((n, 2), np.nan), np.full(n, np.nan), np.full(n, np.nan)
        pixels = np.zeros(n, np.int64)
        union = np.zeros((H, W), bool)
        order: list[int] = []
        pending: list[int] = []
        cap = self.config.max_corrections or n
        batch = self.config.first_batch(max_found or self.config.max_corrections)
        cand = list(self.search_order(z, S, (H, W)))
        while cand:
            if len(order) >= cap or (max_found and int(found.sum()) >= max_found):
                skipped[cand] = True
                break
            i = cand.pop(0)
            u0, v0, mask = ellipse_pixels(z[i], S[i], self.config.gate, (H, W), margin)
            cnt = int(mask.sum())
            if cnt == 0:
                continue
            order.append(i)
            searched[i] = True
            pixels[i] = cnt
            bh, bw = mask.shape
            union[v0 : v0 + bh, u0 : u0 + bw] |= mask
            if not self._match_one(i, z, S, matcher, (u0, v0, mask), uv, score, d2):
                continue
            found[i] = True
            if repredict is not None:
                pending.append(i)
                if len(pending) >= batch:
                    cand = self._corrected(repredict, pending, uv, cand, z, S, (H, W))
                    pending, batch = [], 1
        if pending:  # the last matches still correct the back end
            self._corrected(repredict, pending, uv, [], z, S, (H, W))
        npx = float(H * W)
        return ActiveSearchResult(
            order=np.asarray(order, dtype=np.int64),
            searched=searched,
            found=found,
            uv=uv,
            score=score,
            d2=d2,
            pixels=pixels,
            image_fraction=float(union.sum()) / npx,
            image_fraction_sum=float(pixels.sum()) / npx,
            skipped=skipped,
            z=z,
            S=S,
        )

    @staticmethod
    def _match_one(i, z, S, matcher, box, uv, score, d2) -> bool:
        """Run ``matcher`` on landmark ``i`` in its ellipse ``box`` = ``(u0, v0, mask)``;
        fills ``uv``, ``score``, ``d2`` at ``i``; returns whether a match was accepted."""
        Si = inv2(S[i])
        m, sc, e2 = matcher(i, Si, *box)
        if sc is not None:
            score[i] = sc
        if m is None:
            return False
        if e2 is None:
            e = m - z[i]
            e2 = float(e @ Si @ e)
        d2[i] = e2
        uv[i] = m
        return True

    def _corrected(self, repredict, pending, uv, cand, z, S, shape) -> list:
        """Hand the matches ``pending`` to the back end, write the re-predictions of
        ``cand`` into ``z`` and ``S``, and return ``cand`` re-sorted (largest first;
        those now out of the image or too large dropped, as by :meth:`search_order`)."""
        p = np.asarray(pending, dtype=np.int64)
        c = np.asarray(cand, dtype=np.int64)
        z_new, S_new = repredict(p, uv[p].copy(), c)
        if not len(c):
            return []
        # checked as the caller's predictions: one row for 9 asked was broadcast to all 9
        z_new, S_new = _checked_predictions(z_new, S_new)
        if len(z_new) != len(c):
            raise InputError(f"repredict returned {len(z_new)} predictions for the {len(c)} landmarks asked")
        z[c] = z_new
        S[c] = 0.5 * (S_new + np.swapaxes(S_new, 1, 2))  # exactly symmetric, as the tracker's
        return c[self.search_order(z[c], S[c], shape)].tolist()
