"""Android depth photos: JPEGs with a depth map, in Dynamic Depth 1.0 or the older GDepth XMP.

**Dynamic Depth 1.0** (Google, 2019): the primary JPEG's XMP describes a ``Device`` with a
``Container:Directory`` of items (``Item:Mime``, ``Item:Length``, ``Item:DataURI``, optional
``Item:Padding``); the first item is the primary image, the others are files appended after its
end-of-image marker in that order. ``Device:Cameras`` holds a ``Camera:DepthMap`` (``DepthMap:Format``
``RangeLinear``/``RangeInverse``, ``Near``, ``Far``, ``Units``, ``DepthURI`` naming an item) and
a ``Camera:ImagingModel`` (``FocalLengthX/Y``, ``PrincipalPointX/Y``, ``ImageWidth/Height``): the
intrinsics of the camera.

**GDepth** (Google's Lens Blur format, 2014): ``GDepth:Format``, ``Near``, ``Far``, ``Mime`` in the
standard XMP and the depth file itself, base64, in ``GDepth:Data`` in the extended XMP. No intrinsics:
the EXIF 35 mm equivalent focal length gives them. Lens Blur's depth comes from structure from
motion, at an arbitrary scale: its Near and Far are not metres (``pcdof info`` says so); a blur given
as a share of the image width (``--blur``) does not depend on the scale.

Both store the depth normalised to 8 (or 16) bits in the stored (unrotated) orientation of the photo;
the EXIF orientation turns photo, depth and intrinsics alike.
"""

from __future__ import annotations

import base64
import binascii
import os

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import ImageReadError
from ..io._files import decode_image, read_bytes, sniff
from .jpeg_xmp import find_property, primary_end, prop, read_segments, xmp_roots
from .phone import PhoneDepthSource, check_aspect, depth_from_normalized, exif_tags, orient, phone_rig, \
    photo_intrinsics, scaled_intrinsics

NS_GDEPTH = "http://ns.google.com/photos/1.0/depthmap/"
_DD = "http://ns.google.com/photos/dd/1.0/"
NS = {name: f"{_DD}{name.lower()}/" for name in ("Device", "Container", "Item", "Camera", "DepthMap", "ImagingModel")}
#: DepthMap / GDepth Format -> :func:`~pcdof.sources.phone.depth_from_normalized` rule
FORMATS = {"RangeLinear": "linear", "RangeInverse": "inverse"}
#: DepthMap:Units / GDepth:Units -> metres per unit (None: the file gives no scale)
UNITS = {"Meters": 1.0, "m": 1.0, "Millimeters": 0.001, "mm": 0.001, "None": None, None: None}
_SNIFF_BYTES = 1 << 20


def can_open(path: str, head: bytes) -> bool:
    """A JPEG whose XMP mentions a Dynamic Depth device or GDepth (read from the first MiB)."""
    if os.path.isdir(path) or not head.startswith(b"\xff\xd8"):
        return False
    try:
        with open(path, "rb") as f:
            start = f.read(_SNIFF_BYTES)
    except OSError:
        return False
    return NS_GDEPTH.encode() in start or f"{_DD}device/".encode() in start


def orient_intrinsics(cam: Intrinsics, orientation: int | None) -> Intrinsics:
    """*cam* of the stored image, for the image turned upright by EXIF *orientation* (as :func:`orient`)."""
    W, H, fx, fy, cx, cy = cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy
    code = orientation or 1
    if code >= 5:  # transpose first
        W, H, fx, fy, cx, cy = H, W, fy, fx, cy, cx
    if code in (2, 3, 6, 7):
        cx = W - 1 - cx
    if code in (3, 4, 7, 8):
        cy = H - 1 - cy
    return Intrinsics(W, H, fx, fy, cx, cy)


