"""The fill's strategies by name (:data:`FILL_METHODS`), its public entry :func:`fill_depth`, and the warm-up
that compiles its kernels."""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from .directional import fill_joint_bilateral, fill_nearest_background
from .telea import fill_telea


#: Fill strategies by name; all take ``(depth_m, color, **options)`` and return filled float32 metres.
FILL_METHODS = {
    "joint-bilateral": fill_joint_bilateral,
    "telea": fill_telea,
    "nearest-background": fill_nearest_background,
}


def check_fill_method(method, name: str = "method") -> None:
    """InputError naming *name* unless *method* is one of :data:`FILL_METHODS`' names (a str)."""
    if not isinstance(method, str) or method not in FILL_METHODS:
        raise InputError(f"{name} must be one of {sorted(FILL_METHODS)}; got {method!r}")


def fill_depth(depth_m, color, *, method: str = "joint-bilateral", parallel: bool | None = None,
               **options) -> np.ndarray:
    """Fill every unknown pixel of a registered depth map.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, z-depth at colour resolution, 0 = unknown (sensor
        holes and disocclusions; NaN, inf and negative values are unknown too)
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float in [0, 1]: the guide
    method : str, a key of :data:`FILL_METHODS`
    parallel : None (chosen from the number of holes by :func:`~pcdof.stages.fill.plan.plan_fill`), True or
        False: run the kernels on all numba threads or on one; the result is the same
    **options : keyword options of the chosen method (``edge_ratio``, ``sigma_color``,
        ``background_bias``, ``border`` for ``"joint-bilateral"``; ``edge_ratio``, ``border`` for
        ``"nearest-background"``; ``radius_px`` for ``"telea"``)

    Returns
    -------
    (H, W) float32 ndarray, metres: known pixels unchanged, holes filled with values in
    [min known, max known] (outside the depth camera's view with ``border="candidates"``, down to
    min known / 1.1, where a surface runs nearer than all measured depth); a copy when there are no holes

    Raises
    ------
    InputError
        bad shapes, dtypes or options, an unknown method, or no known pixel at all

    Examples
    --------
    >>> d = np.array([[1.0, 0.0, 2.0]], np.float32)
    >>> fill_depth(d, np.zeros((1, 3, 3), np.uint8)).tolist()
    [[1.0, 2.0, 2.0]]
    """
    check_fill_method(method)
    fn = FILL_METHODS[method]
    try:
        return fn(depth_m, color, parallel=parallel, **options)
    except TypeError as exc:
        if "unexpected keyword" in str(exc):
            raise InputError(f"method {method!r} got an unknown option: {exc}") from None
        raise


def fill_aligned(depth_m, color, *, method: str = "joint-bilateral", parallel: bool | None = None,
                 **options) -> tuple[np.ndarray, int]:
    """What the pipeline's fill stage does: with the colour-guided ``"joint-bilateral"`` method, measured pixels next
    to depth edges first move to the side whose colour they have (:func:`~pcdof.stages.fill.edges.align_depth_edges`,
    with the method's ``edge_ratio`` when given), then every unknown pixel is filled (:func:`fill_depth`; the other
    methods fill only). Parameters as :func:`fill_depth`'s. Returns the filled depth ((H, W) float32 metres) and the
    number of measured pixels moved."""
    from .edges import align_depth_edges

    check_fill_method(method)
    moved = 0
    if method == "joint-bilateral":
        edge = {"edge_ratio": options["edge_ratio"]} if "edge_ratio" in options else {}
        depth_m, moved = align_depth_edges(depth_m, color, with_count=True, **edge)
    return fill_depth(depth_m, color, method=method, parallel=parallel, **options), moved


def warmup() -> None:
    """Compile (or load from numba's cache) the fill kernels on a tiny input, for 8-bit colour (what
    cameras and image files give). The other colour path (float64, for every other dtype: see
    :func:`~pcdof.stages.fill.inputs.color_for_kernel`) compiles when first used, once: a first frame does not
    wait for it."""
    from .edges import align_depth_edges

    d = np.array([[1.0, 0.0, 2.0], [1.0, 0.0, 2.0]], np.float32)
    fill_joint_bilateral(d, np.zeros((2, 3, 3), np.uint8), parallel=False)
    align_depth_edges(np.array([[1.0, 2.0, 0.0], [1.0, 2.0, 0.0]], np.float32), np.zeros((2, 3, 3), np.uint8))
    fill_nearest_background(d, None, parallel=False)
