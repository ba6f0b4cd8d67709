"""3-D inspection of the focal plane and the depth of field (PyVista).

The scene is drawn in the colour camera's frame (OpenCV: x right, y down, z forward, metres):

* the coloured point cloud of the registered, hole-filled depth;
* the camera frustum, apex at the origin, out to the far plane ``z_far`` (the scene's largest depth,
  or the focus distance when that is farther);
* the focal plane ``z = d_f``, clipped to the frustum: the rectangle through the back-projections
  of the four image corners at depth ``d_f``;
* the depth-of-field slab between the near and far depths where the thin-lens circle of confusion
  ``c(z) = A * fx * |1/d_f - 1/z|`` equals an acceptable size (1 px by default); a far limit at
  infinity (focus past the hyperfocal distance) is clipped at ``z_far``.

Image corners are the outer pixel edges ``(-0.5, -0.5)``, ``(W - 0.5, -0.5)``, ``(W - 0.5, H - 0.5)``,
``(-0.5, H - 0.5)`` (pixel centres are integers, OpenCV). They are back-projected through the
calibrated distortion model (undistorted with :func:`pcdof.geometry.undistort_pixels`), so each
corner of the drawn plane projects exactly onto an image corner. The frustum's sides are drawn
straight between those corner rays; with lens distortion the true image borders are slightly curved
in space, which the drawing ignores. Where the distortion model has no inverse at a corner the
pinhole ray (distortion ignored) is used for that corner.

The geometry is pure numpy (:func:`image_corner_rays`, :func:`focal_plane_corners`, :func:`dof_slab`,
:func:`frustum_lines`); :func:`build_scene` puts it into a PyVista plotter and returns a
:class:`FocusViewer` whose methods (:meth:`FocusViewer.set_focus`, :meth:`FocusViewer.set_f_number`,
:meth:`FocusViewer.pick_point`, :meth:`FocusViewer.toggle_coc_colors`) are what the sliders, the point
picker and the checkbox call, so a test can drive the interaction without a display.
"""

from __future__ import annotations

import math
import os
import secrets
from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics, check_color
from .cloud import check_stride
from .color import to_float
from .errors import ImageWriteError, InputError, LensError
from .lens import ThinLens, positive_number

#: Colours of the scene elements (named colours PyVista understands; tests look for the plane's).
PLANE_COLOR = (255, 140, 0)  # dark orange
SLAB_COLOR = (0, 191, 255)  # deep sky blue
FRUSTUM_COLOR = (60, 60, 60)
#: Opacity of the focal plane's and the depth-of-field slab's faces.
PLANE_OPACITY = 0.35
SLAB_OPACITY = 0.15
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


def _check_intrinsics(intrinsics) -> Intrinsics:
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
    intr = _check_intrinsics(intrinsics)
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
    from .geometry import undistort_pixels

    intr = _check_intrinsics(intrinsics)
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
    intr = _check_intrinsics(intrinsics)
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
    from .geometry import depth_to_points

    intr = _check_intrinsics(intrinsics)
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
    if rgb.dtype == np.uint8:
        return rgb
    return np.clip(np.rint(to_float(rgb) * 255), 0, 255).astype(np.uint8)


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


def render_preview(color, depth_m, lens: ThinLens, fx: float, *, method: str = "physical") -> np.ndarray:
    """The depth-of-field photograph for the live preview (the pipeline's cached-depth renderer).

    Parameters
    ----------
    color : (h, w, 3) RGB ndarray
    depth_m : (h, w) float32 ndarray, metres, registered and hole-free
    lens : ThinLens
    fx : float, focal length of *color* in pixels

    Returns
    -------
    (h, w, 3) uint8 ndarray, sRGB
    """
    from .pipeline import render_from_depth

    image, _trace = render_from_depth(color, depth_m, lens, fx, method=method)
    return _to_uint8_rgb(np.asarray(image))


# --------------------------------------------------------------------------------------------------
# PyVista scene
# --------------------------------------------------------------------------------------------------

def _quad_mesh(corners: np.ndarray):
    import pyvista as pv

    return pv.PolyData(np.asarray(corners, np.float64), faces=np.array([4, 0, 1, 2, 3]))


