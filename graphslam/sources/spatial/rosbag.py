"""ROS bags as image sequences: ``--dataset BAG`` (``rosbags``; numpy + OpenCV, no gtsam).

A bag is a ROS 1 ``.bag`` file or a ROS 2 bag folder (``metadata.yaml`` with
sqlite3 ``.db3`` or ``.mcap`` files; naming one of its files names the
folder). :func:`read_bag` returns a :class:`BagSequence`, an
:class:`ImageSequence` like any folder's, so every command runs on it unchanged:

* images: ``sensor_msgs/msg/Image`` (mono8, mono16/16UC1, bgr8, rgb8, bgra8,
  rgba8) or ``sensor_msgs/msg/CompressedImage`` (any format ``cv2.imdecode``
  reads), as greyscale, read lazily from the bag by :meth:`BagSequence.load`;
* intrinsics and distortion: ``sensor_msgs/msg/CameraInfo`` (``K``, ``D``;
  plumb_bob or rational_polynomial), the first message; without a camera-info
  topic, an intrinsics file (as a plain folder's) in a ROS 2 bag folder or
  beside the bag;
* ground truth: ``geometry_msgs/msg/PoseStamped`` or ``TransformStamped``
  (or ``nav_msgs/msg/Odometry`` when named), the camera-to-world pose,
  associated with each image by the nearest header stamp within 0.02 s as
  for TUM RGB-D, images without truth dropped;
* odometry: ``nav_msgs/msg/Odometry`` (:func:`with_odometry`), the
  sequence's own odometry (``--odometry sequence``, what ``auto`` picks).

Topics, per role (``image``, ``camera_info``, ``truth``, ``odometry``): the
one topic of the role's types, or the one named by ``--topics
image=/cam0/image_raw,...`` (``odometry=none``: do not read one); two
candidates and no name is an error listing them; no image topic too. A topic
of no message is no candidate; a topic of several message types is not read.
Times are the header stamps; when every header stamp of the images, the truth
or the odometry is zero, the record times of all three (one clock: said in the
notes). Images out of order by header stamp are sorted (said in the notes);
a repeated stamp is refused. The notes (``BagSequence.notes``) list the
topics used; the run summary prints them.
"""

from __future__ import annotations

import os
import struct
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from graphslam.sources.spatial import rosbag_messages as rm
from graphslam.sources.spatial.sequence import IMAGE_EXTENSIONS, ImageSequence
from slamcore.errors import ConfigError, InputError, quote
from slamcore.files import folder_name
from slamcore.input_files import check_input_path

#: Message types of each ``--topics`` role; a role is chosen automatically from
#: :data:`AUTO_TYPES` only (an Odometry topic is truth only when named).
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "image": (rm.IMAGE, rm.COMPRESSED_IMAGE),
    "camera_info": (rm.CAMERA_INFO,),
    "truth": (rm.POSE_STAMPED, rm.TRANSFORM_STAMPED, rm.ODOMETRY),
    "odometry": (rm.ODOMETRY,),
}
AUTO_TYPES: dict[str, tuple[str, ...]] = {**ROLE_TYPES, "truth": (rm.POSE_STAMPED, rm.TRANSFORM_STAMPED)}
#: ``--topics ROLE=none``: do not read that role (say, odometry without a usable covariance).
NO_TOPIC = "none"
INSTALL_HINT = 'reading ROS bags needs the rosbags package: pip install ".[bags]"'


def bag_path(spec: str | Path) -> Path | None:
    """The path the bag reader opens for ``spec`` (a ``.bag`` file, a ROS 2 bag folder,
    or a ``.db3``/``.mcap`` file of one), or None when ``spec`` is not a bag."""
    path = Path(spec)
    if path.is_file() and (path.suffix == ".bag" or _starts_as_ros1_bag(path)):
        if path.suffix == ".active":
            raise InputError(
                "a ROS 1 bag that rosbag record did not close (.active: the recording was cut): "
                "run 'rosbag reindex' on it, then name it .bag",
                path,
            )
        return path
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    _refuse_bag_without_metadata(path)
    return None


def bag_camera_file(path: Path) -> Path | None:
    """The intrinsics file a bag without camera_info takes (``path`` as :func:`bag_path`
    gives it): in a ROS 2 bag's folder, else in the folder holding the bag; or None."""
    from graphslam.sources.spatial.calibration import find_intrinsics_file

    folders = ([path] if path.is_dir() else []) + [path.parent]
    return next((f for f in map(find_intrinsics_file, folders) if f is not None), None)


