"""Optional GPU backend: every stage of the per-frame pipeline as CUDA kernels (numba).

Install with ``pip install pcdof[gpu]`` (numba's CUDA target, ``numba-cuda``, and the CUDA runtime wheels).
The default install stays CPU-only; without a usable GPU nothing here is imported by the pipeline, and
``device="gpu"`` fails with one line saying why.

Modules: :mod:`~pcdof.gpu.device` (discovery: :func:`available`), :mod:`~pcdof.gpu.coc`,
:mod:`~pcdof.gpu.register`, :mod:`~pcdof.gpu.fill`, :mod:`~pcdof.gpu.render` (the kernels of each stage),
:mod:`~pcdof.gpu.stages` (the stages chained on the device), :mod:`~pcdof.gpu.api` (``run(frame, options)``,
the pipeline's result) and :mod:`~pcdof.gpu.stream` (frames streamed with upload, compute and download
overlapped). The kernels run unchanged in numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), which is how the
test suite checks them against the stages' plain references (``pcdof.stages.<stage>.reference``) on a machine without a GPU.
"""

from .device import available, require

__all__ = ["available", "require"]
