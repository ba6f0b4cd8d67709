"""Finding a usable CUDA GPU, and choosing the device a run uses.

Nothing here imports numba's CUDA target until asked, and nothing here raises on import: a machine without
a GPU (or without the ``gpu`` extra) gets a reason, not a traceback.
"""

from __future__ import annotations

import functools
import os

from ..errors import DeviceError, InputError

#: What a user without a usable GPU is told to do.
INSTALL_HINT = "install the GPU extra with `pip install pcdof[gpu]` (needs an NVIDIA GPU and driver)"

#: Devices :func:`resolve_device` accepts (those of :data:`pcdof.options.DEVICES`).
DEVICE_NAMES = ("auto", "cpu", "gpu")


def simulated() -> bool:
    """Whether numba's CUDA simulator is switched on (``NUMBA_ENABLE_CUDASIM=1`` before numba was imported)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")


@functools.lru_cache(maxsize=1)
def _probe() -> tuple[bool, str]:
    try:
        from numba import cuda
    except Exception as err:  # numba without its CUDA target, or a broken install
        return False, f"numba's CUDA target cannot be imported ({type(err).__name__}: {err})"
    if simulated():
        return True, "numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1): kernels run on the CPU, slowly"
    try:
        if not cuda.is_available():
            why = ""
            try:
                why = str(cuda.cuda_error() or "").strip().splitlines()[0].rstrip(".")
            except Exception:
                pass
            return False, f"no CUDA driver or device found{f' ({why})' if why else ''}"
        dev = cuda.get_current_device()
        cc = dev.compute_capability
        if cc < (3, 5):
            return False, f"{dev.name.decode() if isinstance(dev.name, bytes) else dev.name} has compute " \
                          f"capability {cc[0]}.{cc[1]}; 3.5 or newer is needed"
        name = dev.name.decode() if isinstance(dev.name, bytes) else str(dev.name)
        return True, f"{name} (compute capability {cc[0]}.{cc[1]})"
    except Exception as err:  # a driver that loads but fails (no device, wrong version, out of resources)
        return False, f"the CUDA driver failed ({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})"


def available() -> tuple[bool, str]:
    """Whether a usable CUDA GPU is there, and a one-line description of it or of why not.

    The answer is probed once per process (the driver is initialised then). Under numba's CUDA simulator the
    answer is True (the kernels run, on the CPU).

    Returns
    -------
    (usable : bool, what : str)
    """
    return _probe()


def require() -> str:
    """The GPU's one-line description; :class:`pcdof.errors.DeviceError` (one line: why, and how to install the
    extra) when there is no usable GPU."""
    ok, what = available()
    if not ok:
        raise DeviceError(f"no usable GPU was found: {what}; {INSTALL_HINT}, or use --device cpu")
    return what


def resolve_device(device: str) -> str:
    """The device a run uses: "cpu" or "gpu".

    Parameters
    ----------
    device : "auto" (the GPU when the ``gpu`` extra is installed and :func:`available` finds real hardware; never
        the simulator), "cpu" or "gpu" (:class:`pcdof.errors.DeviceError` when no usable GPU is there)
    """
    if not isinstance(device, str) or device not in DEVICE_NAMES:
        raise InputError(f"device must be one of {list(DEVICE_NAMES)}; got {device!r}")
    if device == "cpu":
        return "cpu"
    if device == "gpu":
        require()
        return "gpu"
    if not extra_installed():  # a CPU-only install never pays for importing numba's CUDA target (seconds)
        return "cpu"
    ok, _ = available()
    return "gpu" if ok and not simulated() else "cpu"


@functools.lru_cache(maxsize=1)
def extra_installed() -> bool:
    """Whether the ``gpu`` extra's CUDA target (the ``numba-cuda`` package) is installed; looked up, not imported."""
    import importlib.util

    return importlib.util.find_spec("numba_cuda") is not None
