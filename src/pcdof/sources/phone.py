"""What phone depth photos share: one frame, a depth map in the colour camera at another resolution.

A phone stores the depth it measured (or estimated) beside the photo, in the photo's own camera:
same optical centre, same field of view, fewer pixels (an iPhone's 768x576 map beside its 4032x3024
photo). :func:`phone_rig` says exactly that as a :class:`~pcdof.camera.Rig` (identity extrinsics,
the colour intrinsics scaled to the depth grid), so pcdof's ordinary registration back-projects the
depth pixels, reprojects them into the photo, and the colour-guided fill upsamples them: depth edges
then follow the photo's edges, not the depth grid.

The depth is stored normalised (8 or 16 bits) with a near and a far distance and a rule saying how
the stored value maps to distance (:func:`depth_from_normalized`). Intrinsics come from what the file
holds (a calibration where there is one; else the EXIF focal length in 35 mm terms:
:func:`intrinsics_from_35mm`); orientation from the EXIF (:func:`orient`).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..camera import Intrinsics, Rig
from ..errors import CalibrationError, ImageReadError, InputError
from .base import FrameSource, SourceFrame

#: the diagonal of a 36 x 24 mm frame, mm: "35 mm equivalent" focal lengths keep the diagonal angle of view
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: the 35 mm equivalent assumed when a file has no focal length at all (a phone's main camera)
ASSUMED_FOCAL_35MM = 26.0

#: depth encodings -> how a normalised value v in [0, 1] becomes a distance between near and far
DEPTH_FORMATS = ("linear", "inverse")


def depth_from_normalized(v, near_m: float, far_m: float, fmt: str) -> np.ndarray:
    """Distances from stored values normalised to [0, 1].

    Parameters
    ----------
    v : (h, w) float ndarray, the stored value divided by its maximum (0 .. 1)
    near_m, far_m : float, distances of v at its ends, metres (or the file's units), 0 < near < far
    fmt : str, one of :data:`DEPTH_FORMATS`; v = 0 at near and 1 at far in both: ``"linear"`` (linear in z:
        z = near + v (far - near); Dynamic Depth / GDepth RangeLinear, HEIF uniform Z), ``"inverse"`` (linear
        in 1/z: z = far near / (far - v (far - near)); Dynamic Depth / GDepth RangeInverse; HEIF uniform
        inverse Z and disparity store 1 - v)

    Returns
    -------
    (h, w) float32 ndarray, distances in the units of *near_m*

    References
    ----------
    Google, Dynamic Depth 1.0, DepthMap "Format"; ISO/IEC 23008-12 depth representation information.
    """
    if fmt not in DEPTH_FORMATS:
        raise InputError(f"fmt must be one of {', '.join(DEPTH_FORMATS)}; got {fmt!r}")
    if not (math.isfinite(near_m) and math.isfinite(far_m) and 0 < near_m < far_m):
        raise ImageReadError(f"the depth map's near and far must be finite with 0 < near < far; got "
                             f"near {near_m!r}, far {far_m!r}")
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    if fmt == "linear":
        z = near_m + v * (far_m - near_m)
    else:  # 1/z = (1 - v) / near + v / far
        z = far_m * near_m / (far_m - v * (far_m - near_m))
    return z.astype(np.float32)


def intrinsics_from_35mm(width: int, height: int, focal_35mm: float) -> Intrinsics:
    """Pinhole intrinsics of a photo whose lens is *focal_35mm* in 35 mm terms (diagonal angle of view).

    Parameters
    ----------
    width, height : int, pixels of the photo as displayed
    focal_35mm : float, 35 mm equivalent focal length, mm (> 0)

    Returns
    -------
    Intrinsics, square pixels, principal point at the image centre, no distortion:
    ``fx = focal_35mm * hypot(W, H) / 43.27``
    """
    if isinstance(focal_35mm, bool) or not isinstance(focal_35mm, (int, float)) or not (
            math.isfinite(focal_35mm) and focal_35mm > 0):
        raise CalibrationError(f"focal_35mm must be a finite number of mm > 0; got {focal_35mm!r}")
    f = float(focal_35mm) * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM
    return Intrinsics(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def scaled_intrinsics(cam: Intrinsics, width: int, height: int) -> Intrinsics:
    """*cam* seen on a grid of *width* x *height* pixels over the same field of view (pixel centres kept)."""
    sx, sy = width / cam.width, height / cam.height
    return Intrinsics(int(width), int(height), cam.fx * sx, cam.fy * sy, (cam.cx + 0.5) * sx - 0.5,
                      (cam.cy + 0.5) * sy - 0.5)


def phone_rig(color: Intrinsics, depth_shape: tuple[int, int], *, max_range_m: float) -> Rig:
    """The rig of a phone depth photo: the depth camera is *color* at the depth map's resolution.

    Parameters
    ----------
    color : Intrinsics of the photo
    depth_shape : (h, w), the depth map's size
    max_range_m : float, the farthest depth the map can hold, metres

    Raises
    ------
    ImageReadError
        The depth map's aspect ratio differs from the photo's by more than one depth pixel (it cannot
        cover the same field of view).
    """
    h, w = (int(s) for s in depth_shape)
    check_aspect((color.height, color.width), (h, w))
    # integer depth in 1/65535 of the range: export writes 16-bit PNGs that hold every distance up to max_range_m
    scale = max(0.001, max_range_m / 65535.0)
    return Rig(color, scaled_intrinsics(color, w, h), np.eye(4), depth_scale=scale, max_range_m=max_range_m)


def check_aspect(color_shape: tuple[int, int], depth_shape: tuple[int, int]) -> None:
    """ImageReadError when a (h, w) depth map's aspect ratio differs from the (H, W) photo's by over a depth pixel."""
    (H, W), (h, w) = color_shape[:2], depth_shape[:2]
    if abs(w * H / W - h) > 1.0:
        raise ImageReadError(f"the depth map is {w}x{h} but the photo is {W}x{H}: a depth map of another aspect "
                             "ratio does not cover the photo's field of view")


# EXIF orientation 1..8 (TIFF 6.0 tag 274) -> (transpose first, then flip left-right, flip up-down)
_ORIENT = {1: (False, False, False), 2: (False, True, False), 3: (False, True, True), 4: (False, False, True),
           5: (True, False, False), 6: (True, True, False), 7: (True, True, True), 8: (True, False, True)}


def orient(image: np.ndarray, orientation: int) -> np.ndarray:
    """*image* (H, W[, C]) turned upright as EXIF *orientation* (1..8) says; other values leave it as is."""
    t, lr, ud = _ORIENT.get(int(orientation) if orientation else 1, (False, False, False))
    out = np.swapaxes(image, 0, 1) if t else image
    if lr:
        out = out[:, ::-1]
    if ud:
        out = out[::-1]
    return np.ascontiguousarray(out)


def exif_tags(exif: bytes | None) -> dict:
    """Orientation, focal length (mm), 35 mm equivalent (mm) and f-number of an EXIF block (None where absent)."""
    out = {"orientation": None, "focal_length_mm": None, "focal_35mm": None, "f_number": None, "model": None}
    if not exif:
        return out
    from PIL import Image

    data = exif[6:] if exif.startswith(b"Exif\0\0") else exif
    try:
        tags = Image.Exif()
        tags.load(data)
        sub = tags.get_ifd(0x8769)  # the Exif IFD
    except Exception as err:  # noqa: BLE001 - Pillow raises many kinds for a damaged block; a photo without EXIF
        warnings.warn(f"the EXIF block cannot be read ({type(err).__name__}); orientation and focal length unknown")
        return out

    def number(value):
        try:
            v = float(value)
        except (TypeError, ValueError, ZeroDivisionError):
            return None
        return v if math.isfinite(v) and v > 0 else None

    out["orientation"] = int(tags.get(0x0112, 1)) if tags.get(0x0112) in range(1, 9) else None
    out["focal_length_mm"] = number(sub.get(0x920A))
    out["focal_35mm"] = number(sub.get(0xA405))
    out["f_number"] = number(sub.get(0x829D))
    out["model"] = str(tags.get(0x0110)).strip("\0 ") if tags.get(0x0110) else None
    return out


def photo_intrinsics(width: int, height: int, tags: dict) -> tuple[Intrinsics, str]:
    """Intrinsics from the EXIF *tags* (:func:`exif_tags`) of a photo: (intrinsics, where they came from)."""
    if tags.get("focal_35mm"):
        return intrinsics_from_35mm(width, height, tags["focal_35mm"]), \
            f"EXIF 35 mm equivalent focal length {tags['focal_35mm']:g} mm"
    warnings.warn(f"the file gives no 35 mm equivalent focal length; assuming a phone's main camera "
                  f"({ASSUMED_FOCAL_35MM:g} mm equivalent)")
    return intrinsics_from_35mm(width, height, ASSUMED_FOCAL_35MM), \
        f"assumed {ASSUMED_FOCAL_35MM:g} mm equivalent (no focal length in the file)"


class PhoneDepthSource(FrameSource):
    """One colour photo with its depth map, read whole when opened.

    Subclasses decode the file in :meth:`open` and call ``super().__init__``.

    Parameters
    ----------
    path : str
    color : (H, W, 3) uint8 RGB, upright
    depth_m : (h, w) float32, metres, 0 = unknown, upright, same aspect ratio as *color*
    rig : Rig, from :func:`phone_rig`
    depth_info : dict, what the file says about the depth (representation, near, far, size, ...)
    camera_info : dict, where the intrinsics came from, the EXIF focal lengths and f-number
    """

    def __init__(self, path: str, color: np.ndarray, depth_m: np.ndarray, rig: Rig, *, depth_info: dict,
                 camera_info: dict) -> None:
        super().__init__(path, rig, calibration_from=camera_info.get("intrinsics_from", "file"))
        self.color, self.depth_m = color, depth_m
        self.depth_info, self.camera_info = depth_info, camera_info
        # a one-frame recording to the tools that read recordings by their paired streams (batch): one colour
        # and one depth image at time 0 (a photo has no clock), paired with each other
        self.color_times = self.depth_times = np.zeros(1)
        self.pairs = np.zeros((1, 2), np.int64)

    @classmethod
    def check_options(cls, path: str, calib, depth_scale, max_difference_s) -> None:
        """InputError for options that do not apply to a photo that carries its own depth."""
        for name, value in (("calib", calib), ("depth_scale", depth_scale), ("max_difference_s", max_difference_s)):
            if value is not None:
                raise InputError(f"{name} does not apply to the phone depth photo {path}: it carries its own "
                                 f"depth and camera (got {name}={value!r})")

    def __len__(self) -> int:
        return 1

    def _read(self, i: int) -> SourceFrame:
        return SourceFrame(0, self.color, self.depth_m, self.rig, None, None)

    def _info(self) -> dict:
        valid = self.depth_m[self.depth_m > 0]
        measured = [float(valid.min()), float(valid.max())] if valid.size else None
        return {"phone": {"depth": {**self.depth_info, "measured_range_m": measured},
                          "camera": self.camera_info},
                "streams": {"color": {"width": self.rig.color.width, "height": self.rig.color.height, "frames": 1},
                            "depth": {"width": self.rig.depth.width, "height": self.rig.depth.height, "frames": 1}},
                "pairing": {"unpaired_color": 0, "unpaired_depth": 0}}
