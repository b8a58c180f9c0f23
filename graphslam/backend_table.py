"""The one table of back ends: what each is called, on which data it runs and what it
accepts. Every layer asks this table (through :mod:`graphslam.registry`) instead of
comparing back-end names, so a new back end is one row here plus its modules.

A back end has up to three implementations, one per kind of data:

- ``landmarks``: 2-D streams (synthetic worlds, MRCLAM, Victoria Park, 2-D pose-graph
  files streamed frame by frame), :class:`slamcore.planar.backend.Backend`;
- ``images``: image sequences (3-D), :class:`slamcore.spatial.backend.VisualBackend`;
- ``pose_graph``: whole pose-graph files (2-D and 3-D), solved by
  :mod:`graphslam.backends.posegraph` under the back end's name.

Implementations are named as ``"module:attribute"`` strings and imported only when
used: building the command-line parser imports no gtsam.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any


def load(ref: str) -> Any:
    """The object a ``"module:attribute"`` reference names (imported now)."""
    module, _, attribute = ref.partition(":")
    return getattr(importlib.import_module(module), attribute)


@dataclass(frozen=True)
class Implementation:
    """One back end on one kind of data.

    Attributes:
        backend: ``"module:Class"`` of the back end; built as ``Class(config)``.
        config: ``"module:Class"`` of its configuration dataclass (its ``SECTION``
            is the config-file section it reads).
        fixed: overrides the name itself implies (``fastslam2``: ``version = 2``),
            applied over the file and the caller's overrides.
        seeded: it draws random numbers, so ``--seed`` reaches it (as ``seed``).
        localiser: ``"module:Class"`` of its localisation-only variant on a fixed
            2-D map (``graphslam run --map``), built as
            ``Class(ids, landmarks_w, landmark_cov, config)``; None when it has none.
        filtering: a filter: its pose covariance exists only at the time and is
            kept frame by frame; a smoother's comes from its marginals afterwards. It
            keeps only each robot's latest pose, so every odometry step must extend
            one: a run checks the whole chain first (``planar.run(chained=)``).
        run_overrides: ``"module:function"`` turning a visual run's situation
            ``(odometry mode, seed, no_polish, nearest_depth_m)`` into overrides of
            its config section; None when a run implies none.
        ranges: it takes range-only observations (beacons: the Plaza logs) beside
            range and bearing.
        sample_covariance: its pose covariance is the spread of its samples
            (particles), which resampling shrinks below the error (measured: 13 to
            1e22 of its sigmas from iSAM2 on sound runs), so no test of its estimate
            against its own covariance holds.
    """

    backend: str
    config: str
    fixed: dict = field(default_factory=dict)
    seeded: bool = False
    localiser: str | None = None
    filtering: bool = False
    run_overrides: str | None = None
    ranges: bool = False
    sample_covariance: bool = False


@dataclass(frozen=True)
class BackendDescriptor:
    """A back end: its name and what it runs on (module docstring).

    Attributes:
        name: the name on the command line and in every output.
        landmarks: its 2-D streaming implementation, or None.
        images: its image-sequence implementation, or None.
        pose_graph: it solves whole pose-graph files.
        streams: it runs frame by frame; False for solvers that only take a whole
            pose-graph file (``batch``, ``auto``).
        polish: it ends with a batch polish that ``--no-polish`` turns off (on
            every kind of data it runs on).
        reference: ``graphslam compare`` measures the others' distance to it.
        pose_graph_unread: the ``[posegraph]`` keys its whole-file solve never reads
            (iSAM2's under ``batch``), said as doing nothing when a file sets them.
    """

    name: str
    landmarks: Implementation | None = None
    images: Implementation | None = None
    pose_graph: bool = False
    streams: bool = True
    polish: bool = False
    reference: bool = False
    pose_graph_unread: tuple[str, ...] = ()


_ISAM2_CONFIG = "graphslam.backends.planar.isam2_config:Isam2Config"
_EKF_CONFIG = "filters.ekf_slam_config:EkfSlamConfig"
_FASTSLAM = "filters.fastslam:FastSlam"
_FASTSLAM_CONFIG = "filters.fastslam_config:FastSlamConfig"


def _fastslam(version: int) -> Implementation:
    """FastSLAM ``version``: particles (seeded; a sample covariance), a filter."""
    return Implementation(
        _FASTSLAM,
        _FASTSLAM_CONFIG,
        fixed={"version": version},
        seeded=True,
        filtering=True,
        sample_covariance=True,
    )


#: Every back end, in the order the command line lists them.
TABLE: tuple[BackendDescriptor, ...] = (
    BackendDescriptor(
        "isam2",
        landmarks=Implementation(
            "graphslam.backends.planar.isam2:Isam2Backend",
            _ISAM2_CONFIG,
            localiser="graphslam.backends.planar.isam2_localise:Isam2Localiser",
            ranges=True,
        ),
        images=Implementation(
            "graphslam.backends.spatial.isam2:VisualIsam2Backend",
            "graphslam.backends.spatial.isam2_config:VisualIsam2Config",
            run_overrides="graphslam.backends.spatial.isam2_config:run_overrides",
        ),
        pose_graph=True,
        polish=True,
        reference=True,
    ),
    BackendDescriptor(
        "ekf",
        landmarks=Implementation(
            "filters.ekf_slam:EkfSlam",
            _EKF_CONFIG,
            filtering=True,
            localiser="filters.ekf_localise:EkfLocaliser",
        ),
        # the monocular EKF draws its one-point RANSAC's hypotheses (when it has more
        # measurements than it tries: MonoEkfConfig.why_no_draws)
        images=Implementation(
            "filters.mono_ekf:MonoEkf",
            "filters.mono_ekf_config:MonoEkfConfig",
            seeded=True,
            filtering=True,
            run_overrides="filters.mono_ekf_config:run_overrides",
        ),
    ),
    BackendDescriptor("fastslam1", landmarks=_fastslam(1)),
    BackendDescriptor("fastslam2", landmarks=_fastslam(2)),
    BackendDescriptor(
        "batch",
        pose_graph=True,
        streams=False,
        pose_graph_unread=("relinearize_threshold", "relinearize_skip", "polish"),
    ),
    BackendDescriptor("auto", pose_graph=True, streams=False),
)

#: ``graphslam compare`` entries on image sequences -> (back end, its config overrides):
#: the monocular EKF once per landmark parametrisation.
VISUAL_COMPARE_BACKENDS: dict[str, tuple[str, dict]] = {
    "isam2": ("isam2", {}),
    "ekf-idp": ("ekf", {"landmark_param": "idp"}),
    "ekf-ahp": ("ekf", {"landmark_param": "ahp"}),
}

#: What ``graphslam run`` uses when ``--backend`` is not given: a whole pose-graph
#: file takes the checked route between batch and iSAM2, any stream iSAM2.
DEFAULT_BACKEND = "isam2"
DEFAULT_POSE_GRAPH_BACKEND = "auto"


def descriptor(name: str) -> BackendDescriptor | None:
    """The table's row for ``name``, or None."""
    return next((d for d in TABLE if d.name == name), None)
