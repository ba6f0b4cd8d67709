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
