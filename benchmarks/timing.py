"""One way to time ours against its floor, shared by every benchmark (issue 20 item 1).

A ratio is only honest when ours and the floor are timed the same way: in the
same process, alternated repeat by repeat (so a burst of load on the shared
machine hits both), after a warm-up, with the same BLAS thread count, and
summarised by the median of the repeats (never the best of them, which
flatters whichever side has the longer tail). :func:`alternate` does exactly
that; :func:`summary` is the record every benchmark writes into its JSON under
``"summary"`` so ``benchmarks/table.py`` can rebuild the README table from the
results alone.

Targets are the team's (``TARGETS``): ours at most this many times the floor.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import asdict, dataclass
from typing import Callable, Iterator, Mapping

import numpy as np

#: Team targets: ours / floor at most this (issue 20 item 1; issue 17 item 5).
TARGETS = {"isam2": 1.1, "ekf": 1.2, "harris": 1.2, "orb": 1.1, "fastslam": 1.3}


@dataclass(frozen=True)
class Timing:
    """Seconds per call of one candidate over the alternated repeats."""

    median_s: float
    p25_s: float
    p75_s: float
    samples_s: tuple[float, ...]


def alternate(candidates: Mapping[str, Callable[[], object]], repeats: int, *,
              warmup: int = 1, setup: Mapping[str, Callable[[], object]] | None = None,
              number: int = 1, clock: Callable[[], float] = time.perf_counter
              ) -> dict[str, Timing]:
    """Time each candidate ``repeats`` times, interleaved, and return the medians.

    Repeat ``r`` runs every candidate once, starting with candidate ``r mod k``
    (so none is always first after the others warmed the caches). ``setup[name]``
    runs untimed before each timed call (fresh inputs for a call that consumes
    them). ``number`` calls are timed together and divided, for calls too short
    for the clock. Every candidate is called ``warmup`` times first.
    """
    if repeats < 1 or number < 1:
        raise ValueError("repeats and number must be at least 1")
    names = list(candidates)
    setup = dict(setup or {})
    for name in names:
        for _ in range(warmup):
            if name in setup:
                setup[name]()
            candidates[name]()
    samples: dict[str, list[float]] = {name: [] for name in names}
    for r in range(repeats):
        k = r % len(names)
        for name in names[k:] + names[:k]:
            samples[name].append(_time_once(candidates[name], setup.get(name), number, clock))
    return {name: _summarise(s) for name, s in samples.items()}


def _time_once(fn: Callable[[], object], setup: Callable[[], object] | None, number: int,
               clock: Callable[[], float]) -> float:
    total = 0.0
    for _ in range(number):
        if setup is not None:
            setup()
        t0 = clock()
        fn()
        total += clock() - t0
    return total / number


def _summarise(samples: list[float]) -> Timing:
    a = np.asarray(samples)
    return Timing(float(np.median(a)), float(np.percentile(a, 25)), float(np.percentile(a, 75)),
                  tuple(float(s) for s in samples))


@contextlib.contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """Pin the BLAS/OpenMP pools to ``n`` threads for ours and the floor alike.

    ``None`` leaves them as they are. One thread is the default of the speed
    benchmarks: on a shared 2-core machine a second BLAS thread makes both
    sides swing with the neighbours' load rather than with the code.
    """
    if n is None:
        yield
        return
    from threadpoolctl import threadpool_limits  # ships with scikit-learn

    with threadpool_limits(limits=n):
        yield


def summary(name: str, ours_s: float, floor_s: float, *, target: float | None, floor: str,
            command: str, unit: str = "s", **extra: object) -> dict:
    """The record a benchmark writes under ``"summary"`` (one row of the README table).

    ``floor`` says in words what the floor is (what a user would otherwise
    run); ``command`` is the command that produced the figure; ``target`` is
    the team's maximum ratio (None when the benchmark has no ratio target).
    Extra keys (sizes, the worst case's parameters) are kept as given.
    """
    ratio = ours_s / floor_s if floor_s > 0 else float("inf")
    rec = {"name": name, "ours": ours_s, "floor_value": floor_s, "unit": unit, "ratio": ratio,
           "target": target, "meets_target": None if target is None else bool(ratio <= target),
           "floor": floor, "command": command}
    rec.update(extra)
    return rec


def timing_dict(t: Timing) -> dict:
    """A :class:`Timing` as plain JSON (samples included, for re-analysis)."""
    return asdict(t)
