"""pcdof: physically plausible shallow depth of field from one RGB-D frame.

``import pcdof`` is cheap: the public names below are loaded on first use (PEP 562), so a
command or script pays for numba, OpenCV and the kernels only when it calls into them.
"""

import importlib as _importlib
import os as _os
import sys as _sys

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


def _keep_freed_memory() -> bool:
    """Let glibc's malloc keep freed large blocks for reuse, instead of unmapping them (returns whether it did).

    By default glibc serves each block of 128 KiB or more (up to 32 MiB, as it adapts) with a fresh mmap and
    unmaps it when freed, so every frame's arrays (a 1920x1080 layer buffer is 33 MB) start as untouched pages,
    each first write a page fault: thousands per frame, 2-6 us each, and slower still when two threads fault at
    once (the kernel serialises them). Kept in the heap, the next frame reuses the same pages: 1920x1080 renders
    took 10-15 % less time (pipeline 1.74-2.01x the paper method -> 1.68-1.69x, side by side). Blocks up to
    512 MiB come from the heap, and up to 1 GiB of free memory at its top is kept. Only where the C library is
    glibc, and not when the user set glibc's own MALLOC_MMAP_THRESHOLD_ or MALLOC_TRIM_THRESHOLD_."""
    if not _sys.platform.startswith("linux") or any(
            v in _os.environ for v in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "PCDOF_DEFAULT_MALLOC")):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL(None)
        if not hasattr(libc, "gnu_get_libc_version"):  # musl and others: their own malloc, left alone
            return False
        m_trim_threshold, m_mmap_threshold = -1, -3
        return bool(libc.mallopt(m_mmap_threshold, 512 << 20)) and bool(libc.mallopt(m_trim_threshold, 1 << 30))
    except (OSError, AttributeError):
        return False


#: Whether importing pcdof tuned glibc's malloc to keep freed memory (:func:`_keep_freed_memory`; set
#: PCDOF_DEFAULT_MALLOC to leave it alone).
MALLOC_TUNED = _keep_freed_memory()


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


def _user_cache_dir() -> str:
    """numba's per-user cache folder on this platform (what its ``AppDirs('numba').user_cache_dir`` gives)."""
    if _sys.platform == "darwin":
        return _os.path.expanduser("~/Library/Caches/numba")
    if _os.name == "nt":
        return _os.path.join(_os.environ.get("LOCALAPPDATA", _os.path.expanduser("~")), "numba", "Cache")
    return _os.path.join(_os.environ.get("XDG_CACHE_HOME") or _os.path.expanduser("~/.cache"), "numba")


def _configure_numba() -> None:
    """Threading layer and cache folder for numba, set through its environment variables.

    numba reads them when it is first imported; pcdof imports it lazily (inside the stage
    modules), so setting the variables here, before any of that, is enough. When numba is
    already loaded (the caller imported it first) its live config is set as well. Choices the
    user made (the same variables) are left alone.
    """
    numba = _sys.modules.get("numba")
    # numba's default order tries TBB first, which warns on every run when Open3D's older bundled
    # TBB is already loaded (ray casting in pcdof.synth); the layer used is OpenMP either way.
    if "NUMBA_THREADING_LAYER" not in _os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in _os.environ:
        _os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = "omp tbb workqueue"
        if numba is not None:
            numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
    if not _os.environ.get("NUMBA_CACHE_DIR"):
        import tempfile

        uid = _os.getuid() if hasattr(_os, "getuid") else 0
        cache = _numba_cache_fallback(
            [_os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "__pycache__"), _user_cache_dir()],
            _os.path.join(tempfile.gettempdir(), f"pcdof-numba-cache-{uid}"))
        if cache is not None:
            _os.environ["NUMBA_CACHE_DIR"] = cache
            if numba is not None:
                numba.config.CACHE_DIR = cache


_configure_numba()

#: public name -> the module that defines it (loaded on first attribute access)
_EXPORTS = {
    "Intrinsics": "camera", "Rig": "camera", "RGBDFrame": "camera",
    "CalibrationError": "errors", "ImageReadError": "errors", "ImageWriteError": "errors",
    "InputError": "errors", "LensError": "errors", "PcdofError": "errors",
    "colored_points": "cloud", "write_ply": "cloud",
    "load_frame": "io", "read_calibration": "io", "read_color": "io", "read_depth": "io",
    "write_depth": "io", "write_image": "io", "write_json": "io",
    "ThinLens": "lens", "PaperLens": "lens", "focus_depth_at": "lens",
    "register_depth": "stages.register", "fill_depth": "fill",
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
