"""The browser viewer's page (trame): the 3-D scene, the lens controls, the numbers and the live preview.

One :class:`WebViewer` serves one frame. The 3-D scene is a :class:`pcdof.viewer.actors.FocusScene` rendered
on the server and streamed as images (nothing but pictures reaches the browser, so a large point cloud
costs the network nothing); the photograph is a :class:`pcdof.viewer.web.session.ViewSession` render.

Every browser tab shows the same session (trame shares one state between its clients): a second tab
sees and moves the same lens and adds no work of its own. A lens change renders a draft preview at once
and schedules the full-resolution one for when the slider is released (or after :data:`RELEASE_DELAY_S`
without a change, for keyboard steps); when the last tab closes, the pending render is cancelled.
"""

from __future__ import annotations

import asyncio
import base64
import logging
import math
import os
import secrets
import sys

import numpy as np

from ...errors import ImageWriteError, InputError, PcdofError, ServeError
from ..actors import FocusScene
from ..html_export import page_title
from .session import ViewSession

log = logging.getLogger("pcdof")

#: Seconds without a lens change after which the full-resolution preview is rendered (keyboard steps
#: have no "released" event).
RELEASE_DELAY_S = 0.35
#: JPEG quality of the preview images sent to the browser (the download is a lossless PNG).
PREVIEW_JPEG_QUALITY = 90
#: Size of the server-side render window before the browser reports its own, pixels.
SCENE_WINDOW = (900, 700)
#: Addresses that keep the server on this machine.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


def jpeg_data_url(image: np.ndarray) -> str:
    """An (h, w, 3) uint8 RGB image as a ``data:image/jpeg;base64,...`` URL."""
    import cv2

    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[:, :, ::-1]),
                            [cv2.IMWRITE_JPEG_QUALITY, PREVIEW_JPEG_QUALITY])
    if not ok:
        raise InputError(f"cannot encode a preview of shape {image.shape}")
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode("ascii")


def png_bytes(image: np.ndarray) -> bytes:
    """An (h, w, 3) uint8 RGB image as PNG file bytes."""
    import cv2

    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[:, :, ::-1]))
    if not ok:
        raise InputError(f"cannot encode an image of shape {image.shape}")
    return data.tobytes()


def _connection_watch(on_change):
    """A wslink link protocol that reports the set of open websocket connections to *on_change*."""
    from wslink.websocket import LinkProtocol

    class ConnectionWatch(LinkProtocol):
        def __init__(self):
            super().__init__()
            self.clients: set = set()

        def onConnect(self, request, client_id):  # noqa: N802 - wslink's name
            self.clients.add(client_id)
            on_change(len(self.clients))

        def onClose(self, client_id):  # noqa: N802 - wslink's name
            self.clients.discard(client_id)
            on_change(len(self.clients))

    return ConnectionWatch()


