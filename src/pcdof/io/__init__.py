"""Reading and writing pcdof's inputs and outputs.

Readers: :func:`read_calibration` (``calib.json``, OpenCV FileStorage YAML/XML, Open3D intrinsic JSON),
:func:`read_color`, :func:`read_depth`, :func:`load_frame`. Writers (atomic: a temporary file in the
same folder, then ``os.replace``): :func:`write_image`, :func:`write_depth`, :func:`write_json`.
"""

from ._files import MAX_PIXELS, exr_available
from .calibration import read_calibration
from .images import load_frame, read_color, read_depth
from .writers import (
    DEPTH_FORMATS,
    IMAGE_FORMATS,
    MAX_PNG_DEPTH_M,
    depth_to_png_mm,
    output_format,
    write_depth,
    write_image,
    write_json,
)

__all__ = [
    "read_calibration", "read_color", "read_depth", "load_frame",
    "write_image", "write_depth", "write_json", "output_format", "depth_to_png_mm", "exr_available",
    "IMAGE_FORMATS", "DEPTH_FORMATS", "MAX_PNG_DEPTH_M", "MAX_PIXELS",
]
