"""The viewer's scene: the geometry, framing and numbers of the focal plane and the depth of field (pure numpy).

The scene is drawn in the colour camera's frame (OpenCV: x right, y down, z forward, metres):

* the coloured point cloud of the registered, hole-filled depth;
* the camera frustum, apex at the origin, out to the far plane ``z_far`` (the 90th percentile of the
  scene's depths, :func:`scene_far_m`, or the focus distance when that is farther);
* the focal plane ``z = d_f``, clipped to the frustum: the rectangle through the back-projections
  of the four image corners at depth ``d_f``;
* the depth-of-field slab between the near and far depths where the thin-lens circle of confusion
  ``c(z) = A * fx * |1/d_f - 1/z|`` equals an acceptable size (1 px by default); a far limit beyond
  ``z_far`` (at infinity past the hyperfocal distance) is clipped there. It is drawn as an outline and
  a light tint on the faces turned away from the viewer only, so the points inside it keep their colours.

Image corners are the outer pixel edges ``(-0.5, -0.5)``, ``(W - 0.5, -0.5)``, ``(W - 0.5, H - 0.5)``,
``(-0.5, H - 0.5)`` (pixel centres are integers, OpenCV). They are back-projected through the
calibrated distortion model (undistorted with :func:`pcdof.geometry.undistort_pixels`), so each
corner of the drawn plane projects exactly onto an image corner. The frustum's sides are drawn
straight between those corner rays; with lens distortion the true image borders are slightly curved
in space, which the drawing ignores. Where the distortion model has no inverse at a corner the
pinhole ray (distortion ignored) is used for that corner.

The geometry, the framing and the numbers are pure numpy (:func:`image_corner_rays`, :func:`focal_plane_corners`,
:func:`dof_slab`, :func:`frustum_lines`, :func:`fit_camera`, :func:`lens_numbers`, :func:`prepare_frame`): this module.
The PyVista user interface is :mod:`pcdof.viewer.ui`, the static HTML page :mod:`pcdof.viewer.html_export`, the
browser viewer :mod:`pcdof.viewer.web`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics, check_color
from ..cloud import check_stride
from ..errors import InputError, LensError
from ..lens import ThinLens, positive_number

#: Colours of the scene elements (named colours PyVista understands; tests look for the plane's).
PLANE_COLOR = (255, 140, 0)  # dark orange
SLAB_COLOR = (0, 191, 255)  # deep sky blue
FRUSTUM_COLOR = (60, 60, 60)
#: Opacity of the focal plane's and the depth-of-field slab's faces.
PLANE_OPACITY = 0.35
SLAB_OPACITY = 0.12
#: Title of the circle-of-confusion scalar bar.
COC_BAR_TITLE = "CoC (px)"
#: Largest side of the live 2-D preview, pixels (the preview is rendered on a downscaled copy).
PREVIEW_MAX_SIDE = 400
#: Range of the f-number slider.
F_NUMBER_RANGE = (0.95, 22.0)
#: Colour-by modes of the point cloud.
COLOR_BY = ("rgb", "coc")
#: Smallest and largest window side, pixels. 16384 is what common OpenGL drivers draw (Mesa's llvmpipe,
#: which renders off screen without a GPU, draws a black image beyond it; many GPUs stop there too).
MIN_WINDOW_SIDE = 64
MAX_WINDOW_SIDE = 16384
#: Largest window in all, pixels (8192 x 8192; a 16384 x 4096 off-screen render takes about 4.5 GB).
MAX_WINDOW_PIXELS = 8192 * 8192


def check_window_size(window_size, *, name: str = "window_size") -> tuple[int, int]:
    """(width, height) in pixels, or InputError naming *name* when the renderer cannot draw that window.

    Each side must lie in [:data:`MIN_WINDOW_SIDE`, :data:`MAX_WINDOW_SIDE`] and the area must not
    exceed :data:`MAX_WINDOW_PIXELS`.
    """
    try:
        width, height = (int(v) for v in window_size)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be (width, height) in pixels; got {window_size!r}") from None
    if not (MIN_WINDOW_SIDE <= width <= MAX_WINDOW_SIDE and MIN_WINDOW_SIDE <= height <= MAX_WINDOW_SIDE):
        raise InputError(f"{name} sides must be in [{MIN_WINDOW_SIDE}, {MAX_WINDOW_SIDE}] pixels; got {width}x{height}")
    if width * height > MAX_WINDOW_PIXELS:
        raise InputError(f"{name} must be at most {MAX_WINDOW_PIXELS:,} pixels in all (e.g. 8192x8192); "
                         f"got {width}x{height}")
    return width, height


def check_intrinsics(intrinsics) -> Intrinsics:
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"intrinsics must be an Intrinsics; got {type(intrinsics).__name__}")
    return intrinsics


# --------------------------------------------------------------------------------------------------
# Pure geometry
# --------------------------------------------------------------------------------------------------

def image_corner_pixels(intrinsics: Intrinsics) -> np.ndarray:
    """The outer corners of the image, pixels, in the order top-left, top-right, bottom-right, bottom-left.

    Returns
    -------
    (4, 2) float64 ndarray, (u, v) pixels: ``(-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5)``
    """
    intr = check_intrinsics(intrinsics)
    w, h = intr.width - 0.5, intr.height - 0.5
    return np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]])


def image_corner_rays(intrinsics: Intrinsics) -> np.ndarray:
    """Rays through the four image corners, scaled to z = 1 (undistorted through the calibration).

    Parameters
    ----------
    intrinsics : Intrinsics, of the colour camera

    Returns
    -------
    (4, 3) float64 ndarray, ``(x/z, y/z, 1)`` for top-left, top-right, bottom-right, bottom-left;
    a corner where the distortion model has no inverse falls back to its pinhole ray.
    """
    from ..geometry import undistort_pixels

    intr = check_intrinsics(intrinsics)
    uv = image_corner_pixels(intr)
    pinhole = np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy], axis=-1)
    xy = undistort_pixels(uv, intr) if intr.has_distortion else pinhole
    bad = ~np.all(np.isfinite(xy), axis=1)
    xy[bad] = pinhole[bad]
    return np.concatenate([xy, np.ones((4, 1))], axis=1)


def focal_plane_corners(intrinsics: Intrinsics, focus_distance_m: float) -> np.ndarray:
    """Corners of the focal plane ``z = d_f`` clipped to the camera frustum.

    Parameters
    ----------
    intrinsics : Intrinsics, of the colour camera
    focus_distance_m : float, d_f in metres (> 0)

    Returns
    -------
    (4, 3) float64 ndarray, metres, camera frame; top-left, top-right, bottom-right, bottom-left.
    Each corner projects onto the matching image corner (:func:`image_corner_pixels`).

    Examples
    --------
    >>> intr = Intrinsics(4, 2, 2.0, 2.0, 1.5, 0.5)
    >>> focal_plane_corners(intr, 2.0)[0].tolist()
    [-2.0, -1.0, 2.0]
    """
    d_f = positive_number("focus_distance_m", focus_distance_m)
    return image_corner_rays(intrinsics) * d_f


@dataclass(frozen=True)
class DofSlab:
    """The depth-of-field slab: the frustum section between the near and far limits.

    near_m, far_m : float, metres, depths where c(z) equals the acceptable circle of confusion
        (``far_m`` is ``inf`` when the focus lies at or past the hyperfocal distance)
    z_clip_m : float, metres, the depth where a far limit beyond it is cut (the frustum's far plane)
    near_corners, far_corners : (4, 3) float64, metres, corners of the drawn slab's faces
        (the far face lies at ``min(far_m, z_clip_m)``)
    """

    near_m: float
    far_m: float
    z_clip_m: float
    near_corners: np.ndarray
    far_corners: np.ndarray

    @property
    def far_clipped(self) -> bool:
        """True when the drawn far face is the clip plane rather than the far limit."""
        return self.far_m > self.z_clip_m

    @property
    def corners(self) -> np.ndarray:
        """(8, 3) float64: the near face's four corners, then the far face's (VTK hexahedron order)."""
        return np.concatenate([self.near_corners, self.far_corners])


def dof_slab(intrinsics: Intrinsics, lens: ThinLens, *, coc_limit_px: float = 1.0, z_max_m: float) -> DofSlab:
    """Depth-of-field slab of *lens* in the colour camera's frustum.

    Parameters
    ----------
    intrinsics : Intrinsics, of the colour camera (``fx`` turns the aperture into pixels)
    lens : ThinLens
    coc_limit_px : float, acceptable circle-of-confusion diameter, pixels
    z_max_m : float, metres, the scene's largest depth; the slab is cut at
        ``max(z_max_m, lens.focus_distance_m)`` so the focal plane always lies inside it

    Returns
    -------
    DofSlab

    References
    ----------
    Thin lens: c(z) = A * fx * |1/d_f - 1/z| pixels with A = f / N, so the limits are
    ``1/z = 1/d_f +- c / (A fx)`` (:meth:`pcdof.lens.ThinLens.dof_limits_m`).
    """
    intr = check_intrinsics(intrinsics)
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    z_max = positive_number("z_max_m", z_max_m, InputError)
    near, far = lens.dof_limits_m(intr.fx, coc_limit_px)
    z_clip = max(z_max, lens.focus_distance_m)
    rays = image_corner_rays(intr)
    return DofSlab(near, far, z_clip, rays * near, rays * min(far, z_clip))


def frustum_lines(intrinsics: Intrinsics, far_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The camera frustum as line segments: apex at the origin, four edges, the far rectangle.

    Parameters
    ----------
    intrinsics : Intrinsics, of the colour camera
    far_m : float, metres, depth of the far plane

    Returns
    -------
    points : (5, 3) float64 ndarray, metres: the apex (origin), then the far corners
        (top-left, top-right, bottom-right, bottom-left)
    segments : (8, 2) int64 ndarray, indices into *points*: the four edges, then the far rectangle
    """
    far = positive_number("far_m", far_m, InputError)
    points = np.concatenate([np.zeros((1, 3)), image_corner_rays(intrinsics) * far])
    segments = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]], dtype=np.int64)
    return points, segments


