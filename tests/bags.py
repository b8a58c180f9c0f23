"""ROS bags for the tests, written with ``rosbags`` itself (imported when a bag is
written: without it the tests that need one skip): ROS 1 (``kind`` ros1) and ROS 2
(sqlite3, mcap), and the first frames of KITTI 07 as one."""

from __future__ import annotations

from decimal import Decimal
from pathlib import Path

import numpy as np

from tests.conftest import SHARED_DATA

KITTI07 = SHARED_DATA / "kitti07"
#: Frames of KITTI 07 the bags hold: enough for a run, few enough to be quick.
N = 20
#: Record times are the header stamps plus this: the reader must take the header's.
RECORD_OFFSET_NS = 7_000_000_000


class BagWriter:
    """A ROS 1 bag (``kind`` ros1) or a ROS 2 bag (sqlite3, mcap), written by rosbags."""

    def __init__(self, path: Path, kind: str):
        from rosbags.typesys import Stores, get_typestore

        self.kind = kind
        if kind == "ros1":
            from rosbags.rosbag1 import Writer

            self.ts = get_typestore(Stores.ROS1_NOETIC)
            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.ts = get_typestore(Stores.ROS2_HUMBLE)
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.conns: dict[str, object] = {}

    def __enter__(self):
        self.writer.open()
        return self

    def __exit__(self, *exc):
        self.writer.close()

    def write(self, topic: str, ns: int, msg, record_ns: int | None = None) -> None:
        msgtype = msg.__msgtype__
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        raw = (self.ts.serialize_ros1(msg, msgtype) if self.kind == "ros1"
               else self.ts.serialize_cdr(msg, msgtype))
        self.writer.write(self.conns[topic], ns + RECORD_OFFSET_NS if record_ns is None
                          else record_ns, raw)

    # messages -----------------------------------------------------------------

    def make(self, msgtype: str, **kw):
        cls = self.ts.types[msgtype]
        names = set(cls.__dataclass_fields__)
        # ROS 1 spells CameraInfo's matrices K, D, R, P
        return cls(**{(k if k in names else k.upper()): v for k, v in kw.items()})

    def header(self, ns: int):
        kw = {"stamp": self.make("builtin_interfaces/msg/Time", sec=ns // 10**9,
                                 nanosec=ns % 10**9), "frame_id": "cam0"}
        if "seq" in self.ts.types["std_msgs/msg/Header"].__dataclass_fields__:
            kw["seq"] = 0
        return self.make("std_msgs/msg/Header", **kw)

    def image(self, ns: int, img: np.ndarray, encoding: str = "mono8"):
        h, w = img.shape[:2]
        data = np.ascontiguousarray(img).view(np.uint8).reshape(-1)
        return self.make("sensor_msgs/msg/Image", header=self.header(ns), height=h, width=w,
                         encoding=encoding, is_bigendian=0, step=data.size // h, data=data)

    def compressed(self, ns: int, data: bytes, fmt: str = "png"):
        return self.make("sensor_msgs/msg/CompressedImage", header=self.header(ns), format=fmt,
                         data=np.frombuffer(data, dtype=np.uint8).copy())

    def camera_info(self, ns: int, K: np.ndarray, size: tuple[int, int], d=()):
        roi = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0,
                        width=0, do_rectify=False)
        return self.make("sensor_msgs/msg/CameraInfo", header=self.header(ns), height=size[1],
                         width=size[0], distortion_model="plumb_bob",
                         d=np.array(d, dtype=np.float64), k=np.asarray(K, np.float64).reshape(9),
                         r=np.eye(3).reshape(9), p=np.zeros(12), binning_x=0, binning_y=0, roi=roi)

    def pose(self, ns: int, t, q_xyzw):
        point = self.make("geometry_msgs/msg/Point", x=t[0], y=t[1], z=t[2])
        quat = self.make("geometry_msgs/msg/Quaternion", x=q_xyzw[0], y=q_xyzw[1], z=q_xyzw[2],
                         w=q_xyzw[3])
        return self.make("geometry_msgs/msg/PoseStamped", header=self.header(ns),
                         pose=self.make("geometry_msgs/msg/Pose", position=point,
                                        orientation=quat))


def bag_path(tmp: Path, kind: str, name: str = "seq") -> Path:
    return tmp / (f"{name}.bag" if kind == "ros1" else name)


# --------------------------------------------------------------------------- KITTI 07

def kitti_frames():
    """``(time texts, times ns, image paths, K, poses as (t, q_xyzw))`` of the first N frames."""
    from graphslam.sources.spatial.kitti import read_kitti_calib, read_kitti_poses
    from slamcore.spatial.geometry import rotation_to_quaternion

    texts = KITTI07.joinpath("times.txt").read_text().split()[:N]
    ns = [int(Decimal(t) * 10**9) for t in texts]
    images = sorted(KITTI07.joinpath("image_0").glob("*.png"))[:N]
    K, _ = read_kitti_calib(KITTI07 / "calib.txt")
    wTc = read_kitti_poses(KITTI07 / "poses.txt")[:N]
    poses = [(T[:3, 3], rotation_to_quaternion(T[None, :3, :3])[0]) for T in wTc]
    return texts, ns, images, K, poses


def write_kitti_bag(path: Path, kind: str, compressed: bool = False,
                    second_camera: bool = False, extra=None) -> Path:
    """The first N frames of KITTI 07: ``/cam0/image_raw`` (mono8, or PNG bytes on
    ``/cam0/image_raw/compressed``), ``/cam0/camera_info`` (P0's K, one message),
    ``/ground_truth/pose`` (PoseStamped). ``second_camera``: also ``/cam1/image_raw``
    and ``/cam1/camera_info``, the frames mirrored left to right (two of a kind).
    ``extra(writer)`` writes more messages."""
    import cv2

    _, ns, images, K, poses = kitti_frames()
    h, w_px = cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape
    with BagWriter(path, kind) as w:
        for cam in ("cam0", "cam1") if second_camera else ("cam0",):
            w.write(f"/{cam}/camera_info", ns[0], w.camera_info(ns[0], K, (w_px, h)))
        for t, img, (p, q) in zip(ns, images, poses):
            grey = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
            if compressed:
                w.write("/cam0/image_raw/compressed", t, w.compressed(t, img.read_bytes()))
            else:
                w.write("/cam0/image_raw", t, w.image(t, grey))
            if second_camera:
                w.write("/cam1/image_raw", t, w.image(t, np.ascontiguousarray(grey[:, ::-1])))
            w.write("/ground_truth/pose", t, w.pose(t, p, q))
        if extra is not None:
            extra(w)
    return path
