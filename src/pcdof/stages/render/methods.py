"""The renderers by name (:data:`METHODS`), the checked entry that dispatches to them, and the warm-up
that compiles every kernel of the stage."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...camera import check_color
from ...validate import short_repr
from ...errors import InputError
from ...lens import ThinLens
from ...plans import RenderPlan, check_quality, plan_render
from .border import check_source_border
from .paper import render_paper
from .physical import render_physical


#: method name -> renderer, all with one signature
METHODS = {"physical": render_physical, "paper": render_paper}


def check_method(method) -> None:
    """InputError unless *method* is one of :data:`METHODS`' names (a str: lists and other unhashables too)."""
    if not isinstance(method, str) or method not in METHODS:
        raise InputError(f"method must be one of {sorted(METHODS)}; got {short_repr(method)}")


def render_image(color, depth_m, lens, *, fx, method="physical", max_range_m=10.0, linear=False,
                 quality="balanced", signed_coc=None, plan=None, border_most=None, source_border_px=0):
    """Render a registered, hole-free RGB-D pair. Returns (image, info); see :data:`METHODS`.

    *plan* (physical method only): a :class:`pcdof.plans.RenderPlan` that overrides the one
    :func:`pcdof.plans.plan_render` makes from *quality*; ``info["plan"]`` records the plan used.
    *border_most* (physical method only): the brightest linear colour continued beyond the frame's edge
    (:mod:`pcdof.stages.render.border`; None: no limit).
    *source_border_px*: an int b >= 0; *color* is (H + 2 b, W + 2 b[, C]) for *depth_m* (H, W), the frame's border
    continued b pixels beyond it (:func:`pcdof.stages.render.border.continue_border`); the image returned is the
    frame's, (H, W[, C]).

    Raises
    ------
    InputError
        an unknown *method* or *quality*, a colour image that :func:`pcdof.camera.check_color`
        refuses, or a depth map of another size than the colour image
    """
    check_method(method)
    check_quality(quality)
    color = check_color(color)
    depth_m = np.asarray(depth_m, np.float32)
    b = check_source_border(color.shape, depth_m.shape, source_border_px)
    if signed_coc is not None and np.shape(signed_coc) != depth_m.shape:
        raise InputError(f"signed_coc must be (H, W) = {depth_m.shape}; got {np.shape(signed_coc)}")
    return METHODS[method](color, depth_m, lens, fx=fx, max_range_m=max_range_m, linear=linear, quality=quality,
                           signed_coc=signed_coc, plan=plan, border_most=border_most, source_border_px=b)


def warmup() -> None:
    """Compile (or load from numba's cache) every renderer kernel on a tiny frame that takes every path:
    copy tiles, an in-focus layer and blur layers extended behind a blurred foreground, uniform tiles
    convolved and reduced-resolution layers, encoded to 8 and 16 bits."""
    h, w = 48, 96
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, 40:48] = 1.0  # in front of focus: blurred, extends the layers behind it
    depth[:, 56:] = 50.0  # far behind: a large blur, uniform tiles, reduced resolution
    depth[16:32, 50:56] = 50.0  # and beside the foreground: what the middle layer continues behind it is cut short
    color = (np.indices((h, w)).sum(axis=0) % 7 * 36).astype(np.uint8)[:, :, None].repeat(3, axis=2)
    lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=2.0)
    lens.coc_maps_px(depth, 300.0)  # the pipeline's CoC stage (the renderer's own calls take the signed map)
    # a plan that reduces from 2 px cells, so that this small blur takes the reduced path whatever the tiers'
    # thresholds
    plan = RenderPlan(threads=plan_render().threads, reduce_min_coc_px=2.0)
    for image in (color, color.astype(np.uint16) * 257):
        render_image(image, depth, lens, fx=300.0, quality="balanced", plan=plan)
    # and one at full resolution, whose far layer's uniform tiles take the convolution path
    render_image(color, depth, lens, fx=300.0, quality="exact")
    # and one focused in front of everything: blur layers extended behind nearer ones (the farthest with no
    # farther layer near, so its nearest pixels are found by its own transform)
    near = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=0.5)
    render_image(color, depth, near, fx=300.0, quality="exact")
    # and a wall with one CoC (18 px) on a 1/4 grid: uniform tiles convolved on a reduced grid
    wall = np.full((96, 96), 4.0, np.float32)
    texture = (np.indices((96, 96)).sum(axis=0) % 5 * 50).astype(np.uint8)[:, :, None].repeat(3, axis=2)
    render_image(texture, wall, lens, fx=2000.0, quality="balanced", plan=replace(plan, reduce_min_coc_px=4.0))
