"""Sightings whose errors are correlated in time: the information one more sighting of
the same landmark carries.

A back end that takes every sighting as independent learns a landmark N times
faster than it should when consecutive sightings repeat the same error. On real
cameras they do: on UTIAS MRCLAM Dataset 6 (``benchmarks/calibrate_mrclam.py``)
the range errors of two sightings of one landmark from one robot correlate 0.97
within 0.3 s, 0.54 at 3-4 s and 0.21 at 8-12 s, whether the robot moved between
them or not (0.16 at the same spot after 16 s): the error lives in time, not in
the viewpoint. A landmark fused from 50 sightings of one second is then believed
to 1-2 cm while its estimate is 5 cm off, its gate shrinks below its error, and
with unknown ids the next sighting starts a second landmark.

Model: a share ``c`` of a component's error variance is an exponentially
correlated process of time constant ``tau`` (correlation ``c exp(-dt / tau)``
between sightings ``dt`` apart), the rest white. The mean of N sightings of such
a process, ``rho = exp(-dt / tau)`` apart, has the variance of N independent ones
times ``1 + 2 c rho / (1 - rho)`` (the AR(1) variance factor, for large N), so each
sighting of a landmark is given its covariance times that factor, with ``dt`` the
time since the previous sighting of the *same* landmark (as the back end
associated it): the first sighting, and one after a long gap, keep their own
covariance; a burst carries about what one sighting carries per ``tau``. This is
the covariance inflation of correlated measurements (Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001,
sec. 8.3), chosen over augmenting the state with one error process per landmark
because it keeps the back ends' state and costs nothing per step.

Who uses it: readers put the model and the time stamp on each
:class:`~slamcore.planar.records.Observation` (the MRCLAM reader, fitted by
``benchmarks/calibrate_mrclam.py``); the 2-D iSAM2 and the EKF weigh each sighting
by it through a :class:`LastSightings` of their own, keyed by the landmark they
associated it with (so it works with unknown ids too). FastSLAM uses it in its
particles' weights only (:meth:`SightingCorrelation.weight_share`, through
:func:`filters.fastslam_update.weight_shares`): a burst of sightings is one piece of
evidence for a path, not one per sighting. Its landmark EKFs and 2.0's proposal keep
the stated noise: inflated there too, its known-id ATE on MRCLAM Dataset 6 rose on four
robots of five (FastSLAM 2.0: 0.14-0.26 m to 0.25-0.42 m), the weaker sightings leaving
the paths to the odometry. In the weights alone, FastSLAM 2.0's median ATE over seeds
0-19 went from 0.170/0.305/0.195/0.185/0.270 m to 0.133/0.147/0.153/0.197/0.226 m with
known ids and from 0.160/0.480/0.450/0.380/0.210 m to 0.151/0.252/0.169/0.239/0.172 m
with unknown ids on robots 1-5 (``[fastslam] temper_correlated``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Protocol, TypeVar

import numpy as np

from slamcore.errors import ConfigError

#: Largest inflation factor: two sightings at one time stamp (rho = 1) are one.
MAX_INFLATION = 1e6


@dataclass(frozen=True)
class SightingCorrelation:
    """Time-correlated part of a range-bearing sensor's error (module docstring).

    Attributes:
        time_constant_s: ``tau``, s (> 0).
        range_share: share of the range error's variance that is correlated, in [0, 1].
        bearing_share: the same for the bearing.
        sensor: which sensor (sightings by two sensors are not correlated: two
            robots' cameras).
    """

    time_constant_s: float
    range_share: float
    bearing_share: float
    sensor: int = 0

    def __post_init__(self):
        if not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0.0):
            raise ConfigError(
                f"sighting correlation: time constant must be > 0 s, got {self.time_constant_s}"
            )
        for name in ("range_share", "bearing_share"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"sighting correlation: {name} must be in [0, 1], got {v}")

    def factors(self, dt_s: float) -> tuple[float, float]:
        """Variance factors (range, bearing) of a sighting ``dt_s`` from the previous one
        of its landmark (``inf``: none before)."""
        if not abs(dt_s) < math.inf:
            return 1.0, 1.0
        rho = math.exp(-abs(dt_s) / self.time_constant_s)
        gain = 2.0 * rho / (1.0 - rho) if rho < 1.0 else MAX_INFLATION
        return (
            min(1.0 + self.range_share * gain, MAX_INFLATION),
            min(1.0 + self.bearing_share * gain, MAX_INFLATION),
        )

    def weight_share(self, dt_s: np.ndarray) -> np.ndarray:
        """Share of a sighting's log-likelihood that is new information, for sightings
        ``dt_s`` (any shape, s; ``inf``: none before) from the previous one of their
        landmark: ``1 / sqrt(f_r f_b)`` of :meth:`factors`, the likelihood tempered as
        if its covariance were inflated by the geometric mean of the two factors (the
        same determinant). In (0, 1]; 1 for a first sighting or one after a long gap."""
        dt = np.abs(np.asarray(dt_s, dtype=np.float64))
        with np.errstate(over="ignore", divide="ignore"):
            rho = np.exp(-dt / self.time_constant_s)
            gain = np.minimum(np.where(rho < 1.0, 2.0 * rho / (1.0 - rho), MAX_INFLATION), MAX_INFLATION)
        fr = np.minimum(1.0 + self.range_share * gain, MAX_INFLATION)
        fb = np.minimum(1.0 + self.bearing_share * gain, MAX_INFLATION)
        return 1.0 / np.sqrt(fr * fb)

    def covariance(self, covariance: np.ndarray, dt_s: float) -> np.ndarray:
        """``covariance`` (2, 2) ``[range, bearing]`` inflated for a sighting ``dt_s`` from
        the previous one of its landmark."""
        fr, fb = self.factors(dt_s)
        s = np.sqrt([fr, fb])
        return np.asarray(covariance, dtype=np.float64) * np.outer(s, s)


class TimedSighting(Protocol):
    """What :class:`LastSightings` reads of a sighting (a
    :class:`~slamcore.planar.records.Observation`, which imports this module)."""

    @property
    def covariance(self) -> np.ndarray: ...
    @property
    def stamp_s(self) -> float | None: ...
    @property
    def correlation(self) -> SightingCorrelation | None: ...


#: A dataclass sighting (an Observation): ``dataclasses.replace`` cannot be typed on a Protocol.
Sighting = TypeVar("Sighting", bound=Any)


class LastSightings:
    """When each landmark was last sighted by each sensor, and the covariance a new
    sighting gets (a part each back end owns; landmark ids as the back end assigned them)."""

    def __init__(self) -> None:
        self._last: dict[tuple[int, int], float] = {}

    def covariance(self, obs: TimedSighting, landmark_id: int, *, record: bool = True) -> np.ndarray:
        """The covariance ``obs`` (a sighting of ``landmark_id``) is weighed with, recorded
        as that landmark's latest sighting (with ``record``; else :meth:`record` once the
        back end has used it); its own without a correlation or a time."""
        model = obs.correlation
        if model is None or obs.stamp_s is None:
            return obs.covariance
        prev = self._last.get((model.sensor, int(landmark_id)))
        if record:
            self.record(obs, landmark_id)
        return model.covariance(obs.covariance, math.inf if prev is None else obs.stamp_s - prev)

    def record(self, obs: TimedSighting, landmark_id: int) -> None:
        """``obs`` is the latest sighting of ``landmark_id`` used (no-op without a time)."""
        model = obs.correlation
        if model is None or obs.stamp_s is None:
            return
        key = (model.sensor, int(landmark_id))
        prev = self._last.get(key)
        self._last[key] = obs.stamp_s if prev is None else max(prev, obs.stamp_s)

    def observation(self, obs: Sighting, landmark_id: int) -> Sighting:
        """``obs`` with the covariance of :meth:`covariance`."""
        cov = self.covariance(obs, landmark_id)
        return obs if cov is obs.covariance else replace(obs, covariance=cov)

    def merged(self, keep: int, drop: int) -> None:
        """Landmark ``drop`` became ``keep``: per sensor, the later last sighting is ``keep``'s."""
        for sensor, lid in [k for k in self._last if k[1] == drop]:
            t = self._last.pop((sensor, lid))
            self._last[(sensor, keep)] = max(t, self._last.get((sensor, keep), t))
