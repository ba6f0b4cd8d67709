"""Azure Kinect recordings: the Matroska ``.mkv`` files k4arecorder and the Azure Kinect SDK write.

Layout (SDK "Recording file format"): video tracks named ``COLOR`` (``V_MS/VFW/FOURCC`` with FourCC
``MJPG``, ``NV12``, ``YUY2`` or ``BGRA``) and ``DEPTH`` (FourCC ``b16g``: 16-bit big-endian
millimetres, 0 = no measurement), optional ``IR`` and ``IMU`` tracks, track tags ``K4A_COLOR_MODE``
(e.g. ``MJPG_1080P``) and ``K4A_DEPTH_MODE`` (e.g. ``NFOV_UNBINNED``), and the attachment
``calibration.json``: the device's factory calibration.

The file is read with PyAV (FFmpeg's Matroska demuxer): packets are indexed once when the file is
opened, and a frame is read by seeking to its timestamp. MJPG colour is decoded by pcdof's JPEG
reader (damaged data is an error, not a made-up image); the raw colour formats and the depth are
converted with NumPy / OpenCV.

Calibration (:func:`k4a_rig`): each camera's ``ModelParameters`` are
``[cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, codx, cody, p2, p1]``, normalised by the calibration
image size with (0, 0) the top-left *corner* of the top-left pixel. They are made mode-specific as
the SDK does (``src/transformation/mode_specific_calibration.c``): scaled by the mode's binned
calibration size, shifted by its crop offset, and moved to OpenCV's pixel-centre convention
(-0.5 px). The lens model ``BrownConrady`` is OpenCV's rational model, so the 8 coefficients are kept
in OpenCV order ``(k1, k2, p1, p2, k3, k4, k5, k6)``. Each camera's ``Rt`` maps points from the
depth camera's frame (the reference) into that camera's frame, translation in metres (the SDK
multiplies it by 1000 to work in millimetres; pcdof works in metres), so
``T_color_from_depth = Rt_color @ inv(Rt_depth)``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Intrinsics, Rig
from ..errors import CalibrationError, ImageReadError, PcdofError
from ..io._files import open_regular
from .base import RecordedStreams, RecordingSource, pair_by_time

MATROSKA_MAGIC = b"\x1a\x45\xdf\xa3"


@dataclass(frozen=True)
class ModeInfo:
    """A sensor mode: output size, the calibration image size it is binned from, its crop offset (pixels)."""

    width: int
    height: int
    binned: tuple[int, int]
    crop: tuple[int, int]
    sensor: tuple[int, int]
    max_range_m: float = 10.0


#: K4A_DEPTH_MODE -> mode (SDK mode_specific_calibration.c; operating ranges from the Azure Kinect DK
#: hardware specification: NFOV binned 5.46 m, NFOV unbinned 3.86 m, WFOV binned 2.88 m, WFOV unbinned 2.21 m)
DEPTH_MODES = {
    "NFOV_2X2BINNED": ModeInfo(320, 288, (512, 512), (96, 90), (1024, 1024), 5.46),
    "NFOV_UNBINNED": ModeInfo(640, 576, (1024, 1024), (192, 180), (1024, 1024), 3.86),
    "WFOV_2X2BINNED": ModeInfo(512, 512, (512, 512), (0, 0), (1024, 1024), 2.88),
    "WFOV_UNBINNED": ModeInfo(1024, 1024, (1024, 1024), (0, 0), (1024, 1024), 2.21),
}
#: colour resolution (the part of K4A_COLOR_MODE after the format) -> mode, for a 4:3 (4096 x 3072) calibration
COLOR_MODES = {
    "720P": ModeInfo(1280, 720, (1280, 960), (0, 120), (4096, 3072)),
    "1080P": ModeInfo(1920, 1080, (1920, 1440), (0, 180), (4096, 3072)),
    "1440P": ModeInfo(2560, 1440, (2560, 1920), (0, 240), (4096, 3072)),
    "1536P": ModeInfo(2048, 1536, (2048, 1536), (0, 0), (4096, 3072)),
    "2160P": ModeInfo(3840, 2160, (3840, 2880), (0, 360), (4096, 3072)),
    "3072P": ModeInfo(4096, 3072, (4096, 3072), (0, 0), (4096, 3072)),
}
#: colour FourCCs read, and how their bytes become RGB
COLOR_FORMATS = ("MJPG", "NV12", "YUY2", "BGRA")
_LENS_MODELS = ("CALIBRATION_LensDistortionModelBrownConrady", "CALIBRATION_LensDistortionModelRational6KT")


# ----------------------------------------------------------------------------------------- calibration
def k4a_rig(calibration, *, depth_mode: str, color_mode: str, where: str = "calibration.json") -> Rig:
    """Convert an Azure Kinect factory calibration to a :class:`~pcdof.camera.Rig` for two modes.

    Parameters
    ----------
    calibration : bytes, str or dict, the ``calibration.json`` content
    depth_mode : str, a key of :data:`DEPTH_MODES` (the ``K4A_DEPTH_MODE`` tag)
    color_mode : str, the ``K4A_COLOR_MODE`` tag, e.g. ``"MJPG_1080P"`` (format, underscore, resolution)
    where : str, names the calibration in error messages

    Returns
    -------
    Rig, depth in millimetres (``depth_scale`` 0.001), ``max_range_m`` the depth mode's range

    Raises
    ------
    CalibrationError
        Not the factory schema, a camera missing, an unknown mode or lens model.
    """
    obj = calibration
    if isinstance(obj, (bytes, bytearray, str)):
        try:
            obj = json.loads(obj.rstrip(b"\0" if isinstance(obj, (bytes, bytearray)) else "\0"))
        except (ValueError, RecursionError) as err:
            raise CalibrationError(f"{where} is not valid JSON: {err}") from None
    try:
        cameras = {c["Location"]: c for c in obj["CalibrationInformation"]["Cameras"]}
    except (TypeError, KeyError) as err:
        raise CalibrationError(f"{where} is not an Azure Kinect calibration: no CalibrationInformation.Cameras "
                               f"with a Location each ({type(err).__name__} {err})") from None
    if depth_mode not in DEPTH_MODES:
        raise CalibrationError(f"depth mode {depth_mode!r} has no depth image; expected one of {sorted(DEPTH_MODES)}")
    resolution = color_mode.split("_", 1)[-1]
    if resolution not in COLOR_MODES:
        raise CalibrationError(f"colour mode {color_mode!r} is not one of the SDK's (e.g. MJPG_1080P; resolutions "
                               f"{', '.join(COLOR_MODES)})")
    dmode = DEPTH_MODES[depth_mode]
    depth, Rt_depth = _camera(cameras, "CALIBRATION_CameraLocationD0", dmode, where)
    color, Rt_color = _camera(cameras, "CALIBRATION_CameraLocationPV0", COLOR_MODES[resolution], where)
    T = Rt_color @ np.linalg.inv(Rt_depth)
    try:
        return Rig(color, depth, T, depth_scale=0.001, max_range_m=dmode.max_range_m)
    except CalibrationError as err:
        raise CalibrationError(f"{where}: {err}") from None


def _camera(cameras: dict, location: str, mode: ModeInfo, where: str) -> tuple[Intrinsics, np.ndarray]:
    """One camera's mode-specific intrinsics and its 4x4 ``Rt`` (metres)."""
    if location not in cameras:
        raise CalibrationError(f"{where} has no camera {location} (found {sorted(cameras)})")
    cam = cameras[location]
    try:
        intr = cam["Intrinsics"]
        model, params = intr["ModelType"], np.asarray(intr["ModelParameters"], dtype=np.float64)
        size = (int(cam["SensorWidth"]), int(cam["SensorHeight"]))
        R = np.asarray(cam["Rt"]["Rotation"], dtype=np.float64).reshape(3, 3)
        t = np.asarray(cam["Rt"]["Translation"], dtype=np.float64).reshape(3)
    except (TypeError, KeyError, ValueError) as err:
        raise CalibrationError(f"{where}: camera {location} lacks or has a malformed {err} "
                               "(expected Intrinsics.ModelType/ModelParameters, SensorWidth/Height, Rt)") from None
    if model not in _LENS_MODELS:
        raise CalibrationError(f"{where}: camera {location} has lens model {model!r}; pcdof reads "
                               f"{' and '.join(_LENS_MODELS)}")
    if params.size < 14 or not np.all(np.isfinite(params)):
        raise CalibrationError(f"{where}: camera {location} needs 14 finite ModelParameters; got {params.size}")
    cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, codx, cody, p2, p1 = params[:14]
    if codx != 0 or cody != 0:
        raise CalibrationError(f"{where}: camera {location} has a centre of distortion ({codx}, {cody}) != 0, "
                               "which OpenCV's rational model cannot express")
    bw, bh, crop = *mode.binned, mode.crop
    if size != mode.sensor:
        if size == (4096, 2304) and mode.sensor == (4096, 3072):
            # legacy 16:9 colour calibration (4096 x 2304): re-normalised to the 4:3 sensor, as the SDK does
            cy, fy = (cy * size[1] + (mode.sensor[1] - size[1]) / 2) / mode.sensor[1], fy * size[1] / mode.sensor[1]
        else:
            raise CalibrationError(f"{where}: camera {location} was calibrated at {size[0]}x{size[1]}; the mode "
                                   f"needs {mode.sensor[0]}x{mode.sensor[1]}")
    K = (fx * bw, fy * bh, cx * bw - crop[0] - 0.5, cy * bh - crop[1] - 0.5)
    try:
        intrinsics = Intrinsics(mode.width, mode.height, *K, (k1, k2, p1, p2, k3, k4, k5, k6))
    except CalibrationError as err:
        raise CalibrationError(f"{where}: camera {location}: {err}") from None
    Rt = np.eye(4)
    Rt[:3, :3], Rt[:3, 3] = R, t
    return intrinsics, Rt