def strided_points(color, depth_m, intrinsics: Intrinsics, *, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Coloured point cloud of every *stride*-th pixel (in x and y) with known depth.

    Parameters
    ----------
    color : (H, W, 3) RGB ndarray (uint8, uint16 or float in [0, 1])
    depth_m : (H, W) float ndarray, metres, z-depth in the colour camera, 0 = unknown
    intrinsics : Intrinsics, of the colour camera
    stride : int >= 1

    Returns
    -------
    points : (N, 3) float64 ndarray, metres, colour camera frame
    colors : (N, 3) uint8 ndarray, RGB
    """
    from ..geometry import depth_to_points

    intr = check_intrinsics(intrinsics)
    stride = check_stride(stride)
    color = check_color(color, intr.shape)
    depth = np.asarray(depth_m, dtype=np.float32)
    if depth.shape != intr.shape:
        raise InputError(f"depth_m must be (H, W) = {intr.shape}; got {depth.shape}")
    sparse = np.zeros_like(depth)
    sparse[::stride, ::stride] = depth[::stride, ::stride]
    points, index = depth_to_points(sparse, intr, return_index=True)
    rgb = _to_uint8_rgb(color)
    return points, rgb.reshape(-1, 3)[index]


def _to_uint8_rgb(color: np.ndarray) -> np.ndarray:
    rgb = color if color.ndim == 3 else np.repeat(color[:, :, None], 3, axis=2)
    from ..color import to_uint8

    return to_uint8(rgb)


# --------------------------------------------------------------------------------------------------
# Preview
# --------------------------------------------------------------------------------------------------

def downscale_for_preview(color, depth_m, fx: float, *, max_side: int = PREVIEW_MAX_SIDE):
    """A smaller copy of colour and depth for live previews, and the matching focal length.

    Colour is area-averaged; depth takes the nearest sample (averaging would invent depths
    between foreground and background). One uniform scale, ``max_side / max(H, W)``, applies to
    both sides and to ``fx``, so the circle of confusion in preview pixels is the full-size one
    times the scale along both axes (a side that would shrink below 1 pixel stays 1 pixel: its
    scale cannot follow, but a 1-pixel side has no blur to show across it anyway).

    Parameters
    ----------
    color : (H, W, 3) RGB ndarray
    depth_m : (H, W) float ndarray, metres
    fx : float, focal length of *color* in pixels
    max_side : int, largest side of the preview, pixels

    Returns
    -------
    color : (h, w, 3) ndarray, the input's dtype; depth_m : (h, w) float32, metres; fx : float, pixels
    """
    import cv2

    h, w = depth_m.shape
    scale = min(1.0, max_side / max(h, w))
    if scale >= 1.0:
        return color, np.asarray(depth_m, np.float32), float(fx)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small_color = cv2.resize(color, size, interpolation=cv2.INTER_AREA)
    small_depth = cv2.resize(np.asarray(depth_m, np.float32), size, interpolation=cv2.INTER_NEAREST)
    return small_color, small_depth, float(fx) * scale


def render_preview(color, depth_m, lens: ThinLens, fx: float, *, method: str = "physical",
                   options=None) -> np.ndarray:
    """The depth-of-field photograph for the live preview (the pipeline's cached-depth renderer).

    Parameters
    ----------
    color : (h, w, 3) RGB ndarray
    depth_m : (h, w) float32 ndarray, metres, registered and hole-free
    lens : ThinLens
    fx : float, focal length of *color* in pixels
    method : a key of :data:`pcdof.stages.render.METHODS` (used when *options* is None)
    options : optional RenderOptions: its method, quality, linear and highlights (its lens and focus
        are ignored: *lens* is the viewer's current one)

    Returns
    -------
    (h, w, 3) uint8 ndarray, sRGB
    """
    from ..pipeline import render_from_depth

    settings = {"method": method} if options is None else {
        "method": options.method, "quality": options.quality, "linear": options.linear,
        "highlights": options.highlights}
    image, _trace = render_from_depth(color, depth_m, lens, fx, **settings)
    image = np.asarray(image)
    if settings.get("linear") and image.dtype.kind == "f":  # linear light out: encode for the screen
        from ..color import encode_from_linear

        return _to_uint8_rgb(encode_from_linear(image, np.uint8))
    return _to_uint8_rgb(image)

# --------------------------------------------------------------------------------------------------
# Scene extent, framing and the numbers shown next to the scene
# --------------------------------------------------------------------------------------------------

#: The twelve edges of a hexahedron in :attr:`DofSlab.corners` order.
HEX_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                      [0, 4], [1, 5], [2, 6], [3, 7]], dtype=np.int64)
#: The six quadrilateral faces of a hexahedron in :attr:`DofSlab.corners` order (orientation not yet fixed).
_HEX_FACES = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
#: Percentile of the scene's depths that bounds the drawn frustum and slab: nine in ten points lie inside.
#: The farthest tenth (a window or a far wall behind the subject, and the hole filling's guesses there:
#: in the bundled TUM frame the filled depth's 95th percentile is 6.4 m against a 2.5 m median) would
#: otherwise stretch both and shrink the subject to a speck; those points are still drawn.
FAR_PERCENTILE = 90.0


def hex_faces_outward(corners) -> np.ndarray:
    """The six faces of the hexahedron *corners*, each wound counter-clockwise seen from outside.

    Parameters
    ----------
    corners : (8, 3) float ndarray, metres, :attr:`DofSlab.corners` order (near face, then far face)

    Returns
    -------
    (6, 4) int64 ndarray, indices into *corners*; the right-hand normal of each face points away from
    the hexahedron's centre, so front-face culling leaves exactly the faces turned away from the viewer.
    """
    pts = np.asarray(corners, np.float64)
    if pts.shape != (8, 3) or not np.all(np.isfinite(pts)):
        raise InputError(f"corners must be (8, 3) finite coordinates; got shape {pts.shape}")
    centre = pts.mean(axis=0)
    faces = _HEX_FACES.copy()
    for k, face in enumerate(faces):
        p = pts[face]
        normal = np.cross(p[1] - p[0], p[2] - p[0]) + np.cross(p[2] - p[0], p[3] - p[0])
        if np.dot(normal, p.mean(axis=0) - centre) < 0:
            faces[k] = face[::-1]
    return faces


def scene_far_m(depth_m, *, percentile: float = FAR_PERCENTILE) -> float:
    """Depth that bounds the drawn scene: the *percentile*-th percentile of the known depths, metres.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 or non-finite = unknown (at least one known value)
    percentile : float in (0, 100]

    Returns
    -------
    float, metres (> 0)
    """
    depth = np.asarray(depth_m, np.float64)
    known = depth[np.isfinite(depth) & (depth > 0)]
    if known.size == 0:
        raise InputError("depth_m has no known depth (all values are 0, negative or not finite)")
    if not 0 < percentile <= 100:
        raise InputError(f"percentile must be in (0, 100]; got {percentile!r}")
    return float(np.percentile(known, percentile))


def fit_camera(points, direction, *, view_angle_deg: float = 30.0, aspect: float = 1.0,
               margin: float = 1.08) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and focal point that keep every one of *points* inside a perspective view.

    The view looks along ``-direction`` at the centre of the points' bounding box, from the distance at
    which the sphere around that centre through the farthest point fits the narrower of the two field
    angles (vertical *view_angle_deg*, horizontal from *aspect*), times *margin*.

    Parameters
    ----------
    points : (N, 3) float ndarray, metres (N >= 1)
    direction : (3,) float, from the focal point towards the camera (any length > 0)
    view_angle_deg : float, the vertical field of view in degrees, in (0, 180)
    aspect : float, width / height of the view (> 0)
    margin : float >= 1, extra distance factor

    Returns
    -------
    position, focal_point : (3,) float64 ndarrays, metres

    References
    ----------
    A sphere of radius r is inside a cone of half angle a seen from distance r / sin(a).
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    d = np.asarray(direction, np.float64).ravel()
    if len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise InputError(f"points must be (N >= 1, 3) finite coordinates; got shape {pts.shape}")
    if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.linalg.norm(d) > 0:
        raise InputError(f"direction must be 3 finite numbers, not all 0; got {direction!r}")
    half_v = math.radians(positive_number("view_angle_deg", view_angle_deg, InputError)) / 2
    if not half_v < math.pi / 2:
        raise InputError(f"view_angle_deg must be below 180; got {view_angle_deg!r}")
    aspect = positive_number("aspect", aspect, InputError)
    half_h = math.atan(math.tan(half_v) * aspect)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    radius = max(float(np.linalg.norm(pts - centre, axis=1).max()), 1e-6)
    distance = margin * radius / math.sin(min(half_v, half_h))
    return centre + d / np.linalg.norm(d) * distance, centre


def lens_numbers(lens: ThinLens, intrinsics: Intrinsics, *, z_min_m: float, z_max_m: float,
                 coc_limit_px: float = 1.0) -> dict:
    """The numbers shown beside the scene: focus, depth-of-field limits and the largest blur.

    Parameters
    ----------
    lens : ThinLens
    intrinsics : Intrinsics, of the colour camera (``fx`` turns the aperture into pixels)
    z_min_m, z_max_m : float, metres, the nearest and farthest depth in the scene
    coc_limit_px : float, acceptable circle of confusion, pixels

    Returns
    -------
    dict with ``focus_m``, ``near_m``, ``far_m`` (``inf`` past the hyperfocal distance), ``max_blur_px`` (the
    largest circle of confusion of a scene depth: c(z) is monotonic on each side of the focus, so it is
    reached at ``z_min_m`` or ``z_max_m``), ``f_number``, ``focal_length_mm``, ``aperture_blades``, ``coc_limit_px``.
    """
    intr = check_intrinsics(intrinsics)
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    z = np.array([positive_number("z_min_m", z_min_m, InputError), positive_number("z_max_m", z_max_m, InputError)])
    near, far = lens.dof_limits_m(intr.fx, coc_limit_px)
    return {"focus_m": lens.focus_distance_m, "near_m": near, "far_m": far,
            "max_blur_px": float(np.max(lens.coc_px(z.astype(np.float32), intr.fx))),
            "f_number": lens.f_number, "focal_length_mm": lens.focal_length_mm,
            "aperture_blades": lens.aperture_blades, "coc_limit_px": float(coc_limit_px)}


def lens_summary(numbers: dict) -> str:
    """Two short lines for :func:`lens_numbers`' output: the lens, then the depth of field and the largest blur."""
    far = "inf" if math.isinf(numbers["far_m"]) else f"{numbers['far_m']:.2f} m"
    return (f"focus {numbers['focus_m']:.2f} m  f/{numbers['f_number']:.3g}  {numbers['focal_length_mm']:.3g} mm\n"
            f"sharp (CoC <= {numbers['coc_limit_px']:g} px): {numbers['near_m']:.2f} m to {far}; "
            f"max blur {numbers['max_blur_px']:.1f} px")


def prepare_frame(frame, lens: ThinLens, *, fill_method: str = "joint-bilateral", focus_at=None):
    """Register and fill the depth of *frame* once, for a viewer that then only changes the lens.

    Parameters
    ----------
    frame : RGBDFrame
    lens : ThinLens, the starting lens
    fill_method : a key of :data:`pcdof.stages.fill.FILL_METHODS`
    focus_at : None, an (x, y) colour pixel or "center": the lens is focused at the robust depth there
        (:func:`pcdof.focus.resolve_lens`)

    Returns
    -------
    registered_m, filled_m : (H, W) float32 ndarrays, metres, colour camera grid (0 = unknown in the first)
    lens : ThinLens, focused at *focus_at* when given
    """
    from ..camera import RGBDFrame
    from ..stages.fill import check_fill_method
    from ..focus import parse_focus_at, resolve_lens
    from ..pipeline import prepare_depth

    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    check_fill_method(fill_method, "fill_method")  # the cheap checks before registering and filling
    focus_at = parse_focus_at(focus_at)
    registered, filled, _trace = prepare_depth(frame, lens, fill_method=fill_method)
    return registered, filled, resolve_lens(lens, focus_at, registered, filled)