def _slab_mesh(corners: np.ndarray):
    import pyvista as pv

    # the six faces of the hexahedron, outward order does not matter for a translucent box
    faces = np.array([[4, 0, 1, 2, 3], [4, 4, 5, 6, 7], [4, 0, 1, 5, 4],
                      [4, 1, 2, 6, 5], [4, 2, 3, 7, 6], [4, 3, 0, 4, 7]]).ravel()
    return pv.PolyData(np.asarray(corners, np.float64), faces=faces)


#: The twelve edges of a hexahedron in :attr:`DofSlab.corners` order.
_HEX_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                       [0, 4], [1, 5], [2, 6], [3, 7]], dtype=np.int64)


def _lines_mesh(points: np.ndarray, segments: np.ndarray):
    import pyvista as pv

    lines = np.concatenate([np.full((len(segments), 1), 2), segments], axis=1).ravel()
    return pv.PolyData(np.asarray(points, np.float64), lines=lines)


class FocusViewer:
    """A PyVista scene of the point cloud, frustum, focal plane, depth-of-field slab and live preview.

    Build it with :func:`build_scene`. The state is ``lens`` (the current ThinLens) and
    ``coc_colors`` (points coloured by circle of confusion instead of RGB); the methods below
    change it and update every actor, the scalar bar, the status text and the preview.

    Attributes
    ----------
    plotter : pyvista.Plotter, two subplots: (0, 0) the 3-D scene, (0, 1) the 2-D preview
    intrinsics : Intrinsics, of the colour camera
    lens : ThinLens, current lens
    coc_limit_px : float, acceptable circle of confusion, pixels
    z_max_m : float, metres, the scene's largest depth
    points : (N, 3) float64, metres; colors : (N, 3) uint8
    plane_mesh, slab_mesh, frustum_mesh, cloud_mesh, preview_mesh : pyvista.PolyData / ImageData
    preview_image : (h, w, 3) uint8, the current preview photograph
    slab : DofSlab, the current slab
    """

    def __init__(self, plotter, color, depth_filled_m, intrinsics, lens, *, coc_limit_px, stride, color_by,
                 preview_max_side, preview_method, widgets):
        import pyvista as pv

        self.plotter = plotter
        self.intrinsics = intrinsics
        self.lens = lens
        self.coc_limit_px = coc_limit_px
        self.preview_method = preview_method
        self.coc_colors = color_by == "coc"
        depth = np.asarray(depth_filled_m, np.float32)
        known = depth[np.isfinite(depth) & (depth > 0)]
        self.z_min_m = float(known.min())
        self.z_max_m = float(known.max())
        self.points, self.colors = strided_points(color, depth, intrinsics, stride=stride)
        self._preview_inputs = downscale_for_preview(color, depth, intrinsics.fx, max_side=preview_max_side)
        self.preview_image = render_preview(*self._preview_inputs[:2], lens, self._preview_inputs[2],
                                            method=preview_method)
        self._preview_lens = lens
        self.slab = dof_slab(intrinsics, lens, coc_limit_px=coc_limit_px, z_max_m=self.z_max_m)
        self.focus_slider = self.f_number_slider = self.coc_checkbox = None

        # --- 3-D scene ------------------------------------------------------------------------
        plotter.subplot(0, 0)
        self.cloud_mesh = pv.PolyData(self.points)
        self.cloud_mesh.point_data["rgb"] = self.colors
        self.cloud_mesh.point_data["coc_px"] = self._coc_of_points()
        point_size = max(2.0, min(6.0, 1.5 * stride))
        self.rgb_actor = plotter.add_mesh(self.cloud_mesh, scalars="rgb", rgb=True, point_size=point_size,
                                          style="points", lighting=False, name="cloud_rgb", reset_camera=False)
        coc_view = self.cloud_mesh.copy(deep=False)
        self.coc_actor = plotter.add_mesh(
            coc_view, scalars="coc_px", cmap="viridis", clim=self._coc_clim(), point_size=point_size,
            style="points", lighting=False, name="cloud_coc", reset_camera=False,
            scalar_bar_args={"title": COC_BAR_TITLE, "vertical": True, "position_x": 0.88, "position_y": 0.3,
                             "height": 0.5, "width": 0.06, "fmt": "%.1f"})
        self._coc_view = coc_view
        frustum_points, segments = frustum_lines(intrinsics, self._z_far())
        self.frustum_mesh = _lines_mesh(frustum_points, segments)
        plotter.add_mesh(self.frustum_mesh, color=FRUSTUM_COLOR, line_width=2, lighting=False, pickable=False,
                         name="frustum", reset_camera=False)
        self.plane_mesh = _quad_mesh(focal_plane_corners(intrinsics, lens.focus_distance_m))
        plotter.add_mesh(self.plane_mesh, color=PLANE_COLOR, opacity=PLANE_OPACITY, lighting=False,
                         pickable=False, name="focal_plane", reset_camera=False)
        self.plane_outline = self.plane_mesh.copy(deep=False)
        plotter.add_mesh(self.plane_outline, color=PLANE_COLOR, style="wireframe", line_width=3, lighting=False,
                         pickable=False, name="focal_plane_outline", reset_camera=False)
        self.slab_mesh = _slab_mesh(self.slab.corners)
        plotter.add_mesh(self.slab_mesh, color=SLAB_COLOR, opacity=SLAB_OPACITY, lighting=False, pickable=False,
                         name="dof_slab", reset_camera=False)
        self.slab_outline = _lines_mesh(self.slab.corners, _HEX_EDGES)
        plotter.add_mesh(self.slab_outline, color=SLAB_COLOR, line_width=1, lighting=False, pickable=False,
                         name="dof_slab_outline", reset_camera=False)
        self._set_3d_camera()

        # --- 2-D preview ----------------------------------------------------------------------
        plotter.subplot(0, 1)
        ph, pw = self.preview_image.shape[:2]
        self.preview_mesh = pv.ImageData(dimensions=(pw + 1, ph + 1, 1))
        self.preview_mesh.cell_data["rgb"] = self._preview_cells()
        plotter.add_mesh(self.preview_mesh, scalars="rgb", rgb=True, lighting=False, pickable=False,
                         name="preview", show_scalar_bar=False)
        self._set_preview_camera()
        plotter.add_text(f"preview ({pw} x {ph} px): sliders update it when released", position=(0.06, 0.3),
                         viewport=True, font_size=9, color="black", name="preview_caption")
        plotter.subplot(0, 0)

        self._apply_color_mode()
        self._update_text()
        if widgets:
            self._add_widgets()

    # --- state changes (called by the widgets, the picker and tests) -----------------------------

    def set_focus(self, focus_distance_m: float, *, preview: bool = True) -> None:
        """Focus at *focus_distance_m* metres: move plane and slab, recolour points, re-render the preview.

        ``preview=False`` (while a slider is dragged) leaves the preview for :meth:`refresh_preview`.
        """
        d_f = positive_number("focus_distance_m", focus_distance_m)
        self.lens = self.lens.with_focus(d_f)
        self._sync_slider(self.focus_slider, d_f)
        self._update(preview=preview)

    def set_f_number(self, f_number: float, *, preview: bool = True) -> None:
        """Set the f-number N (aperture A = f/N): resize the slab, recolour points, re-render the preview.

        ``preview=False`` (while a slider is dragged) leaves the preview for :meth:`refresh_preview`.
        """
        n = positive_number("f_number", f_number)
        lens = self.lens
        self.lens = ThinLens(lens.focal_length_mm, n, lens.focus_distance_m, lens.aperture_blades,
                             lens.aperture_rotation_deg)
        self._sync_slider(self.f_number_slider, n)
        self._update(preview=preview)

    def refresh_preview(self) -> None:
        """Re-render the preview photograph for the current lens (skipped when it is already current)."""
        if self._preview_lens == self.lens:
            return
        small_color, small_depth, small_fx = self._preview_inputs
        self.preview_image = render_preview(small_color, small_depth, self.lens, small_fx,
                                            method=self.preview_method)
        self._preview_lens = self.lens
        self.preview_mesh.cell_data["rgb"] = self._preview_cells()
        self.plotter.render()

    def pick_point(self, point) -> None:
        """Focus on a picked 3-D point (camera frame): the focus distance becomes its z-depth."""
        p = np.asarray(point, dtype=np.float64).ravel()
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"point must be 3 finite coordinates (x, y, z) in metres; got {point!r}")
        if p[2] <= 0:
            raise InputError(f"picked point must lie in front of the camera (z > 0); got z = {p[2]}")
        self.set_focus(float(p[2]))

    def toggle_coc_colors(self, on: bool | None = None) -> None:
        """Colour points by circle of confusion (True) or by RGB (False); None flips the current mode."""
        self.coc_colors = (not self.coc_colors) if on is None else bool(on)
        if self.coc_checkbox is not None:
            self.coc_checkbox.GetRepresentation().SetState(int(self.coc_colors))
        self._apply_color_mode()
        self.plotter.render()

    # --- output ------------------------------------------------------------------------------

    def screenshot(self, path: str | None = None) -> np.ndarray:
        """Render and return the window as an (H, W, 3) uint8 image; also write it to *path* (PNG) if given.

        InputError (nothing written) when the render comes back empty (all black), as it does for a
        window larger than the graphics driver can draw.
        """
        self.plotter.render()  # after the first frame pyvista's screenshot reads the buffer without rendering
        image = self.plotter.screenshot(None, return_img=True)
        if not image[:, :, :3].any():  # the background is white: all black means the driver drew nothing
            width, height = self.plotter.window_size
            raise InputError(f"the renderer drew nothing in a {width}x{height} window (more than the graphics "
                             "driver can draw); use a smaller window_size (--window-size)")
        if path is not None:
            from .io import write_image

            write_image(path, np.ascontiguousarray(image[:, :, :3]))
        return image[:, :, :3]

    def export_html(self, path: str) -> None:
        """Write the scene as a standalone interactive HTML page (vtk.js; needs ``trame-pyvista``).

        The page shows both panels (3-D scene and preview) at the current settings; the sliders,
        checkbox and picking are not part of it. Written to a temporary file, then renamed.
        """
        component = getattr(self.plotter, "trame", None)
        export = component.export_html if component is not None else self.plotter.export_html
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        # the exporter appends ".html" to other names, so the temporary name ends in it too
        tmp = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.{secrets.token_hex(4)}.html")
        try:
            os.makedirs(folder, exist_ok=True)  # like the image writers: missing folders are created
            export(tmp)
            os.replace(tmp, path)
        except ImportError as err:
            raise ImageWriteError(f"cannot export {path!r}: {err}") from None
        except OSError as err:
            raise ImageWriteError(f"cannot write {path!r}: {err.strerror or err}") from None
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)

    def show(self) -> None:
        """Open the interactive window (blocks until it is closed)."""
        self.plotter.show()

    def close(self) -> None:
        self.plotter.close()

    # --- internals ---------------------------------------------------------------------------

    def _z_far(self) -> float:
        return max(self.z_max_m, self.lens.focus_distance_m)

    def _coc_of_points(self) -> np.ndarray:
        return self.lens.coc_px(self.points[:, 2].astype(np.float32), self.intrinsics.fx)

    def _coc_clim(self) -> tuple[float, float]:
        coc = self.cloud_mesh.point_data["coc_px"] if hasattr(self, "cloud_mesh") else self._coc_of_points()
        top = float(np.percentile(coc, 99)) if coc.size else 0.0
        return 0.0, max(top, 4.0 * self.coc_limit_px)

    def _preview_cells(self) -> np.ndarray:
        # ImageData cells run x fastest from the bottom row; image rows run from the top.
        return np.ascontiguousarray(self.preview_image[::-1]).reshape(-1, 3)

    def _update(self, *, preview: bool = True) -> None:
        """Recompute geometry and colours (and the preview) for the current lens and redraw."""
        self.slab = dof_slab(self.intrinsics, self.lens, coc_limit_px=self.coc_limit_px, z_max_m=self.z_max_m)
        corners = focal_plane_corners(self.intrinsics, self.lens.focus_distance_m)
        self.plane_mesh.points = corners
        self.plane_outline.points = corners
        self.slab_mesh.points = self.slab.corners
        self.slab_outline.points = self.slab.corners
        self.frustum_mesh.points = frustum_lines(self.intrinsics, self._z_far())[0]
        coc = self._coc_of_points()
        self.cloud_mesh.point_data["coc_px"] = coc
        self._coc_view.point_data["coc_px"] = coc
        self.coc_actor.mapper.scalar_range = self._coc_clim()
        self._update_text()
        if preview:
            self.refresh_preview()
        self.plotter.render()

    def _apply_color_mode(self) -> None:
        self.rgb_actor.SetVisibility(not self.coc_colors)
        self.coc_actor.SetVisibility(self.coc_colors)
        bars = self.plotter.scalar_bars
        if COC_BAR_TITLE in bars.keys():
            bars[COC_BAR_TITLE].SetVisibility(self.coc_colors)

    def _status(self) -> str:
        lens, slab = self.lens, self.slab
        far = "inf" if math.isinf(slab.far_m) else f"{slab.far_m:.2f} m"
        return (f"focus {lens.focus_distance_m:.2f} m   f/{lens.f_number:.3g}   f = {lens.focal_length_mm:.3g} mm\n"
                f"in focus (CoC <= {self.coc_limit_px:g} px): {slab.near_m:.2f} m to {far}")

    def _update_text(self) -> None:
        self.plotter.subplot(0, 0)
        self.plotter.add_text(self._status(), position="upper_left", font_size=10, color="black", name="status")

    def _set_3d_camera(self, direction=(1.0, -0.6, -0.25)) -> None:
        # oblique view from the right of, above and slightly behind the camera (y points down), framing the apex and
        # the bulk of the points (a few far outliers would otherwise shrink the scene to a speck)
        z = self.points[:, 2]
        lo_z, hi_z = np.percentile(z, [2, 90]) if len(z) else (0.0, self._z_far())
        bulk = self.points[(z >= lo_z) & (z <= hi_z)]
        pts = np.concatenate([bulk, np.zeros((1, 3)), self.plane_mesh.points])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        mid = 0.5 * (lo + hi)
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        d = np.asarray(direction, float)
        position = mid + d / np.linalg.norm(d) * radius * 2.6
        self.plotter.camera_position = [tuple(position), tuple(mid), (0.0, -1.0, 0.0)]
        self.plotter.renderer.ResetCameraClippingRange()
        self.plotter.render()

    def _viewport_size(self, renderer) -> tuple[float, float]:
        x0, y0, x1, y1 = renderer.GetViewport()
        w, h = self.plotter.window_size
        return (x1 - x0) * w, (y1 - y0) * h

    def _set_preview_camera(self) -> None:
        # parallel projection; the photograph sits in the upper part, the sliders go below it
        renderer = self.plotter.renderer
        ph, pw = self.preview_image.shape[:2]
        vw, vh = self._viewport_size(renderer)
        aspect = vw / max(vh, 1.0)
        top_share = 0.66
        half = max(ph / (2 * top_share), pw / (2 * 0.94 * aspect))
        centre_y = ph + 0.03 * 2 * half - half
        camera = renderer.camera
        camera.parallel_projection = True
        camera.focal_point = (pw / 2, centre_y, 0.0)
        camera.position = (pw / 2, centre_y, 10.0 * max(pw, ph))
        camera.up = (0.0, 1.0, 0.0)
        camera.parallel_scale = half
        renderer.ResetCameraClippingRange()

    def _add_widgets(self) -> None:
        plotter = self.plotter
        preview = plotter.renderers[1]
        x0, _, x1, _ = preview.GetViewport()
        lens = self.lens
        plotter.subplot(0, 1)
        lo = min(self.z_min_m, lens.focus_distance_m)
        hi = max(self.z_max_m, lens.focus_distance_m)
        self.focus_slider = plotter.add_slider_widget(
            self._on_focus_slider, [lo, hi], value=lens.focus_distance_m, title="focus distance (m)",
            interaction_event="always", color="black", fmt="%.2f", style="modern")
        n_lo, n_hi = min(F_NUMBER_RANGE[0], lens.f_number), max(F_NUMBER_RANGE[1], lens.f_number)
        self.f_number_slider = plotter.add_slider_widget(
            self._on_f_number_slider, [n_lo, n_hi], value=lens.f_number, title="f-number",
            interaction_event="always", color="black", fmt="%.1f", style="modern")
        # slider end points are window fractions offset by the preview's viewport origin: put them under it
        for slider, y in ((self.focus_slider, 0.2), (self.f_number_slider, 0.07)):
            # geometry follows the drag; the (slower) preview is rendered when the slider is released
            slider.AddObserver("EndInteractionEvent", lambda *_: self.refresh_preview())
            rep = slider.GetRepresentation()
            rep.GetPoint1Coordinate().SetValue(0.08 * (x1 - x0), y)
            rep.GetPoint2Coordinate().SetValue(0.92 * (x1 - x0), y)
            rep.SetTitleHeight(0.025)
            rep.SetLabelHeight(0.025)
        plotter.subplot(0, 0)
        self.coc_checkbox = plotter.add_checkbox_button_widget(
            self.toggle_coc_colors, value=self.coc_colors, position=(10.0, 10.0), size=28, border_size=3,
            color_on=(253, 231, 37), color_off="lightgrey", background_color="grey")
        plotter.add_text("colour by circle of confusion (key c); right-click a point (or press p) to focus on it",
                         position=(46, 16), font_size=9, color="black", name="help", viewport=False)
        plotter.add_key_event("c", self.toggle_coc_colors)
        # a tight tolerance (fraction of the window diagonal): the picker takes the nearest point to the
        # camera within it, so a wide one grabs foreground points far from the cursor
        plotter.enable_point_picking(callback=self.pick_point, show_message=False, show_point=True, tolerance=0.004,
                                     color="magenta", point_size=12, left_clicking=False)
        plotter.add_key_event("p", self._pick_under_cursor)

    def _pick_under_cursor(self) -> None:
        # the same pick a right-click launches; its end-pick observer calls pick_point
        iren = self.plotter.iren
        x, y = iren.get_event_position()
        iren.picker.Pick(x, y, 0, self.plotter.renderers[0])

    def _on_focus_slider(self, value: float) -> None:
        if not math.isclose(value, self.lens.focus_distance_m, rel_tol=1e-9):
            self.set_focus(value, preview=False)

    def _on_f_number_slider(self, value: float) -> None:
        if not math.isclose(value, self.lens.f_number, rel_tol=1e-9):
            self.set_f_number(value, preview=False)

    @staticmethod
    def _sync_slider(slider, value: float) -> None:
        if slider is None:
            return
        rep = slider.GetRepresentation()
        if value < rep.GetMinimumValue():
            rep.SetMinimumValue(value)
        if value > rep.GetMaximumValue():
            rep.SetMaximumValue(value)
        if not math.isclose(rep.GetValue(), value, rel_tol=1e-9):
            rep.SetValue(value)


