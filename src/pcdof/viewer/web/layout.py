"""The browser viewer's page layout (trame + Vuetify 3): the 3-D view on the left, the controls on the right.

Element ids the tests and the screenshot script use: ``scene`` (the 3-D view's container), ``preview``
(the photograph), ``focus-slider``, ``focus-value``, ``near-value``, ``far-value``, ``blur-value``,
``download``.
"""

from __future__ import annotations

from ..scene import F_NUMBER_RANGE

#: Fractions of the clicked element's box, from its top-left corner, sent with a click.
CLICK_FRACTIONS = ("[($event.clientX - $event.currentTarget.getBoundingClientRect().left)"
                   " / $event.currentTarget.getBoundingClientRect().width,"
                   " ($event.clientY - $event.currentTarget.getBoundingClientRect().top)"
                   " / $event.currentTarget.getBoundingClientRect().height]")

#: Inline styles (Vue drops <style> elements from templates).
STYLE = {
    "page": "display: flex; width: 100vw; height: 100vh; overflow: hidden;",
    "scene": "flex: 3 1 0; min-width: 0; position: relative;",
    "side": ("flex: 2 1 0; min-width: 260px; max-width: 720px; overflow-y: auto; padding: 10px 14px; "
             "box-sizing: border-box; font: 14px/1.4 sans-serif; border-left: 1px solid #ddd;"),
    "title": "font-size: 16px; margin: 0 0 6px 0; overflow-wrap: anywhere;",
    "numbers": "display: grid; grid-template-columns: auto 1fr; column-gap: 10px; margin: 6px 0;",
    "preview": "display: block; width: 100%; height: auto; cursor: crosshair; margin-top: 6px;",
    "hint": "color: #555; font-size: 12px;",
}


def _sliders(app, v3, html) -> None:
    s = app.session
    lo, hi = min(s.z_min_m, s.lens.focus_distance_m), max(s.z_max_m, s.lens.focus_distance_m)
    n_lo, n_hi = min(F_NUMBER_RANGE[0], s.lens.f_number), max(F_NUMBER_RANGE[1], s.lens.f_number)
    f_lo, f_hi = min(10.0, s.lens.focal_length_mm), max(300.0, s.lens.focal_length_mm)
    common = {"hide_details": True, "density": "compact", "end": app.on_release, "color": "orange-darken-2"}
    v3.VSlider(id="focus-slider", v_model=("focus_m",), min=lo, max=hi, step=(hi - lo) / 500 or 0.001,
               label="focus (m)", **common)
    v3.VSlider(id="f-number-slider", v_model=("f_number",), min=n_lo, max=n_hi, step=0.05, label="f-number",
               **common)
    v3.VSlider(id="focal-length-slider", v_model=("focal_length_mm",), min=f_lo, max=f_hi, step=1,
               label="focal length (mm)", **common)
    v3.VSlider(id="blades-slider", v_model=("aperture_blades",), min=0, max=12, step=1,
               label="aperture blades (0 = round)", **common)


def _numbers(html) -> None:
    with html.Div(style=STYLE["numbers"]):
        for label, key, element_id in (("focus distance", "focus", "focus-value"),
                                       ("sharp from (near limit)", "near", "near-value"),
                                       ("sharp to (far limit)", "far", "far-value"),
                                       ("largest blur", "max_blur", "blur-value")):
            html.Span(label)
            html.B(f"{{{{ numbers.{key} }}}}", id=element_id)
        html.Span("sharp means a circle of confusion of at most")
        html.Span("{{ numbers.coc_limit }}")


def build_layout(app):
    """Build the page of the :class:`pcdof.viewer.web.app.WebViewer` *app*; returns its 3-D view widget."""
    from trame.ui.vuetify3 import VAppLayout
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3
    from trame_pyvista import PyVistaRemoteView

    with VAppLayout(app.server, full_height=True) as layout:
        with html.Div(style=STYLE["page"]):
            with html.Div(id="scene", style=STYLE["scene"], __events=["dblclick"],
                          dblclick=(app.on_scene_click, CLICK_FRACTIONS)):
                view = PyVistaRemoteView(app.plotter, interactive_ratio=1, still_ratio=1)
            with html.Div(style=STYLE["side"]):
                html.H1("{{ trame__title }}", style=STYLE["title"])
                _sliders(app, v3, html)
                v3.VCheckbox(v_model=("coc_colors",), label="colour the points by their circle of confusion",
                             hide_details=True, density="compact")
                _numbers(html)
                v3.VBtn("render full resolution and download", id="download", color="primary", size="small",
                        click="utils.download(download_name, trigger('download_full'), 'image/png')")
                html.Div("{{ message }}", id="message", style=STYLE["hint"])
                html.Img(id="preview", style=STYLE["preview"], src=("preview_src",),
                         click=(app.on_preview_click, CLICK_FRACTIONS))
                html.Div("preview {{ preview_size }} ({{ preview_kind }}); click it, or double-click the 3-D view, "
                         "to focus there; drag the 3-D view to turn it", style=STYLE["hint"])
    app.layout = layout
    return view
