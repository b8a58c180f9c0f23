"""Batch polish of the visual graph with robust rejection of wrong loop closures (GNC).

Graduated non-convexity (gtsam's ``GncLMOptimizer``) over the whole graph,
every factor but the loop closures known to be an inlier. GNC weighs the
suspects itself, so their robust kernels are replaced by their Gaussian core
first.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from graphslam.backends import gtsam_convert as conv


def gnc_polish(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    closures: list[tuple[int, int, gtsam.Pose3, np.ndarray]],
    lm_params: gtsam.LevenbergMarquardtParams,
):
    """GNC over ``graph`` from ``initial``, loop closures Gaussian and the only suspects.

    ``closures``: ``(frame a, frame b, aTb, covariance (6, 6) in the
    contract's order)`` of every closure factor ``X(a) -> X(b)`` in
    ``graph`` (modified in place). Returns the graph, the optimised values
    and how many closures GNC weighed below 0.5 (dropped).
    """
    keys = {(X(a), X(b)): (measured, cov) for a, b, measured, cov in closures}
    suspects = []
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None or not isinstance(f, gtsam.BetweenFactorPose3):
            continue
        k = tuple(f.keys())
        if k in keys:  # GNC wants plain Gaussian factors: its own weights are the kernel
            measured, cov = keys[k]
            graph.replace(i, gtsam.BetweenFactorPose3(k[0], k[1], measured, conv.pose3_noise(cov)))
            suspects.append(i)
    params = gtsam.GncLMParams(lm_params)
    suspect = set(suspects)
    params.setKnownInliers([i for i in range(graph.size()) if i not in suspect])
    optimizer = gtsam.GncLMOptimizer(graph, initial, params)
    result = optimizer.optimize()
    weights = np.asarray(optimizer.getWeights())
    return graph, result, int(sum(weights[i] < 0.5 for i in suspects))
