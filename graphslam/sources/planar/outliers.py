"""Inject false loop closures into a dataset, to test how robust a back end is.

What a realistic false closure looks like here. A place-recognition front end
that is fooled (perceptual aliasing: two corridors, two crossroads that look
alike) claims that two poses far apart in the run were taken at almost the same
place. Its measurement therefore looks exactly like a real closure of that
front end: a small relative pose of the usual kind, with the usual covariance.
So :func:`inject_false_closures`:

- picks a pair of poses ``(i, j)``, ``i < j``, uniformly at random among all
  pairs at least ``min_index_gap`` poses apart (a detector excludes recent
  frames): two uniform indices, redrawn while too close;
- copies the measured relative pose (``delta``) **and** the covariance of a
  true closure of the same dataset drawn at random (so neither the size of the
  claimed displacement nor its stated uncertainty gives the lie away); a
  dataset without closures falls back to ``delta = 0`` ("same place") and
  ``covariance`` (required then);
- when a reference trajectory is known (the dataset's ground truth by default,
  or ``reference`` -- e.g. a clean optimum for w10000, which has no ground
  truth), redraws any pair whose claim is in fact nearly true: the claim must
  differ from the reference relative pose ``iTj`` by a Mahalanobis distance of
  at least ``min_mahalanobis`` under the closure's own covariance (the local
  difference ``[dx, dy, wrap(dtheta)]``; a closure that agrees with the truth
  is not false);
- attaches it to the frame of pose ``j`` (the later pose), as ``from_id=i``,
  ``to_id=j``, ``source="injected"``, after the frame's own closures.

Count: ``n = round(fraction * number of loop closures already in the dataset)``
(closures of ``frames[...].loop_closures``; odometry edges do not count), so
"30 %" means 30 false closures per 100 true ones, 23 % of all closures.

Randomness: one ``numpy.random.default_rng(seed)``; the same dataset, fraction
and seed give the same closures, to the bit. numpy only (no gtsam).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from slamcore.errors import GraphSlamError
from slamcore.planar.geometry import between, wrap_angle
from slamcore.planar.records import Dataset, LoopClosure

#: ``LoopClosure.source`` of every injected closure.
INJECTED_SOURCE = "injected"
#: Smallest pose-index gap between the two poses of an injected closure.
DEFAULT_MIN_INDEX_GAP = 50
#: Smallest Mahalanobis distance (unitless, closure covariance) between an
#: injected claim and the reference relative pose, when a reference is known.
DEFAULT_MIN_MAHALANOBIS = 10.0
#: Draws per closure before giving up (every pair nearly true is pathological).
MAX_DRAWS_PER_CLOSURE = 1000


def closure_mahalanobis(lc: LoopClosure, wTi: np.ndarray, wTj: np.ndarray) -> float:
    """Mahalanobis distance (unitless) of ``lc``'s claim from the relative pose of
    ``wTi`` (its ``from_id`` pose) and ``wTj`` (its ``to_id`` pose), each (3,)
    ``[x, y, theta]``: ``[dx, dy, wrap(dtheta)]`` of claimed minus reference
    relative pose, whitened by ``lc.covariance``."""
    poses = []
    for name, pose in (("wTi", wTi), ("wTj", wTj)):
        try:
            p = np.asarray(pose, dtype=np.float64)
        except (TypeError, ValueError):
            p = np.empty(0)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise GraphSlamError(f"closure_mahalanobis: {name} needs a finite [x, y, theta], got {pose!r}")
        poses.append(p)
    e = np.asarray(lc.delta, dtype=np.float64) - between(*poses)
    e[2] = float(wrap_angle(e[2]))
    return float(np.sqrt(e @ np.linalg.solve(lc.covariance, e)))


def is_injected(lc: LoopClosure) -> bool:
    return lc.source == INJECTED_SOURCE


def _template(
    rng: np.random.Generator, true_closures: list[LoopClosure], covariance: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(delta, covariance)`` of the next injected closure: a true closure's, drawn
    with ``rng``, its covariance replaced by ``covariance`` when given; without true
    closures, a zero delta and ``covariance``."""
    if true_closures:
        template = true_closures[int(rng.integers(len(true_closures)))]
        return template.delta, (covariance if covariance is not None else template.covariance)
    if covariance is None:
        raise GraphSlamError("dataset has no loop closure to copy a covariance from; pass covariance=")
    return np.zeros(3), covariance


