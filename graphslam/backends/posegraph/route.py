"""``--backend auto`` for a whole pose-graph file: the fast route, checked.

Batch LM from the relaxation start (LAGO in 2-D, the chordal relaxation in
3-D) reaches the optimum of most graphs many times faster than iSAM2 (gtsam's
sphere2500: 0.9 s against minutes), but LAGO's rotations under large rotation
noise can leave it in a local minimum several times above iSAM2's result,
while LM says it converged. So batch runs first and its result is tested:

- **consistent**: ``2 x`` its cost over the kept edges within the chi-square
  quantile at ``1 - closure_test_alpha`` with ``d (M_kept - N + 1)`` degrees
  of freedom (d = 3 or 6), and no closure rejected: the residuals are what the
  stated noise predicts at an optimum, and batch's result is kept;
- otherwise iSAM2 (one pose at a time, its own starts) runs too, and the lower
  of the two costs is kept: the truncated cost of :mod:`.robust` when closures
  are tested (each closure capped at the outlier threshold, so a solve that
  rejected true closures to escape a bad start pays for each), else the plain
  cost. A candidate above the other by more than :data:`SAME_OPTIMUM_REL` is
  named a local minimum in :attr:`SolveResult.route`.

Where the kept estimate then fails SE-Sync's certificate (:mod:`.certificate`;
the pipeline checks it), :func:`retry_from_certified_rotations` runs batch once
more from Shonan's poses (:func:`.init.relaxed`, computed once; no retry when Shonan
fails) and keeps it when it costs less: a noisy Manhattan walk (0.3 rad of heading noise, seed 2) passes the
chi-square check at cost 158.045, a local minimum the certificate refuses, and
the Shonan start reaches 141.006.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from graphslam.backends.posegraph import factors as fx
from graphslam.backends.posegraph import init
from graphslam.backends.posegraph import robust as rb
from graphslam.backends.posegraph.config import PoseGraphConfig
from slamcore import chi2
from slamcore.posegraph import PoseGraph

#: Two routes whose costs agree to this, relative, reached the same optimum.
SAME_OPTIMUM_REL = 1e-6


#: One-sided probability of the chi-square lower tail below which a kept-edge cost
#: says the stated noise is larger than the data's: a cost this small happens by
#: chance once in a thousand graphs whose noise is stated right.
NOISE_OVERSTATED_ALPHA = 1e-3


def cost_statistic(graph: PoseGraph, result) -> tuple[float, int]:
    """``2 x`` the kept-edge cost and its degrees of freedom ``d (M_kept - N + F)``, ``F``
    the poses held: the ``FIX`` poses, else the first. Each ``FIX`` pose past the first
    takes ``d`` unknowns away; counted as one, a chain between two ``FIX`` poses that
    disagree with its edges was "a tree: every start is the optimum" at any cost."""
    d = 3 if graph.dim == 2 else 6
    kept = int(graph.n_edges - result.rejected.sum())
    held = max(1, len(np.unique(graph.fixed)))
    # nothing rejected (an unpolished iSAM2 solve keeps every edge): the kept cost is the cost
    stat = 2.0 * (result.final_cost if result.final_cost_kept is None else result.final_cost_kept)
    return stat, d * (kept - graph.n_poses + held)


def noise_overstated(graph: PoseGraph, result) -> tuple[float, str] | None:
    """Where the kept-edge cost lies below the chi-square quantile at
    :data:`NOISE_OVERSTATED_ALPHA`: the factor ``sqrt(dof / (2 x cost))`` by which the
    stated sigmas exceed the residuals', and the sentence that says so; else None. Not
    after the closure test rejected any: leaving out the largest residuals truncates the
    kept ones' distribution, so their cost lies low by construction (RRR's NewCollege,
    108 of 641 closures out: 1021.76 against the lower bound 1429.93 of 1599 dof)."""
    stat, dof = cost_statistic(graph, result)
    if dof <= 0 or result.rejected.any():
        return None
    low = chi2.ppf(NOISE_OVERSTATED_ALPHA, dof)
    if stat >= low:
        return None
    factor = math.sqrt(dof / float(stat)) if stat > 0 else math.inf  # Python floats: no overflow warning
    return factor, (
        f"2 x cost over kept edges {stat:.6g} is below the chi-square lower bound {low:.6g} "
        f"({dof} degrees of freedom, {NOISE_OVERSTATED_ALPHA:g})"
    )


def consistent(graph: PoseGraph, result, alpha: float) -> tuple[bool, str]:
    """Whether ``result``'s kept-edge cost is what the stated noise predicts at an
    optimum (chi-square at ``1 - alpha``), and the sentence that says so. A cost
    below the lower tail is no sign of a local minimum (it passes) but is said so:
    the stated noise is then larger than the data's (:func:`noise_overstated`)."""
    stat, dof = cost_statistic(graph, result)
    if dof <= 0:
        return True, "the graph is a tree: every start is the optimum"
    bound = chi2.isf(alpha, dof)
    low = noise_overstated(graph, result)
    if low is not None:
        return True, f"{low[1]}, the stated noise larger than the data's"
    verdict = "within" if stat <= bound else "above"
    return stat <= bound, (
        f"2 x cost over kept edges {stat:.6g} {verdict} the chi-square bound "
        f"{bound:.6g} ({dof} degrees of freedom, 1 - {alpha:g})"
    )


def shared_threshold(a, b) -> float | None:
    """The edge error at which two candidates' closures are truncated for the
    comparison: the looser of their outlier thresholds, or None (plain cost) unless
    both tested their closures."""
    if a.closure_threshold is None or b.closure_threshold is None:
        return None
    return 0.5 * max(a.closure_threshold, b.closure_threshold) ** 2


