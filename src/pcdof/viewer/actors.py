"""The 3-D scene of the focal-plane viewer (PyVista): :class:`FocusScene` draws the point cloud, frustum, focal
plane and depth-of-field slab on one renderer and moves them when the lens changes. The desktop window
(:mod:`.ui`) and the browser viewer (:mod:`pcdof.viewer.web`) use it as it is; the geometry and the numbers come
from :mod:`.scene`.
"""

from __future__ import annotations

import numpy as np

from ..errors import LensError
from ..lens import ThinLens
from .scene import (
    COC_BAR_TITLE,
    FRUSTUM_COLOR,
    HEX_EDGES,
    PLANE_COLOR,
    PLANE_OPACITY,
    SLAB_COLOR,
    SLAB_OPACITY,
    dof_slab,
    fit_camera,
    focal_plane_corners,
    frustum_lines,
    hex_faces_outward,
    lens_numbers,
    scene_far_m,
    strided_points,
)

#: Direction from the scene towards the 3-D view's camera: right of, above and slightly behind the colour
#: camera (y points down), so the frustum's apex and the focal plane are both seen obliquely.
VIEW_DIRECTION = (1.0, -0.6, -0.25)
#: Largest and smallest font size of the on-screen labels, points (labels shrink to fit their pane).
LABEL_FONT_MAX = 12
LABEL_FONT_MIN = 5

def _quad_mesh(corners: np.ndarray):
    import pyvista as pv

    return pv.PolyData(np.asarray(corners, np.float64), faces=np.array([4, 0, 1, 2, 3]))


def _slab_mesh(corners: np.ndarray):
    import pyvista as pv

    faces = np.concatenate([np.full((6, 1), 4), hex_faces_outward(corners)], axis=1).ravel()
    return pv.PolyData(np.asarray(corners, np.float64), faces=faces)


def _lines_mesh(points: np.ndarray, segments: np.ndarray):
    import pyvista as pv

    lines = np.concatenate([np.full((len(segments), 1), 2), segments], axis=1).ravel()
    return pv.PolyData(np.asarray(points, np.float64), lines=lines)


def fit_text(actor, renderer, *, width_px: float, largest: int = LABEL_FONT_MAX, smallest: int = LABEL_FONT_MIN) -> int:
    """Set the largest font size in [smallest, largest] at which the text actor is at most *width_px* wide.

    Returns the size chosen (*smallest* when even that is too wide).
    """
    prop = actor.GetTextProperty()
    bbox = [0.0, 0.0, 0.0, 0.0]
    for size in range(largest, smallest - 1, -1):
        prop.SetFontSize(size)
        actor.GetBoundingBox(renderer, bbox)
        if bbox[1] - bbox[0] <= width_px:
            return size
    return smallest


def viewport_size(plotter, renderer) -> tuple[float, float]:
    """Width and height of *renderer*'s viewport in pixels."""
    x0, y0, x1, y1 = renderer.GetViewport()
    w, h = plotter.window_size
    return (x1 - x0) * w, (y1 - y0) * h


