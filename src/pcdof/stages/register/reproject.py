"""The registration's entry points: whether a rig needs it, the discontinuity ratio, the plan, and the
reprojection itself (pass 1 then pass 2, on the plan's threads)."""

from __future__ import annotations

import math

import numba
import numpy as np

from ...camera import Rig, RGBDFrame
from ...errors import InputError
from ...lens import positive_number
from ...plans import RegisterPlan, as_dict, check_register_plan, plan_register
from .project import project_and_code
from .raster import rasterise
from .rig import rig_constants
from .tasks import thread_pool

#: Smallest automatic discontinuity ratio: a triangle is dropped when max z > (1 + ratio) * min z
#: of its corners. At 0.03 a kept triangle never puts depth more than 3 % behind a corner it was built from.
MIN_DEPTH_RATIO = 0.03

#: The automatic ratio also keeps planes seen at up to this incidence angle (degrees): across a
#: triangle's diagonal (sqrt(2) depth pixels) such a plane's depth changes by sqrt(2) tan(angle) / f.
MAX_INCIDENCE_DEG = 75.0

#: Share of the half pixel that an edge pixel's footprint reaches towards a hole or the border.
UNKNOWN_REACH = 1.0


def needs_registration(rig: Rig) -> tuple[bool, str]:
    """Whether depth must be re-projected into the colour camera, and why (for the pipeline trace).

    Parameters
    ----------
    rig : Rig

    Returns
    -------
    needed : bool
    reason : str, one line
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    if rig.is_registered:
        return False, "depth is already in the colour camera (identity extrinsics, equal intrinsics)"
    reasons = []
    if not np.allclose(rig.T_color_from_depth, np.eye(4), rtol=0, atol=1e-9):
        reasons.append(f"cameras {rig.baseline_m * 1000:.1f} mm apart" if rig.baseline_m > 0 else "cameras rotated")
    if not rig.color.same_as(rig.depth):
        reasons.append(
            f"depth grid {rig.depth.width}x{rig.depth.height} differs from colour {rig.color.width}x{rig.color.height}"
            if rig.depth.shape != rig.color.shape
            else "depth and colour intrinsics differ"
        )
    return True, "; ".join(reasons)


def _depth_input(depth_m, shape) -> np.ndarray:
    """Validated float32 view (a copy only when needed); the kernels treat NaN, inf and z <= 0 as unknown."""
    arr = np.asarray(depth_m)
    if arr.ndim != 2:
        raise InputError(f"depth_m must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.shape != tuple(shape):
        raise InputError(f"depth_m must be (H, W) = {tuple(shape)} (the rig's depth camera); got {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise InputError(f"depth_m must be numeric; got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def default_depth_ratio(depth_intrinsics) -> float:
    """Automatic discontinuity ratio for a depth camera: max(MIN_DEPTH_RATIO, sqrt(2) tan(MAX_INCIDENCE_DEG) / f).

    Coarse depth grids see steep surfaces as large steps between neighbours, so they need a
    larger ratio (Kinect v1/v2, f = 365..580 px: 0.03; a 64-pixel-wide sensor, f = 45 px: 0.12).
    """
    f = min(depth_intrinsics.fx, depth_intrinsics.fy)
    return max(MIN_DEPTH_RATIO, math.sqrt(2.0) * math.tan(math.radians(MAX_INCIDENCE_DEG)) / f)


def _depth_ratio(max_depth_ratio, depth_intrinsics) -> float | None:
    """The checked discontinuity ratio: *max_depth_ratio*, or the camera's default when it is None
    (None again without *depth_intrinsics*)."""
    if max_depth_ratio is None:
        return None if depth_intrinsics is None else default_depth_ratio(depth_intrinsics)
    return positive_number("max_depth_ratio", max_depth_ratio, InputError)


def reproject_depth(depth_m, rig: Rig, *, max_depth_ratio: float | None = None,
                    plan: RegisterPlan | None = None) -> np.ndarray:
    """Re-sample a depth map from the depth camera into the colour camera's pixel grid.

    Always does the reprojection (use :func:`register_depth` or :func:`needs_registration`
    to skip it for a rig whose cameras coincide).

    Parameters
    ----------
    depth_m : (h, w) float ndarray, metres, z-depth in the depth camera (``rig.depth`` size);
        0, NaN, inf and negative values are unknown
    rig : Rig
    max_depth_ratio : float > 0 or None; a triangle of neighbouring depth pixels whose corner depths
        (colour frame) satisfy max z > (1 + max_depth_ratio) * min z spans a discontinuity and
        is not drawn; None = :func:`default_depth_ratio` of the depth camera
    plan : :class:`pcdof.plans.RegisterPlan` or None (:func:`plan_for`): threads, tasks, kernels

    Returns
    -------
    (H, W) float32 ndarray, metres, z-depth in the colour camera (``rig.color`` size), 0 where
    no measured surface maps (sensor holes, disocclusions, outside the depth camera's view)
    """
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    ratio = _depth_ratio(max_depth_ratio, rig.depth)
    depth = _depth_input(depth_m, rig.depth.shape)
    plan = plan_for(rig) if plan is None else check_register_plan(plan)
    consts = rig_constants(rig)
    h, w = depth.shape
    # (u, v, 1/z) per depth pixel in float32 planes (1/z = 0: not projected)
    U = np.empty((h, w), dtype=np.float32)
    V = np.empty((h, w), dtype=np.float32)
    IZ = np.empty((h, w), dtype=np.float32)
    row_lo = np.empty(h)
    row_hi = np.empty(h)
    codes = np.zeros((h + 1, w + 1), dtype=np.uint8)
    out = np.empty(rig.color.shape, dtype=np.float32)
    project_and_code(plan.threads, min(plan.chunks, h), depth, consts.rays, consts.t, consts.cam, consts.dist,
                     consts.tilt, consts.has_dist, consts.r2_max, float(consts.foot[1]), 1.0 + ratio, U, V, IZ,
                     row_lo, row_hi, codes)
    rasterise(plan.threads, min(plan.bands, out.shape[0]), plan.block_kernel, depth, U, V, IZ, codes, row_lo, row_hi,
              consts.foot, 1.0 + ratio, UNKNOWN_REACH, out)
    return out


def plan_for(rig: Rig, *, threads: int | None = None) -> RegisterPlan:
    """The registration's plan for *rig* (:func:`pcdof.plans.plan_register` of its depth and colour heights)."""
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    return plan_register(rig.depth.height, rig.color.height, threads=threads)


def plan_info(rig: Rig, plan: RegisterPlan | None = None) -> dict:
    """The plan :func:`reproject_depth` runs *rig* with, as plain data for the pipeline trace."""
    return as_dict(plan_for(rig) if plan is None else check_register_plan(plan))


def register_depth(frame: RGBDFrame, *, max_depth_ratio: float | None = None,
                   plan: RegisterPlan | None = None) -> np.ndarray:
    """Depth of an RGB-D frame in the colour camera's pixel grid.

    A rig whose cameras coincide (:attr:`Rig.is_registered`) is not re-projected: the result
    is a copy of the frame's depth. Otherwise see :func:`reproject_depth`.

    Parameters
    ----------
    frame : RGBDFrame
    max_depth_ratio : float or None, discontinuity ratio (None: :func:`default_depth_ratio`);
        see :func:`reproject_depth`
    plan : RegisterPlan or None, see :func:`reproject_depth`

    Returns
    -------
    (H, W) float32 ndarray, metres, z-depth in the colour camera, 0 = unknown
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    ratio = _depth_ratio(max_depth_ratio, None)  # checked before the identity-rig shortcut: never ignored
    if plan is not None:
        check_register_plan(plan)
    needed, _ = needs_registration(frame.rig)
    if not needed:
        return np.array(frame.depth_m, dtype=np.float32, copy=True)
    return reproject_depth(frame.depth_m, frame.rig, max_depth_ratio=ratio, plan=plan)


def warmup() -> None:
    """Compile (or load from numba's cache) the registration kernels on a tiny rig and start the helper threads."""
    from ...camera import Intrinsics

    depth_intr = Intrinsics(4, 3, 3.0, 3.0, 1.5, 1.0, (0.01, 0.0, 0.0, 0.0, 0.0))
    tilted = (0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.0)
    color_intr = Intrinsics(6, 5, 4.0, 4.0, 2.5, 2.0, tilted)
    T = np.eye(4)
    T[0, 3] = 0.01
    depth = np.full((3, 4), 1.0, dtype=np.float32)
    depth[0, 0] = 2.0
    rig = Rig(color_intr, depth_intr, T)
    reproject_depth(depth, rig)
    helpers = numba.get_num_threads() - 1
    if helpers > 0:
        pool = thread_pool()
        for f in [pool.submit(int) for _ in range(helpers)]:
            f.result()
