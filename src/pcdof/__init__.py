"""pcdof: physically plausible shallow depth of field from one RGB-D frame.

``import pcdof`` is cheap and changes nothing in the importing process: the public names below are
loaded on first use (PEP 562), so a command or script pays for numba, OpenCV and the kernels only when it
calls into them, and no environment variable, allocator setting or file descriptor is touched. The
``pcdof`` command tunes its own process (:func:`pcdof.runtime.process.tune_process`); a program may call
that too.
"""

import importlib as _importlib

#: public name -> the module that defines it (loaded on first attribute access)
_EXPORTS = {
    "Intrinsics": "camera", "Rig": "camera", "RGBDFrame": "camera",
    "CalibrationError": "errors", "ImageReadError": "errors", "ImageWriteError": "errors",
    "InputError": "errors", "LensError": "errors", "PcdofError": "errors",
    "colored_points": "cloud", "write_ply": "cloud",
    "load_frame": "io", "read_calibration": "io", "read_color": "io", "read_depth": "io",
    "write_depth": "io", "write_image": "io", "write_json": "io",
    "ThinLens": "lens", "PaperLens": "lens", "focus_depth_at": "lens",
    "register_depth": "stages.register", "fill_depth": "stages.fill", "fill_aligned": "stages.fill",
    "depth_view_box": "depth_view", "depth_view_mask": "depth_view", "DepthViewBox": "depth_view",
    "RenderResult": "pipeline", "StageTrace": "pipeline", "render": "pipeline", "run": "pipeline",
    "RenderOptions": "options",
    "open_source": "sources", "FrameSource": "sources", "SOURCES": "sources",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'pcdof' has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups are plain attribute reads
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