def bag_files(spec: str | Path) -> list[Path]:
    """Every file a run of the bag ``spec`` may read: the bag (a ROS 2 bag's folder, every
    file), and the intrinsics file in or beside it that a bag without camera_info takes
    (:func:`bag_camera_file`). A sweep's fingerprint of the data."""
    from slamcore.input_files import files_below

    path = bag_path(spec)
    if path is None:
        return []
    files = files_below(path) if path.is_dir() else [path]
    found = bag_camera_file(path)
    return files if found is None or found in files else [*files, found]


#: The first bytes of a ROS 1 bag (format 2.0, what rosbag record writes).
ROS1_MAGIC = b"#ROSBAG V2.0\n"


def _starts_as_ros1_bag(path: Path) -> bool:
    """Whether ``path`` is a ROS 1 bag by its content, whatever its name (``REC.BAG``,
    ``x.bag.active``: read as text files before)."""
    try:
        with path.open("rb") as f:
            return f.read(len(ROS1_MAGIC)) == ROS1_MAGIC
    except OSError:  # unreadable: left to the reader that opens it, with its own line
        return False


#: Files of a ROS 2 bag's storage (SQLite, MCAP): unreadable without the bag's metadata.yaml.
ROS2_STORAGE = (".db3", ".mcap")


def _refuse_bag_without_metadata(path: Path) -> None:
    """A ROS 2 bag's storage file, or a folder of them with no image, lacking the
    ``metadata.yaml`` beside it: said as that, not as "no images" or "not a text file"."""
    folder = path.parent if path.is_file() and path.suffix in ROS2_STORAGE else path
    if folder is path:
        try:  # an unreadable folder is left to the reader that opens it, with its own line
            suffixes = {p.suffix.lower() for p in path.iterdir()} if path.is_dir() else set()
        except OSError:
            return
        if not suffixes & set(ROS2_STORAGE) or suffixes & set(IMAGE_EXTENSIONS):
            return
    raise InputError(
        f"a ROS 2 bag needs the metadata.yaml that ros2 bag record writes beside its storage, "
        f"and {folder} has none (copy the bag's whole folder)",
        path,
    )


def is_bag(spec: str | Path) -> bool:
    return bag_path(spec) is not None


def split_bag_spec(spec: str | Path) -> tuple[Path, str | None] | None:
    """``BAG`` or ``BAG:TOPIC`` (``graphslam eval``) -> ``(bag, topic or None)``; None
    when ``spec`` names no bag. ROS names hold no ``:``, so the last one splits."""
    text = str(spec)
    if is_bag(text):
        return Path(text), None
    head, sep, topic = text.rpartition(":")
    if sep and topic and is_bag(head):
        return Path(head), topic
    return None


def parse_topics(text: str | None) -> dict[str, str]:
    """``"image=/cam0/image_raw,truth=/vicon/pose"`` -> ``{role: topic}``."""
    out: dict[str, str] = {}
    for item in [] if text is None else str(text).split(","):
        role, eq, topic = item.strip().partition("=")
        if not eq or not topic.strip():
            raise ConfigError(f"--topics takes ROLE=TOPIC items separated by commas, got {quote(item)}")
        role = role.strip()
        if role not in ROLE_TYPES:
            raise ConfigError(f"--topics: unknown role {quote(role)} (roles: {', '.join(ROLE_TYPES)})")
        if role == "image" and topic.strip() == NO_TOPIC:
            raise ConfigError("--topics image=none: a run needs images")
        if role in out:
            raise ConfigError(f"--topics names {role} twice")
        out[role] = topic.strip()
    return out


@contextmanager
def open_bag(path: Path) -> Iterator:
    """An open ``rosbags`` AnyReader on ``path``; a damaged bag is one InputError."""
    errors = bag_errors(path)
    if path.is_dir():  # a FIFO among a ROS 2 bag's files blocks SQLite's open for good
        for entry in sorted(path.iterdir()):
            check_input_path(entry, "file of the bag", folder_ok=True)
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    _check_metadata(path)
    with _named_dot_bag(path) as readable:
        try:
            # bags without message definitions (early ROS 2 ones) are read with Humble's
            reader = AnyReader([readable], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except errors as e:
            raise InputError(f"cannot read the bag: {_reason(e)}", path) from None
        try:
            yield reader
        except errors as e:  # a chunk damaged past the index, met while reading
            raise InputError(f"cannot read the bag: {_reason(e)}", path) from None
        finally:
            reader.close()


@contextmanager
def _named_dot_bag(path: Path) -> Iterator[Path]:
    """``path``, or for a ROS 1 bag file named otherwise (``REC.BAG``) a link to it named
    ``.bag`` in a temporary folder, for the block: rosbags tells ROS 1 from 2 by the suffix."""
    if path.is_dir() or path.suffix == ".bag":
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="graphslam-bag-") as folder:
        link = Path(folder) / "bag.bag"
        link.symlink_to(path.resolve())
        yield link