def build_scene(color, depth_filled_m, intrinsics: Intrinsics, lens: ThinLens, *, coc_limit_px: float = 1.0,
                stride: int = 2, color_by: str = "rgb", off_screen: bool = False,
                window_size: tuple[int, int] = (1500, 750), preview_max_side: int = PREVIEW_MAX_SIDE,
                preview_method: str = "physical", widgets: bool = True) -> FocusViewer:
    """Build the focal-plane inspection scene.

    Parameters
    ----------
    color : (H, W, 3) RGB ndarray (uint8, uint16 or float in [0, 1]), the colour image
    depth_filled_m : (H, W) float ndarray, metres, registered to the colour camera and hole-filled
        (zeros are allowed and shown as no point)
    intrinsics : Intrinsics, of the colour camera
    lens : ThinLens, the starting lens (focus distance, f-number, focal length)
    coc_limit_px : float, acceptable circle of confusion that bounds the depth-of-field slab, pixels
    stride : int, keep every stride-th pixel in x and y for the point cloud; at least one of the
        pixels it keeps must have a known depth (InputError otherwise: lower the stride)
    color_by : "rgb" or "coc", the starting colouring of the points
    off_screen : bool, render without a window (screenshots, HTML export, tests)
    window_size : (width, height) pixels, each side in [64, 16384] and at most 8192 x 8192 pixels in
        all (:func:`check_window_size`)
    preview_max_side : int, largest side of the downscaled preview, pixels
    preview_method : a key of :data:`pcdof.renderer.METHODS` for the preview
    widgets : bool, add the sliders, the checkbox, the key binding and point picking

    Returns
    -------
    FocusViewer

    Raises
    ------
    InputError
        Bad inputs, a window the renderer cannot draw, or a *stride* that keeps no pixel with known depth.
    LensError
        *lens* is not a ThinLens, or *coc_limit_px* is not a finite number > 0.
    """
    import pyvista as pv

    intr = _check_intrinsics(intrinsics)
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    check_color(color, intr.shape)
    depth = np.asarray(depth_filled_m)
    if depth.ndim != 2 or depth.shape != intr.shape:
        raise InputError(f"depth_filled_m must be (H, W) = {intr.shape}; got {depth.shape}")
    if depth.dtype.kind not in "fiu":
        raise InputError(f"depth_filled_m must be numeric; got dtype {depth.dtype}")
    known = np.isfinite(depth) & (depth > 0)
    if not np.any(known):
        raise InputError("depth_filled_m has no known depth (all values are 0, negative or not finite)")
    stride = check_stride(stride)
    if not np.any(known[::stride, ::stride]):
        raise InputError(f"stride {stride} keeps no pixel with known depth (it keeps "
                         f"{known[::stride, ::stride].size} of the {intr.width}x{intr.height} pixels); "
                         "use a smaller stride")
    coc_limit = positive_number("coc_limit_px", coc_limit_px)
    if color_by not in COLOR_BY:
        raise InputError(f"color_by must be one of {list(COLOR_BY)}; got {color_by!r}")
    if isinstance(preview_max_side, bool) or not isinstance(preview_max_side, (int, np.integer)) \
            or preview_max_side < 8:
        raise InputError(f"preview_max_side must be an integer >= 8; got {preview_max_side!r}")
    width, height = check_window_size(window_size)

    plotter = pv.Plotter(shape=(1, 2), col_weights=[3, 2], off_screen=off_screen, window_size=(width, height),
                         border=False)
    plotter.set_background("white")
    return FocusViewer(plotter, color, depth, intr, lens, coc_limit_px=coc_limit, stride=stride, color_by=color_by,
                       preview_max_side=int(preview_max_side), preview_method=preview_method, widgets=widgets)


