"""Write Azure Kinect recordings in the k4arecorder layout, from a rig and frames the caller gives.

The file is what the Azure Kinect SDK's recorder writes, as far as a reader can see: a Matroska file
with video tracks named ``COLOR`` and ``DEPTH`` (codec ``V_MS/VFW/FOURCC``, a ``BITMAPINFOHEADER``
with FourCC ``MJPG`` and ``b16g``), the track tags ``K4A_COLOR_MODE`` / ``K4A_DEPTH_MODE`` /
``K4A_*_TRACK``, the attachment ``calibration.json`` (the factory calibration schema, tagged
``K4A_CALIBRATION_FILE``), timestamps in microseconds, and one cluster per capture. Depth is stored
big-endian (``b16g``). It lets the test suite (and anyone without a device) build recordings of a
scene whose geometry is known exactly. The EBML is written here, byte by byte, so the reader
(FFmpeg's Matroska demuxer through PyAV) is an independent implementation.

References
----------
Matroska element IDs: RFC 9559. Recording layout: Azure Kinect Sensor SDK, "Recording file format";
``k4arecord/record.cpp``. Calibration schema: ``src/calibration/calibration.c``.
"""

from __future__ import annotations

import json
import struct

import cv2
import numpy as np

from ..camera import Rig
from ..errors import InputError
from ..io._files import atomic_write_bytes, fspath
from .azure_kinect import COLOR_MODES, DEPTH_MODES, ModeInfo

# Matroska element IDs (RFC 9559)
_EBML, _SEGMENT, _INFO, _TRACKS, _TRACK, _VIDEO = 0x1A45DFA3, 0x18538067, 0x1549A966, 0x1654AE6B, 0xAE, 0xE0
_ATTACHMENTS, _ATTACHED, _TAGS, _TAG, _TARGETS, _SIMPLE_TAG = 0x1941A469, 0x61A7, 0x1254C367, 0x7373, 0x63C0, 0x67C8
_CLUSTER, _TIMESTAMP, _SIMPLE_BLOCK = 0x1F43B675, 0xE7, 0xA3
TIMESTAMP_SCALE_NS = 1000  # the SDK's: block timestamps in microseconds