def _check_metadata(path: Path) -> None:
    """InputError naming a ROS 2 bag folder's metadata.yaml that is no mapping of
    ``rosbag2_bagfile_information`` (rosbags said "string indices must be integers")."""
    meta = path / "metadata.yaml"
    if not (path.is_dir() and meta.is_file()):
        return
    import yaml

    try:
        data = yaml.safe_load(meta.read_text(encoding="utf-8", errors="replace"))
    except (yaml.YAMLError, OSError) as e:
        raise InputError(f"not readable as YAML: {_reason(e)}", meta) from None
    if not isinstance(data, dict) or not isinstance(data.get("rosbag2_bagfile_information"), dict):
        raise InputError("not a ROS 2 bag's metadata (no rosbag2_bagfile_information mapping)", meta)


def bag_errors(path: Path) -> tuple[type[BaseException], ...]:
    """What ``rosbags`` raises on a damaged bag (its readers' errors, not wrapped
    while messages are read, and the decoders' own); InputError without rosbags."""
    try:
        from rosbags.highlevel import AnyReaderError
        from rosbags.rosbag1 import ReaderError as Reader1Error
        from rosbags.rosbag2 import ReaderError as Reader2Error
        from rosbags.serde import SerdeError
    except ImportError:
        raise InputError(INSTALL_HINT, path) from None
    return (
        AnyReaderError,
        Reader1Error,
        Reader2Error,
        SerdeError,
        OSError,
        ValueError,
        KeyError,
        IndexError,
        EOFError,
        struct.error,
    )


def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 200 else text[:200] + "..."


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag (``graphslam info``): type, message count and mean rate of the
    messages read, and the count the bag's index (a ROS 2 bag's metadata.yaml) states."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None
    stated_count: int


#: What :func:`topic_types` says of a topic holding messages of several types.
MIXED_TYPES = "mixed types"


def topic_types(reader) -> dict[str, str]:
    """``{topic: message type}`` of an open bag; a topic of several types maps to
    ``"mixed types (A, B)"``, which no role takes (rosbags gives None for it)."""
    found: dict[str, set[str]] = {}
    for conn in reader.connections:
        found.setdefault(conn.topic, set()).add(conn.msgtype)
    return {
        topic: next(iter(types)) if len(types) == 1 else f"{MIXED_TYPES} ({', '.join(sorted(types))})"
        for topic, types in found.items()
    }


def bag_topics(spec: str | Path) -> list[TopicSummary]:
    """Every topic of the bag ``spec`` with its type, and the count and rate (from record
    times) of the messages read: a ROS 2 bag's metadata.yaml may state other counts."""
    path = _require_bag(spec)
    with open_bag(path) as reader:
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        counts: dict[str, int] = {}
        for conn, t, _ in reader.messages():
            first.setdefault(conn.topic, t)
            last[conn.topic] = t
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
        types = topic_types(reader)
        out = []
        for name, info in sorted(reader.topics.items()):
            n, span = counts.get(name, 0), (last.get(name, 0) - first.get(name, 0)) / 1e9
            rate_hz = (n - 1) / span if n > 1 and span > 0 else None
            out.append(TopicSummary(name, types.get(name, str(info.msgtype)), n, rate_hz, info.msgcount))
    return out


def chosen_roles(spec: str | Path, topics: list[TopicSummary], named: str | None) -> dict | str:
    """``{role: topic}`` ``--dataset`` would read (``graphslam info``), or why none: the
    reason of a missing or ambiguous topic (a listing is not refused for it)."""
    types = {t.name: t.msgtype for t in topics}
    empty = {t.name for t in topics if t.count == 0}
    try:
        return choose_topics(types, parse_topics(named), _require_bag(spec), empty)
    except InputError as e:
        return e.reason


def _require_bag(spec: str | Path) -> Path:
    path = bag_path(spec)
    if path is None and not Path(spec).exists():
        raise InputError("no such file or folder", spec)
    if path is None:
        raise InputError("not a ROS bag (a .bag file, or a folder with metadata.yaml)", spec)
    return path


