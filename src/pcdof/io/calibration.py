"""Calibration readers: ``calib.json``, OpenCV FileStorage (YAML / XML / JSON), Open3D intrinsic JSON.

:func:`read_calibration` looks at the file's content (and its extension for FileStorage) and
returns a :class:`pcdof.camera.Rig`. Every problem raises :class:`~pcdof.errors.CalibrationError`
with the file and the key in the message; a missing or unreadable file raises
:class:`~pcdof.errors.ImageReadError`.

Formats
-------
calib.json (pcdof's own schema)::

    {"color": {"width": W, "height": H, "fx": .., "fy": .., "cx": .., "cy": .., "distortion": [k1, k2, p1, p2, k3]},
     "depth": {... same keys, the depth camera ...},
     "depth_scale": 0.001,              # metres per unit of integer depth files
     "T_color_from_depth": [[4x4]],     # metres, p_color = R @ p_depth + t
     "max_range_m": 10.0}               # optional, the depth sensor's range

``distortion`` may be left out (no distortion). Keys starting with ``_`` and ``comment`` are ignored;
other unknown keys give a warning.

OpenCV FileStorage (``.yml``/``.yaml``/``.xml``, or ``.json`` written by ``cv2.FileStorage``), in the
names ``cv2.stereoCalibrate`` uses:

* ``cameraMatrix1``, ``distCoeffs1``, ``cameraMatrix2``, ``distCoeffs2``: 3x3 camera matrices and
  OpenCV distortion vectors (distortion may be left out: none);
* ``R`` (3x3, or a 3-vector Rodrigues rotation) and ``T`` (3-vector): stereoCalibrate's convention,
  ``p_cam2 = R @ p_cam1 + T``;
* image sizes as ``[width, height]`` (``cv::Size`` order): ``imageSize1`` / ``imageSize2`` per camera,
  or ``imageSize`` or ``image_width`` + ``image_height`` for both;
* ``color_camera``: 1 or 2, which camera is the colour camera. **Default 2: camera 1 is the depth
  camera and camera 2 the colour camera, so that (R, T) is T_color_from_depth.** With
  ``color_camera: 1`` the inverse of (R, T) is used;
* ``units`` (``m``, ``cm`` or ``mm``) or ``translation_scale`` (metres per unit) for ``T``.
  **Default metres**; a translation longer than 1 m gives a warning (millimetres by mistake?);
* ``depth_scale`` (metres per unit of integer depth files): required unless the caller passes one;
* ``max_range_m``: optional;
* aliases: ``K_color``/``K_rgb``/``K_depth``/``K_ir`` for the camera matrices, ``D_color``/``D_rgb``/
  ``D_depth``/``D_ir`` (or ``dist_*``) for the distortion, ``image_size_color``/``image_size_depth``,
  and ``T_color_from_depth`` (4x4) in place of ``R`` and ``T``. Aliases follow ``color_camera``, so
  ``K_color`` is ``cameraMatrix2`` by default; giving both names of one quantity is an error.

The outputs of stereoCalibrate that pcdof does not use (``E``, ``F``, ``R1``, ``P1``, ``Q``, ...) are
accepted silently; other unknown keys give a warning. Fisheye (``cv2.fisheye``) models are not supported.

Open3D ``PinholeCameraIntrinsic`` JSON (``open3d.io.write_pinhole_camera_intrinsic``)::

    {"width": W, "height": H, "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]}   # column-major

describes one camera whose depth is already registered to colour: the result is
:meth:`Rig.registered <pcdof.camera.Rig.registered>`. Optional ``depth_scale`` and ``max_range_m``
keys may be added (Open3D ignores them); otherwise the caller must pass ``depth_scale``.
"""

from __future__ import annotations

import json
import math
import re
import warnings
import zlib

import cv2
import numpy as np

from ..camera import MAX_IMAGE_SIDE, Intrinsics, Rig, check_depth_scale, validate_rigid
from ..errors import CalibrationError, InputError
from ._files import fspath, read_bytes

