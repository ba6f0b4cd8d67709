"""Versions of the libraries a result depends on, for reports and benchmarks."""

from __future__ import annotations

import os
import platform
import sys
from importlib import metadata

#: Distributions whose versions a report records (None where one is not installed).
PACKAGES = ("pcdof", "numpy", "numba", "open3d", "dask", "distributed", "imageio", "imageio-ffmpeg", "tqdm")
#: The distributions that provide ``cv2``, in the order they are looked for.
OPENCV_DISTRIBUTIONS = ("opencv-contrib-python-headless", "opencv-python-headless", "opencv-contrib-python",
                        "opencv-python")


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def library_versions() -> dict:
    """Python, the machine and the versions of the libraries in :data:`PACKAGES`, cheaply.

    Versions come from the installed distributions' metadata, so nothing is imported (open3d takes
    seconds to import); OpenCV's is ``cv2.__version__`` when cv2 is already loaded, else its
    distribution's. ``numba_threads`` is numba's thread count when numba is already loaded.

    Returns
    -------
    dict, JSON-ready: ``python``, ``platform``, ``machine``, ``cpus``, ``opencv`` and one key per
    package of :data:`PACKAGES` (str, or None when not installed)
    """
    out = {"python": platform.python_version(), "platform": platform.platform(), "machine": platform.machine(),
           "cpus": os.cpu_count()}
    for name in PACKAGES:
        out[name] = _version(name)
    cv2 = sys.modules.get("cv2")
    out["opencv"] = getattr(cv2, "__version__", None) or next(
        (v for v in map(_version, OPENCV_DISTRIBUTIONS) if v is not None), None)
    numba = sys.modules.get("numba")
    if numba is not None and hasattr(numba, "get_num_threads"):
        out["numba_threads"] = numba.get_num_threads()
    return out


__all__ = ["library_versions"]
