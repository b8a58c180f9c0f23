"""The back-end contract shared by iSAM2, EKF-SLAM and FastSLAM (no gtsam here).

A back end is driven frame by frame::

    backend.initialize(first_pose_id, wTb0, covariance0)
    for frame in frames[1:]:
        backend.predict(frame.odometry, frame.pose_id)   # motion step adds a pose
        backend.update(frame.observations)               # observations at that pose
        for lc in frame.loop_closures:
            backend.add_loop_closure(lc)                 # or UnsupportedError
        for ps in frame.pose_sightings:
            backend.add_pose_sighting(ps)                # or UnsupportedError
    estimate = backend.finalize()

Back ends may defer work until an answer is asked for (iSAM2 batches one
``update`` per frame), so callers must not assume a call has been applied
before :meth:`Backend.estimate` or :meth:`Backend.predict_observations`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence

import numpy as np

from slamcore.errors import UnsupportedError
from slamcore.planar.records import (
    Estimate,
    LoopClosure,
    Observation,
    Odometry,
    PoseSighting,
    Prediction,
    SensorField,
)


class Backend(ABC):
    """Abstract SLAM back end. Subclasses set :attr:`name`."""

    #: Short name used on the command line and in reports.
    name: str = "backend"
    #: Whether :meth:`add_loop_closure` can use a relative-pose constraint.
    supports_loop_closures: bool = False
    #: Whether :meth:`add_pose_sighting` can use a pose-to-pose range and bearing.
    supports_pose_sightings: bool = False

    @abstractmethod
    def initialize(self, pose_id: int, wTb: np.ndarray, covariance: np.ndarray) -> None:
        """Anchor the first pose.

        Args:
            pose_id: id of the first pose.
            wTb: (3,) ``[x_m, y_m, theta_rad]``.
            covariance: (3, 3) prior covariance of ``[x, y, theta]`` in the world frame (as
                every covariance of a pose the back ends return).
        """

    @abstractmethod
    def predict(self, odometry: Odometry, pose_id: int) -> None:
        """Motion step: add pose ``pose_id`` linked to a known pose by ``odometry``.

        ``odometry`` connects ``pose_id`` with a pose the back end already has,
        in either direction (pose-graph files store some edges new->old).
        """

    @abstractmethod
    def update(self, observations: Sequence[Observation]) -> None:
        """Apply landmark observations taken at the current pose.

        Unknown landmarks are initialised from their first observation.
        """

    def set_robot_count(self, n_robots: int) -> None:  # noqa: B027
        """How many robots the run's data holds (1, or the ``agents`` of a run of
        several in one estimate); called before :meth:`initialize`.

        Only a back end whose state's sampling depends on it (FastSLAM keeps its
        particle count per robot) uses it; the others need nothing from it.
        """

    def set_sensor_field(self, sensor_field: SensorField | None) -> None:  # noqa: B027
        """Where the sensor reports landmarks and how reliably (the data's
        :class:`~slamcore.planar.records.SensorField`, None when unknown); kept across
        :meth:`initialize`.

        Only a back end that uses missed sightings (the EKF's pruning of landmarks
        it should have seen) keeps it; the others estimate from what was seen and
        need nothing from it.
        """

    def sensor_field_use(self) -> frozenset[str]:
        """What of the data's :class:`~slamcore.planar.records.SensorField` this back end,
        as configured, reads: ``"error_dof"`` (the error's tail, for the gates of unknown
        association) and ``"field"`` (range, field of view and detection probability, for
        pruning landmarks missed in view). Empty (the default): none of it; a data
        reader's settings of them then did nothing, and the CLI says so."""
        return frozenset()

    def reads_sighting_correlation(self) -> bool:
        """Whether this back end, as configured, weighs sightings by the correlation in
        time they state (``Observation.correlation``); False (the default): it takes
        them as independent, and a data reader's correlation settings did nothing."""
        return False

    def add_loop_closure(self, loop_closure: LoopClosure) -> None:
        """Add a relative-pose constraint between two known poses.

        Raises:
            UnsupportedError: back ends that close loops only by re-observing
                landmarks (the filters) say so here.
        """
        raise UnsupportedError(
            f"{self.name} cannot use relative-pose loop closures; it closes loops by re-observing landmarks"
        )

    def add_pose_sighting(self, sighting: PoseSighting) -> None:
        """Add a range and bearing from one known pose to another (several robots).

        Raises:
            UnsupportedError: back ends that keep one robot's pose (the EKF localiser on a saved map).
        """
        raise UnsupportedError(
            f"{self.name} keeps one robot's pose: it cannot use sightings of one robot by another"
        )

    @abstractmethod
    def predict_observations(self, landmark_ids: Iterable[int]) -> list[Prediction]:
        """Predicted measurement and innovation covariance from the current pose.

        Landmarks the back end does not know are skipped.
        """

    @abstractmethod
    def estimate(self, with_covariances: bool = False) -> Estimate:
        """Current belief. Covariances only when asked: they can be costly."""

    def associations(self) -> list[int | None]:
        """Landmark id given to each observation of the last :meth:`update` call.

        Same order as the observations; ``None`` where an observation was not
        used (gated out, or held on a provisional list). With known
        association these are the given ids; with unknown association they are
        the back end's own ids, which the pipeline scores against ground truth.
        """
        return list(self._last_associations)

    _last_associations: list[int | None] = []

    def final_associations(self) -> dict[tuple[int, int], int] | None:
        """The pairings the final estimate rests on, where the back end revised them
        after they were decided (merges, splits, re-association):
        ``(pose id, the observation's place in that update) -> landmark id`` of every
        observation in the estimate, in the estimate's own ids; observations absent
        were left unused. None (the default): the pairings stand as :meth:`associations`
        gave them."""
        return None

    def rejected_observations(self) -> int:
        """Observations of identified landmarks a gate rejected since initialisation (their
        innovation beyond what the estimate's covariance allows: not absorbed); 0 for
        back ends that gate none."""
        return 0

    def restarted_landmark_records(self) -> int:
        """Landmark estimates the back end started again from a sighting because its gate
        had held that landmark's sightings out for too long (FastSLAM 2.0's misread gate
        with known ids: one per particle and record); 0 for back ends that restart none."""
        return 0

    def pruned_landmark_ids(self) -> list[int]:
        """Ids of the landmarks removed from the map during the run (the pruning of
        landmarks missed in the sensor's field: the EKF's map, or every FastSLAM particle
        that held one); none by default."""
        return []

    def reassociation(self) -> tuple[int, bool] | None:
        """``(sightings moved, settled)`` of a re-association of the sightings at the end
        of the run (``settled`` False when its last pass still moved some); None (the
        default) where the back end has none or it did not run."""
        return None

    def finalize(self, with_covariances: bool = False) -> Estimate:
        """End of the run (e.g. a final batch polish); returns the final estimate."""
        return self.estimate(with_covariances=with_covariances)

    def current_pose(self) -> np.ndarray:
        """(3,) latest pose. Back ends with a cheap answer override this."""
        return self.estimate().current_pose

    def current_pose_covariance(self) -> np.ndarray | None:
        """(3, 3) covariance of the latest pose, or ``None`` if unavailable.

        Back ends with a cheap answer override this; the default asks for all
        covariances, which may be slow.
        """
        return self.estimate(with_covariances=True).current_covariance

    def landmark_covariances(self) -> np.ndarray | None:
        """(M, 2, 2) covariances of the estimate's landmarks, in its order, or ``None``.

        Back ends with a cheap answer override this; the default asks for all
        covariances, which may be slow.
        """
        return self.estimate(with_covariances=True).landmark_covariances

    def numerical_recoveries(self) -> list[str]:
        """Numerical fallbacks the back end took (e.g. another factorisation), one
        sentence each, so that the summary and ``metrics.json`` can say so."""
        return []