def choose_topics(
    topics: dict[str, str], named: dict[str, str], where: Path, empty: set[str] | frozenset = frozenset()
) -> dict[str, str]:
    """``{role: topic}`` from the bag's ``{topic: type}`` (:func:`topic_types`) and the
    ``--topics`` names; topics of no message (``empty``) are not chosen automatically."""
    mixed = [f"{t} holds {ty}, not read" for t, ty in sorted(topics.items()) if ty.startswith(MIXED_TYPES)]
    chosen: dict[str, str] = {}
    for role, types in ROLE_TYPES.items():
        if named.get(role) == NO_TOPIC:
            continue
        if role in named:
            topic = named[role]
            if topic not in topics:
                raise InputError(
                    f"--topics {role}={topic}: no such topic (topics: {', '.join(sorted(topics))})", where
                )
            if topics[topic].startswith(MIXED_TYPES):
                raise InputError(
                    f"--topics {role}={topic}: the topic holds {topics[topic]}, not read: "
                    "record each type on a topic of its own",
                    where,
                )
            if topics[topic] not in types:
                raise InputError(
                    f"--topics {role}={topic}: {topics[topic]} is not one of {', '.join(types)}", where
                )
            chosen[role] = topic
            continue
        # an empty topic (declared, never published) is no candidate: it made the choice ambiguous
        found = sorted(
            t
            for t, ty in topics.items()
            if ty in AUTO_TYPES[role] and t not in chosen.values() and t not in empty
        )
        if role == "camera_info" and len(found) > 1 and "image" in chosen:
            # the camera's own: /cam0/camera_info beside /cam0/image_raw(/compressed)
            found = [t for t in found if in_camera_namespace(t, chosen["image"])] or found
        if len(found) > 1:
            raise InputError(
                f"{len(found)} {role} topics ({', '.join(found)}): name one with --topics {role}=TOPIC", where
            )
        if found:
            chosen[role] = found[0]
        elif role == "image":
            raise InputError(
                f"no image topic ({', '.join(types)}); topics: {', '.join(sorted(topics)) or 'none'}"
                + "".join(f"; {m}" for m in mixed),
                where,
            )
    return chosen


#: image_transport's topics of one image stream: ``/cam0/image_raw/compressed`` is
#: ``/cam0/image_raw`` compressed, in namespace ``/cam0`` (not ``/cam0/image_raw``).
TRANSPORT_SUFFIXES = ("/compressed", "/compressedDepth", "/theora")


def raw_image_topic(topic: str) -> str:
    """``topic`` without its image_transport suffix (:data:`TRANSPORT_SUFFIXES`)."""
    for suffix in TRANSPORT_SUFFIXES:
        if topic.endswith(suffix):
            return topic[: -len(suffix)]
    return topic


def in_camera_namespace(info_topic: str, image_topic: str) -> bool:
    """Whether a camera_info topic is in the namespace of an image topic, or above it
    (``/camera_info`` for ``/cam0/image_raw``): the camera the ROS conventions pair."""
    info_ns = info_topic.rsplit("/", 1)[0] + "/"
    return (raw_image_topic(image_topic).rsplit("/", 1)[0] + "/").startswith(info_ns)


def is_rectified(image_topic: str) -> bool:
    """Whether ``image_topic`` holds rectified images: ROS image_pipeline's names
    (``image_rect``, ``image_rect_color``, ``image_rect_raw``)."""
    return "image_rect" in raw_image_topic(image_topic).rsplit("/", 1)[-1]


def foreign_camera_warnings(chosen: dict[str, str], named: dict[str, str]) -> tuple[str, ...]:
    """A warning when the bag's only camera_info, taken without being named, is in
    another camera's namespace (``/cam1/image_raw`` given ``/cam0/camera_info``)."""
    info, image = chosen.get("camera_info"), chosen["image"]
    if info is None or "camera_info" in named or in_camera_namespace(info, image):
        return ()
    return (
        f"images {image} take {info}, the bag's only camera_info, of another namespace: if it is "
        "not their camera, name theirs with --topics camera_info=TOPIC, or give --intrinsics FILE "
        "with --topics camera_info=none",
    )


@dataclass(frozen=True)
class FrameRef:
    """Where one image is in the bag: its connection, record time and rank among
    the messages of that connection recorded at that time (usually 0)."""

    connection: int
    record_ns: int
    rank: int


