"""Intel RealSense recordings: the ROS bag v2 (``.bag``) files the RealSense SDK writes.

Read with the pure-Python ``rosbags`` package (no SDK, no ROS). The SDK's layout (file version 3,
``librealsense`` ``ros_file_format.h``)::

    /device_0/sensor_<s>/<Stream>_<i>/image/data         sensor_msgs/Image (Z16 depth as mono16 / 16UC1;
                                                         colour as rgb8, bgr8, rgba8, bgra8, yuv422/yuyv, mono8)
    /device_0/sensor_<s>/<Stream>_<i>/info/camera_info   sensor_msgs/CameraInfo: K and D, and the model name
    /device_0/sensor_<s>/<Stream>_<i>/tf/0               geometry_msgs/Transform: the stream's extrinsics from
                                                         the reference stream (depth): p_stream = R p_ref + t, m
    /device_0/sensor_<s>/option/Depth Units/value        std_msgs/Float32: metres per depth unit

Frames are the ``image/data`` messages; their header stamps are the frames' timestamps. The
colour/depth extrinsic is ``T_color_from_depth = tf_color @ inv(tf_depth)``: the SDK's own playback
(``pyrealsense2``, ``depth_profile.get_extrinsics_to(color_profile)``) gives the same rotation and
translation for the bundled D435 recording.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..camera import Intrinsics, Rig
from ..errors import CalibrationError, ImageReadError
from ..io._files import open_regular
from .base import RecordedStreams, RecordingSource, float32_value, pair_by_time

BAG_MAGIC = b"#ROSBAG V2.0\n"
_STREAM = re.compile(r"^/device_(\d+)/sensor_(\d+)/([A-Za-z]+)_(\d+)/")
#: colour encodings read -> (channels, OpenCV conversion to RGB or None)
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "yuv422", "yuyv", "mono8")
DEPTH_ENCODINGS = ("mono16", "16UC1")
#: CameraInfo distortion models whose coefficients are OpenCV's (k1, k2, p1, p2, k3)
_OPENCV_MODELS = ("Brown Conrady", "plumb_bob")


def can_open(path: str, head: bytes) -> bool:
    """A ROS bag v2 (magic line ``#ROSBAG V2.0``) or a ``.bag`` name (not a folder)."""
    if os.path.isdir(path):
        return False
    return head.startswith(BAG_MAGIC) or (not head and path.lower().endswith(".bag"))


def _rosbags():
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ImageReadError("reading RealSense .bag recordings needs rosbags: pip install rosbags") from None
    return AnyReader, get_typestore(Stores.ROS1_NOETIC)


class _CheckedBagPath(type(Path())):
    """The path rosbags is given: a ROS1 bag whatever its name's suffix (rosbags goes by the suffix) that
    opens as the file pcdof already opened and checked (a regular file; never opened a second time)."""

    checked_file = None

    @property
    def suffix(self) -> str:
        return ".bag"

    def open(self, *args, **kwargs):
        f, self.checked_file = self.checked_file, None
        if f is None:
            raise ImageReadError(f"{os.fspath(self)}: the recording was already opened")
        return f


class RealSenseBagSource(RecordingSource):
    """Frames of a RealSense ``.bag`` recording; see the module documentation."""

    format = "realsense-bag"

    def __init__(self, path: str, *, rig: Rig | None = None, calib_path: str | None = None,
                 max_difference_s: float | None = None) -> None:
        AnyReader, typestore = _rosbags()
        fd, _ = open_regular(path, "recording")  # a FIFO, device or dangling link is refused, never read
        f = os.fdopen(fd, "rb")
        try:
            if not f.read(len(BAG_MAGIC)) == BAG_MAGIC:
                raise ImageReadError(f"{path} is not a ROS bag v2 file (no '#ROSBAG V2.0' line)")
            f.seek(0)
            bag = _CheckedBagPath(path)
            bag.checked_file = f
            self._reader = AnyReader([bag], default_typestore=typestore)
            self._reader.open()
        except ImageReadError:
            f.close()
            raise
        except Exception as err:  # noqa: BLE001 - rosbags raises its own error classes for damaged files
            f.close()
            raise ImageReadError(f"cannot read recording {path}: truncated or corrupt bag ({err})") from None
        try:
            self._setup(path, rig, calib_path, max_difference_s)
        except BaseException:
            self._reader.close()
            raise

    def _setup(self, path, override, calib_path, max_difference_s) -> None:
        conns = {c.topic: c for c in self._reader.connections}
        self._image = {}
        for kind in ("Depth", "Color"):
            topics = sorted(t for t in conns if t.endswith("/image/data") and _stream_kind(t) == kind)
            if not topics:
                raise ImageReadError(f"{path} has no {kind} stream (image topics: "
                                     f"{sorted(t for t in conns if t.endswith('/image/data')) or 'none'})")
            self._image[kind] = conns[topics[0]]
        self._path = path
        units = self._depth_units(conns, self._image["Depth"].topic)
        stamps, shapes = {}, {}
        for kind, conn in self._image.items():
            stamps[kind] = []
            for _, t, raw in self._messages(conn):
                msg = self._reader.deserialize(raw, conn.msgtype)
                stamps[kind].append((t, msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))
                shapes.setdefault(kind, (int(msg.height), int(msg.width)))
        self._bag_times = {k: [t for t, _ in v] for k, v in stamps.items()}
        times = [np.array([s for _, s in stamps[k]], np.float64) for k in ("Color", "Depth")]
        rig = None
        if override is None:  # the recording's own calibration: needed only when none replaces it
            rig = self._calibration(conns, path, units)
        fps = [self._fps(conns, self._image[k].topic) for k in ("Color", "Depth")]
        pairs, tol = pair_by_time(*times, max_difference_s=max_difference_s,
                                  periods_s=tuple(1 / f if f else None for f in fps))
        self._fps_values = dict(zip(("Color", "Depth"), fps))
        super().__init__(path, rig, times[0], times[1], pairs, max_difference_s=tol, override=override,
                         override_path=calib_path,
                         streams=RecordedStreams(shapes.get("Color"), shapes.get("Depth"), units))

    def _calibration(self, conns: dict, path: str, units: float) -> Rig:
        """The rig of the recording's camera_info and tf messages."""
        infos, poses = {}, {}
        for kind, conn in self._image.items():
            base = conn.topic[: -len("image/data")]
            infos[kind] = self._one(conns, base + "info/camera_info", path)
            poses[kind] = self._one(conns, base + "tf/0", path)
        return Rig(_intrinsics(infos["Color"], f"{path}: colour camera_info"),
                   _intrinsics(infos["Depth"], f"{path}: depth camera_info"),
                   _pose(poses["Color"]) @ np.linalg.inv(_pose(poses["Depth"])), depth_scale=units)

    def _messages(self, conn, start=None, stop=None):
        try:
            yield from self._reader.messages(connections=[conn], start=start, stop=stop)
        except Exception as err:  # noqa: BLE001
            raise ImageReadError(f"{self._path}: the bag is truncated or corrupt ({type(err).__name__}: {err})") \
                from None

    def _one(self, conns: dict, topic: str, path: str):
        if topic not in conns:
            what = "calibration" if "camera_info" in topic else "extrinsics"
            raise CalibrationError(f"{path} has no {topic} message: the recording lacks its {what} "
                                   "(pass a calibration with calib= / --calib)")
        for conn, _, raw in self._messages(conns[topic]):
            return self._reader.deserialize(raw, conn.msgtype)
        raise CalibrationError(f"{path}: topic {topic} holds no message")

    def _depth_units(self, conns: dict, depth_topic: str) -> float:
        sensor = depth_topic.split("/")[2]
        topic = f"/device_0/{sensor}/option/Depth Units/value"
        if topic not in conns:  # the SDK's default for D400 cameras, stated when the option is absent
            return 0.001
        value = float(self._one(conns, topic, self._path).data)
        if not value > 0:
            raise CalibrationError(f"{self._path}: Depth Units is {value}; expected metres per unit > 0")
        return float32_value(value)

    def _fps(self, conns: dict, image_topic: str) -> float | None:
        topic = image_topic[: -len("image/data")] + "info"  # realsense_msgs/StreamInfo: fps, encoding
        if topic not in conns:
            return None
        fps = float(getattr(self._one(conns, topic, self._path), "fps", 0) or 0)
        return fps or None

    def _image_msg(self, kind: str, i: int):
        conn, t = self._image[kind], self._bag_times[kind][i]
        for c, _, raw in self._messages(conn, start=t, stop=t + 1):
            try:
                return self._reader.deserialize(raw, c.msgtype)
            except Exception as err:  # noqa: BLE001
                raise ImageReadError(f"its {kind.lower()} message cannot be decoded ({err})") from None
        raise ImageReadError(f"its {kind.lower()} message at bag time {t} ns is missing")

    def _read_color(self, i: int) -> np.ndarray:
        return decode_color(self._image_msg("Color", i))

    def _read_depth(self, i: int) -> np.ndarray:
        return decode_depth(self._image_msg("Depth", i)) * np.float32(self.rig.depth_scale)

    def _streams(self) -> dict:
        out = {}
        for kind, intr in (("Color", self.rig.color), ("Depth", self.rig.depth)):
            out[kind] = {"topic": self._image[kind].topic, "width": intr.width, "height": intr.height,
                         "frames": len(self._bag_times[kind]), "fps": self._fps_values[kind]}
        out["Depth"]["depth_units_m"] = self.rig.depth_scale
        return out

    def _close(self) -> None:
        self._reader.close()


def _stream_kind(topic: str) -> str | None:
    m = _STREAM.match(topic)
    return m.group(3) if m else None


def _intrinsics(info, where: str) -> Intrinsics:
    K = np.asarray(info.K, dtype=np.float64).reshape(3, 3)
    D = tuple(float(d) for d in np.asarray(info.D, dtype=np.float64).ravel())
    model = str(info.distortion_model)
    if any(D) and model not in _OPENCV_MODELS:
        raise CalibrationError(f"{where}: distortion model {model!r} with coefficients {list(D)} is not OpenCV's "
                               f"(pcdof reads {', '.join(_OPENCV_MODELS)}); pass a calibration with --calib")
    if len(D) not in (0, 4, 5, 8, 12, 14):
        raise CalibrationError(f"{where}: {len(D)} distortion coefficients; expected 5 (k1, k2, p1, p2, k3)")
    try:
        return Intrinsics(int(info.width), int(info.height), K[0, 0], K[1, 1], K[0, 2], K[1, 2], D or (0.0,) * 5)
    except CalibrationError as err:
        raise CalibrationError(f"{where}: {err}") from None


def _pose(tf) -> np.ndarray:
    """geometry_msgs/Transform -> 4x4 (rotation from the unit quaternion x, y, z, w)."""
    q = np.array([tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w], dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-6:
        raise CalibrationError(f"a stream's tf rotation is not a unit quaternion: {q.tolist()}")
    x, y, z, w = q / n
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return T


def _pixels(msg, channels: int, dtype) -> np.ndarray:
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * channels * itemsize or data.size < step * h:
        raise ImageReadError(f"its {msg.encoding} image holds {data.size} bytes; {w}x{h} needs {w * channels * itemsize * h}")
    rows = data[: step * h].reshape(h, step)[:, : w * channels * itemsize]
    big = bool(msg.is_bigendian) and itemsize > 1
    out = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(">" if big else "<"))
    return out.reshape(h, w, channels) if channels > 1 else out.reshape(h, w)


def decode_color(msg) -> np.ndarray:
    """sensor_msgs/Image -> (H, W, 3) uint8 RGB."""
    import cv2

    enc = str(msg.encoding)
    if enc not in COLOR_ENCODINGS:
        raise ImageReadError(f"its colour encoding {enc!r} is not one pcdof reads ({', '.join(COLOR_ENCODINGS)})")
    if enc in ("yuv422", "yuyv"):
        return cv2.cvtColor(_pixels(msg, 2, np.uint8), cv2.COLOR_YUV2RGB_YUY2)
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}[enc]
    img = _pixels(msg, channels, np.uint8)
    if enc == "mono8":
        return np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    return np.ascontiguousarray(img[:, :, ::-1] if enc.startswith("bgr") else img)


def decode_depth(msg) -> np.ndarray:
    """sensor_msgs/Image (Z16) -> (h, w) float32 depth units."""
    enc = str(msg.encoding)
    if enc not in DEPTH_ENCODINGS:
        raise ImageReadError(f"its depth encoding {enc!r} is not Z16 ({', '.join(DEPTH_ENCODINGS)})")
    return _pixels(msg, 1, np.uint16).astype(np.float32)
