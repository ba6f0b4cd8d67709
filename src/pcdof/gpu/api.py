"""``run(frame, options)`` on the GPU: :func:`pcdof.pipeline.run` with the device set to "gpu"."""

from __future__ import annotations

from ..options import as_options
from ..pipeline import RenderResult
from ..pipeline import run as pipeline_run


def run(frame, options, **overrides) -> RenderResult:
    """Register, fill and render one frame on the GPU; the result of :func:`pcdof.pipeline.run`.

    Parameters
    ----------
    frame : pcdof.camera.RGBDFrame
    options : pcdof.options.RenderOptions, or a lens with keyword options (as :func:`pcdof.pipeline.run`)

    Raises
    ------
    pcdof.errors.DeviceError
        no usable GPU (one line: why, and how to install the ``gpu`` extra)
    """
    return pipeline_run(frame, as_options(options, **overrides).replace(device="gpu"))