def comparable_cost(graph: PoseGraph, result, threshold_error: float | None) -> float:
    """The cost both routes are compared on (see the module docstring)."""
    if threshold_error is None:
        return float(result.final_cost)
    errors = rb.EdgeErrors(0.5 * np.square(result.residuals), ~graph.odometry_mask())
    return errors.truncated_cost(threshold_error)


def solve_auto(graph: PoseGraph, config: PoseGraphConfig, solve, should_stop=None):
    """Batch, then iSAM2 where batch's result is not consistent; the better kept.
    ``solve``: :func:`.solver.solve` (passed in: the solver dispatches here)."""
    t0 = time.perf_counter()
    batch = solve(graph, config, "batch", should_stop)
    if batch.stopped is not None:  # the estimate in hand; no second route after a stop
        reason = f"a signal stopped its {batch.stopped}"
        return _named(
            batch, t0, {"kept": "batch", "reason": reason, "batch": _summary(batch, batch.final_cost)}
        )
    ok, why = consistent(graph, batch, config.closure_test_alpha)
    if ok and not batch.rejected.any():
        return _named(batch, t0, {"kept": "batch", "reason": why, "batch": _summary(batch, batch.final_cost)})
    reason = why if not ok else f"batch rejected {int(batch.rejected.sum())} closures"
    incremental = solve(graph, config, "isam2", should_stop)
    if incremental.cut is not None or incremental.stopped is not None:  # batch's estimate is whole
        batch.recoveries.append("stopped while iSAM2 was tried after batch; batch's estimate kept")
        return _named(
            batch, t0, {"kept": "batch", "reason": reason, "batch": _summary(batch, batch.final_cost)}
        )
    threshold = shared_threshold(batch, incremental)
    costs = {
        "batch": comparable_cost(graph, batch, threshold),
        "isam2": comparable_cost(graph, incremental, threshold),
    }
    kept_name = "batch" if costs["batch"] <= costs["isam2"] else "isam2"
    kept, other = (batch, "isam2") if kept_name == "batch" else (incremental, "batch")
    route = {
        "kept": kept_name,
        "reason": f"{reason}: iSAM2 tried too",
        "compared_on": "truncated cost" if threshold is not None else "cost",
        "batch": _summary(batch, costs["batch"]),
        "isam2": _summary(incremental, costs["isam2"]),
    }
    if costs[other] > costs[kept_name] * (1.0 + SAME_OPTIMUM_REL):
        route["local_minimum"] = (
            f"{other} stopped in a local minimum ({costs[other]:.10g} "
            f"against {kept_name}'s {costs[kept_name]:.10g})"
        )
    return _named(kept, t0, route)


def retry_from_certified_rotations(graph: PoseGraph, config: PoseGraphConfig, solve, kept, should_stop=None):
    """``auto``'s kept result, or batch from Shonan's rotations where that costs less
    (compared as :func:`solve_auto` compares; the route says which, and names the
    local minimum). ``solve``: :func:`.solver.solve`; ``should_stop`` (a signal)
    ends Shonan's averaging, with no retry."""
    t0 = time.perf_counter()
    # the file's weights only: where gtsam refuses them (anisotropic 3-D rotation
    # information) there is no retry, for SE-Sync's weights cost Shonan 45-47 s on
    # sphere2500 beside a 2 s solve, too much for a second opinion
    start, failure = init.relaxed(graph, "shonan", config.prior_sigma, should_stop)
    if start is None:  # its fallback (the odometry start) would be no second opinion
        kept.route = {**(kept.route or {}), "shonan_retry": f"not certified; no retry: {_no_retry(failure)}"}
        kept.wall_s += time.perf_counter() - t0
        return kept
    # batch from Shonan's poses, computed once: the graph's vertices replaced by them
    seeded = graph.with_vertices(fx.params_from(graph, start.values))
    shonan = solve(seeded, dataclasses.replace(config, init="vertices"), "batch")
    shonan.init_method = "shonan"
    threshold = shared_threshold(kept, shonan)
    before, after = comparable_cost(graph, kept, threshold), comparable_cost(graph, shonan, threshold)
    route = dict(kept.route or {})
    route["shonan"] = _summary(shonan, after)
    wall_s = kept.wall_s + time.perf_counter() - t0
    if after >= before * (1.0 - SAME_OPTIMUM_REL):
        route["shonan_retry"] = "not certified: batch from Shonan's rotations reached no lower cost"
        kept.route, kept.wall_s = route, wall_s
        return kept
    route["local_minimum"] = (
        f"{route.get('kept', 'the first route')} stopped in a local minimum "
        f"({before:.10g} against {after:.10g} from Shonan's rotations)"
    )
    route["kept"] = "shonan"  # batch from Shonan's rotations
    route["shonan_retry"] = "not certified: batch from Shonan's rotations reached a lower cost"
    shonan.solver, shonan.route, shonan.wall_s = "auto", route, wall_s
    return shonan


def _no_retry(failure: str) -> str:
    """Why Shonan gave no retry, from :func:`.init.relaxed`'s reason."""
    if "must be isotropic" in failure:  # gtsam's std::invalid_argument, as worded in 4.3
        return (
            "the file's rotation information is not isotropic, which gtsam's Shonan "
            "averaging needs (--init shonan runs it on SE-Sync's isotropic weights)"
        )
    return init.why_no_start("shonan", failure)


def _summary(result, cost: float) -> dict:
    return {"cost": cost, "closures_rejected": int(result.rejected.sum()), "wall_s": result.wall_s}


def _named(result, t0: float, route: dict):
    result.solver = "auto"
    result.route = route
    result.wall_s = time.perf_counter() - t0
    return result
