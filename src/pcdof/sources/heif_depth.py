"""HEIF/HEIC depth photos: an iPhone Portrait photo and the depth map stored beside it.

Read with pillow-heif (libheif). The photo is the primary image; the depth is its auxiliary depth
image (``urn:mpeg:hevc:2015:auxid:2``), with depth representation information (ISO/IEC 23008-12,
after H.265's depth representation SEI)::

    representation_type   stored value v (0..1) is linear in      range from
    0 uniform inverse Z   1/z                                     z_near, z_far (metres)
    1 uniform disparity   disparity (Apple: 1/z in 1/m)           d_min, d_max
    2 uniform Z           z                                       z_near, z_far (metres)
    3 non-uniform disparity: a piecewise model (refused: no phone writes it)

libheif applies the primary image's rotation and mirroring (``irot``/``imir``); the EXIF orientation
of a HEIF file describes the same turn. A depth item that carries no turn of its own arrives in the
stored orientation: when its aspect ratio disagrees with the upright photo's, the EXIF orientation is
applied to it too, so that colour and depth end up turned alike. Intrinsics: the EXIF 35 mm equivalent
focal length (:func:`~pcdof.sources.phone.photo_intrinsics`).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..errors import ImageReadError
from .phone import PhoneDepthSource, check_aspect, depth_from_normalized, exif_tags, orient, phone_rig, photo_intrinsics

#: ISO BMFF brands of HEIF still images (the ``ftyp`` box's major or compatible brands)
HEIF_BRANDS = (b"heic", b"heix", b"heim", b"heis", b"mif1", b"msf1", b"hevc", b"avif")
#: representation_type -> (name, stored value linear in ..., range keys)
REPRESENTATIONS = {0: ("uniform inverse Z", "inverse", ("z_near", "z_far")),
                   1: ("uniform disparity", "disparity", ("d_min", "d_max")),
                   2: ("uniform Z", "linear", ("z_near", "z_far")),
                   3: ("non-uniform disparity", None, ("d_min", "d_max"))}


def can_open(path: str, head: bytes) -> bool:
    """An ISO BMFF file whose ``ftyp`` names a HEIF brand, or a ``.heic``/``.heif`` name."""
    if os.path.isdir(path):
        return False
    if len(head) >= 12 and head[4:8] == b"ftyp":
        size = int.from_bytes(head[:4], "big")
        brands = [head[8:12]] + [head[i:i + 4] for i in range(16, min(size, len(head)) - 3, 4)]
        return any(b in HEIF_BRANDS for b in brands)
    return not head and path.lower().endswith((".heic", ".heif"))


def _pillow_heif():
    try:
        import pillow_heif
    except ImportError:
        raise ImageReadError("reading HEIC depth photos needs pillow-heif: pip install pillow-heif") from None
    return pillow_heif


def depth_from_heif(values: np.ndarray, metadata: dict) -> tuple[np.ndarray, dict]:
    """Metres from a HEIF depth image and its depth representation information.

    Parameters
    ----------
    values : (h, w) uint8 or uint16 ndarray, the decoded depth image
    metadata : dict, pillow-heif's ``HeifDepthImage.info["metadata"]`` (``representation_type`` and
        ``z_near``/``z_far`` or ``d_min``/``d_max``)

    Returns
    -------
    depth_m : (h, w) float32, metres (> 0 everywhere)
    info : dict, the representation's name and range, for ``pcdof info``

    Raises
    ------
    ImageReadError
        An unknown or unsupported representation, or a missing or impossible range.
    """
    kind = metadata.get("representation_type")
    if kind not in REPRESENTATIONS:
        raise ImageReadError(f"the depth image has an unknown depth representation type {kind!r} (expected 0-3)")
    name, fmt, keys = REPRESENTATIONS[kind]
    if fmt is None:
        raise ImageReadError(f"the depth image uses {name} (type {kind}), which needs a non-linear model pcdof "
                             "does not read")
    lo, hi = (metadata.get(k) for k in keys)
    if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in (lo, hi)) or not lo < hi:
        raise ImageReadError(f"the depth image's {keys[0]} and {keys[1]} must be finite with 0 < {keys[0]} < "
                             f"{keys[1]}; got {lo!r}, {hi!r}")
    top = 255.0 if values.dtype == np.uint8 else float(np.iinfo(values.dtype).max) if values.dtype.kind == "u" \
        else 1.0
    v = values.astype(np.float64) / top
    info = {"representation": name, "representation_type": kind, keys[0]: lo, keys[1]: hi,
            "bits": 8 * values.dtype.itemsize}
    if fmt == "disparity":
        # linear in disparity between d_min and d_max; Apple's disparity is 1/z in 1/m, so this is linear
        # in 1/z between 1/d_max (near, at v = 1) and 1/d_min (far, at v = 0)
        near, far = 1.0 / hi, 1.0 / lo
        info["units"] = "disparity in 1/m (1/z), as Apple writes it"
    else:
        near, far = float(lo), float(hi)
    # inverse Z and disparity grow towards the camera (v = 1 at near): the rule's v (0 at near) is 1 - v
    depth = depth_from_normalized(v if fmt == "linear" else 1.0 - v, near, far, "linear" if fmt == "linear"
                                  else "inverse")
    return depth, {**info, "near_m": near, "far_m": far}


class HeifDepthSource(PhoneDepthSource):
    """A HEIF/HEIC photo with a depth image (iPhone Portrait); see the module documentation."""

    format = "heif-depth"

    @classmethod
    def open(cls, path: str, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "HeifDepthSource":
        """Decode the photo and its depth map."""
        cls.check_options(path, calib, depth_scale, max_difference_s)
        color, values, metadata, exif = decode_heif(path)
        tags = exif_tags(exif)
        depth_m, depth_info = depth_from_heif(values, metadata)
        turned = False
        if (depth_m.shape[0] > depth_m.shape[1]) != (color.shape[0] > color.shape[1]) \
                and (tags["orientation"] or 1) >= 5:  # stored unturned: turn it as the photo was
            depth_m, turned = orient(depth_m, tags["orientation"]), True
        check_aspect(color.shape, depth_m.shape)
        intrinsics, origin = photo_intrinsics(color.shape[1], color.shape[0], tags)
        rig = phone_rig(intrinsics, depth_m.shape, max_range_m=depth_info["far_m"])
        depth_info.update(width=depth_m.shape[1], height=depth_m.shape[0], turned_by_exif=turned)
        camera = {"intrinsics_from": origin, "exif_orientation": tags["orientation"],
                  "focal_length_mm": tags["focal_length_mm"], "focal_35mm": tags["focal_35mm"],
                  "f_number": tags["f_number"], "model": tags["model"]}
        return cls(path, color, depth_m, rig, depth_info=depth_info, camera_info=camera)


def decode_heif(path: str) -> tuple[np.ndarray, np.ndarray, dict, bytes | None]:
    """(colour (H, W, 3) uint8 upright, depth values (h, w), depth metadata, EXIF bytes) of a HEIF file."""
    pillow_heif = _pillow_heif()
    try:
        heif = pillow_heif.open_heif(path, convert_hdr_to_8bit=True)
        depths = heif.info.get("depth_images") or []
        if not depths:
            raise ImageReadError(f"{path} has no depth image: not a Portrait photo (a HEIC without depth is an "
                                 "ordinary photo; give its depth map as a second file)")
        image = heif.to_pillow().convert("RGB")
        color = np.asarray(image)
        depth = depths[0]
        values = np.asarray(depth.to_pillow())
        metadata = dict(depth.info.get("metadata") or {})
    except ImageReadError:
        raise
    except (OSError, ValueError, RuntimeError, SyntaxError) as err:
        raise ImageReadError(f"cannot read HEIF file {path}: {err}") from None
    if values.ndim == 3:
        values = values[..., 0]
    return np.ascontiguousarray(color), values, metadata, heif.info.get("exif")
