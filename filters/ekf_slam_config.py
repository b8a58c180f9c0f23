"""Settings of the 2-D EKF-SLAM (:class:`filters.ekf_slam.EkfSlam`), checked on creation.

Section ``[ekf]`` of the config file; a bad value raises
:class:`slamcore.errors.ConfigError` naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from slamcore.errors import ConfigError


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


@dataclass(frozen=True)
class EkfSlamConfig:
    """EKF-SLAM settings (config file section ``[ekf]``).

    Attributes:
        association: "known" (landmark_id, else signature) or "unknown"
            (gating + JCBB; the given ids are ignored).
        gate_chi2_prob: individual and joint compatibility probability.
            0.999 by default: at 0.99, 1 % of the true pairings fall outside
            the gate by construction.
        new_landmark_chi2_prob: an unpaired observation starts a landmark only
            if its squared Mahalanobis distance to every landmark exceeds this
            chi-square (2 dof) quantile; must be >= ``gate_chi2_prob``.
            Default equal to the gate (0.999): no discard zone, since a
            discarded observation is a lost one, while a landmark started
            twice is counted (``duplicates`` in the association report).
            Measured on the default synthetic world (course noise, seeds
            0-4): 96.9/89.3/97.6/91.5/97.8 % accuracy, against
            96.9/86.4/97.1/90.4/97.7 % with 0.9999.
        provisional_sightings: sightings before a landmark enters the map
            (1 = at first sighting).
        initial_capacity: landmarks the buffers hold before the first doubling.
        jcbb_max_candidates: individually compatible landmarks kept per observation.
        jcbb_max_nodes: pairing tests JCBB may do per scan.
        jacobians: "oc" (observability-constrained, default) or "standard".
        default_sigma_range_m, default_sigma_bearing_rad: measurement noise used
            by :meth:`~filters.ekf_slam.EkfSlam.predict_observations` before any
            observation is seen.
        odometry_covariance_scale: the odometry covariance is multiplied by
            this in :meth:`~filters.ekf_slam.EkfSlam.predict` (> 0). The filter assumes white
            odometry noise; real odometry errors are correlated (a slowly
            varying heading bias on Victoria Park), so over the steps between
            two sightings they grow faster than the file's per-step covariance
            says, and an unscaled filter trusts its drifted pose too much.
        known_gate_chi2_prob: known association only: an observation whose
            innovation's squared Mahalanobis distance (2 dof) exceeds this
            chi-square quantile is rejected (not absorbed, counted in
            :attr:`~filters.ekf_slam.EkfSlam.rejected_count`, reported as None by
            :meth:`~filters.ekf_slam.EkfSlam.associations`). A given id does not make a
            measurement right: one spurious range-bearing pair absorbed
            with full trust corrupts the pose and the map. None (default)
            absorbs every identified observation.
    """

    SECTION: ClassVar[str] = "ekf"

    association: str = "known"
    gate_chi2_prob: float = 0.999
    new_landmark_chi2_prob: float = 0.999
    provisional_sightings: int = 1
    initial_capacity: int = 64
    jcbb_max_candidates: int = 3
    jcbb_max_nodes: int = 2000
    default_sigma_range_m: float = 0.2
    default_sigma_bearing_rad: float = math.radians(10.0)
    jacobians: str = "oc"
    odometry_covariance_scale: float = 1.0
    known_gate_chi2_prob: float | None = None

    def __post_init__(self):
        if self.jacobians not in ("standard", "oc"):
            raise ConfigError(f"ekf.jacobians must be 'standard' or 'oc', got {self.jacobians!r}")
        if self.association not in ("known", "unknown"):
            raise ConfigError(f"ekf.association must be 'known' or 'unknown', got {self.association!r}")
        for name in ("gate_chi2_prob", "new_landmark_chi2_prob"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < float(v) < 1.0:
                raise ConfigError(f"ekf.{name} must be a probability in (0, 1), got {v!r}")
        if self.new_landmark_chi2_prob < self.gate_chi2_prob:
            raise ConfigError("ekf.new_landmark_chi2_prob must be >= ekf.gate_chi2_prob "
                              f"({self.new_landmark_chi2_prob} < {self.gate_chi2_prob})")
        for name, lo in (("provisional_sightings", 1), ("initial_capacity", 1),
                         ("jcbb_max_candidates", 1), ("jcbb_max_nodes", 0)):
            v = getattr(self, name)
            if not _is_int(v) or v < lo:
                raise ConfigError(f"ekf.{name} must be an integer >= {lo}, got {v!r}")
        for name in ("default_sigma_range_m", "default_sigma_bearing_rad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ConfigError(f"ekf.{name} must be a positive number, got {v!r}")
        v = self.odometry_covariance_scale
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise ConfigError(f"ekf.odometry_covariance_scale must be a positive number, got {v!r}")
        v = self.known_gate_chi2_prob
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not 0.0 < float(v) < 1.0):
            raise ConfigError("ekf.known_gate_chi2_prob must be None or a probability in (0, 1), "
                              f"got {v!r}")
