"""The PyVista desktop viewer: :class:`FocusViewer` adds to the 3-D scene (:class:`.actors.FocusScene`) the live
preview pane, the sliders, the checkbox and the point picking of the desktop window, and its exports; the
geometry and the numbers come from :mod:`.scene`.
"""

from __future__ import annotations

import dataclasses

import math
import os
import secrets

import numpy as np

from ..camera import Intrinsics, check_color
from ..cloud import check_stride
from ..errors import ImageWriteError, InputError, LensError
from ..lens import ThinLens, positive_number
from .scene import (
    COLOR_BY,
    F_NUMBER_RANGE,
    PREVIEW_MAX_SIDE,
    check_intrinsics,
    check_window_size,
    downscale_for_preview,
    lens_summary,
    prepare_frame,
    render_preview,
)
from .actors import FocusScene, fit_text, viewport_size

#: Help line of the desktop window (two short lines, so it fits a narrow pane).
HELP_TEXT = "c / box: colour by circle of confusion\nright-click (or p) on a point: focus there"


class FocusViewer(FocusScene):
    """The desktop window: the 3-D :class:`FocusScene`, the live preview pane, sliders, checkbox and picking.

    Build it with :func:`build_scene`. Its methods (:meth:`set_focus`, :meth:`set_f_number`,
    :meth:`pick_point`, :meth:`toggle_coc_colors`) are what the sliders, the point picker and the checkbox
    call, so a test can drive the interaction without a display.

    Attributes (besides :class:`FocusScene`'s)
    ----------------------------------------
    plotter : pyvista.Plotter, two subplots: (0, 0) the 3-D scene, (0, 1) the 2-D preview
    preview_image : (h, w, 3) uint8, the current preview photograph; preview_mesh : pyvista.ImageData
    """

    def __init__(self, plotter, color, depth_filled_m, intrinsics, lens, *, coc_limit_px, stride, color_by,
                 preview_max_side, preview_method, widgets, preview_options=None):
        plotter.subplot(0, 0)
        super().__init__(plotter, color, depth_filled_m, intrinsics, lens, coc_limit_px=coc_limit_px,
                         stride=stride, color_by=color_by)
        self.preview_method = preview_method
        self.preview_options = preview_options
        self._preview_inputs = downscale_for_preview(color, np.asarray(depth_filled_m, np.float32), intrinsics.fx,
                                                     max_side=preview_max_side)
        self.preview_image = render_preview(*self._preview_inputs[:2], lens, self._preview_inputs[2],
                                            method=preview_method, options=preview_options)
        self._preview_lens = lens
        self.focus_slider = self.f_number_slider = self.coc_checkbox = None
        self.frame_camera()
        self._add_preview_pane()
        plotter.subplot(0, 0)
        self._update_text()
        if widgets:
            self._add_widgets()
        if plotter.render_window is not None:  # labels are fitted again when the window is resized
            plotter.render_window.AddObserver("WindowResizeEvent", lambda *_: self._layout_labels())

    def _add_preview_pane(self) -> None:
        import pyvista as pv

        plotter = self.plotter
        plotter.subplot(0, 1)
        ph, pw = self.preview_image.shape[:2]
        self.preview_mesh = pv.ImageData(dimensions=(pw + 1, ph + 1, 1))
        self.preview_mesh.cell_data["rgb"] = self._preview_cells()
        plotter.add_mesh(self.preview_mesh, scalars="rgb", rgb=True, lighting=False, pickable=False,
                         name="preview", show_scalar_bar=False)
        self._set_preview_camera()
        self.caption_actor = plotter.add_text(f"preview ({pw} x {ph} px): sliders update it when released",
                                              position=(10, 10), font_size=9, color="black", name="preview_caption")

    # --- state changes (called by the widgets, the picker and tests) -----------------------------

    def set_focus(self, focus_distance_m: float, *, preview: bool = True) -> None:
        """Focus at *focus_distance_m* metres: move plane and slab, recolour points, re-render the preview.

        ``preview=False`` (while a slider is dragged) leaves the preview for :meth:`refresh_preview`.
        """
        d_f = positive_number("focus_distance_m", focus_distance_m)
        self._sync_slider(self.focus_slider, d_f)
        self._update(self.lens.with_focus(d_f), preview=preview)

    def set_f_number(self, f_number: float, *, preview: bool = True) -> None:
        """Set the f-number N (aperture A = f/N): resize the slab, recolour points, re-render the preview.

        ``preview=False`` (while a slider is dragged) leaves the preview for :meth:`refresh_preview`.
        """
        n = positive_number("f_number", f_number)
        lens = self.lens
        self._sync_slider(self.f_number_slider, n)
        self._update(dataclasses.replace(lens, f_number=n), preview=preview)

    def refresh_preview(self) -> None:
        """Re-render the preview photograph for the current lens (skipped when it is already current)."""
        if self._preview_lens == self.lens:
            return
        small_color, small_depth, small_fx = self._preview_inputs
        self.preview_image = render_preview(small_color, small_depth, self.lens, small_fx,
                                            method=self.preview_method, options=self.preview_options)
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
        self.set_coc_colors((not self.coc_colors) if on is None else bool(on))
        if self.coc_checkbox is not None:
            self.coc_checkbox.GetRepresentation().SetState(int(self.coc_colors))
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
            from ..io import write_image

            write_image(path, np.ascontiguousarray(image[:, :, :3]))
        return image[:, :, :3]

    def export_html(self, path: str, *, source_name: str = "scene") -> None:
        """Write the scene as a standalone interactive HTML page (vtk.js; needs ``trame-pyvista``).

        The page (:func:`pcdof.viewer.html_export.scene_page`) fills the browser window with the 3-D scene at the
        current settings, titled ``pcdof — <source_name> — focus X m, f/N``, with the lens values and the
        preview photograph beside it; the sliders, checkbox and picking are not part of it. Written to a
        temporary file, then renamed.
        """
        from .html_export import export_scene_html

        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        tmp = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.{secrets.token_hex(4)}.html")
        try:
            page = export_scene_html(self, source_name=source_name)
            os.makedirs(folder, exist_ok=True)  # like the image writers: missing folders are created
            with open(tmp, "w", encoding="utf-8") as out:
                out.write(page)
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

    def _preview_cells(self) -> np.ndarray:
        # ImageData cells run x fastest from the bottom row; image rows run from the top.
        return np.ascontiguousarray(self.preview_image[::-1]).reshape(-1, 3)

    def _update(self, lens: ThinLens, *, preview: bool = True) -> None:
        """Move the scene to *lens*, update the text (and the preview) and redraw."""
        self.set_lens(lens)
        self._update_text()
        if preview:
            self.refresh_preview()
        self.plotter.render()

    def _status(self) -> str:
        return lens_summary(self.numbers)

    def _update_text(self) -> None:
        self.plotter.subplot(0, 0)
        self.status_actor = self.plotter.add_text(self._status(), position=(10, 10), font_size=10, color="black",
                                                  name="status")
        self.status_actor.GetTextProperty().SetVerticalJustificationToTop()
        self._layout_labels()

    def _layout_labels(self) -> None:
        """Fit every label to its pane's width and pin it to its corner (for any window size)."""
        scene, preview = self.plotter.renderers[0], self.plotter.renderers[1]
        vw, vh = viewport_size(self.plotter, scene)
        self.status_actor.SetPosition(10, vh - 8)
        fit_text(self.status_actor, scene, width_px=vw - 20, largest=14)
        help_actor = getattr(self, "help_actor", None)
        if help_actor is not None:
            help_actor.SetPosition(46, 8)
            fit_text(help_actor, scene, width_px=vw - 46 - 10, largest=12)
        pw, _ = viewport_size(self.plotter, preview)
        fit_text(self.caption_actor, preview, width_px=pw - 20, largest=10)
        self.caption_actor.SetPosition(10, 0.3 * viewport_size(self.plotter, preview)[1])

    def _set_preview_camera(self) -> None:
        # parallel projection; the photograph sits in the upper part, the sliders go below it
        renderer = self.plotter.renderer
        ph, pw = self.preview_image.shape[:2]
        vw, vh = viewport_size(self.plotter, renderer)
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
        x0, _, x1, _ = plotter.renderers[1].GetViewport()
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
        self.help_actor = plotter.add_text(HELP_TEXT, position=(46, 8), font_size=9, color="black", name="help")
        self._layout_labels()
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