@dataclass(frozen=True, eq=False, kw_only=True)
class BagSequence(ImageSequence):
    """An image sequence read from a ROS bag (module doc).

    Extra attributes:
        bag: the path the reader opens; topics: ``{role: topic}`` used;
        image_type: the image topic's message type;
        frames: ``{image path: FrameRef}``; the image paths are pseudo-names
            ``<bag>#<topic>/<index>``, read with :meth:`load`, never from disk;
        notes: what was read from where, one line each (the run summary prints them).
        odometry, odometry_covariance, odometry_sigmas: of an Odometry topic
            (:func:`with_odometry`), else None.
        odometry_unused: why the bag's Odometry topic was left out ("/odom not used:
            ..."), else None: ``--odometry sequence`` says it.
    """

    bag: str
    topics: dict[str, str]
    image_type: str
    frames: dict[str, FrameRef]
    notes: tuple[str, ...] = ()
    odometry: np.ndarray | None = None
    odometry_covariance: np.ndarray | None = None
    odometry_sigmas: tuple | None = None
    odometry_unused: str | None = None
    #: ``(pid, reader, context)`` of the open bag: opened on the first load, again in a
    #: forked child (``graphslam compare``), whose file offsets must not be the parent's.
    _open_reader: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def load_raw(self, i: int) -> np.ndarray:
        name = self.image_paths[i]
        ref = self.frames[name]
        reader = self._reader()
        conn = reader.connections[ref.connection]
        try:
            got = [raw for _, _, raw in reader.messages([conn], start=ref.record_ns, stop=ref.record_ns + 1)]
            if len(got) <= ref.rank:
                raise InputError("image message not found again in the bag", name)
            msg = reader.deserialize(got[ref.rank], conn.msgtype)
        except bag_errors(Path(self.bag)) as e:
            raise InputError(f"cannot read the image: {_reason(e)}", name) from None
        img = rm.image_gray(msg, self.image_type, name)
        if (img.shape[1], img.shape[0]) != tuple(self.image_size):
            raise InputError(
                f"image is {img.shape[1]}x{img.shape[0]} px, the sequence's "
                f"are {self.image_size[0]}x{self.image_size[1]}",
                name,
            )
        return img

    def _reader(self):
        state = self._open_reader
        if state is None or state[0] != os.getpid():
            context = open_bag(Path(self.bag))
            state = (os.getpid(), context.__enter__(), context)
            object.__setattr__(self, "_open_reader", state)  # frozen: the one cache field
        return state[1]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_open_reader"] = None  # an open file does not travel
        return state


# --------------------------------------------------------------------------- reading


def read_bag(
    spec: str | Path,
    topics: dict[str, str] | None = None,
    *,
    calibrated: bool = True,
    intrinsics_file: str | Path | None = None,
) -> ImageSequence:
    """The image sequence of the bag ``spec`` (module doc); ``topics``: ``--topics`` names.
    ``calibrated=False`` (``graphslam loops``): without a camera, ``K`` is None.
    ``intrinsics_file`` (``--intrinsics``): the camera of a bag without a camera_info
    topic (refused beside one: the bag's own camera is the one its images were taken with)."""
    path = _require_bag(spec)
    with open_bag(path) as reader:
        types = topic_types(reader)
        empty = {name for name, info in reader.topics.items() if info.msgcount == 0}
        chosen = choose_topics(types, topics or {}, path, empty)
        image_type = types[chosen["image"]]
        index = _index_images(reader, chosen["image"], image_type, path)
        if intrinsics_file is not None:
            if "camera_info" in chosen:
                raise ConfigError(
                    f"--intrinsics: the bag has a camera_info topic ({chosen['camera_info']}), "
                    "its images' own camera; --intrinsics is for a bag without one"
                )
            from graphslam.sources.spatial.calibration import read_intrinsics_file

            K, dist = read_intrinsics_file(intrinsics_file)
            notes: tuple = (f"intrinsics: {intrinsics_file} (--intrinsics)",)
            camera_warnings: tuple = ()
        else:
            K, dist, notes, camera_warnings = _calibration(
                reader, chosen.get("camera_info"), index.size, path, calibrated, chosen["image"]
            )
            camera_warnings += foreign_camera_warnings(chosen, topics or {})
        truth = odometry = None
        if "truth" in chosen:
            truth = _pose_messages(reader, chosen["truth"], types[chosen["truth"]], path)
        if "odometry" in chosen:
            odometry = _pose_messages(reader, chosen["odometry"], rm.ODOMETRY, path)
    # one clock for every topic: images on record times matched to truth by header
    # stamps (another clock) paired each image with another frame's truth, silently
    roles = (("image", index), ("truth", truth), ("odometry", odometry))
    read = {chosen[role]: got.stamps for role, got in roles if got is not None}
    zero = [topic for topic, stamps in read.items() if not any(stamps.header_ns)]
    record_clock = bool(zero)
    clock_notes = (
        (
            f"every header stamp of {', '.join(zero)} is 0: the bag's record times are used for "
            f"{', '.join(read)}",
        )
        if zero
        else ()
    )
    index = _in_stamp_order(index, chosen["image"], path, record_clock)
    paths = [f"{path}#{chosen['image']}/{k:06d}" for k in range(len(index.refs))]
    seq = BagSequence(
        name=f"rosbag-{path.stem if path.is_file() else folder_name(path)}",
        image_paths=paths,
        stamps_s=rm.ns_to_s(index.stamps_ns),
        K=K,
        distortion=dist,
        wTc_true=None,
        image_size=index.size,
        source_path=str(path),
        camera_warnings=camera_warnings,
        bag=str(path),
        topics=chosen,
        image_type=image_type,
        frames=dict(zip(paths, index.refs, strict=True)),
        notes=(
            f"image: {chosen['image']} ({image_type}, {len(paths)} messages)",
            *notes,
            *clock_notes,
            *index.notes,
            *(
                []
                if truth is None
                else [f"truth: {chosen['truth']} ({types[chosen['truth']]}, {len(truth.poses)} poses)"]
            ),
        ),
    )
    if truth is not None:
        from graphslam.sources.ground_truth import with_ground_truth

        # first: frames without truth are dropped (dataclasses.replace keeps the class)
        seq = cast(BagSequence, with_ground_truth(seq, _trajectory(truth, record_clock)))
    if odometry is None:
        return seq
    return with_odometry(seq, chosen["odometry"], *_on_clock(odometry, record_clock))


