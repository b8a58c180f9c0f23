"""Names on the command line -> datasets and back ends (imports are lazy).

What a back end is and accepts comes from one table, :mod:`graphslam.backend_table`;
the lists and factories here are read from it, and callers ask them rather than
compare names.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from graphslam.backend_table import (
    DEFAULT_BACKEND,
    DEFAULT_POSE_GRAPH_BACKEND,
    TABLE,
    VISUAL_COMPARE_BACKENDS,
    BackendDescriptor,
    Implementation,
    descriptor,
    load,
)
from slamcore.config import ConfigFile, load_section, section_name
from slamcore.errors import ConfigError, GraphSlamError, InputError, quote
from slamcore.input_files import check_input_path
from slamcore.planar.backend import Backend
from slamcore.planar.records import Dataset

if TYPE_CHECKING:
    from filters.ekf_localise import EkfLocaliser
    from filters.mono_ekf_config import MonoEkfConfig
    from graphslam.backends.planar.isam2_localise import Isam2Localiser
    from graphslam.backends.spatial.isam2_config import VisualIsam2Config

#: A parsed config file, a path to one, or None (defaults only).
ConfigSource = ConfigFile | str | Path | None

#: Every section a config file may hold (``tests/repo/test_config_sections.py`` checks
#: this list against the ``SECTION`` of every config dataclass in the tree).
CONFIG_SECTIONS = (
    "synthetic",
    "isam2",
    "ekf",
    "fastslam",  # 2-D worlds and back ends
    "mrclam",  # the UTIAS MRCLAM logs (robot, sensor calibration)
    "synthetic_images",
    "visual",
    "odometry_noise",
    "tracker",
    "active_search",
    "harris",
    "orb",
    "isam2_visual",
    "mono_ekf",  # image sequences
    "loops",
    "loop_verify",
    "loop_pnp",
    "loop_closing",  # place recognition
    "posegraph",  # pose-graph files (g2o, TORO; 2-D and 3-D)
    "localize",
    "relocalise",  # saved maps, tracking loss
)


def read_config(path: str | Path | None) -> ConfigFile:
    """Parse ``--config`` once for the whole run; refuse sections nothing reads."""
    config = ConfigFile.read(path)
    config.check_sections(CONFIG_SECTIONS)
    return config


#: Built-in datasets; anything else is taken as a pose-graph file path.
DATASETS = ("synthetic", "victoria-park", "city10000", "w10000", "plaza1", "plaza2")
#: Every back end's name, in the table's order.
BACKEND_NAMES = tuple(d.name for d in TABLE)
#: Back ends that stream 2-D data (landmark logs, synthetic worlds, 2-D graphs frame by frame).
BACKENDS = tuple(d.name for d in TABLE if d.landmarks is not None)
#: Back ends that solve whole pose-graph files (2-D and 3-D).
POSEGRAPH_BACKENDS = tuple(d.name for d in TABLE if d.pose_graph)
#: Solvers that take a whole pose-graph file only (no stream).
WHOLE_GRAPH_BACKENDS = tuple(d.name for d in TABLE if d.pose_graph and not d.streams)
#: Back ends that localise against a fixed 2-D map (``graphslam run --map``).
LOCALISING_BACKENDS = tuple(
    d.name for d in TABLE if d.landmarks is not None and d.landmarks.localiser is not None
)
#: 2-D back ends whose configuration takes a ``seed``.
#: 2-D back ends that take range-only observations (the Plaza logs).
RANGE_BACKENDS = tuple(d.name for d in TABLE if d.landmarks is not None and d.landmarks.ranges)
SEEDED_BACKENDS = tuple(d.name for d in TABLE if d.landmarks is not None and d.landmarks.seeded)
#: Back ends ``graphslam run`` offers on image sequences.
VISUAL_BACKENDS = tuple(d.name for d in TABLE if d.images is not None)


def backend_row(name: str) -> BackendDescriptor:
    """The table's row of back end ``name``; ConfigError naming the known ones."""
    row = descriptor(name)
    if row is None:
        raise ConfigError(f"unknown back end {quote(name)} (available: {', '.join(BACKEND_NAMES)})")
    return row