#: Longest depth-to-colour translation (metres) accepted without a warning.
MAX_PLAUSIBLE_BASELINE_M = 1.0
#: Deepest nesting an OpenCV FileStorage file (YAML / XML) may possibly have; see :func:`_filestorage_depth_bound`.
#: OpenCV's parsers recurse once per level and overflow the stack (a crash, not an error) at some 30 000
#: levels (about 250 bytes of an 8 MiB stack each); a calibration needs 3.
MAX_FILESTORAGE_NESTING = 10_000
#: Largest decompressed ``.gz`` FileStorage file read, bytes.
MAX_FILESTORAGE_BYTES = 64 << 20

_CALIB_KEYS = {"color", "depth", "depth_scale", "T_color_from_depth", "max_range_m"}
_INTRINSIC_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "distortion"}
_OPEN3D_KEYS = {"width", "height", "intrinsic_matrix", "depth_scale", "max_range_m",
                "class_name", "version_major", "version_minor"}
# Written by cv2.stereoCalibrate / stereoRectify scripts, not needed here: accepted without a warning.
_OPENCV_IGNORED = {"E", "F", "R1", "R2", "P1", "P2", "Q", "rms", "RMS", "reprojection_error", "perViewErrors",
                   "validRoi1", "validRoi2", "roi1", "roi2", "calibration_time", "calibrationDate", "nframes",
                   "flags", "square_size", "board_width", "board_height"}
_OPENCV_MARKERS = ("cameraMatrix1", "cameraMatrix2", "K_color", "K_depth", "K_rgb", "K_ir")
_UNITS = {"m": 1.0, "metre": 1.0, "metres": 1.0, "meter": 1.0, "meters": 1.0,
          "cm": 0.01, "mm": 0.001, "millimetre": 0.001, "millimetres": 0.001, "millimeter": 0.001,
          "millimeters": 0.001}


def read_calibration(path, *, depth_scale: float | None = None, default_depth_scale: float | None = None) -> Rig:
    """Read a calibration file into a :class:`~pcdof.camera.Rig`.

    Parameters
    ----------
    path : str or os.PathLike
        ``calib.json``, an OpenCV FileStorage file (YAML / XML / JSON) or an Open3D
        ``PinholeCameraIntrinsic`` JSON; see the module documentation for each schema.
    depth_scale : float, optional
        Metres per unit of integer depth files. Overrides the file's ``depth_scale``, and is
        required for files that have none (unless *default_depth_scale* is given).
    default_depth_scale : float, optional
        Metres per unit used when neither *depth_scale* nor the file gives one (a dataset layout's
        convention, e.g. TUM RGB-D's 0.0002).

    Returns
    -------
    Rig

    Raises
    ------
    ImageReadError
        The file is missing or unreadable.
    CalibrationError
        Unknown format, a missing key, a wrong type, a non-finite or impossible value, or a
        non-rigid transform; the message names the file and the key.

    Examples
    --------
    >>> rig = read_calibration("data/real/tum_rgbd_open3d/calib.json")  # doctest: +SKIP
    >>> rig.color.fx, rig.depth_scale  # doctest: +SKIP
    (525.0, 0.0002)
    """
    path = fspath(path, name="calibration path")
    if depth_scale is not None:
        depth_scale = scale_argument(depth_scale)
    if default_depth_scale is not None:
        default_depth_scale = check_depth_scale(default_depth_scale, InputError, "default_depth_scale")
    data = read_bytes(path, "calibration")
    unknown: list[str] = []
    try:
        kind, obj = _detect(path, data)
        if kind == "opencv":
            rig = _rig_from_opencv(_read_filestorage(path, data), (depth_scale, default_depth_scale), unknown)
        elif kind == "open3d":
            rig = _rig_from_open3d(obj, (depth_scale, default_depth_scale), unknown)
        else:
            rig = _rig_from_calib_json(obj, (depth_scale, default_depth_scale), unknown)
    except CalibrationError as err:
        raise CalibrationError(f"{path}: {err}") from None
    if unknown:
        warnings.warn(f"{path}: ignoring unknown calibration keys: {', '.join(sorted(unknown))}", stacklevel=2)
    if rig.baseline_m > MAX_PLAUSIBLE_BASELINE_M:
        note = "set units: mm or translation_scale" if kind == "opencv" else "T_color_from_depth must be in metres"
        warnings.warn(
            f"{path}: the depth-to-colour translation is {rig.baseline_m:.3g} m, far more than an RGB-D rig's "
            f"few centimetres; is it in millimetres? ({note})",
            stacklevel=2,
        )
    return rig