def clock_name(record_clock: bool) -> str:
    return "record time" if record_clock else "header stamp"


@dataclass(frozen=True)
class Stamps:
    """The header stamps and record times (ns) of a topic's messages, in one order."""

    header_ns: list[int]
    record_ns: list[int]

    def on(self, record_clock: bool) -> list[int]:
        return self.record_ns if record_clock else self.header_ns


@dataclass(frozen=True)
class ImageIndex:
    """The image messages of a topic (:func:`_index_images`): as read, or in stamp
    order on the bag's clock (:func:`_in_stamp_order`, then ``stamps_ns`` is set)."""

    refs: list[FrameRef]
    stamps: Stamps
    size: tuple[int, int]
    stamps_ns: list[int] = field(default_factory=list)
    notes: tuple[str, ...] = ()


def _index_images(reader, topic: str, msgtype: str, path: Path) -> ImageIndex:
    """Every image message of ``topic``, as read: where it is, its stamps; sizes of raw
    images checked (a compressed one's when it is loaded)."""
    conns = [c for c in reader.connections if c.topic == topic]
    position = {id(c): k for k, c in enumerate(reader.connections)}
    refs: list[FrameRef] = []
    stamps: list[int] = []
    record: list[int] = []
    size: tuple[int, int] | None = None
    seen: dict[tuple[int, int], int] = {}
    for conn, t, raw in reader.messages(conns):
        msg = reader.deserialize(raw, conn.msgtype)
        where = f"{path}#{topic}/{len(refs):06d}"
        wh = (
            rm.image_size(msg, msgtype, where)
            if msgtype == rm.IMAGE
            else _decoded_size(msg, msgtype, where)
            if size is None
            else None
        )
        if size is None:
            size = wh
        elif wh is not None and wh != size:
            raise InputError(
                f"image is {wh[0]}x{wh[1]} px, the topic's first is "
                f"{size[0]}x{size[1]}: images of changing size",
                where,
            )
        key = (position[id(conn)], t)
        seen[key] = seen.get(key, -1) + 1
        refs.append(FrameRef(key[0], t, seen[key]))
        stamps.append(rm.stamp_ns(msg.header))
        record.append(t)
    if not refs or size is None:  # (the first message gives the size)
        raise InputError(f"topic {topic} has no messages", path)
    return ImageIndex(refs, Stamps(stamps, record), size)