def inject_false_closures(
    dataset: Dataset,
    fraction: float,
    seed: int,
    *,
    covariance: np.ndarray | None = None,
    min_index_gap: int = DEFAULT_MIN_INDEX_GAP,
    reference: tuple[np.ndarray, np.ndarray] | None = None,
    min_mahalanobis: float = DEFAULT_MIN_MAHALANOBIS,
) -> Dataset:
    """A copy of ``dataset`` with ``round(fraction * closures)`` false closures added.

    See the module docstring for how they are drawn.

    Args:
        dataset: the clean dataset (not modified).
        fraction: false closures per true closure, >= 0.
        seed: seed of the generator; same inputs, same output bits.
        covariance: (3, 3) covariance for every injected closure, overriding the
            copied one; required when the dataset has no closure to copy from.
        min_index_gap: the two poses are at least this many frames apart.
        reference: ``(pose_ids (N,), wTb (N, 3))`` trajectory used to keep only
            claims that are really false; defaults to the ground truth (if any).
            ``None`` with no ground truth: no such check.
        min_mahalanobis: see module docstring; ignored without a reference.

    Returns:
        A new :class:`Dataset` (frames replaced where closures were added).
    """
    if not np.isfinite(fraction) or fraction < 0:
        raise GraphSlamError(f"fraction must be a finite number >= 0, got {fraction}")
    frames = list(dataset.frames)
    n_frames = len(frames)
    true_closures = [lc for f in frames for lc in f.loop_closures]
    n_inject = int(round(fraction * len(true_closures)))
    if n_inject == 0:
        return dataclasses.replace(dataset, frames=frames)
    if n_frames <= min_index_gap:
        raise GraphSlamError(f"cannot inject closures {min_index_gap} poses apart into {n_frames} frames")
    if not true_closures and covariance is None:
        raise GraphSlamError("dataset has no loop closure to copy a covariance from; pass covariance=")
    if reference is None:
        reference = dataset.ground_truth()
    ref_pose = None
    if reference is not None:
        ref_ids, ref_wTb = (np.asarray(a) for a in reference)
        by_id = {int(p): np.asarray(ref_wTb[k], dtype=np.float64) for k, p in enumerate(ref_ids)}
        ref_pose = by_id.get

    rng = np.random.default_rng(seed)
    pose_ids = [f.pose_id for f in frames]
    added: dict[int, list[LoopClosure]] = {}
    for _ in range(n_inject):
        for _draw in range(MAX_DRAWS_PER_CLOSURE):
            ki, kj = sorted(int(k) for k in rng.integers(0, n_frames, size=2))
            if kj - ki < min_index_gap:
                continue
            delta, cov = _template(rng, true_closures, covariance)
            lc = LoopClosure(pose_ids[ki], pose_ids[kj], delta, cov, source=INJECTED_SOURCE)
            if ref_pose is not None:
                wTi, wTj = ref_pose(lc.from_id), ref_pose(lc.to_id)
                if (
                    wTi is not None
                    and wTj is not None
                    and closure_mahalanobis(lc, wTi, wTj) < min_mahalanobis
                ):
                    continue  # nearly true: not a false closure, draw again
            added.setdefault(kj, []).append(lc)
            break
        else:
            raise GraphSlamError(
                f"no false closure found in {MAX_DRAWS_PER_CLOSURE} draws "
                f"(min_mahalanobis={min_mahalanobis} too large?)"
            )
    for kj, lcs in added.items():
        frames[kj] = dataclasses.replace(
            frames[kj], loop_closures=tuple(frames[kj].loop_closures) + tuple(lcs)
        )
    return dataclasses.replace(dataset, frames=frames)
