"""Process-wide tuning, for a process that exists to run pcdof: the ``pcdof`` command calls
:func:`tune_process` before anything else loads; a program that imports pcdof as a library gets none of it
unless it calls :func:`tune_process` itself.

What it changes, each only where the user has not made the choice already:

* ``GOMP_SPINCOUNT=10000``: OpenMP (numba's parallel kernels, Open3D) keeps its threads spinning after each
  parallel region, by default for 300 000 iterations; on a machine with few cores those spinning threads
  take the CPU from the stage that runs next. Left alone when ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY`` is set.
* ``NUMBA_THREADING_LAYER_PRIORITY="omp tbb workqueue"``: numba's default order tries TBB first, which warns
  on every run when Open3D's older bundled TBB is already loaded; the layer used is OpenMP either way.
* ``NUMBA_CACHE_DIR``: only when neither the package's ``__pycache__`` nor the user's cache folder is
  writable (a read-only install run by a service without a home folder), a folder in the temporary directory.
* glibc's malloc keeps freed large blocks for reuse instead of unmapping them (``mallopt``), so every frame's
  arrays do not start as untouched pages (thousands of page faults a frame: 1920x1080 renders took 10-15 %
  less time). Not where the C library is not glibc, nor when ``MALLOC_MMAP_THRESHOLD_``,
  ``MALLOC_TRIM_THRESHOLD_`` or ``PCDOF_DEFAULT_MALLOC`` is set.
* Every thread allocates from one malloc arena (``M_ARENA_MAX`` 1), so what a worker thread frees (the
  ownership transforms, a kernel's scratch) is reused by the others instead of being kept in an arena of its
  own: a 3840x2160 frame peaked 8 bytes a pixel lower, at the same speed. Not where the C library is not
  glibc, nor when ``MALLOC_ARENA_MAX`` or ``PCDOF_DEFAULT_MALLOC`` is set.
* What C libraries (libpng, libjpeg, libtiff) print on file descriptor 2 while an image decodes is captured
  and turned into pcdof's one-line errors (:func:`pcdof.io.capture.captured_stderr`).

The environment variables are read by numba and OpenMP when they load, so :func:`tune_process` must run
before numba is imported for those two to take effect (it says which took effect in its result).
"""

from __future__ import annotations

import os
import sys
import tempfile

#: what :func:`tune_process` changed in this process (name -> value); empty until it runs
_tuned: dict = {}


def tuning() -> dict:
    """What :func:`tune_process` changed in this process, as ``{name: value}`` (a copy; empty if it has not run)."""
    return dict(_tuned)


def tune_process() -> dict:
    """Tune this process for rendering (see the module docstring); returns what was changed, ``{name: value}``.

    Idempotent: a second call changes nothing more. Settings the user made (the same environment variables)
    are left alone.
    """
    if _tuned:
        return dict(_tuned)
    changes: dict = {"tuned": True}
    numba_loaded = "numba" in sys.modules
    if "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ:
        os.environ["GOMP_SPINCOUNT"] = changes["GOMP_SPINCOUNT"] = "10000"
    if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ \
            and not numba_loaded:
        os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = changes["NUMBA_THREADING_LAYER_PRIORITY"] = \
            "omp tbb workqueue"
    cache = numba_cache_fallback()
    if cache is not None and not os.environ.get("NUMBA_CACHE_DIR") and not numba_loaded:
        os.environ["NUMBA_CACHE_DIR"] = changes["NUMBA_CACHE_DIR"] = cache
    if keep_freed_memory():
        changes["malloc"] = "keeps freed blocks up to 512 MiB"
    if share_one_arena():
        changes["malloc_arenas"] = 1
    from ..io import capture

    capture.enable(True)
    changes["capture_library_messages"] = True
    _tuned.update(changes)
    return dict(_tuned)


def keep_freed_memory() -> bool:
    """Let glibc's malloc keep freed large blocks (up to 512 MiB, and up to 1 GiB free at the heap's top) for
    reuse instead of unmapping them; returns whether it did (only with glibc, and not when the user set
    ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_`` or ``PCDOF_DEFAULT_MALLOC``)."""
    if any(v in os.environ for v in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "PCDOF_DEFAULT_MALLOC")):
        return False
    libc = _glibc()
    m_trim_threshold, m_mmap_threshold = -1, -3
    return libc is not None and bool(libc.mallopt(m_mmap_threshold, 512 << 20)) and bool(
        libc.mallopt(m_trim_threshold, 1 << 30))


def _glibc():
    """The C library as a ctypes handle when it is glibc (None elsewhere: musl and others have their own malloc)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        libc = ctypes.CDLL(None)
    except OSError:
        return None
    return libc if hasattr(libc, "gnu_get_libc_version") and hasattr(libc, "mallopt") else None


def share_one_arena() -> bool:
    """Let every thread allocate from glibc's main arena (``M_ARENA_MAX`` 1), so that blocks one thread frees are
    reused by any; returns whether it did (only with glibc, before any other thread allocated, and not when the
    user set ``MALLOC_ARENA_MAX`` or ``PCDOF_DEFAULT_MALLOC``). glibc fixes its arena limit when a second thread
    first allocates, so this must run before threads start (:func:`tune_process` runs first)."""
    if any(v in os.environ for v in ("MALLOC_ARENA_MAX", "PCDOF_DEFAULT_MALLOC")):
        return False
    libc = _glibc()
    m_arena_max = -8
    return libc is not None and bool(libc.mallopt(m_arena_max, 1))


def writable_folder(path: str) -> bool:
    """Whether *path* is (or can be made) a folder this process can create files in."""
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def user_cache_dir() -> str:
    """numba's per-user cache folder on this platform (what its ``AppDirs('numba').user_cache_dir`` gives)."""
    if sys.platform == "darwin":
        return os.path.expanduser("~/Library/Caches/numba")
    if os.name == "nt":
        return os.path.join(os.environ.get("LOCALAPPDATA", os.path.expanduser("~")), "numba", "Cache")
    return os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "numba")


def numba_cache_fallback(candidates=None, fallback: str | None = None) -> str | None:
    """The folder numba's on-disk cache should use, or None when one of *candidates* is writable.

    numba caches compiled kernels next to the source (``__pycache__``) or in the user's cache folder, and
    fails when neither is writable. *candidates* default to those two; *fallback* to a per-user folder in
    the temporary directory (returned only if writable).
    """
    if candidates is None:
        package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        candidates = [os.path.join(package, "__pycache__"), user_cache_dir()]
    if fallback is None:
        uid = os.getuid() if hasattr(os, "getuid") else 0
        fallback = os.path.join(tempfile.gettempdir(), f"pcdof-numba-cache-{uid}")
    if any(writable_folder(c) for c in candidates):
        return None
    return fallback if writable_folder(fallback) else None