def _in_stamp_order(index: ImageIndex, topic: str, path: Path, record_clock: bool) -> ImageIndex:
    """``index`` sorted by stamp on the bag's clock (header stamps, or record times);
    a repeated stamp refused."""
    stamps = index.stamps.on(record_clock)
    notes = []
    order = np.argsort(np.array(stamps, dtype=np.int64), kind="stable")
    if np.any(order != np.arange(len(order))):
        late = int(np.sum(np.diff(np.array(stamps, dtype=np.int64)) < 0))
        clock = clock_name(record_clock)
        notes.append(f"{topic}: {late} images recorded out of {clock} order: sorted by {clock}")
    stamps = [stamps[k] for k in order]
    dup = [k for k in range(1, len(stamps)) if stamps[k] == stamps[k - 1]]
    if dup:
        raise InputError(
            f"two images on {topic} have the {clock_name(record_clock)} "
            f"{float(rm.ns_to_s([stamps[dup[0]]])[0])} s",
            path,
        )
    return ImageIndex([index.refs[k] for k in order], index.stamps, index.size, stamps, tuple(notes))


def _decoded_size(msg, msgtype: str, where: str) -> tuple[int, int]:
    img = rm.image_gray(msg, msgtype, where)
    return int(img.shape[1]), int(img.shape[0])


def _calibration(
    reader, topic: str | None, size: tuple[int, int], path: Path, calibrated: bool, image_topic: str
):
    """``(K, distortion or None, notes, warnings)``: the first CameraInfo of ``topic``, else
    an intrinsics file beside the bag (as a plain image folder's). Rectified images
    (:func:`is_rectified`) take the CameraInfo's ``P`` and no distortion."""
    from graphslam.sources.spatial.calibration import INTRINSICS_FILE_NAMES, read_intrinsics_file

    if topic is None:
        found = bag_camera_file(path)
        if found is None and not calibrated:
            return None, None, ("no camera calibration",), ()
        if found is None:
            raise InputError(
                f"no camera_info topic ({rm.CAMERA_INFO}) and no intrinsics file "
                f"({', '.join(INTRINSICS_FILE_NAMES)}) in or beside the bag",
                path,
            )
        K, dist = read_intrinsics_file(found)
        return K, dist, (f"intrinsics: {found}",), ()
    where = f"{path}#{topic}"
    conns = [c for c in reader.connections if c.topic == topic]
    for conn, _, raw in reader.messages(conns):
        msg = reader.deserialize(raw, conn.msgtype)
        K, dist, wh = rm.camera_calibration(msg, where)
        if wh != (0, 0) and wh != tuple(size):
            raise InputError(
                f"camera info is for {wh[0]}x{wh[1]} px images, the images are {size[0]}x{size[1]}", where
            )
        note = f"camera_info: {topic} (first message)"
        if not is_rectified(image_topic):
            return K, dist, (note,), ()
        # K and D are the raw camera's: undistorting rectified images with them distorts them
        # again; the rectified camera is P's left 3x3, with no distortion (sensor_msgs/CameraInfo)
        K_rect = rm.rectified_K(msg, where)
        if K_rect is None:
            return (
                K,
                None,
                (f"{note}: K, no distortion, for the rectified {image_topic}",),
                (
                    f"{where}: P is all zeros: the rectified images {image_topic} are taken with K "
                    "and no distortion",
                ),
            )
        return K_rect, None, (f"{note}: P's 3x3, no distortion, for the rectified {image_topic}",), ()
    raise InputError("camera info topic has no messages", where)


@dataclass(frozen=True)
class PoseMessages:
    """The pose messages of a topic, as read (:func:`_pose_messages`)."""

    where: str
    stamps: Stamps
    poses: np.ndarray
    covariances: np.ndarray | None


def _trajectory(messages: PoseMessages, record_clock: bool):
    """``messages`` as a :class:`~graphslam.sources.ground_truth.Trajectory` on the bag's clock."""
    from graphslam.sources.ground_truth import Trajectory

    stamps_s, poses, _ = _on_clock(messages, record_clock)
    # said: another file's times are compared with the record clock (hostile pass 18)
    notes = ("header stamps are all 0: its times are the bag's record times",) if record_clock else ()
    return Trajectory("tum", stamps_s, poses, messages.where, notes=notes)


def _pose_messages(reader, topic: str, msgtype: str, path: Path) -> PoseMessages:
    """Poses ``(N, 4, 4)``, stamps and covariances ``(N, 6, 6)`` (of Odometry, else None)
    of ``topic``, as read."""
    where = f"{path}#{topic}"
    conns = [c for c in reader.connections if c.topic == topic]
    stamps: list[int] = []
    record: list[int] = []
    poses: list[np.ndarray] = []
    covs: list[np.ndarray] = []
    for conn, t, raw in reader.messages(conns):
        msg = reader.deserialize(raw, conn.msgtype)
        poses.append(rm.pose_matrix(msg, msgtype, f"{where}/{len(poses)}"))
        stamps.append(rm.stamp_ns(msg.header))
        record.append(t)
        if msgtype == rm.ODOMETRY:
            covs.append(np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6))
    if not poses:
        raise InputError("pose topic has no messages", where)
    return PoseMessages(where, Stamps(stamps, record), np.array(poses), np.array(covs) if covs else None)