#: Back ends with a final batch polish (``--no-polish``).
POLISHED_BACKENDS = tuple(d.name for d in TABLE if d.polish)


def check_no_polish(name: str) -> None:
    """``--no-polish`` on a back end without a polish is refused, one line."""
    if not backend_row(name).polish:
        raise ConfigError(
            f"--no-polish applies to the {' or '.join(POLISHED_BACKENDS)} back "
            f"end only (its final batch polish); {name} has none"
        )


def default_backend(spec: str) -> str:
    """``graphslam run --dataset spec`` without ``--backend``: the checked route for a
    pose-graph file (one a streaming back end also solves whole: no landmark lines),
    iSAM2 for everything else (built-in graphs, landmark files, logs, images)."""
    from graphslam.sources.builtin_posegraphs import is_builtin_pose_graph

    whole = not is_builtin_pose_graph(spec) and is_pose_graph_run(spec, DEFAULT_BACKEND)
    return DEFAULT_POSE_GRAPH_BACKEND if whole else DEFAULT_BACKEND


#: What each kind of implementation runs on, in messages.
_KIND_DATA = {"landmarks": "2-D data", "images": "image sequences"}


def _implementation(name: str, kind: str) -> Implementation:
    impl = getattr(backend_row(name), kind)
    if impl is None:
        data = _KIND_DATA[kind]
        available = [d.name for d in TABLE if getattr(d, kind) is not None]
        raise ConfigError(f"back end {name!r} does not run on {data} (available: {', '.join(available)})")
    return impl


def load_dataset(
    spec: str, *, seed: int | None = None, config: ConfigSource = None, robot: int | str | None = None
) -> Dataset:
    """Dataset by name, pose-graph file path (``.graph`` TORO, ``.g2o``; TORO ``BR`` lines
    are landmark observations), a landmark log in Victoria Park's format, an
    MRCLAM folder (``robot`` overrides ``[mrclam] robot``), or a Plaza range-only log
    (``plaza1``, ``plaza2`` from gtsam's wheel, a ``*_DR.txt`` file or its folder)."""
    if robot is not None and not is_mrclam_dataset(spec):
        raise ConfigError("--robot applies to MRCLAM folders only")
    if is_mrclam_dataset(spec):
        from graphslam.sources.planar.mrclam import MrclamConfig, read_mrclam

        check_input_path(Path(spec), "--dataset", folder_ok=True)
        overrides = (
            {}
            if robot is None
            else {"all_robots": True}
            if robot == "all"
            else {"robot": robot, "all_robots": False}
        )
        settings = load_section(MrclamConfig, config, overrides)
        if settings.all_robots:
            from graphslam.sources.planar.mrclam_joint import read_mrclam_all

            return read_mrclam_all(Path(spec), settings)
        return read_mrclam(spec, settings)
    if spec == "synthetic":
        from graphslam.sources.planar.synthetic import SyntheticConfig, make_synthetic

        world = make_synthetic(load_section(SyntheticConfig, config, {"seed": seed}))
        if isinstance(config, ConfigFile):  # the signatures are drawn, but no run reads one
            config.mark_inert(
                "synthetic",
                ("signature_count",),
                "observations without a landmark id (the Python API: every synthetic observation has one)",
            )
        return world
    if spec == "victoria-park":
        from graphslam.sources.planar.victoria_park import read_victoria_park, victoria_park_path

        return read_victoria_park(victoria_park_path())
    if spec in ("plaza1", "plaza2") or is_plaza_dataset(spec):
        from graphslam.sources.planar.plaza import plaza_files, plaza_path, read_plaza

        path = plaza_path(int(spec[-1])) if spec in DATASETS else Path(spec)
        check_input_path(path, "--dataset", folder_ok=True)
        files = plaza_files(path)
        if files is None:
            from graphslam.sources.planar.plaza import plaza_folder_problem

            raise InputError(
                plaza_folder_problem(path) or "not a Plaza log: no *_DR.txt with its *_TD.txt", path
            )
        dr, td, _ = files
        return read_plaza(dr, td)
    if spec == "city10000":
        from graphslam.sources.planar.posegraph import read_city10000

        return read_city10000()
    if spec == "w10000":
        from graphslam.sources.planar.posegraph import read_w10000

        return read_w10000()
    check_dataset_named(spec)
    path = Path(spec)
    check_input_path(path, "--dataset")
    from graphslam.sources.planar.posegraph import read_pose_graph
    from graphslam.sources.posegraph_files import TAGS, first_tag

    tag = first_tag(path)
    if tag in ("ODOMETRY", "LANDMARK"):  # a landmark log in Victoria Park's format
        from graphslam.sources.planar.victoria_park import read_victoria_park

        return read_victoria_park(path, name=path.stem)
    if tag is not None and tag in TAGS and TAGS[tag][1] == 3:
        raise ConfigError(f"{path} is a 3-D pose graph: run it with --backend isam2 or batch")
    # the [posegraph] reading of the file's numbers holds for every back end
    settings = pose_graph_config(config)
    return read_pose_graph(path, settings.toro_noise, settings.information_fix)


