"""`pcdof view`: the focal plane and the depth of field of one frame, in 3-D (PyVista)."""

from __future__ import annotations

import logging
import os
import sys

import click

from ..errors import InputError
from ._common import build_render_options, check_output_file, check_output_folder, focus_source, \
    handle_errors, load_source_frame, photo_lens, render_options, source_arguments, warn_float_colour
from ._report import report_decision
from .render import IMAGE_SUFFIXES

HTML_SUFFIXES = (".html", ".htm")


def parse_size(ctx, param, value):
    """Click callback: "WxH" -> (int, int)."""
    if value is None:
        return None
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected WIDTHxHEIGHT in pixels (e.g. 1500x750); got {value!r}") from None
    return w, h


def has_display() -> bool:
    """Whether an interactive window can open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@click.command("view")
@source_arguments
@render_options
@click.option("--coc-limit", "coc_limit_px", type=float, default=1.0, show_default=True,
              help="Acceptable circle of confusion in pixels: bounds the depth-of-field slab.")
@click.option("--color-by", type=click.Choice(["rgb", "coc"]), default="rgb", show_default=True,
              help="Colour the points by their RGB or by their circle of confusion.")
@click.option("--stride", type=click.IntRange(min=1), default=2, show_default=True,
              help="Keep every N-th pixel in x and y for the point cloud.")
@click.option("--screenshot", type=click.Path(readable=False), default=None,
              help="Render off screen (no display needed) and write this PNG.")
@click.option("--html", "html_path", type=click.Path(readable=False), default=None,
              help="Write a standalone interactive HTML page of the scene (no display needed).")
@click.option("--window-size", type=str, default="1500x750", show_default=True, callback=parse_size,
              metavar="WxH", help="Window (and screenshot) size in pixels: sides 64 to 16384, at most 8192x8192 "
                                  "pixels in all.")
@click.option("--serve", is_flag=True, help="Serve the viewer to a web browser (no display needed) instead.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to serve on with --serve; anything but the loopback lets other machines in.")
@click.option("--port", type=click.IntRange(1, 65535), default=8080, show_default=True, help="Port for --serve.")
@click.option("--output-dir", type=click.Path(readable=False), default=None,
              help="With --serve: folder where the download button also saves the full-resolution PNG.")
@handle_errors
def command(color, depth, calib, depth_scale, frame_index, time_s, render_flags, coc_limit_px, color_by, stride,
            screenshot, html_path, window_size, serve, host, port, output_dir):
    """Inspect the focal plane and depth of field of one frame in 3-D.

    INPUT is a colour image followed by its DEPTH image (with --calib), or alone a recording
    (.mkv, .bag; --frame or --time chooses the frame), a sequence (folder, TUM folder, list file), or a
    phone depth photo (iPhone Portrait .heic, Android Dynamic Depth or GDepth .jpg).

    Opens a window with the point cloud in the colour camera's frame, the camera frustum, the focal
    plane, the depth-of-field slab and a live preview of the photograph, with sliders for the focus
    distance and the f-number. Right-click a point (or press p over it) to focus on it, c to colour points by their
    circle of confusion. With --screenshot or --html nothing opens: the scene is written instead. With --serve
    the same viewer is served to a web browser (http://127.0.0.1:8080/ by default; Ctrl-C stops it).
    """
    from ..viewer.scene import check_window_size
    from ..viewer.ui import scene_from_frame

    window_size = check_window_size(window_size, name="--window-size")
    check_view_outputs(screenshot, html_path, serve=serve, output_dir=output_dir, host=host, port=port)
    options = build_render_options(render_flags, extra_positive={"--coc-limit": coc_limit_px}, thin_lens=True)
    off_screen = bool(screenshot or html_path or serve)
    if output_dir:
        check_output_folder(output_dir, "--output-dir")
    if not off_screen and not has_display():
        raise InputError("no display to open a window on (DISPLAY is not set); "
                         "use --screenshot OUT.png, --html OUT.html, or --serve (a browser, also over SSH)")
    if off_screen:  # VTK warns that there is no X server, which off-screen rendering does not need
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    if html_path:  # the HTML exporter loads a trame module that tries to download VTK's WebAssembly
        # build in the background; offline, its failed task would be logged with a traceback
        logging.getLogger("asyncio").setLevel(logging.CRITICAL)
    frame, _what = load_source_frame(color, depth, calib=calib, depth_scale=depth_scale, frame_index=frame_index,
                                     time_s=time_s, outputs={"--screenshot": screenshot, "--html": html_path},
                                     folders={"--output-dir": output_dir})
    warn_float_colour(frame.color, options)
    options = photo_lens(options, render_flags, frame.rig)  # --equivalent-f-number / --blur for this camera
    if serve:
        serve_frame(frame, options, coc_limit_px=coc_limit_px, stride=stride, color_by=color_by,
                    source_name=os.path.basename(color), host=host, port=port, output_dir=output_dir)
        return
    viewer = scene_from_frame(frame, options.lens, fill_method=options.fill_method, focus_at=options.focus_at,
                              coc_limit_px=coc_limit_px, stride=stride, color_by=color_by, off_screen=off_screen,
                              window_size=window_size, preview_method=options.method, preview_options=options)
    try:
        # the screenshot first: rendering after the HTML export starts the exporter's network tasks
        if screenshot:
            viewer.screenshot(screenshot)
        if html_path:
            try:
                viewer.export_html(html_path, source_name=os.path.basename(color))
            except BaseException:
                if screenshot:  # both outputs or neither
                    os.remove(screenshot)
                raise
        for path in (screenshot, html_path):
            if path:
                report_decision("view", output=path, focus_distance_m=float(viewer.lens.focus_distance_m),
                                focus_source=focus_source(render_flags),
                                details=f"f/{viewer.lens.f_number:g}, depth of field for a {coc_limit_px:g} px "
                                        f"circle of confusion")
        if not off_screen:
            viewer.show()
    finally:
        viewer.close()


def check_view_outputs(screenshot, html_path, *, serve: bool, output_dir, host: str, port: int) -> None:
    """The output flags of ``pcdof view`` checked before the frame is loaded (one line per mistake)."""
    if serve and (screenshot or html_path):
        raise InputError("--serve cannot be combined with --screenshot or --html")
    if output_dir and not serve:
        raise InputError("--output-dir is for --serve (the download button's folder)")
    if serve:  # a bad address or a taken port is found before the frame is loaded
        from ..viewer.web.listen import check_listen_address

        check_listen_address(host, port)
    if screenshot:
        check_output_file(screenshot, "--screenshot")
    if html_path:
        check_output_file(html_path, "--html")
    if screenshot and os.path.splitext(screenshot)[1].lower() not in IMAGE_SUFFIXES:
        raise InputError(f"--screenshot must end in one of {', '.join(IMAGE_SUFFIXES)}; got {screenshot!r}")
    if html_path and os.path.splitext(html_path)[1].lower() not in HTML_SUFFIXES:
        raise InputError(f"--html must end in one of {', '.join(HTML_SUFFIXES)}; got {html_path!r}")


def serve_frame(frame, options, *, coc_limit_px, stride, color_by, source_name, host, port, output_dir) -> None:
    """Register and fill *frame* once (as *options* say), then serve the browser viewer until interrupted."""
    from ..viewer.scene import prepare_frame
    from ..viewer.web.app import WebViewer
    from ..viewer.web.session import ViewSession

    registered, filled, lens = prepare_frame(frame, options.lens, fill_method=options.fill_method,
                                             focus_at=options.focus_at)
    session = ViewSession(frame.color, registered, filled, frame.rig.color, lens, coc_limit_px=coc_limit_px,
                          method=options.method, options=options)
    app = WebViewer(session, stride=stride, color_by=color_by, source_name=source_name, output_dir=output_dir)
    shown = f"[{host}]" if ":" in host else host
    app.ctrl.on_server_ready.add(
        lambda **_: click.echo(f"pcdof: serving the viewer on http://{shown}:{port}/ (Ctrl-C to stop)", err=True))
    app.start(host=host, port=port)
