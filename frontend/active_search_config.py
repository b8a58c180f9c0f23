"""Settings of active search (:class:`frontend.active_search.ActiveSearch`), checked on creation.

Its own module so that the matchers (:mod:`frontend.search_matchers`) and the
search share them without importing each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

from frontend.image import MAX_PATCH_PX, MAX_POINTS_PER_FRAME
from slamcore.config import Validated, bounded
from slamcore.errors import ConfigError

__all__ = ["ActiveSearchConfig", "chi2_2dof"]


def chi2_2dof(probability: float) -> float:
    """Chi-square quantile with 2 degrees of freedom: ``-2 ln(1 - p)`` (9.2103 at 0.99)."""
    if not 0.0 < probability < 1.0:
        raise ConfigError(f"gate probability must be in (0, 1), got {probability!r}")
    return -2.0 * math.log1p(-probability)


@dataclass(frozen=True)
class ActiveSearchConfig(Validated):
    """Active search settings (config section ``[active_search]``).

    Attributes:
        mode: ``"zncc"`` (software patch correlation) or ``"nearest"`` (hardware:
            nearest Harris point inside the ellipse); None: ``"zncc"``, or in a
            tracked run what ``[tracker] search`` chooses (which decides there: a
            different mode set here is refused, it did nothing).
        gate_probability: probability mass of the search ellipse (chi-square, 2 dof).
        max_corrections: landmarks searched per frame at most (largest
            ellipses first); 0 = no cap.
        patch_size_px: odd side of the correlation patch, pixels.
        min_score: smallest ZNCC accepted, in [-1, 1].
        min_patch_std: patches / image windows with a grey-level standard
            deviation below this are not matched (flat, ZNCC undefined).
        subpixel: parabolic sub-pixel refinement of the ZNCC peak.
        predict_appearance: warp the patch by the given per-landmark affine
            before correlating (needs the previous image and points, or
            larger source patches; the tracker's patches are warped by the
            view change since they were cut, :mod:`frontend.appearance`).
        max_half_extent_px: landmarks whose ellipse's bounding box has a
            half-side above this are not searched (their prediction is
            meaningless; they would cost a large part of the frame).
        order: ``"batch"`` or ``"sequential"`` (module docstring); sequential
            needs a back end that corrects one landmark at a time (the
            monocular EKF).
        ransac_every: sequential only: one correction in ``n`` comes from the
            back end's one-point RANSAC over the first matches (module
            docstring); 0: none (every correction sequential, gated alone).
    """

    SECTION: ClassVar[str] = "active_search"

    mode: Literal["zncc", "nearest"] | None = None
    gate_probability: float = bounded(0.99, gt=0.0, lt=1.0)
    max_corrections: int = bounded(20, min=0, max=MAX_POINTS_PER_FRAME)
    patch_size_px: int = bounded(11, min=3, max=MAX_PATCH_PX)
    min_score: float = bounded(0.8, min=-1.0, max=1.0)
    # 8-bit grey levels spread at most 127.5 (half 0, half 255): more refuses every patch
    min_patch_std: float = bounded(3.0, min=0.0, max=127.5)
    subpixel: bool = True
    predict_appearance: bool = False
    max_half_extent_px: float = bounded(150.0, gt=0.0)
    order: Literal["batch", "sequential"] = "batch"
    # 1 would hand every match to RANSAC at once: the batch order
    ransac_every: int = bounded(0, min=0, max=MAX_POINTS_PER_FRAME)

    def __post_init__(self):
        super().__post_init__()
        if self.ransac_every == 1 or (self.ransac_every and self.order != "sequential"):
            raise ConfigError(
                f"active_search.ransac_every must be 0 or at least 2, with order "
                f"'sequential' (got {self.ransac_every!r}, order {self.order!r})"
            )
        if self.patch_size_px % 2 == 0:  # parity is not a range: checked here
            raise ConfigError(
                f"active_search.patch_size_px must be odd (a centre pixel), got {self.patch_size_px!r}"
            )

    @property
    def gate(self) -> float:
        """Mahalanobis-squared threshold gamma of the ellipse."""
        return chi2_2dof(self.gate_probability)

    def first_batch(self, budget: int | None) -> int:
        """Matches handed to the back end together before the first re-prediction
        (sequential order): ``ceil(budget / ransac_every)``, else 1."""
        if not self.ransac_every or not budget:
            return 1
        return max(1, -(-int(budget) // self.ransac_every))