def is_builtin_dataset(spec: str) -> bool:
    """Whether ``spec`` names a built-in dataset (not a path)."""
    return spec in DATASETS or spec in VISUAL_DATASETS


def shadowed_dataset_name(spec) -> str | None:
    """The sentence when ``spec`` is both a built-in name and a file or folder here
    (hostile pass 18: which one was read was unsaid), else None. A built-in pose graph
    gives way to the file (a user's own ``w10000``), the other built-ins do not."""
    from graphslam.sources.builtin_posegraphs import BUILTIN_POSE_GRAPHS

    name = str(spec)
    if not (name in BUILTIN_POSE_GRAPHS or is_builtin_dataset(name)) or not Path(name).exists():
        return None
    if name in BUILTIN_POSE_GRAPHS:
        return f"{name} is read from the file of that name here, not the built-in graph {name}"
    return f"{name} is the built-in data set; the file of that name here is not read (give ./{name} for it)"


def no_such_dataset(shown: str = "") -> str:
    """The sentence for a dataset that is neither built in nor a file or folder
    (``shown``: its name, where the error does not already say it)."""
    named = f" {shown}" if shown else ""
    return f"no such dataset or file{named} (built-in datasets: {', '.join(DATASETS + VISUAL_DATASETS)})"


def check_dataset_named(spec: str) -> None:
    """InputError when ``spec`` is neither a built-in dataset nor an existing path (checked
    before the options that depend on the dataset, so a typo is named as one)."""
    if not (is_builtin_dataset(spec) or Path(spec).exists()):
        if Path(spec).is_symlink():  # "no such file" of a name that is there misleads
            raise InputError(
                "a symbolic link that resolves to nothing (its target is missing, the links loop, "
                "or the chain is too long)",
                Path(spec),
            )
        raise InputError(no_such_dataset(), Path(spec))
    refuse_part_of_a_log(spec)


def refuse_part_of_a_log(spec: str) -> None:
    """InputError when ``spec`` is one of a Plaza log's other files (``*_TD.txt``, ``*_.mat``):
    read as a file of its own it was "not a text file" or a Victoria Park line's "unknown
    tag" (tenth hostile pass); likewise one file of an MRCLAM folder (a pose graph's
    "unknown tag" at its first data line)."""
    from graphslam.sources.planar.mrclam import mrclam_part_of
    from graphslam.sources.planar.plaza import dr_of_part

    part = mrclam_part_of(spec)
    if part is not None:
        folder, robot = part
        robot_flag = f" --robot {robot}" if robot is not None else ""
        raise InputError(
            f"a file of the MRCLAM data set in {folder}: give --dataset {folder}{robot_flag}, "
            "which reads it with the others",
            Path(spec),
        )
    dr = dr_of_part(spec)
    if dr is not None:
        raise InputError(
            f"a file of the Plaza range-only log {dr.name}: give --dataset {dr.name} (or its folder), "
            "which reads it with the others",
            Path(spec),
        )


