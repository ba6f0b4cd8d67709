"""pcdof: physically plausible shallow depth of field from one RGB-D frame."""

import os as _os

# OpenMP (numba's parallel kernels, Open3D) keeps its threads spinning after each parallel region,
# by default for 300 000 iterations. On a machine with few cores those spinning threads take the
# CPU from the stage that runs next (registration runs on its own threads right after the previous
# frame's render): a shorter spin keeps the renderer's back-to-back regions fast without that cost.
# Read once when the OpenMP runtime loads, so it is set before anything loads it; a value the user
# has set, or an explicit OMP_WAIT_POLICY, is left alone.
#: Whether importing pcdof set GOMP_SPINCOUNT (the peer benchmarks give other libraries their default back).
SPINCOUNT_SET = "GOMP_SPINCOUNT" not in _os.environ and "OMP_WAIT_POLICY" not in _os.environ
if SPINCOUNT_SET:
    _os.environ["GOMP_SPINCOUNT"] = "10000"



def _writable_folder(path: str) -> bool:
    """Whether *path* is (or can be made) a folder this process can create files in."""
    import tempfile

    try:
        _os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def _numba_cache_fallback(candidates, fallback: str):
    """The folder numba's on-disk cache should use, or None when one of *candidates* is writable.

    numba caches compiled kernels next to the source (``__pycache__``) or in the user's cache
    folder, and fails at import when neither is writable (a read-only install run by a user
    without a home folder, e.g. a service). Then the cache goes to *fallback* instead.
    """
    if any(_writable_folder(c) for c in candidates):
        return None
    return fallback if _writable_folder(fallback) else None


import numba as _numba  # noqa: E402 - after GOMP_SPINCOUNT, which the OpenMP runtime reads when it loads

# numba's parallel kernels use OpenMP (the layer the spin count above tunes). Its default order tries
# TBB first, which warns on every run when Open3D's older bundled TBB is already loaded (ray casting
# in pcdof.synth); a layer or order the user has chosen is left alone.
if "NUMBA_THREADING_LAYER" not in _os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in _os.environ:
    _numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

if not _os.environ.get("NUMBA_CACHE_DIR"):
    import tempfile as _tempfile

    from numba.misc.appdirs import AppDirs as _AppDirs

    _cache = _numba_cache_fallback(
        [_os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "__pycache__"),
         _AppDirs(appname="numba", appauthor=False).user_cache_dir],
        _os.path.join(_tempfile.gettempdir(), f"pcdof-numba-cache-{_os.getuid() if hasattr(_os, 'getuid') else 0}"))
    if _cache is not None:
        _os.environ["NUMBA_CACHE_DIR"] = _cache
        _numba.config.CACHE_DIR = _cache

from .camera import Intrinsics, RGBDFrame, Rig
from .errors import (
    CalibrationError,
    ImageReadError,
    ImageWriteError,
    InputError,
    LensError,
    PcdofError,
)
from .cloud import colored_points, write_ply
from .io import load_frame, read_calibration, read_color, read_depth, write_depth, write_image, write_json
from .lens import PaperLens, ThinLens, focus_depth_at
from .register import register_depth
from .fill import fill_depth
from .pipeline import RenderResult, StageTrace, render, run

__all__ = [
    "Intrinsics", "Rig", "RGBDFrame", "ThinLens", "PaperLens", "focus_depth_at",
    "load_frame", "read_calibration", "read_color", "read_depth", "write_image", "write_depth", "write_json",
    "colored_points", "write_ply", "register_depth", "fill_depth", "render", "run", "RenderResult", "StageTrace",
    "PcdofError", "InputError", "CalibrationError", "LensError", "ImageReadError", "ImageWriteError",
]