# ------------------------------------------------------------------------------------------- reading
def can_open(path: str, head: bytes) -> bool:
    """A Matroska file (EBML magic and DocType ``matroska``) or a ``.mkv`` name (not a folder)."""
    if os.path.isdir(path):
        return False
    if head.startswith(MATROSKA_MAGIC):
        return b"matroska" in head[:64]
    return path.lower().endswith(".mkv")


def _av():
    try:
        import av
    except ImportError:
        raise ImageReadError("reading Azure Kinect .mkv recordings needs PyAV: pip install av") from None
    return av


class AzureKinectSource(RecordingSource):
    """Frames of an Azure Kinect ``.mkv`` recording; see the module documentation."""

    format = "azure-kinect"

    def __init__(self, path: str, *, rig: Rig | None = None, calib_path: str | None = None,
                 max_difference_s: float | None = None) -> None:
        av = _av()
        check_segment_size(path)
        try:
            self._container = av.open(path)
        except Exception as err:  # noqa: BLE001 - FFmpeg's errors and PyAV's own
            raise ImageReadError(f"cannot read recording {path}: {err}") from None
        with contextlib.ExitStack() as on_error:
            on_error.callback(self._container.close)
            self._setup(path, rig, calib_path, max_difference_s)
            on_error.pop_all()  # set up: the container stays open until close()

    def _setup(self, path, override, calib_path, max_difference_s) -> None:
        av = _av()
        c = self._container
        tracks = {s.metadata.get("title", s.metadata.get("TITLE", "")): s for s in c.streams.video}
        for name in ("COLOR", "DEPTH"):
            if name not in tracks:
                raise ImageReadError(f"{path} is not an Azure Kinect recording with colour and depth: it has no "
                                     f"{name} track (video tracks: {sorted(tracks) or 'none'})")
        self._color, self._depth = tracks["COLOR"], tracks["DEPTH"]
        self._color_fourcc = _fourcc(self._color)
        if self._color_fourcc not in COLOR_FORMATS:
            raise ImageReadError(f"{path}: the COLOR track's codec {self._color_fourcc!r} is not one pcdof reads "
                                 f"({', '.join(COLOR_FORMATS)})")
        if _fourcc(self._depth) != "b16g":
            raise ImageReadError(f"{path}: the DEPTH track's codec {_fourcc(self._depth)!r} is unknown; Azure Kinect "
                                 "depth is 'b16g' (16-bit big-endian millimetres)")
        sizes = {name: (s.codec_context.height, s.codec_context.width)
                 for name, s in (("COLOR", self._color), ("DEPTH", self._depth))}
        rig = None
        self._modes = {name: s.metadata.get(tag) or c.metadata.get(tag)  # as recorded, when the tags are there
                       for name, s, tag in (("COLOR", self._color, "K4A_COLOR_MODE"),
                                            ("DEPTH", self._depth, "K4A_DEPTH_MODE"))}
        if override is None:  # the recording's own calibration: needed only when none replaces it
            rig = self._recorded_rig(path, av)
            for name, intr in (("COLOR", rig.color), ("DEPTH", rig.depth)):
                if sizes[name] != intr.shape:
                    raise ImageReadError(f"{path}: the {name} track is {sizes[name][1]}x{sizes[name][0]}; "
                                         f"its mode needs {intr.width}x{intr.height}")
        self._index = {s.index: [] for s in (self._color, self._depth)}
        try:
            for packet in c.demux(self._color, self._depth):
                if packet.pts is not None and packet.size:
                    self._index[packet.stream.index].append(int(packet.pts))
        except av.FFmpegError as err:
            raise ImageReadError(f"{path} is damaged: demuxing stopped with {err}") from None
        times = [np.asarray(self._index[s.index], np.float64) * float(s.time_base) for s in (self._color, self._depth)]
        fps = float(self._color.average_rate or 0) or None
        pairs, tol = pair_by_time(*times, max_difference_s=max_difference_s,
                                  periods_s=(1 / fps if fps else None, 1 / fps if fps else None))
        super().__init__(path, rig, times[0], times[1], pairs, max_difference_s=tol, override=override,
                         override_path=calib_path, streams=RecordedStreams(sizes["COLOR"], sizes["DEPTH"], 0.001))

    def _recorded_rig(self, path: str, av) -> Rig:
        """The rig of the recording's calibration.json attachment and its mode tags."""
        depth_mode = self._tag(path, self._depth, "K4A_DEPTH_MODE")
        color_mode = self._tag(path, self._color, "K4A_COLOR_MODE")
        self._modes = {"COLOR": color_mode, "DEPTH": depth_mode}
        return k4a_rig(self._calibration(av), depth_mode=depth_mode, color_mode=color_mode,
                       where=f"{path}: calibration.json")

    def _tag(self, path: str, stream, name: str) -> str:
        value = stream.metadata.get(name) or self._container.metadata.get(name)
        if not value:
            raise ImageReadError(f"{path}: the {stream.metadata.get('title')} track has no {name} tag")
        return value

    def _calibration(self, av) -> bytes:
        name = self._container.metadata.get("K4A_CALIBRATION_FILE", "calibration.json")
        for s in self._container.streams:
            if s.type == "attachment" and getattr(s, "name", None) == name:
                return bytes(s.data)
        raise CalibrationError(f"{self._container.name} has no {name} attachment: the recording carries no "
                               "calibration (pass one with calib= / --calib)")

    def _packet(self, stream, i: int) -> bytes:
        av = _av()
        pts = self._index[stream.index][i]
        try:
            self._container.seek(pts, stream=stream, backward=True, any_frame=True)
            for packet in self._container.demux(stream):
                if packet.pts is not None and packet.pts >= pts:
                    if packet.pts != pts:
                        break
                    return bytes(packet)
        except av.FFmpegError as err:
            raise ImageReadError(f"its {stream.metadata.get('title')} packet cannot be read ({err})") from None
        raise ImageReadError(f"its {stream.metadata.get('title')} packet at {pts * float(stream.time_base):.6f} s "
                             "is missing")

    def _read_color(self, i: int) -> np.ndarray:
        return decode_k4a_color(self._packet(self._color, i), self._color_fourcc, self.rig.color.shape)

    def _read_depth(self, i: int) -> np.ndarray:
        data = self._packet(self._depth, i)
        h, w = self.rig.depth.shape
        if len(data) != 2 * w * h:
            raise ImageReadError(f"its depth image holds {len(data)} bytes; {w}x{h} b16g needs {2 * w * h}")
        return np.frombuffer(data, ">u2").reshape(h, w).astype(np.float32) * np.float32(self.rig.depth_scale)

    def _streams(self) -> dict:
        out = {}
        for s in (self._color, self._depth):
            name = s.metadata.get("title")
            out[name] = {"codec": _fourcc(s), "mode": self._modes[name], "width": s.codec_context.width,
                         "height": s.codec_context.height, "frames": len(self._index[s.index]),
                         "fps": float(s.average_rate) if s.average_rate else None}
        return out

    def _close(self) -> None:
        self._container.close()


