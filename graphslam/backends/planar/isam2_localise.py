"""iSAM2 localisation against a fixed 2-D landmark map (``graphslam run --map DIR``).

The smoother of :class:`~graphslam.backends.planar.isam2.Isam2Backend` (same
odometry, prior, loop closures, polish) with the map's landmarks as
*constants*: a map landmark enters the graph, when first seen, as a variable
held by ``gtsam.NonlinearEqualityPoint2`` at its saved position (a hard
constraint: iSAM2 and the LM polish eliminate it exactly, so it never moves),
and each observation of it is the usual ``BearingRangeFactor2D``.

Why constants rather than landmark variables with priors of their saved
covariance: with priors, every re-observation would pull the landmarks, i.e.
the run would be SLAM seeded with a map, not localisation, and the map would
drift towards this run's noise; a localisation-only run must leave the map as
it was given. The map's uncertainty is not thrown away: each observation's
noise is ``R + H_m C H_m^T`` (``C`` the landmark's saved 2x2 covariance,
``H_m`` the measurement Jacobian at the pose's initial value), the landmark
marginalised into the factor. Repeated sightings of one landmark then count its
error as independent each time (optimistic where a landmark is seen for long);
the EKF localiser (:mod:`filters.ekf_localise`) carries that correlation.

Observations of landmarks not in the map, or without an id, are not used
(``None`` in :meth:`associations`, counted in ``unmapped_count``); no landmark is
added. The estimate's landmarks are the map's, those in the graph read back
from the solution (so that a moved constant would show).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from graphslam.backends import gtsam_convert as conv
from graphslam.backends.planar.isam2 import Isam2Backend
from graphslam.backends.planar.isam2_config import Isam2Config
from slamcore.errors import ConfigError, GraphSlamError, UnsupportedError
from slamcore.planar import geometry as models
from slamcore.planar.records import Estimate, Observation, ObservationKind, Prediction


class Isam2Localiser(Isam2Backend):
    """iSAM2 on a fixed landmark map (module docstring).

    Args:
        landmark_ids: (M,) map landmark ids; landmarks_w: (M, 2) metres;
            landmark_cov: (M, 2, 2) m^2.
        config: the ``[isam2]`` section.
    """

    name = "isam2"

    def __init__(self, landmark_ids, landmarks_w, landmark_cov, config: Isam2Config | None = None):
        super().__init__(config)
        if self.config.association != "known":  # ran by id anyway, and its metrics counted none used
            raise ConfigError(
                "isam2: localisation against a map associates by landmark id; "
                '[isam2] association = "unknown" is not supported with --map'
            )
        self._map_ids = np.asarray(landmark_ids, dtype=np.int64).copy()
        self._map_xy = np.asarray(landmarks_w, dtype=np.float64).reshape(-1, 2).copy()
        self._map_cov = np.asarray(landmark_cov, dtype=np.float64).reshape(-1, 2, 2).copy()
        self._map_slot = {int(i): k for k, i in enumerate(self._map_ids)}
        self._constants: set[int] = set()  # map landmarks already in the graph
        #: Observations of landmarks not in the map (or without an id): not used.
        self.unmapped_count = 0

    def update(self, observations: Sequence[Observation]) -> None:
        if any(o.kind is not ObservationKind.RANGE_BEARING for o in observations):
            # a range-only log's map was refused as "covariance must be 1x1" of one
            # observation, as if the file were bad
            raise UnsupportedError(
                "isam2: localising against a map takes range-bearing sightings; got "
                f"{next(o.kind.value for o in observations if o.kind is not ObservationKind.RANGE_BEARING)} "
                "ones (range-only data runs without a map)"
            )
        assoc: list[int | None] = []
        for obs in observations:
            slot = None if obs.landmark_id is None else self._map_slot.get(int(obs.landmark_id))
            if slot is None or obs.landmark_id is None:  # no id: no slot either
                self.unmapped_count += 1
                assoc.append(None)
                continue
            if obs.pose_id not in self._pose_set:
                raise GraphSlamError(f"isam2: observation from unknown pose {obs.pose_id}")
            lid = int(obs.landmark_id)
            point = self._map_xy[slot]
            if lid not in self._constants:
                self._values.insert(L(lid), point)
                self._graph.add(gtsam.NonlinearEqualityPoint2(L(lid), point))
                self._constants.add(lid)
            wTb = conv.pose2_vector(self._pose(obs.pose_id))
            _, H_m = models.observe_jacobians(wTb, point)
            R = obs.covariance + H_m @ self._map_cov[slot] @ H_m.T
            # under the SLAM run's robust kernel: without it one misread sighting of a map
            # landmark pulled the smoothed poses metres (hostile pass 24: MRCLAM robot 3 on
            # an all-robots map, 2.7 m at step 700) and [isam2] observation_kernel did nothing
            self._graph.add(
                conv.bearing_range_factor(
                    dataclasses.replace(obs, covariance=0.5 * (R + R.T)),
                    lid,
                    self.config.observation_kernel,
                    self.config.observation_kernel_k,
                )
            )
            self._measurement_cov[lid] = obs.covariance
            assoc.append(lid)
        self._last_associations = assoc

    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        """``S = H_x P_x H_x^T + H_m C H_m^T + R``: the pose's marginal and the map's covariance."""
        wanted = [int(i) for i in landmark_ids if int(i) in self._map_slot]
        if not self._pose_ids or not wanted:
            return []
        wTb = self.current_pose()
        P_x = self.current_pose_covariance()
        out = []
        for lid in wanted:
            slot = self._map_slot[lid]
            H_x, H_m = models.observe_jacobians(wTb, self._map_xy[slot])
            R = self._measurement_cov.get(lid, np.zeros((2, 2)))
            S = H_x @ P_x @ H_x.T + H_m @ self._map_cov[slot] @ H_m.T + R
            out.append(Prediction(lid, models.observe(wTb, self._map_xy[slot]), 0.5 * (S + S.T)))
        return out

    def estimate(self, with_covariances: bool = False) -> Estimate:
        values = self._values_now()
        est = conv.values_to_estimate(values, self._pose_ids, ())
        landmarks = self._map_xy.copy()
        for lid in self._constants:
            landmarks[self._map_slot[lid]] = values.atPoint2(L(lid))
        pcov = lcov = None
        if with_covariances:
            marginals = self._marginals(values)
            pcov = np.array(
                [
                    conv.pose2_covariance_from_gtsam(theta, marginals.marginalCovariance(X(i)))
                    for i, theta in zip(self._pose_ids, est.wTb[:, 2], strict=True)
                ]
            ).reshape(-1, 3, 3)
            lcov = self._map_cov.copy()
        return Estimate(est.pose_ids, est.wTb, self._map_ids.copy(), landmarks, pcov, lcov)