def is_pose_graph_run(spec: str, backend: str) -> bool:
    """Whether ``--dataset spec --backend backend`` is a pose-graph solve: a
    g2o/TORO file (not a built-in name) with a pose-graph back end. Filters on
    2-D pose-graph files still stream them frame by frame (odometry only). A TORO
    file with landmark lines (``BR``) runs as landmark SLAM with ``isam2``; a
    whole-graph solver (``batch``, ``auto``) is sent to the pose-graph reader,
    which refuses it at its first such line."""
    from graphslam.sources.builtin_posegraphs import is_builtin_pose_graph

    row = descriptor(backend)
    if is_builtin_pose_graph(spec) and row is not None and row.pose_graph and not row.streams:
        return True  # a built-in graph solved whole (streamed by the other back ends)
    if spec in DATASETS or backend not in POSEGRAPH_BACKENDS or not Path(spec).is_file():
        return False
    refuse_part_of_a_log(spec)
    if is_bag_dataset(spec):
        return False
    from graphslam.sources.posegraph_files import TAGS, first_tag, has_landmark_lines, is_pose_graph_tag

    whole_only = row is not None and not row.streams
    tag = first_tag(spec)
    if tag is None or not is_pose_graph_tag(tag):
        # a file a whole-graph solver was asked for goes to the pose-graph reader, whose
        # refusal says what the file is (compressed, empty, of another format) where
        # "--backend batch solves pose-graph files only" said nothing (hostile pass 17)
        return whole_only
    # only a 2-D TORO file can be landmark SLAM (BR lines, as gtsam.load2D reads them):
    # others are read once, by the pose-graph reader, which refuses a BR line
    fmt, dim = TAGS[tag][:2] if tag in TAGS else ("toro", 2)
    return whole_only or (fmt, dim) != ("toro", 2) or not has_landmark_lines(spec)


def has_pose_graph_tag(spec: str | Path) -> bool:
    """Whether the file ``spec`` begins with a g2o or TORO tag (False for a built-in
    name, a folder or a file that cannot be read)."""
    from graphslam.sources.posegraph_files import first_tag, is_pose_graph_tag

    try:
        return Path(spec).is_file() and is_pose_graph_tag(first_tag(spec))
    except (OSError, GraphSlamError):
        return False


def load_pose_graph(spec: str | Path, toro_noise: str = "auto", information_fix: str = "nearest"):
    """A g2o or TORO pose-graph file, 2-D or 3-D, or a built-in pose graph's name
    (``w10000``, ``city10000``), as a :class:`slamcore.posegraph.PoseGraph`
    (``information_fix``: what is done with information that is not positive definite)."""
    from graphslam.sources.builtin_posegraphs import builtin_pose_graph, is_builtin_pose_graph
    from graphslam.sources.posegraph_files import read_pose_graph_file

    if is_builtin_pose_graph(spec):
        return builtin_pose_graph(str(spec))[0]
    if Path(spec).exists():  # a missing file: the reader's own message
        check_input_path(spec, "pose-graph file")
    return read_pose_graph_file(spec, toro_noise, information_fix)


def pose_graph_config(config: ConfigSource = None, overrides: dict | None = None):
    """The pose-graph solver's settings, section ``[posegraph]``."""
    from graphslam.backends.posegraph.config import PoseGraphConfig

    return load_section(PoseGraphConfig, config, overrides)


def make_backend(name: str, *, config: ConfigSource = None, overrides: dict | None = None) -> Backend:
    """2-D back end by name, configured from the file's section plus ``overrides``
    (plus what the name itself fixes, e.g. FastSLAM's version)."""
    impl = landmark_implementation(name)
    return load(impl.backend)(_settings(name, impl, config, overrides))


def backend_settings(name: str, config: ConfigSource = None, overrides: dict | None = None):
    """The settings :func:`make_backend` gives the 2-D back end ``name``."""
    return _settings(name, landmark_implementation(name), config, overrides)


def make_localiser(
    name: str,
    landmark_ids,
    landmarks_w,
    landmark_cov,
    *,
    config: ConfigSource = None,
    overrides: dict | None = None,
) -> Isam2Localiser | EkfLocaliser:
    """Localisation-only back end by name on a fixed landmark map ((M,) ids, (M, 2)
    positions, (M, 2, 2) covariances), configured as :func:`make_backend` does."""
    impl = landmark_implementation(name)
    if impl.localiser is None:
        raise ConfigError(
            f"--map: {name} cannot localise against a fixed map (available: {', '.join(LOCALISING_BACKENDS)})"
        )
    ids, xy, cov = checked_landmark_map(landmark_ids, landmarks_w, landmark_cov)
    return load(impl.localiser)(ids, xy, cov, _settings(name, impl, config, overrides))