def _id(eid: int) -> bytes:
    return eid.to_bytes((eid.bit_length() + 7) // 8, "big")


def _size(n: int) -> bytes:
    length = 1
    while n >= (1 << (7 * length)) - 1:
        length += 1
    return ((1 << (7 * length)) | n).to_bytes(length, "big")


def _el(eid: int, payload) -> bytes:
    if isinstance(payload, (list, tuple)):
        payload = b"".join(payload)
    elif isinstance(payload, str):
        payload = payload.encode("utf-8")
    elif isinstance(payload, float):
        payload = struct.pack(">d", payload)
    elif isinstance(payload, int):
        payload = payload.to_bytes(max(1, (payload.bit_length() + 7) // 8), "big")
    return _id(eid) + _size(len(payload)) + bytes(payload)


def bitmap_info_header(width: int, height: int, fourcc: bytes, bits: int) -> bytes:
    """The 40-byte little-endian ``BITMAPINFOHEADER`` the SDK puts in a track's CodecPrivate."""
    return struct.pack("<IiiHH4sIiiII", 40, width, height, 1, bits, fourcc, width * height * bits // 8, 0, 0, 0, 0)


def k4a_calibration_json(rig: Rig, *, depth_mode: str, color_mode: str) -> dict:
    """The factory calibration (``calibration.json``) that gives *rig* in the two modes.

    The inverse of :func:`pcdof.sources.azure_kinect.k4a_rig`: pixel intrinsics become the SDK's
    raw ones, normalised by the calibration image and 0-cornered; the depth camera is the reference
    (identity ``Rt``) and the colour camera's ``Rt`` is ``T_color_from_depth`` (metres, row-major).
    """
    cameras = []
    for intr, mode, location, purpose in ((rig.depth, _mode(DEPTH_MODES, depth_mode), "D0", "Depth"),
                                          (rig.color, _mode(COLOR_MODES, color_mode[5:]), "PV0", "PhotoVideo")):
        if intr.shape != (mode.height, mode.width):
            raise InputError(f"{purpose} intrinsics are {intr.width}x{intr.height}; mode needs {mode.width}x{mode.height}")
        d = np.zeros(8)
        d[: len(intr.distortion)] = intr.distortion[:8]
        k1, k2, p1, p2, k3, k4, k5, k6 = d
        bw, bh = mode.binned
        params = [(intr.cx + 0.5 + mode.crop[0]) / bw, (intr.cy + 0.5 + mode.crop[1]) / bh, intr.fx / bw,
                  intr.fy / bh, k1, k2, k3, k4, k5, k6, 0.0, 0.0, p2, p1]
        T = np.eye(4) if purpose == "Depth" else np.asarray(rig.T_color_from_depth)
        cameras.append({
            "Intrinsics": {"ModelParameterCount": 14, "ModelParameters": [float(v) for v in params],
                           "ModelType": "CALIBRATION_LensDistortionModelBrownConrady"},
            "Location": f"CALIBRATION_CameraLocation{location}", "Purpose": f"CALIBRATION_CameraPurpose{purpose}",
            "MetricRadius": 1.7, "Rt": {"Rotation": T[:3, :3].ravel().tolist(), "Translation": T[:3, 3].tolist()},
            "SensorHeight": mode.sensor[1], "SensorWidth": mode.sensor[0], "Shutter": "CALIBRATION_ShutterTypeUndefined",
            "ThermalAdjustmentParams": {"Params": [0.0] * 12},
        })
    return {"CalibrationInformation": {"Cameras": cameras, "InertialSensors": [],
                                       "Metadata": {"SerialId": "000000000000", "FactoryCalDate": "", "Version": {}}}}


def _mode(table: dict, name: str) -> ModeInfo:
    if name not in table:
        raise InputError(f"mode must be one of {sorted(table)}; got {name!r}")
    return table[name]


def write_k4a_recording(path, colors, depths_mm, rig: Rig, *, depth_mode: str = "NFOV_2X2BINNED",
                        color_mode: str = "MJPG_720P", timestamps_us=None, depth_delay_us: int = 0,
                        jpeg_quality: int = 95, calibration: dict | bytes | None = None,
                        depth_fourcc: bytes = b"b16g") -> None:
    """Write colour and depth frames as an Azure Kinect recording (atomically).

    Parameters
    ----------
    path : str or os.PathLike, the ``.mkv`` to write
    colors : sequence of (H, W, 3) uint8 RGB ndarrays, the colour mode's size
    depths_mm : sequence of (h, w) uint16 ndarrays, millimetres, the depth mode's size
    rig : Rig, written as ``calibration.json`` (unless *calibration* is given)
    depth_mode : a K4A_DEPTH_MODE name (``NFOV_2X2BINNED``, ``NFOV_UNBINNED``, ``WFOV_2X2BINNED``, ``WFOV_UNBINNED``)
    color_mode : ``MJPG_`` + a resolution (``720P``, ``1080P``, ``1440P``, ``1536P``, ``2160P``, ``3072P``)
    timestamps_us : sequence of int, colour timestamps (default 33333 us apart, from 0)
    depth_delay_us : int, depth timestamp minus colour timestamp (the recorder's ``--depth-delay``)
    jpeg_quality : int, 1..100
    calibration : dict or bytes, attachment content to write instead of the rig's; ``b""`` = no attachment
    depth_fourcc : bytes, the depth track's FourCC (other than ``b16g`` only to test readers)
    """
    colors, depths = list(colors), list(depths_mm)
    if not colors or len(colors) != len(depths):
        raise InputError(f"colors and depths_mm must be equally long and not empty; got {len(colors)} and {len(depths)}")
    times = [33333 * i for i in range(len(colors))] if timestamps_us is None else [int(t) for t in timestamps_us]
    if calibration is None:
        calibration = k4a_calibration_json(rig, depth_mode=depth_mode, color_mode=color_mode)
    if isinstance(calibration, dict):
        calibration = json.dumps(calibration, indent=4).encode()
    cmode, dmode = _mode(COLOR_MODES, color_mode[5:]), _mode(DEPTH_MODES, depth_mode)
    tracks = [(1, 0x5A5A0001, "COLOR", bitmap_info_header(cmode.width, cmode.height, b"MJPG", 24), cmode),
              (2, 0x5A5A0002, "DEPTH", bitmap_info_header(dmode.width, dmode.height, depth_fourcc, 16), dmode)]
    head = [_el(0x2AD7B1, TIMESTAMP_SCALE_NS), _el(0x4D80, "pcdof"), _el(0x5741, "pcdof k4a_writer"),
            _el(0x7BA9, "Azure Kinect")]
    body = [_el(_INFO, head), _el(_TRACKS, [
        _el(_TRACK, [_el(0xD7, n), _el(0x73C5, uid), _el(0x83, 1), _el(0x9C, 0), _el(0x536E, name),
                     _el(0x86, "V_MS/VFW/FOURCC"), _el(0x63A2, bih),
                     _el(_VIDEO, [_el(0xB0, m.width), _el(0xBA, m.height)])]) for n, uid, name, bih, m in tracks])]
    tags = [_tag("K4A_COLOR_TRACK", str(0x5A5A0001), 0x63C5, 0x5A5A0001), _tag("K4A_COLOR_MODE", color_mode, 0x63C5, 0x5A5A0001),
            _tag("K4A_DEPTH_TRACK", str(0x5A5A0002), 0x63C5, 0x5A5A0002), _tag("K4A_DEPTH_MODE", depth_mode, 0x63C5, 0x5A5A0002),
            _tag("K4A_DEPTH_DELAY_NS", str(depth_delay_us * 1000)), _tag("K4A_START_OFFSET_NS", "0")]
    if calibration:
        body.append(_el(_ATTACHMENTS, [_el(_ATTACHED, [_el(0x466E, "calibration.json"),
                                                       _el(0x4660, "application/octet-stream"),
                                                       _el(0x465C, calibration), _el(0x46AE, 0x5A5A00CA)])]))
        tags.append(_tag("K4A_CALIBRATION_FILE", "calibration.json", 0x63C6, 0x5A5A00CA))
    body.append(_el(_TAGS, tags))
    for t, color, depth in zip(times, colors, depths):
        body.append(_cluster(t, _jpeg(color, jpeg_quality, cmode), _depth_bytes(depth, dmode), depth_delay_us))
    header = _el(_EBML, [_el(0x4286, 1), _el(0x42F7, 1), _el(0x42F2, 4), _el(0x42F3, 8), _el(0x4282, "matroska"),
                         _el(0x4287, 4), _el(0x4285, 2)])
    atomic_write_bytes(fspath(path, name="path"), header + _el(_SEGMENT, body))


def _tag(name: str, value: str, target_id: int | None = None, target_uid: int | None = None) -> bytes:
    targets = [] if target_id is None else [_el(target_id, target_uid)]
    return _el(_TAG, [_el(_TARGETS, targets), _el(_SIMPLE_TAG, [_el(0x45A3, name), _el(0x4487, value)])])


def _block(track: int, rel_us: int, data: bytes) -> bytes:
    return _el(_SIMPLE_BLOCK, bytes([0x80 | track]) + struct.pack(">hB", rel_us, 0x80) + data)


def _cluster(t_us: int, color: bytes, depth: bytes, delay_us: int) -> bytes:
    base = min(t_us, t_us + delay_us)
    return _el(_CLUSTER, [_el(_TIMESTAMP, base), _block(1, t_us - base, color), _block(2, t_us + delay_us - base, depth)])


def _jpeg(color, quality: int, mode: ModeInfo) -> bytes:
    color = np.asarray(color)
    if color.shape != (mode.height, mode.width, 3) or color.dtype != np.uint8:
        raise InputError(f"colour frames must be ({mode.height}, {mode.width}, 3) uint8; got {color.shape} {color.dtype}")
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(color[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise InputError("OpenCV could not encode a colour frame as JPEG")
    return buf.tobytes()


def _depth_bytes(depth, mode: ModeInfo) -> bytes:
    depth = np.asarray(depth)
    if depth.shape != (mode.height, mode.width) or depth.dtype != np.uint16:
        raise InputError(f"depth frames must be ({mode.height}, {mode.width}) uint16; got {depth.shape} {depth.dtype}")
    return depth.astype(">u2").tobytes()


__all__ = ["write_k4a_recording", "k4a_calibration_json", "bitmap_info_header"]