class WebViewer:
    """The trame application of one frame.

    Parameters
    ----------
    session : ViewSession, the frame, its depth and the starting lens
    stride : int, keep every stride-th pixel in x and y for the point cloud
    color_by : "rgb" or "coc", the starting colouring of the points
    source_name : str, the input's name for the page title
    output_dir : optional str, folder where the download button also saves the full-resolution PNG
        (nothing is written anywhere else; without it nothing is written at all)
    """

    def __init__(self, session: ViewSession, *, stride: int = 2, color_by: str = "rgb", source_name: str = "frame",
                 output_dir: str | None = None):
        import pyvista as pv

        try:
            import trame_vtk  # noqa: F401 - the page's 3-D view
            import trame_vuetify  # noqa: F401 - the page's controls
            from trame.app import get_server
        except ImportError as exc:
            raise PcdofError(f"the browser viewer needs the web extra ({exc.name} is missing): "
                             "pip install 'pcdof[web]'") from None
        if not isinstance(session, ViewSession):
            raise InputError(f"session must be a ViewSession; got {type(session).__name__}")
        self.session = session
        self.source_name = source_name
        self.output_dir = output_dir
        self.server = get_server(f"pcdof-{secrets.token_hex(4)}", client_type="vue3")
        self.state, self.ctrl = self.server.state, self.server.controller
        self.plotter = pv.Plotter(off_screen=True, window_size=SCENE_WINDOW)
        self.plotter.set_background("white")
        self.scene = FocusScene(self.plotter, session.color, session.filled_m, session.intrinsics, session.lens,
                                coc_limit_px=session.coc_limit_px, stride=stride, color_by=color_by)
        self.scene.frame_camera()
        self.clients = 0
        self._full_timer = None
        self._init_state(color_by)
        self.server.add_protocol_to_configure(lambda protocol: protocol.registerLinkProtocol(
            _connection_watch(self._on_clients)))
        self.state.change("focus_m", "f_number", "focal_length_mm", "aperture_blades")(self._on_lens_state)
        self.state.change("coc_colors")(self._on_coc_colors)
        self.ctrl.trigger("download_full")(self.download_full)
        from .layout import build_layout

        self.view = build_layout(self)
        self.ctrl.on_client_connected.add(self.view.update)  # the new tab's first picture of the scene

    def _init_state(self, color_by: str) -> None:
        lens, state = self.session.lens, self.state
        state.focus_m, state.f_number = lens.focus_distance_m, lens.f_number
        state.focal_length_mm, state.aperture_blades = lens.focal_length_mm, lens.aperture_blades
        state.coc_colors = color_by == "coc"
        state.stats = {"draft": 0, "full": 0, "scene": 0, "clients": 0}
        state.message, state.picked_point, state.picks = "", None, 0
        self._publish_numbers()
        self._show(draft=False)

    # --- lens changes -------------------------------------------------------------------------------

    def _on_lens_state(self, focus_m, f_number, focal_length_mm, aperture_blades, **_):
        """A control moved: move the scene and show a draft preview now, the full one when it settles."""
        try:
            lens = self.session.set_lens(focus_distance_m=float(focus_m), f_number=float(f_number),
                                         focal_length_mm=float(focal_length_mm),
                                         aperture_blades=int(aperture_blades))
        except (PcdofError, TypeError, ValueError) as err:
            self.state.message = f"not applied: {err}"
            return
        if lens == self.scene.lens:
            return
        self.state.message = ""
        self.scene.set_lens(lens)
        self._push_scene()
        self._publish_numbers()
        self._show(draft=True)
        self._schedule_full()

    def on_release(self, *_args) -> None:
        """A slider was released: render the full-resolution preview now."""
        self._cancel_full()
        self._show(draft=False)

    def _schedule_full(self) -> None:
        self._cancel_full()
        if self.clients == 0:
            return  # nobody is looking: no work left behind
        loop = asyncio.get_event_loop()
        self._full_timer = loop.call_later(RELEASE_DELAY_S, self._show_full_later)

    def _show_full_later(self) -> None:
        self._full_timer = None
        with self.state:
            self._show(draft=False)

    def _cancel_full(self) -> None:
        if self._full_timer is not None:
            self._full_timer.cancel()
            self._full_timer = None

    def _on_clients(self, count: int) -> None:
        self.clients = count
        if count == 0:
            self._cancel_full()
        with self.state:
            self.state.stats = {**self.state.stats, "clients": count}

    # --- picking ------------------------------------------------------------------------------------

    def on_preview_click(self, x_frac, y_frac) -> None:
        """Focus at the depth of the preview's pixel at fractions (x_frac, y_frac) of its width and height."""
        try:
            depth = self.session.depth_at_fraction(float(x_frac), float(y_frac))
        except (PcdofError, TypeError, ValueError) as err:
            self.state.message = f"no focus there: {err}"
            return
        self.state.picked_point = None
        self._focus_on(depth)

    def on_scene_click(self, x_frac, y_frac) -> None:
        """Focus on the cloud point drawn at fractions (x_frac, y_frac) of the 3-D view (from its top-left)."""
        self.state.picks = self.state.picks + 1
        width, height = self.plotter.render_window.GetSize()
        point = self.scene.pick(float(x_frac) * width, (1.0 - float(y_frac)) * height)
        if point is None:
            self.state.message = "no point there: double-click on the point cloud"
            return
        self.state.picked_point = [float(v) for v in point]
        self._focus_on(float(point[2]))

    def _focus_on(self, depth_m: float) -> None:
        self.state.focus_m = depth_m
        self._on_lens_state(depth_m, self.state.f_number, self.state.focal_length_mm, self.state.aperture_blades)
        self.on_release()

    def _on_coc_colors(self, coc_colors, **_):
        self.scene.set_coc_colors(bool(coc_colors))
        self._push_scene()

    # --- output -------------------------------------------------------------------------------------

    def _push_scene(self) -> None:
        self.state.stats = {**self.state.stats, "scene": self.state.stats["scene"] + 1}
        self.state.plane_z_m = float(np.mean(self.scene.plane_mesh.points[:, 2]))
        view = getattr(self, "view", None)
        if view is not None and self.clients:
            view.update()

    def _publish_numbers(self) -> None:
        numbers = self.session.numbers
        far = "infinity" if math.isinf(numbers["far_m"]) else f"{numbers['far_m']:.3f} m"
        self.state.numbers = {"focus": f"{numbers['focus_m']:.3f} m", "near": f"{numbers['near_m']:.3f} m",
                              "far": far, "max_blur": f"{numbers['max_blur_px']:.1f} px",
                              "focus_m": numbers["focus_m"], "coc_limit": f"{numbers['coc_limit_px']:g} px"}
        self.state.plane_z_m = float(np.mean(self.scene.plane_mesh.points[:, 2]))
        self.state.trame__title = page_title(self.source_name, numbers)
        lens = self.session.lens
        self.state.download_name = (f"pcdof_focus{lens.focus_distance_m:.2f}m_f{lens.f_number:.3g}_"
                                    f"{lens.focal_length_mm:.3g}mm.png")

    def _show(self, *, draft: bool) -> None:
        image = self.session.render(draft=draft)
        self.state.preview_src = jpeg_data_url(image)
        self.state.preview_kind = "draft" if draft else "full"
        self.state.preview_size = f"{image.shape[1]} x {image.shape[0]} px"
        self.state.stats = {**self.state.stats, **self.session.counts}

    def download_full(self):
        """The full-resolution photograph as a PNG attachment (also saved in ``output_dir`` when one was given)."""
        image = self.session.render(draft=False)
        self.state.stats = {**self.state.stats, **self.session.counts}
        if self.output_dir is not None:
            try:
                self.state.message = f"saved {self._save(image)}"
            except PcdofError as err:
                self.state.message = f"not saved: {err}"
        return self.server.protocol.addAttachment(memoryview(png_bytes(image)))

    def _save(self, image: np.ndarray) -> str:
        from ...io import write_image

        path = os.path.join(self.output_dir, os.path.basename(self.state.download_name))
        try:
            os.makedirs(self.output_dir, exist_ok=True)
        except OSError as err:
            raise ImageWriteError(f"cannot create {self.output_dir}: {err.strerror or err}") from None
        write_image(path, image)  # written to a temporary file, then renamed
        return path

    # --- serving ------------------------------------------------------------------------------------

    def start(self, *, host: str = "127.0.0.1", port: int = 8080, **options) -> None:
        """Serve until interrupted (blocks). ``host`` other than the loopback is logged as a warning.

        Raises
        ------
        InputError
            *host* is not an address of this machine (:func:`pcdof.viewer.web.listen.check_listen_address`).
        ServeError
            The port is taken or needs privileges.
        """
        from .listen import check_listen_address, quiet_server_logs

        check_listen_address(host, port)
        quiet_server_logs()
        if host not in LOOPBACK_HOSTS:
            log.warning("serving on %s: anyone who can reach this machine on port %s can use the viewer", host, port)
        argv = sys.argv
        sys.argv = argv[:1]  # trame also reads its own options from the command line: give it none
        try:
            self.server.start(host=host, port=port, open_browser=False, show_connection_info=False, timeout=0,
                              **options)
        except OSError as err:  # taken between the check and the start
            raise ServeError(f"cannot listen on {host} port {port}: {err.strerror or err}; choose another "
                             "with --port") from None
        finally:
            sys.argv = argv