def checked_landmark_map(landmark_ids, landmarks_w, landmark_cov):
    """``(ids (M,) int64, positions (M, 2), covariances (M, 2, 2))`` or MeasurementError.
    The localisers reshaped what they were given: positions of shape (2, 3) for three ids
    moved the pose, ids 1.5 became 1, a repeated id, NaN positions and negative variances
    were taken (twentieth hostile pass, the Python API)."""
    import numpy as np

    from slamcore.errors import MeasurementError

    try:
        ids = np.asarray(landmark_ids)
        xy = np.asarray(landmarks_w, dtype=np.float64)
        cov = np.asarray(landmark_cov, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeasurementError("landmark map: ids, positions and covariances must be numbers") from None
    m = len(ids) if ids.ndim == 1 else -1
    if m < 0 or xy.shape != (m, 2) or cov.shape != (m, 2, 2):
        raise MeasurementError(
            f"landmark map: expected ids (M,), positions (M, 2) and covariances (M, 2, 2); got "
            f"{ids.shape}, {xy.shape} and {cov.shape}"
        )
    if ids.dtype.kind not in "iu" and not (
        ids.dtype.kind == "f" and np.all(np.isfinite(ids)) and np.all(ids == np.round(ids))
    ):
        raise MeasurementError(f"landmark map: ids must be whole numbers, got {ids[:3].tolist()}")
    ids = ids.astype(np.int64)
    if len(np.unique(ids)) != m:
        raise MeasurementError("landmark map: a landmark id is repeated")
    if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(cov))):
        raise MeasurementError("landmark map: positions or covariances are not finite")
    if np.any(np.diagonal(cov, axis1=1, axis2=2) <= 0) or np.any(
        np.abs(cov - np.swapaxes(cov, 1, 2)) > 1e-9 * (1 + np.abs(cov))
    ):
        raise MeasurementError("landmark map: a covariance is not symmetric with positive variances")
    return ids, xy, cov


def seed_draws_nothing(dataset: str, backend: str) -> bool:
    """``--seed`` changes nothing in a 2-D run of ``backend`` on ``dataset``: the data is
    not simulated and the back end draws no random numbers (run, compare and sweep
    refuse it by this one rule)."""
    return dataset != "synthetic" and backend not in SEEDED_BACKENDS


def seed_override(name: str, seed: int | None) -> dict:
    """Config override that hands ``--seed`` to 2-D back ends that draw random numbers."""
    row = descriptor(name)
    if seed is None or row is None or row.landmarks is None or not row.landmarks.seeded:
        return {}
    return {"seed": seed}


def planar_sections(dataset: str, backend: str) -> dict[str, type]:
    """Config classes a 2-D ``graphslam run`` of ``dataset`` on ``backend`` reads,
    by section name (``graphslam sweep`` checks its overrides against them)."""
    from graphslam.sources.planar.synthetic import SyntheticConfig

    config_class = load(landmark_implementation(backend).config)
    out: dict[str, type] = {config_class.SECTION: config_class}
    if dataset == "synthetic":
        out[SyntheticConfig.SECTION] = SyntheticConfig
    elif is_mrclam_dataset(dataset):
        from graphslam.sources.planar.mrclam import MrclamConfig

        out[MrclamConfig.SECTION] = MrclamConfig
    return out


# --------------------------------------------------------------------------- image sequences

#: Built-in image-sequence datasets; a folder path is read as an image sequence
#: (KITTI, TUM RGB-D, EuRoC or a plain folder of images), a file as a pose graph.
VISUAL_DATASETS = ("synthetic-images",)


def is_mrclam_dataset(spec: str) -> bool:
    """Whether ``--dataset spec`` is a folder holding a UTIAS MRCLAM data set."""
    from graphslam.sources.planar.mrclam import is_mrclam_folder

    return spec not in DATASETS and spec not in VISUAL_DATASETS and is_mrclam_folder(spec)