def scene_from_frame(frame, lens: ThinLens, *, fill_method: str = "joint-bilateral", focus_at=None,
                     **options) -> FocusViewer:
    """Register and fill the depth of *frame*, then :func:`build_scene` in its colour camera.

    Parameters
    ----------
    frame : RGBDFrame
    lens : ThinLens, the starting lens
    fill_method : a key of :data:`pcdof.fill.FILL_METHODS`
    focus_at : optional (x, y) colour pixel; focus at the robust depth around it
        (:func:`pcdof.lens.focus_depth_at` on the registered depth, or the filled one where
        registration left nothing known)
    **options : keyword options of :func:`build_scene`

    Returns
    -------
    FocusViewer
    """
    from .camera import RGBDFrame
    from .fill import check_fill_method
    from .lens import focus_depth_at, parse_focus_pixel
    from .pipeline import fill_stage, register_stage

    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    check_fill_method(fill_method, "fill_method")  # the cheap checks before registering and filling
    pixel = parse_focus_pixel(focus_at)
    if "window_size" in options:
        check_window_size(options["window_size"])
    if "stride" in options:
        check_stride(options["stride"])
    trace: list = []
    registered = register_stage(frame, trace)
    filled = fill_stage(registered, frame.color, trace, method=fill_method)
    if pixel is not None:
        source = registered if np.any(registered > 0) else filled
        lens = lens.with_focus(focus_depth_at(source, *pixel))
    return build_scene(frame.color, filled, frame.rig.color, lens, **options)
