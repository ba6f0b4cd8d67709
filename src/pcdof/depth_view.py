"""What the depth camera sees, in the colour image: the pixels it measures at every depth of the scene, and the
largest upright rectangle of them, to crop a render to where no depth was invented.

A colour camera wider than its depth camera (Kinect v2: colour 84 x 54 degrees, depth 71 x 60) leaves strips
at the frame border that no depth pixel measures; the fill guesses their depth (docs/fill.md). A colour pixel
is in the depth camera's view over a depth range [near, far] when its ray, at both ends of the range, projects
inside the depth image: the ray's points between those ends project onto the segment between the two
projections (a straight line for a pinhole depth camera), and the image is convex, so the whole segment lies
inside. With lens distortion the segment bends slightly; the ends are still checked exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Rig
from .errors import InputError
from .geometry import pixel_rays, project_points, transform_points


@dataclass(frozen=True)
class DepthViewBox:
    """An upright rectangle of colour pixels: columns x0 .. x1 - 1 and rows y0 .. y1 - 1."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0

    @property
    def slices(self) -> tuple[slice, slice]:
        """(rows, columns) slices that cut the rectangle out of an (H, W, ...) array."""
        return slice(self.y0, self.y1), slice(self.x0, self.x1)


def _check_range(near_m, far_m) -> tuple[float, float]:
    try:
        near, far = float(near_m), float(far_m)
    except (TypeError, ValueError):
        raise InputError(f"near_m and far_m must be numbers; got {near_m!r} and {far_m!r}") from None
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near <= far):
        raise InputError(f"near_m and far_m must be finite with 0 < near_m <= far_m (metres); got {near} and {far}")
    return near, far


def depth_view_mask(rig: Rig, near_m: float, far_m: float) -> np.ndarray:
    """(H, W) bool at colour resolution: the colour pixels whose ray projects inside the depth image at the
    colour-camera depths *near_m* and *far_m* (metres), so at every depth between.

    Parameters
    ----------
    rig : Rig, the colour and depth cameras and the transform between them
    near_m, far_m : float, metres, 0 < near_m <= far_m: the range of depths of the scene (e.g. the measured
        depth's smallest and largest value)

    Returns
    -------
    (H, W) bool ndarray
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a pcdof.camera.Rig; got {type(rig).__name__}")
    near, far = _check_range(near_m, far_m)
    rays = pixel_rays(rig.color).reshape(-1, 2)
    depth = rig.depth
    inside = np.isfinite(rays[:, 0])
    T_depth_from_color = np.linalg.inv(rig.T_color_from_depth)
    for z in (near, far):
        points = np.column_stack([rays * z, np.full(len(rays), z)])
        uv = project_points(transform_points(T_depth_from_color, points), depth)
        with np.errstate(invalid="ignore"):  # NaN: not projected, outside
            inside &= (uv[:, 0] >= -0.5) & (uv[:, 0] <= depth.width - 0.5)
            inside &= (uv[:, 1] >= -0.5) & (uv[:, 1] <= depth.height - 0.5)
    return inside.reshape(rig.color.height, rig.color.width)


def largest_box(mask: np.ndarray) -> DepthViewBox | None:
    """The upright rectangle of largest area whose pixels are all True in *mask* ((H, W) bool), among those
    that span whole runs of rows each True on one contiguous stretch (what a camera's view, a convex region,
    gives); None when *mask* has no True pixel."""
    mask = np.asarray(mask, bool)
    if mask.ndim != 2:
        raise InputError(f"mask must be (H, W); got shape {mask.shape}")
    h, w = mask.shape
    any_row = mask.any(axis=1)
    left = np.where(any_row, np.argmax(mask, axis=1), w)
    right = np.where(any_row, w - np.argmax(mask[:, ::-1], axis=1), 0)
    contiguous = mask.sum(axis=1) == right - left
    left = np.where(contiguous, left, w)  # a row with a gap spans nothing (no rectangle crosses it whole)
    right = np.where(contiguous, right, 0)
    best, box = 0, None
    for y0 in range(h):
        if right[y0] <= left[y0]:
            continue
        widths = np.minimum.accumulate(right[y0:]) - np.maximum.accumulate(left[y0:])
        areas = np.maximum(widths, 0) * np.arange(1, h - y0 + 1)
        k = int(np.argmax(areas))
        if areas[k] > best:
            best = int(areas[k])
            y1 = y0 + k + 1
            box = DepthViewBox(int(left[y0:y1].max()), y0, int(right[y0:y1].min()), y1)
    return box


def depth_view_box(rig: Rig, near_m: float, far_m: float) -> DepthViewBox | None:
    """The largest upright rectangle of the colour image that the depth camera sees at every depth from
    *near_m* to *far_m* (:func:`depth_view_mask`); None when it sees no colour pixel at both depths.

    Returns
    -------
    DepthViewBox or None; the whole frame when the depth camera sees all of it
    """
    return largest_box(depth_view_mask(rig, near_m, far_m))


def measured_range_m(depth_registered_m) -> tuple[float, float] | None:
    """(smallest, largest) known depth of *depth_registered_m* ((H, W) metres, 0 = unknown), or None."""
    z = np.asarray(depth_registered_m)
    known = z[np.isfinite(z) & (z > 0)]
    return (float(known.min()), float(known.max())) if known.size else None


def crop_result(result, box: DepthViewBox):
    """*result* (a :class:`pcdof.pipeline.RenderResult`) with its image and maps cut to *box* (contiguous
    copies); the lens and the trace unchanged."""
    import dataclasses

    h, w = result.image.shape[:2]
    if not (isinstance(box, DepthViewBox) and 0 <= box.x0 < box.x1 <= w and 0 <= box.y0 < box.y1 <= h):
        raise InputError(f"box must be a DepthViewBox inside the {w}x{h} render; got {box!r}")
    rows, cols = box.slices

    def cut(a):
        return None if a is None else np.ascontiguousarray(a[rows, cols])

    return dataclasses.replace(result, image=cut(result.image), depth_registered_m=cut(result.depth_registered_m),
                               depth_filled_m=cut(result.depth_filled_m), coc_px=cut(result.coc_px))