def is_plaza_dataset(spec: str) -> bool:
    """Whether ``--dataset spec`` is a Plaza range-only log: a ``*_DR.txt`` file, or a
    folder holding one with its ``*_TD.txt`` (the built-in ``plaza1``, ``plaza2`` aside),
    or a folder of ``*_DR.txt`` files that is not one (its reading says why)."""
    from graphslam.sources.planar.plaza import plaza_files, plaza_folder_problem

    if spec in DATASETS or spec in VISUAL_DATASETS:
        return False
    return plaza_files(spec) is not None or plaza_folder_problem(spec) is not None


def is_bag_dataset(spec: str) -> bool:
    """Whether ``--dataset spec`` is a ROS bag (a ``.bag`` file, a ROS 2 bag folder)."""
    from graphslam.sources.spatial.rosbag import is_bag

    return spec not in DATASETS and spec not in VISUAL_DATASETS and is_bag(spec)


def is_visual_dataset(spec: str) -> bool:
    """Whether ``--dataset spec`` names an image sequence (built-in, a ROS bag, or a
    folder other than an MRCLAM or Plaza log)."""
    return (
        spec in VISUAL_DATASETS
        or is_bag_dataset(spec)
        or (Path(spec).is_dir() and not is_mrclam_dataset(spec) and not is_plaza_dataset(spec))
    )


def dataset_files(spec: str) -> list[Path]:
    """Every file a run of ``--dataset spec`` may read, as each reader knows its own: a
    pose-graph or log file; a Plaza log's ``_DR.txt``, ``_TD.txt`` and ``.mat``; an MRCLAM
    folder's files; an image folder's files through symbolic links, with a KITTI
    sequence's truth outside it; a bag with the intrinsics file beside it. Empty for a
    built-in dataset (its data comes with the code and gtsam: their versions name it).

    Raises:
        OSError: a file or folder that cannot be listed.
    """
    from slamcore.input_files import files_below

    if spec in DATASETS or spec in VISUAL_DATASETS:
        return []
    if is_bag_dataset(spec):
        from graphslam.sources.spatial.rosbag import bag_files

        return bag_files(spec)
    if is_plaza_dataset(spec):
        from graphslam.sources.planar.plaza import plaza_files

        return [p for p in plaza_files(spec) or () if p.is_file()]
    if is_mrclam_dataset(spec):
        return files_below(spec)
    if Path(spec).is_dir():
        from graphslam.sources.spatial.images import sequence_files

        return sequence_files(spec)
    return [Path(spec)] if Path(spec).is_file() else []


def camera_file(spec: str) -> Path | None:
    """The intrinsics file a run of ``--dataset spec`` finds on its own: an image folder's
    (:data:`~graphslam.sources.spatial.calibration.INTRINSICS_FILE_NAMES`), the one in or
    beside a bag; None for other datasets or where there is none. A command whose
    ``--out`` holds it must neither replace nor remove it as an earlier output."""
    from graphslam.sources.spatial.calibration import find_intrinsics_file
    from graphslam.sources.spatial.rosbag import bag_camera_file, bag_path

    if spec in DATASETS or spec in VISUAL_DATASETS or is_mrclam_dataset(spec):
        return None
    bag = bag_path(spec)
    if bag is not None:
        return bag_camera_file(bag)
    return find_intrinsics_file(Path(spec)) if Path(spec).is_dir() else None


def check_topics_flag(spec: str, topics: str | None) -> None:
    """``--topics`` is refused, one line, for a dataset that is not a ROS bag."""
    if topics is not None and not is_bag_dataset(spec):
        raise ConfigError(
            f"--topics applies to ROS bags only; {spec} is not one "
            "(a .bag file, or a ROS 2 bag folder with metadata.yaml)"
        )


