"""The static HTML page of the focal-plane scene (``pcdof view --html``).

The 3-D scene is exported by trame's vtk.js offline viewer; :func:`scene_page` then gives that page a
title naming the input and the lens, makes the 3-D view fill the browser window, and adds a panel with
the lens values, the depth of field and the preview photograph.
"""

from __future__ import annotations

import base64
import html
import re

import numpy as np

from ..errors import InputError
from .scene import lens_summary

#: Style of the page: the vtk.js container fills the window, the panel floats at the top right.
PAGE_STYLE = """<style>
  .content { position: fixed; inset: 0; }
  #pcdof-panel { position: fixed; top: 12px; right: 12px; width: min(32vw, 520px); box-sizing: border-box;
    background: rgba(255, 255, 255, 0.9); color: #111; padding: 10px 12px; border-radius: 6px;
    font: 14px/1.4 sans-serif; box-shadow: 0 1px 5px rgba(0, 0, 0, 0.35); }
  #pcdof-panel h1 { font-size: 15px; margin: 0 0 6px 0; overflow-wrap: anywhere; }
  #pcdof-panel p { margin: 2px 0; }
  #pcdof-panel img { display: block; width: 100%; margin-top: 8px; image-rendering: auto; }
</style>
"""


def page_title(source_name: str, numbers: dict) -> str:
    """``pcdof — <source_name> — focus X m, f/N`` for :func:`pcdof.viewer.lens_numbers` output."""
    return f"pcdof \u2014 {source_name} \u2014 focus {numbers['focus_m']:.2f} m, f/{numbers['f_number']:.3g}"


def scene_page(exported_html: str, *, source_name: str, numbers: dict, preview_png: bytes | None = None) -> str:
    """Turn trame's exported vtk.js page into pcdof's scene page.

    Parameters
    ----------
    exported_html : str, the page written by trame's ``export_html`` (one ``<title>``, one ``<body>``)
    source_name : str, the input's name for the title
    numbers : dict, :func:`pcdof.viewer.lens_numbers` output
    preview_png : optional bytes, a PNG of the preview photograph shown in the panel

    Returns
    -------
    str, the page
    """
    if not isinstance(exported_html, str) or "<body>" not in exported_html or "</head>" not in exported_html:
        raise InputError("exported_html must be an HTML page with <head> and <body>")
    title = html.escape(page_title(source_name, numbers))
    page = re.sub(r"<title>.*?</title>", lambda _m: f"<title>{title}</title>", exported_html, count=1, flags=re.S)
    if "<title>" not in page:
        page = page.replace("</head>", f"<title>{title}</title></head>", 1)
    page = page.replace("</head>", PAGE_STYLE + "</head>", 1)
    lines = "".join(f"<p>{html.escape(line)}</p>" for line in lens_summary(numbers).splitlines())
    image = ""
    if preview_png is not None:
        data = base64.b64encode(preview_png).decode("ascii")
        image = f'<img alt="depth-of-field preview" src="data:image/png;base64,{data}">'
    panel = (f'<div class="content"></div><div id="pcdof-panel"><h1>{title}</h1>{lines}'
             f"<p>drag to rotate, wheel to zoom</p>{image}</div>")
    return page.replace("<body>", "<body>" + panel, 1)


def export_scene_html(scene, *, source_name: str) -> str:
    """The scene page of a :class:`pcdof.viewer.actors.FocusScene` (3-D actors only, its camera and numbers).

    A viewer with a ``preview_image`` attribute (the desktop :class:`pcdof.viewer.ui.FocusViewer`) also
    has its preview photograph put in the panel.
    """
    import cv2
    import pyvista as pv
    import vtk

    source = scene.renderer
    plotter = pv.Plotter(off_screen=True, window_size=tuple(scene.plotter.window_size))
    try:
        plotter.set_background("white")
        for actor in source.GetActors():  # 3-D actors only: labels, widgets and scalar bars are not exported
            if isinstance(actor, vtk.vtkActor) and actor.GetVisibility():
                plotter.renderer.AddActor(actor)
        plotter.renderer.GetActiveCamera().DeepCopy(source.GetActiveCamera())
        plotter.renderer.ResetCameraClippingRange()
        exported = plotter.trame.export_html(None).read()
    finally:
        plotter.close()
    png = None
    preview = getattr(scene, "preview_image", None)
    if preview is not None:
        png = cv2.imencode(".png", np.ascontiguousarray(preview[:, :, ::-1]))[1].tobytes()
    return scene_page(exported, source_name=source_name, numbers=scene.numbers, preview_png=png)
