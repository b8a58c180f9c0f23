"""ROS messages -> numpy: images, camera calibration, stamped poses (numpy + OpenCV, no gtsam).

The messages are the objects :mod:`rosbags` deserialises (ROS 1 and ROS 2
alike: it names every type the ROS 2 way, ``sensor_msgs/msg/Image``, and
gives ROS 1 headers the ROS 2 ``stamp.sec``/``stamp.nanosec``). Bad content
raises :class:`~slamcore.errors.InputError` naming the bag and the topic.
"""

from __future__ import annotations

import cv2
import numpy as np

from frontend.image import check_sixteen_bit_levels, decode_gray
from graphslam.sources.spatial.sequence import check_distortion, check_K, check_rotation, quat_to_rotation
from slamcore.errors import InputError, quote

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
ODOMETRY = "nav_msgs/msg/Odometry"

#: Raw encodings read: (channels, bytes per channel, conversion to grey or None); colour
#: by ``cvtColor``, as :func:`frontend.image.to_gray` turns a colour file grey.
ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    "mono8": (1, 1, None),
    "8UC1": (1, 1, None),
    "mono16": (1, 2, None),
    "16UC1": (1, 2, None),
    "bgr8": (3, 1, cv2.COLOR_BGR2GRAY),
    "rgb8": (3, 1, cv2.COLOR_RGB2GRAY),
    "bgra8": (4, 1, cv2.COLOR_BGRA2GRAY),
    "rgba8": (4, 1, cv2.COLOR_RGBA2GRAY),
}
#: Distortion models whose ``D`` OpenCV's undistortion takes as it is.
OPENCV_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "")


def stamp_ns(header) -> int:
    """A header's stamp in integer nanoseconds (exact; seconds are taken from it by
    an integer division, so a stamp written from ``0.1038752`` reads back as that float)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def ns_to_s(ns) -> np.ndarray:
    """Integer nanoseconds -> seconds, each the float nearest the exact quotient (as
    the text of a times file would parse): ``int / int`` rounds once, ``ns * 1e-9`` twice."""
    return np.array([int(t) / 1_000_000_000 for t in ns], dtype=np.float64)


def image_size(msg, msgtype: str, where: str) -> tuple[int, int] | None:
    """``(W, H)`` of a raw image without decoding it (None for a compressed one);
    InputError for an encoding :data:`ENCODINGS` lacks or a buffer too short."""
    if msgtype != IMAGE:
        return None
    enc = str(msg.encoding)
    if enc not in ENCODINGS:
        raise InputError(
            f"image encoding {quote(enc)} is not supported (supported: "
            f"{', '.join(ENCODINGS)}; or a sensor_msgs/CompressedImage)",
            where,
        )
    channels, depth, _ = ENCODINGS[enc]
    w, h, step = int(msg.width), int(msg.height), int(msg.step)
    if w < 1 or h < 1 or step < w * channels * depth or len(msg.data) < step * h:
        raise InputError(
            f"{w}x{h} {enc} image with row step {step} holds {len(msg.data)} bytes: not a whole image", where
        )
    return w, h


def image_gray(msg, msgtype: str, where: str) -> np.ndarray:
    """The image of a ``sensor_msgs`` Image or CompressedImage as (H, W) uint8 grey."""
    if msgtype == COMPRESSED_IMAGE:
        return decode_gray(np.asarray(msg.data, dtype=np.uint8).tobytes(), where)
    size = image_size(msg, msgtype, where)
    if size is None:
        raise InputError(f"{msgtype} is not an image message (expected {IMAGE} or {COMPRESSED_IMAGE})", where)
    w, h = size
    channels, depth, code = ENCODINGS[str(msg.encoding)]
    rows = np.asarray(msg.data, dtype=np.uint8)[: int(msg.step) * h].reshape(h, int(msg.step))
    pixels = rows[:, : w * channels * depth]
    if depth == 2:
        order = ">" if msg.is_bigendian else "<"
        wide = pixels.copy().view(np.dtype(f"{order}u2")).reshape(h, w)
        # 12-bit values in mono16 are near black as 8 bits: refused as image files of them
        # are, on the same 8-bit reading (the top 8 bits, as OpenCV reads a 16-bit PNG)
        top = (wide >> 8).astype(np.uint8)
        check_sixteen_bit_levels(top, where)
        # the top 8 bits, as a 16-bit PNG of the same frame reads: one rule for a folder and
        # a bag (cv_bridge's mono8 rounds the scale by 1/256 instead, one level above on half
        # the pixels; hostile pass 21 found the folder and the bag of the same photos apart)
        return top
    img = np.ascontiguousarray(pixels.reshape(h, w, channels) if channels > 1 else pixels.reshape(h, w))
    return img if code is None else cv2.cvtColor(img, code)


def camera_calibration(msg, where: str) -> tuple[np.ndarray, np.ndarray | None, tuple[int, int]]:
    """``(K (3, 3), distortion or None, (W, H))`` of a CameraInfo message."""
    model = str(msg.distortion_model)
    if model not in OPENCV_DISTORTION_MODELS:
        raise InputError(
            f"distortion model {quote(model)} is not supported (supported: plumb_bob, rational_polynomial)",
            where,
        )
    # ROS 1 spells the fields K and D, ROS 2 k and d
    K = check_K(np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3), where)
    # a D of 3 or 6 coefficients crashed OpenCV's undistortion at the first image
    D = check_distortion(np.asarray(_field(msg, "d"), dtype=np.float64), where, what="camera_info D")
    return K, D, (int(msg.width), int(msg.height))


def rectified_K(msg, where: str) -> np.ndarray | None:
    """The camera of the rectified images of a CameraInfo: its projection ``P``'s left
    (3, 3); None when ``P`` is all zeros (not filled in by the driver)."""
    P = np.asarray(_field(msg, "p"), dtype=np.float64).reshape(-1)
    if P.size != 12:
        raise InputError(f"camera_info P has {P.size} numbers, not 12", where)
    if not np.any(P):
        return None
    return check_K(P.reshape(3, 4)[:, :3], where)


def _field(msg, name: str):
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def pose_matrix(msg, msgtype: str, where: str) -> np.ndarray:
    """(4, 4) pose of a PoseStamped, TransformStamped or Odometry message (its
    frame in the header's frame: the camera-to-world pose when it is the camera's)."""
    if msgtype == POSE_STAMPED:
        p, q = msg.pose.position, msg.pose.orientation
    elif msgtype == ODOMETRY:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
    elif msgtype == TRANSFORM_STAMPED:
        p, q = msg.transform.translation, msg.transform.rotation
    else:
        raise InputError(
            f"{msgtype} holds no pose (expected {POSE_STAMPED}, {TRANSFORM_STAMPED} or {ODOMETRY})", where
        )
    t = np.array([p.x, p.y, p.z], dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise InputError("non-finite position", where)
    T = np.eye(4)
    # the TUM reader's own conversion: a pose from a bag and from its TUM file agree bit for bit
    T[:3, :3] = check_rotation(quat_to_rotation(q.w, q.x, q.y, q.z, where, None), where, None)
    T[:3, 3] = t
    return T
