"""The directional fill (steps 1-5 of :mod:`pcdof.stages.fill`, and the rules before and after them): the
kernels run in order, on the planned threads; ``"joint-bilateral"`` and ``"nearest-background"``."""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ...runtime.kernels import read_only
from ...runtime.threads import numba_threads
from .boundary import fit_boundary, sweep
from .cleanup import despeckle, median_far
from .combine import combine
from .index import index_depth
from .inputs import color_for_kernel, option_number, prepare
from .lost import blend_not_lost, nearest_not_lost
from .plan import planned_threads
from .rules import (BORDER_RULES, DEFAULT_BACKGROUND_BIAS, DEFAULT_BORDER, DEFAULT_EDGE_RATIO, DEFAULT_SIGMA_COLOR,
                    DIRS, FIT_RADIUS_STEPS, HALF, LOST, MEDIAN_ITERATIONS, MEDIAN_MIN_R_STEPS, Boundary, Holes,
                    kernel_rules)


def _fill_kernels(depth, guide, unit, *, use_color, edge_ratio, sigma_color, background_bias, border=DEFAULT_BORDER,
                  out=None):
    """Filled depth and each hole's kind (``SURFACE``, ``BORDER``, ``LOST``), by hole index; *out*: a
    copy of *depth* to fill (made here when None)."""
    depth, guide = read_only(depth), read_only(guide)  # one kernel type whatever the caller's flags
    code, hole_y, hole_x, b_y, b_x, row_start, zmin, zmax = index_depth(depth)
    rules = kernel_rules(depth.shape, use_color=use_color, unit=unit, edge_ratio=edge_ratio, sigma_color=sigma_color,
                         background_bias=background_bias, zmin=zmin, zmax=zmax, border=border)
    holes = Holes(hole_y, hole_x, sweep(code, hole_x, row_start, DIRS, HALF))
    bnd = Boundary(b_y, b_x, np.empty((b_y.size, 3), np.float64))
    fit_boundary(depth, b_y, b_x, FIT_RADIUS_STEPS * rules.step, rules.step, edge_ratio, bnd.plane)
    out = depth.copy() if out is None else out
    r_near = np.empty(hole_y.size, dtype=np.float64)
    kind = np.empty(hole_y.size, dtype=np.int8)
    combine(depth, guide, holes, bnd, DIRS, rules, out, r_near, kind)
    lost = kind == LOST
    if lost.any():
        # outside the view with no known pixel on its row or column (a corner), or no known pixel on
        # any of the 16 lines (a small island off every line): the nearest filled or known pixel
        lost_mask = np.zeros(depth.shape, bool)
        lost_mask[hole_y[lost], hole_x[lost]] = True
        out = nearest_not_lost(out, lost_mask) if border == "hold" else blend_not_lost(out, lost_mask)
    median_far(out, hole_y, hole_x, r_near, MEDIAN_MIN_R_STEPS * rules.step, rules.step, edge_ratio,
               MEDIAN_ITERATIONS)
    despeckle(out, hole_y, hole_x, edge_ratio)
    return out, kind


def check_border(border, name: str = "border") -> str:
    """*border* if it is one of :data:`~pcdof.stages.fill.rules.BORDER_RULES`, else an InputError naming *name*."""
    if not isinstance(border, str) or border not in BORDER_RULES:
        raise InputError(f"{name} must be one of {', '.join(BORDER_RULES)}; got {border!r}")
    return border


def fill_directional(depth_m, color, *, use_color, edge_ratio, sigma_color, background_bias, parallel=None,
                     with_kinds=False, border=DEFAULT_BORDER):
    """Validated options and inputs, then the planned kernels (see :mod:`pcdof.stages.fill`)."""
    border = check_border(border)
    edge_ratio = option_number("edge_ratio", edge_ratio, minimum=0.0)
    sigma_color = option_number("sigma_color", sigma_color, minimum=0.0)
    background_bias = option_number("background_bias", background_bias, minimum=1.0, inclusive=True)
    threads = planned_threads(depth_m, parallel)
    depth, color, _, done, out = prepare(depth_m, color, need_color=use_color)
    if done is not None:
        return (done, np.empty(0, np.int8)) if with_kinds else done
    guide, unit = color_for_kernel(color) if use_color else (np.zeros((1, 1, 3), np.uint8), 1.0)
    with numba_threads(threads):
        out, kind = _fill_kernels(depth, guide, unit, use_color=use_color, edge_ratio=edge_ratio,
                                  sigma_color=sigma_color, background_bias=background_bias, border=border, out=out)
    return (out, kind) if with_kinds else out


# ---------------------------------------------------------------------------------------------
# public methods (same signature: depth_m, color, keyword options)


def fill_joint_bilateral(depth_m, color, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                         sigma_color: float = DEFAULT_SIGMA_COLOR, background_bias: float = DEFAULT_BACKGROUND_BIAS,
                         parallel: bool | None = None, border: str = DEFAULT_BORDER) -> np.ndarray:
    """Colour-guided, background-preferring fill (the default; see :mod:`pcdof.stages.fill`).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown (NaN, inf, negative are unknown too)
    color : (H, W, 3) RGB or (H, W) grey ndarray, uint8, uint16 or float (in [0, 1]): the guide
    edge_ratio : float > 0, relative depth gap between candidates that separates two surfaces
    sigma_color : float > 0, colour range sigma (colour scaled to [0, 1])
    background_bias : float >= 1, how many times more colour support a nearer surface needs than
        the farthest one to be chosen
    parallel : None, True or False, see :func:`~pcdof.stages.fill.plan.plan_fill`
    border : str, the rule outside the depth camera's view, one of :data:`~pcdof.stages.fill.rules.BORDER_RULES`

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    return fill_directional(depth_m, color, use_color=True, edge_ratio=edge_ratio, sigma_color=sigma_color,
                            background_bias=background_bias, parallel=parallel, border=border)


def fill_nearest_background(depth_m, color=None, *, edge_ratio: float = DEFAULT_EDGE_RATIO,
                            parallel: bool | None = None, border: str = DEFAULT_BORDER) -> np.ndarray:
    """Fill from the farthest surface among the 16 directional candidates, ignoring colour.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 = unknown
    color : (H, W, 3) or (H, W) ndarray or None; validated when given, not used
    edge_ratio : float > 0, relative depth gap that separates two surfaces
    parallel : None, True or False, see :func:`~pcdof.stages.fill.plan.plan_fill`
    border : str, the rule outside the depth camera's view, one of :data:`~pcdof.stages.fill.rules.BORDER_RULES`

    Returns
    -------
    (H, W) float32 ndarray, metres, no zeros; known pixels unchanged
    """
    return fill_directional(depth_m, color, use_color=False, edge_ratio=edge_ratio,
                            sigma_color=DEFAULT_SIGMA_COLOR, background_bias=DEFAULT_BACKGROUND_BIAS,
                            parallel=parallel, border=border)