def _fourcc(stream) -> str:
    """The track's FourCC as FFmpeg read it ("unrecognised" when FFmpeg knows no codec for it)."""
    ctx = stream.codec_context
    tag = (ctx.codec_tag if ctx is not None else None) or getattr(stream, "codec_tag", None) or "unrecognised"
    return tag if isinstance(tag, str) else str(tag)


def decode_k4a_color(data: bytes, fourcc: str, shape: tuple[int, int]) -> np.ndarray:
    """One COLOR packet -> (H, W, 3) uint8 RGB; ImageReadError for damaged or wrongly sized data."""
    from ..io._files import decode_image

    h, w = shape
    if fourcc == "MJPG":
        try:
            bgr = decode_image(data, "jpeg", "(MJPG frame)", "colour")
        except PcdofError as err:
            reason = str(err).split("(MJPG frame)", 1)[-1].lstrip(": ")
            raise ImageReadError(f"its colour image (MJPG, {len(data)} bytes) cannot be decoded: {reason}") from None
        if bgr.ndim != 3 or bgr.shape[2] != 3:
            raise ImageReadError(f"its colour image decodes to shape {bgr.shape}; expected ({h}, {w}, 3)")
        return np.ascontiguousarray(bgr[:, :, ::-1])
    sizes = {"NV12": w * h * 3 // 2, "YUY2": w * h * 2, "BGRA": w * h * 4}
    if len(data) != sizes[fourcc]:
        raise ImageReadError(f"its colour image holds {len(data)} bytes; {w}x{h} {fourcc} needs {sizes[fourcc]}")
    buf = np.frombuffer(data, np.uint8)
    if fourcc == "NV12":
        return cv2.cvtColor(buf.reshape(h * 3 // 2, w), cv2.COLOR_YUV2RGB_NV12)
    if fourcc == "YUY2":
        return cv2.cvtColor(buf.reshape(h, w, 2), cv2.COLOR_YUV2RGB_YUY2)
    return cv2.cvtColor(buf.reshape(h, w, 4), cv2.COLOR_BGRA2RGB)


def check_segment_size(path: str) -> None:
    """ImageReadError when the file is shorter than its Matroska segment declares (a truncated copy).

    FFmpeg reads a truncated file up to where it stops, silently; the segment's size field in the
    header says how long the file must be (a recording whose writer was killed has an unknown size,
    all ones, and is read as far as it goes).
    """
    fd, size = open_regular(path, "recording")  # a FIFO, device or dangling link is refused, never read
    try:
        head = os.read(fd, 4096)
    except OSError as err:
        raise ImageReadError(f"cannot read recording {path}: {err.strerror or err}") from None
    finally:
        os.close(fd)
    if not head.startswith(MATROSKA_MAGIC):
        raise ImageReadError(f"{path} is not a Matroska file (no EBML header)")
    pos = 4
    ebml_size, pos = _vint(head, pos, path)
    if ebml_size is None:  # the EBML header is a few fixed elements: its writer always knows their size
        raise ImageReadError(f"{path} is corrupt: its EBML header declares an unknown size")
    pos += ebml_size
    if head[pos:pos + 4] != b"\x18\x53\x80\x67":
        raise ImageReadError(f"{path} is truncated or not a Matroska file: no Segment after its EBML header")
    seg_size, start = _vint(head, pos + 4, path)
    if seg_size is not None and start + seg_size > size:
        raise ImageReadError(f"{path} is truncated: its Matroska segment declares {start + seg_size} bytes, "
                             f"the file has {size}")


def _vint(data: bytes, pos: int, path: str) -> tuple[int | None, int]:
    """An EBML size at *pos*: (value, or None for 'unknown'; the position after it)."""
    if pos >= len(data) or data[pos] == 0:
        raise ImageReadError(f"{path} is truncated or corrupt: invalid EBML size at byte {pos}")
    length = 8 - int(math.log2(data[pos]))
    raw = int.from_bytes(data[pos:pos + length], "big") & ((1 << (7 * length)) - 1)
    return (None if raw == (1 << (7 * length)) - 1 else raw), pos + length