def scale_argument(value) -> float:
    return check_depth_scale(value, InputError)


def _detect(path: str, data: bytes) -> tuple[str, dict | None]:
    """("calib" | "open3d" | "opencv", parsed JSON object or None)."""
    head = data.lstrip(b"\xef\xbb\xbf \t\r\n")
    name = path.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    if head.startswith((b"%YAML", b"<?xml", b"<opencv_storage")) or name.endswith((".yml", ".yaml", ".xml")):
        return "opencv", None
    if head.startswith(b"{"):
        try:
            obj = json.loads(data.decode("utf-8-sig"))
        except UnicodeDecodeError:
            raise CalibrationError("not a text file (expected JSON, YAML or XML)") from None
        except json.JSONDecodeError as err:
            raise CalibrationError(f"is not valid JSON: {err}") from None
        except ValueError as err:  # e.g. an integer of more than sys.get_int_max_str_digits() digits
            reason = str(err).split(";")[0]  # without the advice to call sys.set_int_max_str_digits
            raise CalibrationError(f"is not a calibration: its JSON cannot be read ({reason})") from None
        except RecursionError:
            raise CalibrationError("is not a calibration: its JSON is nested too deeply to be read") from None
        if not isinstance(obj, dict):
            raise CalibrationError(f"must hold a JSON object; got {type(obj).__name__}")
        if "intrinsic_matrix" in obj:
            return "open3d", obj
        if any(k in obj for k in _OPENCV_MARKERS):  # JSON written by cv2.FileStorage
            return "opencv", None
        if _CALIB_KEYS & set(obj):
            return "calib", obj
        raise CalibrationError(
            "unrecognised calibration JSON: expected calib.json keys (color, depth, depth_scale, T_color_from_depth), "
            "Open3D keys (width, height, intrinsic_matrix) or OpenCV keys (cameraMatrix1, cameraMatrix2, R, T, ...); "
            f"got keys {sorted(obj)}"
        )
    raise CalibrationError(
        "unrecognised calibration format: expected calib.json, an OpenCV FileStorage .yml/.xml or an Open3D "
        "intrinsic JSON"
    )


# -- value checks (messages name the key; read_calibration adds the file) ----------------------------------


def _require(obj: dict, key: str, where: str = "", hint: str = ""):
    if key not in obj:
        raise CalibrationError(f"missing key {where}{key}{f' ({hint})' if hint else ''}")
    return obj[key]


def _number(value, key: str, *, positive: bool = False) -> float:
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(()).item()
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CalibrationError(f"{key} must be a number; got {type(value).__name__} {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise CalibrationError(f"{key} must be finite; got an integer too large for a float "
                               f"({int(value).bit_length()} bits)") from None
    if not math.isfinite(v):
        raise CalibrationError(f"{key} must be finite; got {v}")
    if positive and v <= 0:
        raise CalibrationError(f"{key} must be > 0; got {v}")
    return v


def _side(value, key: str) -> int:
    v = _number(value, key)
    if not v.is_integer() or not 1 <= v <= MAX_IMAGE_SIDE:
        raise CalibrationError(f"{key} must be a whole number of pixels in [1, {MAX_IMAGE_SIDE}]; got {value!r}")
    return int(v)