def load_image_sequence(
    spec: str,
    *,
    seed: int | None = None,
    config: ConfigSource = None,
    topics: str | None = None,
    intrinsics: str | Path | None = None,
):
    """Image sequence by name (``synthetic-images``, section ``[synthetic_images]``), ROS
    bag (``topics``: the ``--topics`` text, ``role=topic,...``) or folder (``intrinsics``:
    an intrinsics file for a plain or TUM folder or a bag without camera_info, ``--intrinsics``)."""
    check_topics_flag(spec, topics)
    if is_bag_dataset(spec):
        from graphslam.sources.spatial.calibration import is_estimate
        from graphslam.sources.spatial.rosbag import parse_topics, read_bag

        if is_estimate(intrinsics):
            raise ConfigError(
                "--intrinsics estimate applies to plain image folders; a bag's camera comes "
                "from its camera_info topic or an intrinsics file"
            )

        return read_bag(spec, parse_topics(topics), intrinsics_file=intrinsics)
    if intrinsics is not None and spec == "synthetic-images":
        raise ConfigError(
            "--intrinsics applies to image folders and bags: the synthetic sequence has its own camera"
        )
    if spec == "synthetic-images":
        from graphslam.sources.spatial.synthetic_images import SyntheticImagesConfig, make_synthetic_images

        return make_synthetic_images(load_section(SyntheticImagesConfig, config, {"seed": seed}))
    from graphslam.sources.spatial.images import read_image_sequence

    return read_image_sequence(Path(spec), intrinsics_file=intrinsics)


def visual_backend_config(name: str) -> type[VisualIsam2Config | MonoEkfConfig]:
    """Config class of the visual back end ``name``: ``isam2`` (section
    ``[isam2_visual]``) or ``ekf`` (monocular EKF-SLAM, section ``[mono_ekf]``)."""
    return load(visual_implementation(name).config)


def landmark_implementation(name: str) -> Implementation:
    """The table's 2-D streaming implementation of back end ``name``."""
    return _implementation(name, "landmarks")


def visual_implementation(name: str) -> Implementation:
    """The table's image-sequence implementation of back end ``name``."""
    return _implementation(name, "images")


def make_visual_backend(name: str, *, config: ConfigSource = None, overrides: dict | None = None):
    """Visual back end by name (:func:`visual_backend_config` names its section)."""
    impl = visual_implementation(name)
    return load(impl.backend)(_settings(name, impl, config, overrides))


def _settings(name: str, impl: Implementation, config: ConfigSource, overrides: dict | None):
    """The implementation's config section from ``config``, ``overrides`` on top, and on
    top of those what the back end's name fixes (FastSLAM's version). A file or an
    override setting such a key otherwise is refused: ``[fastslam] version = 1`` under
    ``--backend fastslam2`` ran FastSLAM 2.0 with nothing said."""
    if overrides is not None and not isinstance(overrides, dict):  # a list of pairs was AttributeError
        raise ConfigError(f"overrides must be a dict of settings, got {type(overrides).__name__}")
    if not (config is None or isinstance(config, (ConfigFile, str, Path))):
        raise ConfigError(f"config must be a ConfigFile or a path, got {type(config).__name__}")
    cls = load(impl.config)
    file = config if isinstance(config, ConfigFile) else ConfigFile.read(config)
    refuse_contradicted(file, section_name(cls), impl.fixed, f"the back end {name}", overrides)
    return file.section(cls, {**(overrides or {}), **impl.fixed})


def refuse_contradicted(
    file: ConfigFile, section: str, chosen: dict, who: str, overrides: dict | None = None
) -> None:
    """ConfigError for a setting of ``section`` (in ``file`` or ``overrides``) that ``who``
    (a back end, a compared entry) fixes otherwise by its name (``chosen``): ``[fastslam]
    version = 1`` under ``--backend fastslam2`` ran FastSLAM 2.0, and ``[mono_ekf]
    landmark_param = "ahp"`` under compare's ``ekf-idp`` ran idp, each with nothing said."""
    in_file = file.data.get(section) or {}
    given = {**in_file, **{k: v for k, v in (overrides or {}).items() if v is not None}}
    for key, value in chosen.items():
        if key in given and given[key] != value:
            line = file.line_of(section, key) if key in in_file else None
            raise ConfigError(
                f"[{section}] {key} = {quote(given[key])} contradicts {who} ({key} = {quote(value)}); "
                "its name chooses it: remove the setting",
                file.path if line is not None else None,
                line,
            )


def visual_compare_backend(name: str) -> tuple[str, dict]:
    """``(back end, overrides)`` of a ``graphslam compare`` entry on image sequences."""
    if name not in VISUAL_COMPARE_BACKENDS:
        raise ConfigError(
            f"back end {name!r} is not compared on image sequences "
            f"(available: {', '.join(VISUAL_COMPARE_BACKENDS)})"
        )
    return VISUAL_COMPARE_BACKENDS[name]