def check_scene_inputs(color, depth_filled_m, intrinsics, lens, *, coc_limit_px, stride, color_by):
    """Validate :func:`build_scene`'s inputs. Returns (intrinsics, depth, stride, coc_limit_px)."""
    intr = check_intrinsics(intrinsics)
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
    return intr, depth, stride, coc_limit


def build_scene(color, depth_filled_m, intrinsics: Intrinsics, lens: ThinLens, *, coc_limit_px: float = 1.0,
                stride: int = 2, color_by: str = "rgb", off_screen: bool = False,
                window_size: tuple[int, int] = (1500, 750), preview_max_side: int = PREVIEW_MAX_SIDE,
                preview_method: str = "physical", widgets: bool = True, preview_options=None) -> FocusViewer:
    """Build the focal-plane inspection window.

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
        all (:func:`pcdof.viewer.check_window_size`)
    preview_max_side : int, largest side of the downscaled preview, pixels
    preview_method : a key of :data:`pcdof.stages.render.METHODS` for the preview
    preview_options : optional RenderOptions whose method, quality, linear and highlights the preview
        uses (instead of *preview_method*)
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

    intr, depth, stride, coc_limit = check_scene_inputs(color, depth_filled_m, intrinsics, lens,
                                                        coc_limit_px=coc_limit_px, stride=stride, color_by=color_by)
    if isinstance(preview_max_side, bool) or not isinstance(preview_max_side, (int, np.integer)) \
            or preview_max_side < 8:
        raise InputError(f"preview_max_side must be an integer >= 8; got {preview_max_side!r}")
    width, height = check_window_size(window_size)
    plotter = pv.Plotter(shape=(1, 2), col_weights=[3, 2], off_screen=off_screen, window_size=(width, height),
                         border=False)
    plotter.set_background("white")
    return FocusViewer(plotter, color, depth, intr, lens, coc_limit_px=coc_limit, stride=stride, color_by=color_by,
                       preview_max_side=int(preview_max_side), preview_method=preview_method, widgets=widgets,
                       preview_options=preview_options)


def scene_from_frame(frame, lens: ThinLens, *, fill_method: str = "joint-bilateral", focus_at=None,
                     **options) -> FocusViewer:
    """Register and fill the depth of *frame* (:func:`pcdof.viewer.prepare_frame`), then :func:`build_scene`.

    Parameters
    ----------
    frame : RGBDFrame
    lens : ThinLens, the starting lens
    fill_method : a key of :data:`pcdof.stages.fill.FILL_METHODS`
    focus_at : None, an (x, y) colour pixel or "center": focus at the robust depth there (:mod:`pcdof.focus`)
    **options : keyword options of :func:`build_scene`

    Returns
    -------
    FocusViewer
    """
    if "window_size" in options:  # the cheap checks before registering and filling
        check_window_size(options["window_size"])
    if "stride" in options:
        check_stride(options["stride"])
    _registered, filled, lens = prepare_frame(frame, lens, fill_method=fill_method, focus_at=focus_at)
    return build_scene(frame.color, filled, frame.rig.color, lens, **options)
