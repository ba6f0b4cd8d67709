"""3-D inspection of the focal plane and the depth of field.

* :mod:`.scene`: the geometry, framing and numbers (pure numpy), and :func:`prepare_frame` (register and fill
  once, then only the lens changes);
* :mod:`.actors`: the 3-D scene (:class:`FocusScene`); :mod:`.ui`: the PyVista desktop viewer (:class:`FocusViewer`, :func:`build_scene`,
  :func:`scene_from_frame`);
* :mod:`.html_export`: the scene as one self-contained HTML page;
* :mod:`.web`: the browser viewer served by trame (``pcdof view --serve``).

The names below are loaded on first use, so importing the package loads neither PyVista nor trame.
"""

import importlib as _importlib

#: public name -> the submodule that defines it
_EXPORTS = {
    "prepare_frame": "scene", "lens_numbers": "scene", "lens_summary": "scene", "render_preview": "scene",
    "downscale_for_preview": "scene", "F_NUMBER_RANGE": "scene",
    "FocusScene": "actors", "FocusViewer": "ui", "build_scene": "ui", "scene_from_frame": "ui",
    "export_scene_html": "html_export",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(_importlib.import_module(f".{module}", __name__), name)


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
