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
from .lens import PaperLens, ThinLens, focus_depth_at

__all__ = [
    "Intrinsics", "Rig", "RGBDFrame", "ThinLens", "PaperLens", "focus_depth_at",
    "PcdofError", "InputError", "CalibrationError", "LensError", "ImageReadError", "ImageWriteError",
]