class DepthJpegSource(PhoneDepthSource):
    """A JPEG depth photo (Dynamic Depth 1.0 or GDepth); see the module documentation."""

    format = "depth-jpeg"

    @classmethod
    def open(cls, path: str, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "DepthJpegSource":
        """Decode the photo, its depth map and camera."""
        cls.check_options(path, calib, depth_scale, max_difference_s)
        data = read_bytes(path, "depth photo")
        meta = read_segments(data, path)
        roots = xmp_roots(meta, path)
        bgr = decode_image(data, "jpeg", path, "depth photo")
        color = cv2.cvtColor(bgr, cv2.COLOR_GRAY2RGB if bgr.ndim == 2 else cv2.COLOR_BGR2RGB)
        tags = exif_tags(meta.exif)
        device = next((e for r in roots for e in r.iter(f"{{{NS['Device']}}}Cameras")), None)
        if device is not None:
            values, depth_info, cam = _dynamic_depth(roots, data, meta.scan_start, path)
        elif any(find_property(r, NS_GDEPTH, "Format") is not None for r in roots):
            values, depth_info, cam = _gdepth(roots, path), _gdepth_info(roots, path), None
        else:
            raise ImageReadError(f"{path} has no depth map: its XMP holds neither Dynamic Depth nor GDepth")
        stored_h, stored_w = color.shape[:2]
        if cam is not None:
            origin = "Dynamic Depth ImagingModel"
            if (cam.width, cam.height) != (stored_w, stored_h):  # the model of another size of the same photo
                cam = scaled_intrinsics(cam, stored_w, stored_h)
            intrinsics = orient_intrinsics(cam, tags["orientation"])
        color = orient(color, tags["orientation"] or 1)
        values = orient(values, tags["orientation"] or 1)
        check_aspect(color.shape, values.shape)
        if cam is None:
            intrinsics, origin = photo_intrinsics(color.shape[1], color.shape[0], tags)
        top = 255.0 if values.dtype == np.uint8 else 65535.0
        unit = UNITS.get(depth_info.get("units"), None)
        scale = unit if unit is not None else 1.0
        near, far = depth_info["near"] * scale, depth_info["far"] * scale
        depth_m = depth_from_normalized(values / top, near, far, FORMATS[depth_info["format"]])
        depth_info.update(near_m=near, far_m=far, width=values.shape[1], height=values.shape[0],
                          bits=8 * values.dtype.itemsize, metric=unit is not None)
        rig = phone_rig(intrinsics, depth_m.shape, max_range_m=far)
        camera = {"intrinsics_from": origin, "exif_orientation": tags["orientation"],
                  "focal_length_mm": tags["focal_length_mm"], "focal_35mm": tags["focal_35mm"],
                  "f_number": tags["f_number"], "model": tags["model"]}
        return cls(path, color, depth_m, rig, depth_info=depth_info, camera_info=camera)


def _number(value, what: str, path: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ImageReadError(f"{path}: {what} must be a number; got {value!r}") from None
    if not np.isfinite(v):
        raise ImageReadError(f"{path}: {what} must be finite; got {value!r}")
    return v


def _range_info(fmt, near, far, units, path: str, what: str) -> dict:
    if fmt not in FORMATS:
        raise ImageReadError(f"{path}: {what}Format must be one of {', '.join(FORMATS)}; got {fmt!r}")
    if units not in UNITS:
        raise ImageReadError(f"{path}: {what}Units must be one of Meters, Millimeters, None; got {units!r}")
    near, far = _number(near, f"{what}Near", path), _number(far, f"{what}Far", path)
    if not 0 < near < far:
        raise ImageReadError(f"{path}: {what}Near and Far must satisfy 0 < Near < Far; got {near:g}, {far:g}")
    return {"format": fmt, "near": near, "far": far, "units": units}


def _decode_depth(blob: bytes, path: str, what: str) -> np.ndarray:
    """A depth file (PNG or JPEG bytes) as (h, w) uint8 or uint16 values."""
    kind = sniff(blob)
    if kind not in ("png", "jpeg"):
        raise ImageReadError(f"{path}: the {what} is not a PNG or JPEG file")
    img = decode_image(blob, kind, path, what)
    if img.ndim == 3:
        img = img[..., 0]
    if img.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"{path}: the {what} must hold 8- or 16-bit values; got {img.dtype}")
    return img


def _gdepth_info(roots, path: str) -> dict:
    def get(name):
        return next((v for r in roots if (v := find_property(r, NS_GDEPTH, name)) is not None), None)

    info = _range_info(get("Format"), get("Near"), get("Far"), get("Units"), path, "GDepth:")
    return {"container": "GDepth", **info, "mime": get("Mime")}


def _gdepth(roots, path: str) -> np.ndarray:
    data = next((v for r in roots if (v := find_property(r, NS_GDEPTH, "Data")) is not None), None)
    if data is None:
        raise ImageReadError(f"{path}: GDepth metadata without GDepth:Data (the depth map is missing)")
    try:
        blob = base64.b64decode("".join(data.split()), validate=True)
    except (binascii.Error, ValueError):
        raise ImageReadError(f"{path}: GDepth:Data is not valid base64") from None
    return _decode_depth(blob, path, "GDepth depth map")


def _dynamic_depth(roots, data: bytes, scan_start: int, path: str):
    """(depth values, depth info, camera intrinsics or None) of a Dynamic Depth file."""
    items = [e for r in roots for e in r.iter(f"{{{NS['Container']}}}Item")]
    depth_map = next((e for r in roots for e in r.iter(f"{{{NS['Camera']}}}DepthMap")), None)
    if depth_map is None or not items:
        raise ImageReadError(f"{path}: Dynamic Depth metadata without a depth map or a container directory")
    def g(name):
        return prop(depth_map, NS["DepthMap"], name)

    info = {"container": "Dynamic Depth 1.0", **_range_info(g("Format"), g("Near"), g("Far"), g("Units"), path,
                                                            "DepthMap:")}
    info.update(measure=g("MeasureType") or "OpticalAxis", semantic=g("ItemSemantic"))
    uri = g("DepthURI")
    offset = primary_end(data, scan_start, path)
    blob = None
    for k, item in enumerate(items):
        length = int(_number(prop(item, NS["Item"], "Length") or 0, "Item:Length", path))
        padding = int(_number(prop(item, NS["Item"], "Padding") or 0, "Item:Padding", path))
        if k == 0:  # the primary image: its bytes are the JPEG before the appended items
            continue
        if length < 0 or offset + length > len(data):
            raise ImageReadError(f"{path}: the container item {prop(item, NS['Item'], 'DataURI')!r} runs past the "
                                 "end of the file (truncated)")
        if prop(item, NS["Item"], "DataURI") == uri:
            blob = data[offset:offset + length]
            break
        offset += length + padding
    if blob is None:
        raise ImageReadError(f"{path}: the depth map's item {uri!r} is not in the container directory")
    values = _decode_depth(blob, path, "Dynamic Depth depth map")
    model = next((e for r in roots for e in r.iter(f"{{{NS['Camera']}}}ImagingModel")), None)
    return values, info, _imaging_model(model, path) if model is not None else None


def _imaging_model(model, path: str) -> Intrinsics:
    """Intrinsics of a Dynamic Depth ImagingModel (pixels; normalised values (<= 1) scaled by the image size)."""
    def get(name):
        return _number(prop(model, NS["ImagingModel"], name), f"ImagingModel:{name}", path)

    w, h = int(get("ImageWidth")), int(get("ImageHeight"))
    fx, fy, cx, cy = get("FocalLengthX"), get("FocalLengthY"), get("PrincipalPointX"), get("PrincipalPointY")
    if fx <= 1.0 and fy <= 1.0:  # the specification's normalised form: by the larger image side
        fx, fy = fx * max(w, h), fy * max(w, h)
    if 0 <= cx <= 1.0 and 0 <= cy <= 1.0:
        cx, cy = cx * w, cy * h
    return Intrinsics(w, h, fx, fy, cx, cy)
