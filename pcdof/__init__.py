"""pcdof: physically plausible shallow depth of field from one RGB-D frame."""

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
