"""Loop closures that may be wrong: the test, the kernel and the GNC solve.

Real pose graphs from place recognisers carry wrong closures, in runs
(perceptual aliasing), and one wrong closure bends a least-squares map by
tens of metres. The policy, for ``robust_closures = "auto"`` (the default) and
``"gnc"``:

- **The test.** A closure is an outlier when its squared whitened residual
  exceeds the chi-square quantile at ``1 - alpha / M`` (M closures, ``alpha``
  = ``closure_test_alpha``): a Bonferroni bound, so a graph whose closures all
  follow their stated noise loses none of them with probability at least
  ``1 - alpha``. Clean benchmark graphs thus keep every closure and reach the
  least-squares optimum; a fixed per-closure level (gtsam's 0.99) would drop
  1 % of their closures.
- **iSAM2** adds closures under a Cauchy kernel whose scale is that
  threshold: an inlier keeps at least half its weight, a closure 10x beyond it
  about 1 %, so a run of wrong closures does not bend the incremental estimate
  (plain iSAM2 on a real graph with wrong closures ends tens of metres off).
- **The final solve** (batch, or iSAM2's polish) starts from the candidate
  with the lowest truncated cost (odometry edges in full, each closure capped
  at the threshold) and runs LM over every edge. At that least-squares optimum
  the closures are tested, the threshold loosened by their median-based
  noise scale where the stated noise is too small (:func:`noise_scale`); if
  all pass, that optimum is the result. Otherwise gtsam's GNC (truncated least
  squares, odometry and gauge priors known inliers, the stated threshold)
  weighs the closures from the initialiser's start; those it weighs below 0.5
  are left out, LM over the kept edges follows, and every closure is re-tested
  at that optimum until the kept set is stable, the threshold loosened by the
  kept edges' own noise scale where the stated noise is too small
  (:func:`kept_noise_scale`, the a posteriori variance factor, measured once, at
  the first kept-edge optimum, so that closures let back in do not loosen it
  further).

``auto`` skips all of it for a graph without closures; ``none`` is plain least
squares everywhere; ``gnc`` runs GNC even when every closure passes the test.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from graphslam.backends import deep_stack
from slamcore import chi2
from slamcore.posegraph import PoseGraph, components


def is_robust(mode: str, graph: PoseGraph) -> bool:
    """Whether ``robust_closures = mode`` treats ``graph``'s closures as suspects."""
    return mode == "gnc" or (mode == "auto" and bool((~graph.odometry_mask()).any()))


def threshold_error(graph: PoseGraph, alpha: float) -> float:
    """The outlier threshold in gtsam error units (``0.5 r^2``): the chi-square
    quantile at ``1 - alpha / M`` with the edge's dimension (3 in 2-D, 6 in 3-D)."""
    n_closures = max(int((~graph.odometry_mask()).sum()), 1)
    dof = 3 if graph.dim == 2 else 6
    return 0.5 * chi2.isf(alpha / n_closures, dof)


def cauchy_kernel(threshold: float):
    """The Cauchy kernel of scale ``sqrt(2 threshold)`` (whitened units: the
    threshold residual keeps half its weight), one for every closure."""
    return gtsam.noiseModel.mEstimator.Cauchy.Create(float(np.sqrt(2.0 * threshold)))


def noise_scale(graph: PoseGraph, errors: np.ndarray) -> float:
    """Squared scale of the stated noise that ``errors`` (the closures' at the
    least-squares optimum) support: median ``r^2`` against the chi-square
    median, never below 1 (the usual median-based scale of M-estimation, used
    only to loosen the test). A graph whose stated noise is too small (a
    generator's, or TORO numbers read with the other convention) would
    otherwise lose true closures by the dozen; while fewer than half the
    closures are wrong the median is a true one's. Used for the first test
    only: once GNC has left closures out, the kept graph is close to a tree and
    its residuals say nothing of the noise."""
    dof = 3 if graph.dim == 2 else 6
    return max(1.0, float(np.median(2.0 * errors)) / float(chi2.median(dof)))


def kept_noise_scale(graph: PoseGraph, errors: np.ndarray, rejected: np.ndarray) -> float:
    """Squared scale of the stated noise at the kept-edge optimum: the a posteriori
    variance factor of least squares, ``2 E / r`` over the kept edges (``E``: their
    errors ``0.5 r^2``), with ``r`` the redundancy, ``dof x (kept edges - poses +
    components)``: what the edges say beyond a spanning tree. Never below 1 (used only
    to loosen the re-test), 1 without redundancy. Leverage is counted: a closure in
    a long, loose odometry loop adds redundancy and leaves almost no residual, one in
    a run of closures (short cycles) shows its own noise. ``errors``, ``rejected``:
    (M,) per edge. On the RRR graphs the stated closure noise is too small: 2.30
    (Bovisa04, 66 closures kept) and 1.70 (Bovisa06, 164 kept)."""
    kept = ~np.asarray(rejected, dtype=bool)
    rows = graph.index_of(graph.edges[kept].ravel()).reshape(-1, 2)
    dof = 3 if graph.dim == 2 else 6
    redundancy = dof * (int(kept.sum()) - graph.n_poses + len(components(graph.n_poses, rows)))
    if redundancy <= 0:
        return 1.0
    return max(1.0, 2.0 * float(np.asarray(errors)[kept].sum()) / redundancy)


@dataclass
class EdgeErrors:
    """Errors ``0.5 r^2`` of every edge at one estimate.

    Attributes:
        errors: (M,) per edge, file order.
        closures: (M,) bool, the closures.
    """

    errors: np.ndarray
    closures: np.ndarray

    @classmethod
    def at(cls, graph: PoseGraph, edges: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> EdgeErrors:
        errors = np.array([edges.at(e).error(values) for e in range(edges.size())])
        return cls(errors, ~graph.odometry_mask())

    def truncated_cost(self, threshold: float) -> float:
        """Odometry edges in full, closures capped at ``threshold``."""
        capped = np.where(self.closures, np.minimum(self.errors, threshold), self.errors)
        return float(capped.sum())

    def failing(self, threshold: float) -> np.ndarray:
        """(M,) bool: closures whose error exceeds ``threshold``."""
        return self.closures & (self.errors > threshold)


def gnc(
    graph: PoseGraph,
    full: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    lm_params: gtsam.LevenbergMarquardtParams,
    threshold: float,
    failing: np.ndarray | None = None,
) -> tuple[gtsam.Values, np.ndarray]:
    """GNC (truncated least squares) over ``full`` (the edges in file order, then
    the gauge priors), odometry and priors known inliers, every closure's
    threshold ``threshold``. Returns the estimate and (M,) bool rejected
    (closures weighed below 0.5)."""
    closures = ~graph.odometry_mask()
    params = gtsam.GncLMParams(lm_params)
    params.setKnownInliers([i for i in range(full.size()) if i >= graph.n_edges or not closures[i]])
    optimizer = gtsam.GncLMOptimizer(full, values, params)
    optimizer.setInlierCostThresholds(float(threshold))
    if failing is not None:
        weights = np.ones(full.size())
        weights[: graph.n_edges][failing] = 0.0
        optimizer.setWeights(weights)
    result = deep_stack.call(optimizer.optimize)
    weights = np.asarray(optimizer.getWeights())[: graph.n_edges]
    return result, closures & (weights < 0.5)