def _numbers(value, key: str) -> np.ndarray:
    """A JSON list / nested list or an array of numbers as float64 (any shape); rejects str, bool, None."""
    if isinstance(value, np.ndarray):
        arr = value
        if arr.dtype.kind not in "fiu":
            raise CalibrationError(f"{key} must hold numbers; got dtype {arr.dtype}")
    else:
        if not isinstance(value, (list, tuple)):
            raise CalibrationError(f"{key} must be a list of numbers; got {type(value).__name__} {value!r}")
        try:
            arr = np.array(value, dtype=object)
        except ValueError:
            arr = None
        if arr is None or any(isinstance(v, (list, tuple)) for v in arr.ravel()):
            raise CalibrationError(f"{key} must be a rectangular list of numbers; got {value!r}")
        for v in arr.ravel():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise CalibrationError(f"{key} must hold numbers only; got {type(v).__name__} {v!r}")
    try:
        arr = np.asarray(arr, dtype=np.float64)
    except OverflowError:
        raise CalibrationError(f"{key} must be finite; got an integer too large for a float") from None
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{key} must be finite; got NaN or inf in {arr.tolist()}")
    return arr


def _intrinsics(width: int, height: int, K: np.ndarray, dist, key: str) -> Intrinsics:
    dist = tuple(float(d) for d in dist) or (0.0,) * 5  # none given: Intrinsics' own "no distortion"
    try:
        return Intrinsics(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)
    except CalibrationError as err:
        raise CalibrationError(f"{key}: {err}") from None


