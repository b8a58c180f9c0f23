"""``graphslam run --write-bag``: the estimate as a ROS 1 bag that ``rosbag``, ``rqt_bag``
and evo read (``evo_ape bag run.bag /groundtruth /graphslam/trajectory``).

One ``geometry_msgs/PoseStamped`` per pose on :data:`TOPIC`, frame
:data:`FRAME_ID`, the header stamp and the record time both the TUM file's time
(pose ids for a pose graph, seconds for a sequence). Written with ``rosbags``
(pure Python) to a temporary file and moved into place, so an interrupted write
leaves no half bag. Numpy at the interface; the message types are rosbags'.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcore.errors import ConfigError, InputError
from slamcore.files import move_into_place, temporary_beside
from slamcore.spatial.geometry import rotation_to_quaternion

__all__ = ["TOPIC", "FRAME_ID", "check_bag_writer", "write_trajectory_bag"]

#: Topic and frame of the written poses.
TOPIC = "/graphslam/trajectory"
FRAME_ID = "world"
_POSE = "geometry_msgs/msg/PoseStamped"
#: rosbags writes the stamp's seconds as int32 (builtin_interfaces/Time), whatever ROS 1 allows
ROS1_TIME_LIMIT_S = 2.0**31


def check_bag_writer() -> None:
    """ConfigError (one line) when ``rosbags`` is not installed."""
    try:
        import rosbags.rosbag1  # noqa: F401
    except ImportError:
        raise ConfigError('--write-bag needs the rosbags package: pip install ".[bags]"') from None


def write_trajectory_bag(path: str | Path, stamps_s: np.ndarray, wTc: np.ndarray, topic: str = TOPIC) -> Path:
    """Write ``wTc`` ((N, 4, 4), camera or body to world) at ``stamps_s`` ((N,) seconds,
    >= 0: ROS time is unsigned) as a ROS 1 bag at ``path``; returns ``path``."""
    check_bag_writer()
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    stamps_s = np.asarray(stamps_s, np.float64).reshape(-1)
    wTc = np.asarray(wTc, np.float64).reshape(-1, 4, 4)
    if len(stamps_s) != len(wTc):
        raise ValueError(f"{len(stamps_s)} stamps for {len(wTc)} poses")
    if len(stamps_s) and (not np.isfinite(stamps_s).all() or stamps_s.min() < 0):
        raise InputError("a ROS bag takes finite times >= 0; the trajectory has others", path)
    if len(stamps_s) and stamps_s.max() >= ROS1_TIME_LIMIT_S:  # its seconds are an int32
        raise InputError(
            f"a ROS 1 bag takes times below 2^31 s (the year 2038); the trajectory reaches "
            f"{stamps_s.max():.6g} s (a pose graph's times are its pose ids)",
            path,
        )
    ts = get_typestore(Stores.ROS1_NOETIC)
    types = ts.types
    q = rotation_to_quaternion(wTc[:, :3, :3])
    ns = np.round(stamps_s * 1e9).astype(np.int64)
    tmp = temporary_beside(path)
    tmp.unlink()  # rosbags refuses to overwrite; the name stays ours (same folder, random)
    try:
        with Writer(tmp) as writer:
            conn = writer.add_connection(topic, _POSE, typestore=ts)
            for k, (t_ns, T, qk) in enumerate(zip(ns.tolist(), wTc, q, strict=True)):
                header = types["std_msgs/msg/Header"](
                    seq=k,
                    stamp=types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                    frame_id=FRAME_ID,
                )
                pose = types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](*map(float, T[:3, 3])),
                    orientation=types["geometry_msgs/msg/Quaternion"](*map(float, qk)),
                )
                msg = types[_POSE](header=header, pose=pose)
                writer.write(conn, t_ns, ts.serialize_ros1(msg, _POSE))
        move_into_place(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