class FocusScene:
    """Point cloud, camera frustum, focal plane and depth-of-field slab on the plotter's current renderer.

    Attributes
    ----------
    plotter : pyvista.Plotter; renderer : the renderer the scene is drawn in
    intrinsics : Intrinsics, of the colour camera
    lens : ThinLens, current lens; slab : DofSlab, the current slab
    coc_limit_px : float, acceptable circle of confusion, pixels; coc_colors : bool, points coloured by CoC
    z_min_m, z_max_m : float, metres, nearest and farthest known depth; z_scene_m : the far bound drawn
        (:func:`pcdof.viewer.scene_far_m`)
    points : (N, 3) float64, metres; colors : (N, 3) uint8
    plane_mesh, slab_mesh, frustum_mesh, cloud_mesh : pyvista.PolyData
    """

    def __init__(self, plotter, color, depth_filled_m, intrinsics, lens, *, coc_limit_px, stride, color_by):
        self.plotter = plotter
        self.renderer = plotter.renderer
        self.intrinsics = intrinsics
        self.lens = lens
        self.coc_limit_px = coc_limit_px
        self.coc_colors = color_by == "coc"
        depth = np.asarray(depth_filled_m, np.float32)
        known = depth[np.isfinite(depth) & (depth > 0)]
        self.z_min_m, self.z_max_m = float(known.min()), float(known.max())
        self.z_scene_m = scene_far_m(depth)
        self.points, self.colors = strided_points(color, depth, intrinsics, stride=stride)
        self.slab = dof_slab(intrinsics, lens, coc_limit_px=coc_limit_px, z_max_m=self.z_scene_m)
        self._add_cloud(max(2.0, min(6.0, 1.5 * stride)))
        self._add_geometry()
        self.set_coc_colors(self.coc_colors)

    def _add_cloud(self, point_size: float) -> None:
        import pyvista as pv

        plotter = self.plotter
        self.cloud_mesh = pv.PolyData(self.points)
        self.cloud_mesh.point_data["rgb"] = self.colors
        self.cloud_mesh.point_data["coc_px"] = self._coc_of_points()
        self.rgb_actor = plotter.add_mesh(self.cloud_mesh, scalars="rgb", rgb=True, point_size=point_size,
                                          style="points", lighting=False, name="cloud_rgb", reset_camera=False)
        self._coc_view = self.cloud_mesh.copy(deep=False)
        self.coc_actor = plotter.add_mesh(
            self._coc_view, scalars="coc_px", cmap="viridis", clim=self._coc_clim(), point_size=point_size,
            style="points", lighting=False, name="cloud_coc", reset_camera=False,
            scalar_bar_args={"title": COC_BAR_TITLE, "vertical": True, "position_x": 0.88, "position_y": 0.3,
                             "height": 0.5, "width": 0.06, "fmt": "%.1f"})

    def _add_geometry(self) -> None:
        plotter = self.plotter
        flat = {"lighting": False, "pickable": False, "reset_camera": False}
        self.frustum_mesh = _lines_mesh(*frustum_lines(self.intrinsics, self.z_far_m))
        plotter.add_mesh(self.frustum_mesh, color=FRUSTUM_COLOR, line_width=2, name="frustum", **flat)
        self.plane_mesh = _quad_mesh(focal_plane_corners(self.intrinsics, self.lens.focus_distance_m))
        plotter.add_mesh(self.plane_mesh, color=PLANE_COLOR, opacity=PLANE_OPACITY, name="focal_plane", **flat)
        self.plane_outline = self.plane_mesh.copy(deep=False)
        plotter.add_mesh(self.plane_outline, color=PLANE_COLOR, style="wireframe", line_width=3,
                         name="focal_plane_outline", **flat)
        # only the faces turned away from the viewer are tinted: points inside the slab are drawn in
        # front of them and keep their colours, points behind it are tinted
        self.slab_mesh = _slab_mesh(self.slab.corners)
        plotter.add_mesh(self.slab_mesh, color=SLAB_COLOR, opacity=SLAB_OPACITY, culling="front", name="dof_slab",
                         **flat)
        self.slab_outline = _lines_mesh(self.slab.corners, HEX_EDGES)
        plotter.add_mesh(self.slab_outline, color=SLAB_COLOR, line_width=2, name="dof_slab_outline", **flat)

    # --- state -------------------------------------------------------------------------------------

    @property
    def z_far_m(self) -> float:
        """Depth of the frustum's far plane, metres: the scene's far bound, or the focus when farther."""
        return max(self.z_scene_m, self.lens.focus_distance_m)

    @property
    def numbers(self) -> dict:
        """:func:`pcdof.viewer.lens_numbers` for the current lens."""
        return lens_numbers(self.lens, self.intrinsics, z_min_m=self.z_min_m, z_max_m=self.z_max_m,
                            coc_limit_px=self.coc_limit_px)

    def set_lens(self, lens: ThinLens) -> None:
        """Move the plane, slab and frustum and recolour the points for *lens* (no render)."""
        if not isinstance(lens, ThinLens):
            raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
        self.lens = lens
        self.slab = dof_slab(self.intrinsics, lens, coc_limit_px=self.coc_limit_px, z_max_m=self.z_scene_m)
        corners = focal_plane_corners(self.intrinsics, lens.focus_distance_m)
        self.plane_mesh.points = corners
        self.plane_outline.points = corners
        self.slab_mesh.points = self.slab.corners
        self.slab_outline.points = self.slab.corners
        self.frustum_mesh.points = frustum_lines(self.intrinsics, self.z_far_m)[0]
        coc = self._coc_of_points()
        self.cloud_mesh.point_data["coc_px"] = coc
        self._coc_view.point_data["coc_px"] = coc
        self.coc_actor.mapper.scalar_range = self._coc_clim()

    def set_coc_colors(self, on: bool) -> None:
        """Colour the points by circle of confusion (True) or RGB (False), with the scalar bar (no render)."""
        self.coc_colors = bool(on)
        self.rgb_actor.SetVisibility(not self.coc_colors)
        self.coc_actor.SetVisibility(self.coc_colors)
        bars = self.plotter.scalar_bars
        if COC_BAR_TITLE in bars.keys():
            bars[COC_BAR_TITLE].SetVisibility(self.coc_colors)

    def frame_camera(self) -> None:
        """Point the 3-D view's camera so the whole frustum (apex to far plane) and the focal plane are in view."""
        vw, vh = viewport_size(self.plotter, self.renderer)
        frustum = frustum_lines(self.intrinsics, self.z_far_m)[0]
        camera = self.renderer.GetActiveCamera()
        position, focal = fit_camera(frustum, VIEW_DIRECTION, view_angle_deg=camera.GetViewAngle(),
                                     aspect=vw / max(vh, 1.0))
        # pyvista's setter also marks the camera as set, so a trame view keeps it instead of resetting it
        self.renderer.camera_position = [tuple(position), tuple(focal), (0.0, -1.0, 0.0)]
        camera.OrthogonalizeViewUp()
        self.renderer.ResetCameraClippingRange()

    def pick(self, x: float, y: float):
        """The cloud point drawn at display pixel (x, y) (origin bottom-left), as (3,) metres, or None."""
        import vtk

        picker = vtk.vtkPointPicker()
        picker.SetTolerance(0.004)  # of the window diagonal: a wide one grabs foreground points far from (x, y)
        if not picker.Pick(float(x), float(y), 0.0, self.renderer) or picker.GetPointId() < 0:
            return None
        return np.array(picker.GetDataSet().GetPoint(picker.GetPointId()))

    # --- internals ---------------------------------------------------------------------------------

    def _coc_of_points(self) -> np.ndarray:
        return self.lens.coc_px(self.points[:, 2].astype(np.float32), self.intrinsics.fx)

    def _coc_clim(self) -> tuple[float, float]:
        coc = self.cloud_mesh.point_data["coc_px"] if hasattr(self, "cloud_mesh") else self._coc_of_points()
        top = float(np.percentile(coc, 99)) if coc.size else 0.0
        return 0.0, max(top, 4.0 * self.coc_limit_px)