def _on_clock(messages: PoseMessages, record_clock: bool):
    """``(stamps (N,) s, poses (N, 4, 4), covariances or None)`` of ``messages`` in stamp
    order on the bag's clock (header stamps, or record times); a repeated stamp refused."""
    stamps = messages.stamps.on(record_clock)
    order = np.argsort(np.array(stamps, dtype=np.int64), kind="stable")
    stamps_s = rm.ns_to_s([stamps[k] for k in order])
    same = np.nonzero(np.diff(stamps_s) == 0)[0]
    if same.size:
        raise InputError(
            f"two poses have the {clock_name(record_clock)} {float(stamps_s[same[0]])} s", messages.where
        )
    covs = messages.covariances
    return stamps_s, messages.poses[order], (None if covs is None else covs[order])


def with_odometry(
    seq: BagSequence, topic: str, stamps_s: np.ndarray, poses: np.ndarray, covs: np.ndarray
) -> BagSequence:
    """``seq`` with the odometry of an Odometry topic: ``c_k T c_{k+1}`` between the
    messages nearest each image (within 0.02 s), the message pose taken as the
    camera's (no TF is applied). Per step the covariance is the later message's
    pose covariance in the camera frame: drivers publish a fixed per-message
    covariance, with 1e6 or so on the axes they do not measure, which is what a
    step's noise needs; a difference of absolute covariances is zero for them.
    When an image has no message or a covariance is not positive definite the
    odometry is left out and the notes say why."""
    import dataclasses

    from graphslam.sources.spatial.sequence import ASSOCIATION_MAX_DT_S, associate

    idx = associate(np.asarray(seq.stamps_s, dtype=np.float64), stamps_s, ASSOCIATION_MAX_DT_S)
    why = None
    if np.any(idx < 0):
        why = f"{int(np.sum(idx < 0))} of {len(idx)} images have no message within {ASSOCIATION_MAX_DT_S} s"
    else:
        T, P = poses[idx], covs[idx]
        step = np.linalg.inv(T[:-1]) @ T[1:]
        A = np.zeros((len(T) - 1, 6, 6))
        A[:, :3, :3] = A[:, 3:, 3:] = np.transpose(T[1:, :3, :3], (0, 2, 1))
        cov = A @ P[1:] @ np.transpose(A, (0, 2, 1))
        cov = 0.5 * (cov + np.transpose(cov, (0, 2, 1)))
        if len(cov) and not np.all(np.linalg.eigvalsh(cov)[:, 0] > 0):
            why = "its pose covariance is not positive definite"
    if why is not None:
        unused = f"{topic} not used: {why}"
        return dataclasses.replace(seq, notes=(*seq.notes, f"odometry: {unused}"), odometry_unused=unused)
    return dataclasses.replace(
        seq,
        odometry=step,
        odometry_covariance=cov,
        odometry_sigmas=(None, None),
        notes=(*seq.notes, f"odometry: {topic} ({len(idx)} poses, taken as the camera's)"),
    )


def read_bag_trajectory(spec: str | Path, topic: str | None):
    """A trajectory from the pose messages of a bag's ``topic`` (``graphslam eval
    BAG:TOPIC``); without a topic, the bag's one pose topic (any of the truth types)."""
    path = _require_bag(spec)
    with open_bag(path) as reader:
        types = topic_types(reader)
        if topic is None:
            found = sorted(t for t, ty in types.items() if ty in ROLE_TYPES["truth"])
            if len(found) != 1:
                raise InputError(
                    f"{len(found)} pose topics ({', '.join(found) or 'none'}): name one as BAG:TOPIC", path
                )
            topic = found[0]
        if types.get(topic) not in ROLE_TYPES["truth"]:
            raise InputError(
                f"topic {topic} is {types.get(topic) or 'not in the bag'}, not one "
                f"of {', '.join(ROLE_TYPES['truth'])}",
                path,
            )
        messages = _pose_messages(reader, topic, types[topic], path)
    # header stamps all 0: the record times, as for a run's topics
    return _trajectory(messages, not any(messages.stamps.header_ns))