def _camera_matrix(value, key: str) -> np.ndarray:
    K = _numbers(value, key)
    if K.shape != (3, 3):
        raise CalibrationError(f"{key} must be a 3x3 camera matrix; got shape {K.shape}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0, atol=1e-9) or K[1, 0] != 0.0:
        raise CalibrationError(f"{key} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]; got {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
        raise CalibrationError(f"{key} has skew K[0, 1] = {K[0, 1]}; skewed camera matrices are not supported")
    for (i, j), name in (((0, 0), "fx"), ((1, 1), "fy")):
        if K[i, j] <= 0:
            raise CalibrationError(f"{key} {name} = K[{i}, {j}] must be > 0; got {K[i, j]}")
    return K


# -- calib.json --------------------------------------------------------------------------------------------


def _intrinsics_from_json(obj, name: str, unknown: list[str]) -> Intrinsics:
    if not isinstance(obj, dict):
        raise CalibrationError(
            f"{name} must be an object with width, height, fx, fy, cx, cy, distortion; got {type(obj).__name__}"
        )
    unknown.extend(f"{name}.{k}" for k in obj if k not in _INTRINSIC_KEYS and not _ignorable(k))
    width = _side(_require(obj, "width", f"{name}."), f"{name}.width")
    height = _side(_require(obj, "height", f"{name}."), f"{name}.height")
    vals = {k: _number(_require(obj, k, f"{name}."), f"{name}.{k}", positive=k in ("fx", "fy"))
            for k in ("fx", "fy", "cx", "cy")}
    dist = obj.get("distortion", [])
    dist = _numbers(dist if dist is not None else [], f"{name}.distortion").ravel()
    K = np.array([[vals["fx"], 0, vals["cx"]], [0, vals["fy"], vals["cy"]], [0, 0, 1]], dtype=np.float64)
    return _intrinsics(width, height, K, dist, name)


def _depth_scale(obj: dict, scales: tuple, hint: str) -> float:
    """The depth scale that applies: the caller's override, else the file's, else the caller's default."""
    override, default = scales
    if override is not None:
        return override
    if obj.get("depth_scale") is None and default is not None:
        return default
    value = _number(_require(obj, "depth_scale", hint=hint), "depth_scale", positive=True)
    return check_depth_scale(value)


def _ignorable(key: str) -> bool:
    return key.startswith("_") or key.lower() in ("comment", "comments", "description", "notes")


def _rig_from_calib_json(obj: dict, scales: tuple, unknown: list[str]) -> Rig:
    unknown.extend(k for k in obj if k not in _CALIB_KEYS and not _ignorable(k))
    color = _intrinsics_from_json(_require(obj, "color"), "color", unknown)
    depth = _intrinsics_from_json(_require(obj, "depth"), "depth", unknown)
    depth_scale = _depth_scale(obj, scales, "metres per depth unit, e.g. 0.001")
    T = _numbers(_require(obj, "T_color_from_depth", hint="4x4 rigid transform, metres"), "T_color_from_depth")
    T = validate_rigid(T, "T_color_from_depth")
    max_range = _number(obj["max_range_m"], "max_range_m", positive=True) if "max_range_m" in obj else 10.0
    return Rig(color, depth, T, depth_scale, max_range)


# -- Open3D PinholeCameraIntrinsic JSON ------------------------------------------------------------------


def _rig_from_open3d(obj: dict, scales: tuple, unknown: list[str]) -> Rig:
    unknown.extend(k for k in obj if k not in _OPEN3D_KEYS and not _ignorable(k))
    width = _side(_require(obj, "width"), "width")
    height = _side(_require(obj, "height"), "height")
    m = _numbers(_require(obj, "intrinsic_matrix"), "intrinsic_matrix")
    if m.size != 9 or m.ndim != 1:
        raise CalibrationError(f"intrinsic_matrix must be a list of 9 numbers (column-major 3x3); got shape {m.shape}")
    K = m.reshape(3, 3, order="F")  # Open3D stores the matrix column-major
    if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0, atol=1e-9):
        raise CalibrationError(
            "intrinsic_matrix must be Open3D's column-major [fx, 0, 0, 0, fy, 0, cx, cy, 1]; "
            f"got {m.tolist()} (row-major by mistake?)"
        )
    K = _camera_matrix(K, "intrinsic_matrix")
    intr = _intrinsics(width, height, K, (), "intrinsic_matrix")
    depth_scale = _depth_scale(obj, scales, "Open3D intrinsics have no depth scale: add \"depth_scale\" (metres "
                               "per depth unit) to the file or pass depth_scale / --depth-scale")
    max_range = _number(obj["max_range_m"], "max_range_m", positive=True) if "max_range_m" in obj else 10.0
    return Rig.registered(intr, depth_scale=depth_scale, max_range_m=max_range)


# -- OpenCV FileStorage ------------------------------------------------------------------------------------


def _cv_message(err: BaseException) -> str:
    cause = err.__cause__ if isinstance(err.__cause__, cv2.error) else err
    msg = str(getattr(cause, "msg", cause) or cause).strip()
    return msg.split("error: ", 1)[-1]


def _filestorage_text(path: str, data: bytes) -> bytes:
    """The text cv2.FileStorage will parse: *data*, decompressed for a ``.gz`` file (at most MAX_FILESTORAGE_BYTES)."""
    if not path.lower().endswith(".gz"):
        return data
    inflater = zlib.decompressobj(16 + zlib.MAX_WBITS)  # gzip framing
    try:
        text = inflater.decompress(data, MAX_FILESTORAGE_BYTES + 1)
    except zlib.error as err:
        raise CalibrationError(f"is not a valid gzip file ({err})") from None
    if len(text) > MAX_FILESTORAGE_BYTES:
        raise CalibrationError(f"decompresses to more than {MAX_FILESTORAGE_BYTES >> 20} MiB; not a calibration")
    return text


_XML_OPEN_TAG = re.compile(rb"<(?![/?!])")
_YAML_LINE = re.compile(rb"^([ \t]*)(.*)$", re.MULTILINE)


def _filestorage_depth_bound(text: bytes) -> int:
    """An upper bound of the nesting depth cv2.FileStorage reaches in *text*, counted without parsing.

    XML: the number of opening tags. YAML (and FileStorage JSON): the number of ``[`` and ``{`` (flow
    collections) plus the largest, over the lines, of the indentation and the ``:`` and ``-`` in the
    line (block levels: each has its own column, and a line opens at most one per ``key:`` or ``- ``).
    Comments and strings are counted too, so the bound is never too low.
    """
    if text.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<"):
        return len(_XML_OPEN_TAG.findall(text))
    flow = text.count(b"[") + text.count(b"{")
    block = max((len(m[1]) + m[2].count(b":") + m[2].count(b"-") for m in _YAML_LINE.finditer(text)), default=0)
    return flow + block


def _read_filestorage(path: str, data: bytes) -> dict:
    """Top-level entries of a FileStorage file as Python values (matrices as float64 arrays).

    Files that might nest deeper than MAX_FILESTORAGE_NESTING are refused before OpenCV parses them:
    its recursive parsers would crash the process.
    """
    depth = _filestorage_depth_bound(_filestorage_text(path, data))
    if depth > MAX_FILESTORAGE_NESTING:
        raise CalibrationError(
            f"is not a calibration: its entries may be nested up to {depth} levels deep, more than the "
            f"{MAX_FILESTORAGE_NESTING} cv2.FileStorage can read safely"
        )
    try:
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    except Exception as err:  # noqa: BLE001 - cv2 raises cv2.error or SystemError on a parse error
        raise CalibrationError(f"cannot be parsed by cv2.FileStorage: {_cv_message(err)}") from None
    try:
        if not fs.isOpened():
            raise CalibrationError("cannot be opened by cv2.FileStorage")
        root = fs.root()
        if not root.isMap():
            raise CalibrationError("must hold a map of named entries (cameraMatrix1, ..., R, T)")
        try:
            return {key: _node_value(root.getNode(key), key) for key in root.keys()}
        except RecursionError:
            raise CalibrationError("is not a calibration: its entries are nested too deeply to be read") from None
    finally:
        fs.release()


def _node_value(node, key: str):
    if node.empty() or node.isNone():
        return None
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if node.isMap():
        keys = node.keys()
        if {"rows", "cols", "data"} <= set(keys) or {"sizes", "dt", "data"} <= set(keys):  # 2-D or n-D matrix
            try:
                return np.asarray(node.mat(), dtype=np.float64)
            except Exception as err:  # noqa: BLE001
                raise CalibrationError(f"{key} is not a readable OpenCV matrix: {_cv_message(err)}") from None
        return {k: _node_value(node.getNode(k), f"{key}.{k}") for k in keys}
    if node.isSeq():
        return [_node_value(node.at(i), f"{key}[{i}]") for i in range(node.size())]
    return None


def _pick(obj: dict, names: list[str], used: set, *, what: str, required: bool):
    present = [n for n in names if obj.get(n) is not None]
    if len(present) > 1:
        raise CalibrationError(f"both {present[0]} and {present[1]} are given for {what}; keep one")
    if not present:
        if required:
            also = f"; also accepted: {', '.join(names[1:])}" if len(names) > 1 else ""
            raise CalibrationError(f"missing key {names[0]} ({what}{also})")
        return None, None
    used.add(present[0])
    return present[0], obj[present[0]]


def _image_size(value, key: str) -> tuple[int, int]:
    if isinstance(value, dict):
        return (_side(_require(value, "width", f"{key}."), f"{key}.width"),
                _side(_require(value, "height", f"{key}."), f"{key}.height"))
    arr = _numbers(value, key).ravel()
    if arr.size != 2:
        raise CalibrationError(f"{key} must be [width, height]; got {arr.tolist()}")
    return _side(arr[0], f"{key} width"), _side(arr[1], f"{key} height")


def _opencv_camera(obj: dict, n: int, roles: tuple[str, ...], label: str, used: set) -> Intrinsics:
    kname, K = _pick(obj, [f"cameraMatrix{n}", f"K{n}", f"M{n}"] + [f"K_{r}" for r in roles]
                     + [f"camera_matrix_{r}" for r in roles], used, what=f"{label} camera matrix", required=True)
    K = _camera_matrix(K, kname)
    dname, dist = _pick(obj, [f"distCoeffs{n}", f"D{n}"] + [f"{p}_{r}" for p in ("D", "dist", "distortion")
                                                              for r in roles],
                        used, what=f"{label} distortion", required=False)
    dist = _numbers(dist, dname).ravel() if dname else np.zeros(0)
    sname, size = _pick(obj, [f"imageSize{n}"] + [f"image_size_{r}" for r in roles], used,
                        what=f"{label} image size", required=False)
    if sname is None:
        if obj.get("imageSize") is not None:
            sname, size = "imageSize", obj["imageSize"]
            used.add(sname)
        elif obj.get("image_width") is not None or obj.get("image_height") is not None:
            size = {"width": _require(obj, "image_width"), "height": _require(obj, "image_height")}
            sname = "image_width/image_height"
            used.update(("image_width", "image_height"))
        else:
            raise CalibrationError(
                f"missing key imageSize{n} ({label} image size [width, height]; or imageSize, or image_width and "
                "image_height, for both cameras)"
            )
    width, height = _image_size(size, sname)
    return _intrinsics(width, height, K, dist, kname)


def _rig_from_opencv(obj: dict, scales: tuple, unknown: list[str]) -> Rig:
    used = {"color_camera", "units", "translation_scale", "depth_scale", "max_range_m"}
    color_camera = obj.get("color_camera", 2)
    if isinstance(color_camera, str) and color_camera.strip() in ("1", "2"):
        color_camera = int(color_camera)
    if color_camera not in (1, 2) or isinstance(color_camera, bool):
        raise CalibrationError(f"color_camera must be 1 or 2; got {color_camera!r}")
    depth_camera = 3 - color_camera
    color = _opencv_camera(obj, color_camera, ("color", "rgb"), "colour", used)
    depth = _opencv_camera(obj, depth_camera, ("depth", "ir"), "depth", used)

    if obj.get("units") is not None and obj.get("translation_scale") is not None:
        raise CalibrationError("both units and translation_scale are given; keep one")
    scale = 1.0
    if obj.get("units") is not None:
        units = obj["units"]
        if not isinstance(units, str) or units.strip().lower() not in _UNITS:
            raise CalibrationError(f"units must be one of m, cm, mm; got {units!r}")
        scale = _UNITS[units.strip().lower()]
    elif obj.get("translation_scale") is not None:
        scale = _number(obj["translation_scale"], "translation_scale", positive=True)

    tname, T4 = _pick(obj, ["T_color_from_depth"], used, what="extrinsics", required=False)
    if T4 is not None:
        if obj.get("R") is not None or obj.get("T") is not None:
            raise CalibrationError("both T_color_from_depth and R/T are given; keep one")
        M = _numbers(T4, tname)
        if M.shape != (4, 4):
            raise CalibrationError(f"T_color_from_depth must be 4x4; got shape {M.shape}")
        M = M.copy()
        M[:3, 3] *= scale
        M = validate_rigid(M, "T_color_from_depth")
    else:
        _, R = _pick(obj, ["R"], used, what="rotation from camera 1 to camera 2 (p2 = R p1 + T)", required=True)
        _, T = _pick(obj, ["T"], used, what="translation from camera 1 to camera 2 (p2 = R p1 + T)", required=True)
        R = _numbers(R, "R")
        if R.size == 3:
            R = cv2.Rodrigues(R.reshape(3, 1))[0]
        if R.shape != (3, 3):
            raise CalibrationError(f"R must be a 3x3 rotation matrix or a Rodrigues 3-vector; got shape {R.shape}")
        T = _numbers(T, "T").ravel()
        if T.size != 3:
            raise CalibrationError(f"T must be a 3-vector; got {T.tolist()}")
        M = np.eye(4)
        M[:3, :3] = R
        M[:3, 3] = T * scale
        M = validate_rigid(M, "R, T")
        if color_camera == 1:  # (R, T) maps colour (camera 1) into depth (camera 2): invert it
            inv = np.eye(4)
            inv[:3, :3] = M[:3, :3].T
            inv[:3, 3] = -M[:3, :3].T @ M[:3, 3]
            M = inv
    depth_scale = _depth_scale(obj, scales, "metres per depth unit, e.g. 0.001; add it or pass depth_scale / "
                               "--depth-scale")
    max_range = _number(obj["max_range_m"], "max_range_m", positive=True) if obj.get("max_range_m") is not None \
        else 10.0
    unknown.extend(k for k in obj if k not in used and k not in _OPENCV_IGNORED and not _ignorable(k))
    return Rig(color, depth, M, depth_scale, max_range)


__all__ = ["read_calibration", "MAX_PLAUSIBLE_BASELINE_M"]
