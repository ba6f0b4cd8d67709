"""The physical thin-lens renderer (the default method).

Every pixel is a small disc (or aperture polygon) of diameter c(z) = A*fx*|1/d_f - 1/z| pixels
in linear light. Pixels are grouped into depth layers by their signed circle of confusion (layer
edges near |c| = 1, 1.5, 2, 3, 4, 6, 8, 11, ... px, each moved a little off the blur sizes the frame is full of,
so that a surface at one depth is one layer; only the blur sizes present are computed).
Each layer is scattered exactly -- every source spreads its radiance over its own disc with
area-exact, anti-aliased coverage, normalised to carry exactly its energy -- and layers are
composited front to back with the "over" operator, the layer's coverage being its opacity. So a
blurred foreground spreads softly over what lies behind it, and an in-focus subject (opaque)
receives nothing from behind. The result is divided by the accumulated opacity, so every output
pixel is a convex combination of input pixels: a uniform image stays uniform. What lies beyond the frame
is continued from its edge (:mod:`pcdof.stages.render.border`): the frame is rendered widened by the reach
of its largest blur, and cut back. Last, an in-focus structure's edge pixels that carry the depth of the
blurred surface behind it are rendered as the mix their colour says they are (:mod:`pcdof.stages.render.mixed`).

The scatter is written as a gather over output rows (each source row's span on that output row),
so rows run in parallel with no write conflicts and no per-layer image buffers are needed.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ...apertures import Aperture, aperture_from_blades
from ...color import decode_to_linear, encode_from_linear, from_float, to_float
from ...errors import InputError, LensError
from ...runtime.kernels import read_only
from ...lens import MAX_COC_PX, ThinLens, aperture_for
from ...plans import RenderPlan, as_dict, check_quality, check_render_plan, plan_render
from ...runtime.threads import threads_for
from . import classify, composite, serial
from .aperture import RenderAperture, cached_aperture_table
from .border import border_px, check_source_border, continue_border, interior, interior_in_place, replicate_border
from .classify import LAYER_EDGES_PX, SHARP_COC_PX, across_jumps
from .composite import copy_tiles
from .extend import NO_PIXELS
from .frame import Canvas, FrameLayers, RenderFrame, as_channels
from .grids import full_grid, reduced_grid, upsample_cells, upsampled_strips
from .mixed import mix_edges
from .ownership import OwnershipAhead
from .scatter import scatter_sources
from .tiles import TileMap, classify_tiles
from .uniform import UniformTiles, convolve_uniform, convolved_cells


def _layer_range(frame: RenderFrame, key: int) -> tuple[float, float]:
    """The |CoC| range [lo, hi) of the blur layer *key* (nonzero) on the frame's edges of its side, pixels."""
    side = frame.edges[0 if key < 0 else 1]
    return float(side[abs(key) - 1]), float(min(side[abs(key)], MAX_COC_PX))


def _layer_window(frame: RenderFrame, li: int, r_max: float, r_front: float, bbox, s: int = 1):
    """The window a layer's work needs: its box with the reach of its blur and of its extension, starting on a
    multiple of its grid's cell *s* (the frame's border is one, :func:`~pcdof.stages.render.border.border_px`), and
    the extension's reach (0 when the layer is not extended behind nearer layers)."""
    h, w = frame.layer.shape
    extend = frame.extend_behind and li > 0 and r_front > 0
    ext_reach = int(math.ceil(r_front + r_max + 1)) if extend else 0
    margin = ext_reach + int(math.ceil(r_max + 0.5)) + 1
    y0, y1, x0, x1 = (int(v) for v in bbox)
    y0, x0 = max(0, y0 - margin), max(0, x0 - margin)
    box = (slice(y0 - y0 % s, min(h, y1 + margin + 1)), slice(x0 - x0 % s, min(w, x1 + margin + 1)))
    return box, ext_reach


def scatter_layer(lin, radius, member, s, aperture: RenderAperture, hidden=None, reach_px=0, fast=None,
                  upsample=True, origin=(0, 0)):
    """Scatter the pixels of *member* (hb, wb) bool, the box at *origin* (row, column) of *lin* (H, W, C)
    float32 and *radius* (H, W) float32, at 1/s resolution.

    Returns their (H, W, C+1) buffer at full size (premultiplied colour, coverage; with *upsample* False
    and s > 1, on the 1/s grid, for :func:`pcdof.stages.render.grids.upsampled_strips`), whether the
    layer was extended, the number of uniform-blur kernels used and the number of sources scattered
    (cells of the 1/s grid).

    With *hidden* (pixels of nearer, not yet opaque layers) the layer is first extended behind them
    up to *reach_px* (:func:`extend_layer_behind`). *fast* (a :class:`UniformTiles` or None) holds the
    uniform tiles (:meth:`pcdof.stages.render.tiles.TileMap.uniform`): there the layer is computed as a convolution
    (:func:`convolve_uniform`), and only the sources whose footprint reaches another pixel are scattered.
    """
    (h, w), nc = member.shape, lin.shape[2]
    grid = (full_grid(lin, radius, member, hidden, reach_px, origin) if s == 1
            else reduced_grid(lin, radius, member, hidden, reach_px, s, origin))
    hs, ws = grid.member.shape
    buf = np.zeros((hs, ws, 4), np.float32)
    bins, groups, scattered = convolved_cells(grid, fast, s)
    n_scattered = scatter_sources(grid, scattered, aperture, buf)
    if groups:
        convolve_uniform(grid.lin, grid.share, bins, groups, aperture.symmetric, aperture.table, buf)
    if nc < 3:
        buf = np.ascontiguousarray(buf[:, :, list(range(nc)) + [3]])
    if s > 1 and upsample:
        buf = upsample_cells(buf, s, h, w)
    return buf, grid.extended, len(groups), n_scattered


def _sharp_layer(frame: RenderFrame, canvas: Canvas, li: int, n_members: int, box, found) -> dict:
    """Composite the in-focus layer: an opaque copy, no blur (extended behind nearer layers to the pixels
    *found*, a :class:`Behind` or None), read in place from the frame (nothing is copied)."""
    dst, src = (found.dst, found.src) if found is not None else (NO_PIXELS, NO_PIXELS)
    composite.composite_sharp(read_only(frame.lin), frame.layer[box] == li, box[0].start, box[1].start, dst, src,
                              canvas.acc, canvas.opacity)
    return {"key": 0, "coc_px": [0.0, 1.0], "pixels": n_members, "blurred": False, "scale": 1}


def _blur_layer(frame: RenderFrame, canvas: Canvas, li: int, key: int, n_members: int, r_max: float, box,
                ext_reach: int, hidden) -> dict:
    """Scatter one blur layer (at the plan's resolution, uniform tiles convolved; extended behind nearer layers
    to the pixels *hidden*, a :class:`Behind` or None) and composite it behind."""
    m = frame.layer[box] == li
    lo, hi = _layer_range(frame, key)
    plan = frame.plan
    s = plan.scale(lo)
    # uniform tiles: everything within the layer's reach (plus the reduced grid's spread) in this layer
    uniform = np.zeros_like(frame.tiles.copy)
    if plan.convolve_uniform and lo / (2 * s) >= plan.uniform_min_radius_px:
        uniform = frame.tiles.uniform(lo, hi, 1 if key > 0 else -1, r_max + 2 * s + 2)
    fast = UniformTiles(uniform, frame.tiles, box) if uniform.any() else None
    buf, extended, n_kernels, n_scattered = scatter_layer(frame.lin, frame.radius, m, s, frame.aperture, hidden,
                                                          ext_reach, fast, upsample=False,
                                                          origin=(box[0].start, box[1].start))
    h, w = m.shape
    # a reduced layer is upsampled and composited a strip at a time: the full-size layer is never in memory
    strips = [(0, buf)] if s == 1 else upsampled_strips(buf, s, h, w)
    for y0, strip in strips:
        with serial.serial_if(strip.shape[0] * strip.shape[1] < serial.SERIAL_BELOW_PX):
            composite.composite_under(strip, box[0].start + y0, box[1].start, canvas.acc, canvas.opacity, width=w)
    return {"key": int(key), "coc_px": [lo, hi], "pixels": n_members, "blurred": True,
            "side": "front" if key < 0 else "back", "scale": s, "extended": extended,
            "uniform_tiles": int(uniform.sum()), "kernels": n_kernels, "sources_scattered": n_scattered}


def _composite_layers(frame: RenderFrame, canvas: Canvas, keys, counts, r_maxes, boxes) -> list:
    """Render and composite every layer, near to far (per layer: pixel count, largest radius, bounding box);
    returns one record per layer.

    Which hidden pixels a layer continues (:class:`OwnershipAhead`) is found for the next layers on the task pool's
    helpers while a layer renders, when the plan has more than one thread: the same answer, in the layers' shadow."""
    extents, windows = [], []  # per layer: (its window, the extension's reach); what ownership needs, or None
    r_front = 0.0  # largest blur radius of the layers nearer than this one
    for li, key in enumerate(keys):
        s = 1 if key == 0 else frame.plan.scale(_layer_range(frame, int(key))[0])
        box, ext_reach = _layer_window(frame, li, float(r_maxes[li]), r_front, boxes[li], s)
        extents.append((box, ext_reach))
        windows.append((box, boxes[li], ext_reach, s) if ext_reach else None)
        if key != 0:
            r_front = max(r_front, float(r_maxes[li]))
    ownership = OwnershipAhead(frame, canvas, windows, ahead=frame.plan.threads > 1)
    layers_run = []
    try:
        for li, key in enumerate(keys):
            (box, ext_reach), found = extents[li], ownership.continued(li)
            if key == 0:
                layers_run.append(_sharp_layer(frame, canvas, li, int(counts[li]), box, found))
            else:
                layers_run.append(_blur_layer(frame, canvas, li, int(key), int(counts[li]), float(r_maxes[li]), box,
                                              ext_reach, found))
    finally:
        ownership.close()
    return layers_run


def _tiles_for(coc, tiles, plan: RenderPlan) -> TileMap:
    """*tiles* checked against the CoC map, or the plan's tile classification of it."""
    if tiles is None:
        return classify_tiles(coc, tile_px=plan.tile_px, sharp_px=float(LAYER_EDGES_PX[0]))
    if not isinstance(tiles, TileMap) or tiles.shape != coc.shape:
        raise InputError(f"tiles must be a TileMap of shape {coc.shape}; got {tiles!r:.80}")
    return tiles


def _shape_of(aperture, blades, rotation_deg) -> Aperture:
    """The render's aperture shape: *aperture*, or the disc / polygon of *blades* and *rotation_deg*."""
    if aperture is None:
        return aperture_from_blades(blades, rotation_deg)
    if not isinstance(aperture, Aperture):
        raise InputError(f"aperture must be a pcdof.apertures.Aperture; got {type(aperture).__name__}")
    if blades != 0:
        raise InputError(f"give aperture or blades, not both; got blades={blades!r} and aperture={aperture!r:.80}")
    return aperture


def classify_frame(signed_coc: np.ndarray, coc_border_px: int, plan: RenderPlan, extend_behind: bool = True, *,
                   edges: np.ndarray | None = None, tiles: TileMap | None = None) -> FrameLayers:
    """The frame's layers (:class:`~pcdof.stages.render.frame.FrameLayers`), as :func:`render_layers_linear` reads them.

    Parameters
    ----------
    signed_coc : (H, W) float32, the frame's signed circle of confusion, pixels (NaN: in focus)
    coc_border_px : int >= 0, the border the render widens the frame by (the CoC's edge pixels repeated)
    plan : :class:`pcdof.plans.RenderPlan`
    extend_behind : whether layers continue behind nearer ones (then where surfaces end is found)
    edges : (2, n) px or None (:func:`pcdof.stages.render.classify.frame_edges` of *signed_coc*)
    tiles : the widened frame's :class:`TileMap` or None (classified here)
    """
    b = int(coc_border_px)
    # (front, back): the nominal edges moved off the blur sizes the frame is full of
    edges = classify.frame_edges(signed_coc) if edges is None else classify.check_edges(edges)
    wide_coc = replicate_border(np.asarray(signed_coc, np.float32), b)
    coc, radius, layer, keys, counts, r_maxes, boxes = classify.classify_layers(wide_coc, MAX_COC_PX, edges)
    del wide_coc  # the widened map lives only while the layers are classified
    tiles = _tiles_for(coc, tiles, plan)
    # where surfaces end, for the extension behind nearer layers (an int8 map, a quarter of the CoC's size)
    across = across_jumps(coc, layer) if extend_behind and keys.size > 1 else None
    # the layers read the radius and the layer ids: the cleaned CoC is not kept through them
    return FrameLayers(edges, radius, layer, keys, counts, r_maxes, boxes, tiles, across, b, bool(extend_behind))


def render_layers_linear(lin: np.ndarray, signed_coc: np.ndarray, *, blades: int = 0,
                         rotation_deg: float = 0.0, aperture: Aperture | None = None, quality: str = "balanced",
                         extend_behind: bool = True, tiles: TileMap | None = None,
                         plan: RenderPlan | None = None, coc_border_px: int = 0,
                         edges: np.ndarray | None = None, layers: FrameLayers | None = None) -> tuple[np.ndarray, dict]:
    """Physical depth of field in linear light.

    Parameters
    ----------
    lin : (H, W, C) float32, linear radiance, C = 1..3
    signed_coc : (H, W) float32, signed circle-of-confusion diameter in pixels (< 0 in front of focus);
        NaN is unknown and, like unknown depth in :meth:`pcdof.lens.ThinLens.signed_coc_px`, in focus (0)
    blades, rotation_deg : aperture polygon (0 = disc), as :class:`pcdof.lens.ThinLens` has them
    aperture : a :class:`pcdof.apertures.Aperture` instead of *blades* and *rotation_deg* (any shape)
    quality : a key of :data:`QUALITIES`; sets the plan when *plan* is None
    extend_behind : continue each layer behind the soft edges of nearer blurred layers (partial occlusion);
        a hidden pixel is continued from the surface seen next to it, no farther than that surface reaches
        (to a depth jump, :data:`pcdof.stages.render.classify.JUMP_COC_PX`), whichever layers it spans
    tiles : :func:`pcdof.stages.render.tiles.classify_tiles` of *signed_coc*, if the caller has it (else computed here);
        its copy tiles are left out of every layer and come out as the input, exactly
    plan : :class:`pcdof.plans.RenderPlan` or None (:func:`pcdof.plans.plan_render` of *quality*):
        threads, tiles, reduced-resolution layers, convolution of uniform tiles
    coc_border_px : int b >= 0; *signed_coc* is the frame's, (H - 2 b, W - 2 b), its edge continued b pixels
        outward as *lin*'s is (each edge pixel repeated): the widened map lives only while the layers are
        classified (4 bytes a pixel less through the render)
    edges : (2, n) float, the layer edges in front of the focus and behind it, pixels (None:
        :func:`pcdof.stages.render.classify.frame_edges` of *signed_coc* as given)
    layers : :func:`classify_frame` of *signed_coc*, *coc_border_px*, the plan and *extend_behind*, if the caller
        has it (then *edges* and *tiles* are not read)

    Returns
    -------
    (H, W, C) float32 image and an info dict (layers run, pixels blurred, tiles, the plan).
    """
    check_quality(quality)
    if lin.ndim != 3 or not 1 <= lin.shape[2] <= 3:
        raise InputError(f"lin must be (H, W, C) with 1 to 3 channels; got shape {lin.shape}")
    shape = _shape_of(aperture, blades, rotation_deg)
    plan = plan_render(quality=quality) if plan is None else check_render_plan(plan)
    h, w, _ = lin.shape
    b = coc_border_px
    if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or b < 0 or 2 * b >= min(h, w) \
            or np.shape(signed_coc) != (h - 2 * b, w - 2 * b):
        raise InputError(f"signed_coc must be (H - 2 b, W - 2 b) = ({h} - 2 b, {w} - 2 b) for lin {lin.shape} "
                         f"and coc_border_px b, an int >= 0; got {np.shape(signed_coc)} and b = {b!r}")
    lin = np.ascontiguousarray(lin, np.float32)
    with threads_for(plan):
        if layers is None:
            layers = classify_frame(signed_coc, b, plan, extend_behind, edges=edges, tiles=tiles)
        elif not isinstance(layers, FrameLayers) or layers.radius.shape != (h, w) or layers.border_px != b \
                or layers.extend_behind != bool(extend_behind):
            raise InputError(f"layers must be the FrameLayers of this frame ({h}x{w} widened by {b} px, extend_behind "
                             f"{bool(extend_behind)}); got {type(layers).__name__}")
        del signed_coc
        keys, tiles = layers.keys, layers.tiles
        render_aperture = RenderAperture(shape.symmetric, cached_aperture_table(shape))
        frame = RenderFrame(lin, layers.radius, layers.layer, tiles, plan, render_aperture, extend_behind,
                            layers.across, layers.edges)
        canvas = Canvas.start(lin, tiles, plan.copy_tiles)
        layers_run = _composite_layers(frame, canvas, keys, layers.counts, layers.r_maxes, layers.boxes)
        del layers
        out = canvas.acc  # normalised in place: no other full-size image
        composite.normalise(canvas.acc, canvas.opacity, lin, out)
    in_focus = sum(l["pixels"] for l in layers_run if not l["blurred"])
    info = {"layers": layers_run, "foreground_pass": bool((keys < 0).any()), "blurred_pixels": h * w - in_focus,
            "quality": quality, "tiles": tiles.summary(), "plan": as_dict(plan)}
    return out, info


def render_physical(color, depth_m, lens, *, fx, max_range_m=None, linear=False, quality="balanced",
                    signed_coc=None, plan=None, border_most=None, source_border_px=0, layers=None):
    """Thin-lens depth of field (see the module docstring). Returns (image, info).

    *signed_coc* (H, W) float32 pixels, if given, is ``lens.signed_coc_px(depth_m, fx)`` already
    computed by the caller (the pipeline's CoC stage), so it is not computed twice. *plan*: a
    :class:`pcdof.plans.RenderPlan`, or None for :func:`pcdof.plans.plan_render` of *quality*.
    *border_most*: the brightest linear colour continued beyond the frame's edge (None: no limit; the pipeline
    gives 1.0 when the highlights stage estimated light above white, :mod:`pcdof.stages.render.border`).
    *source_border_px*: *color* is (H + 2 b, W + 2 b[, C]) for a depth map (H, W), the frame's border already
    continued b pixels beyond it (:func:`pcdof.stages.render.border.continue_border`, as the pipeline's highlights
    stage hands it over); taken as it is when b is the border this render needs, so the widened colour is not
    copied again (else the frame inside it is continued anew, with *border_most*).
    *layers*: :func:`classify_frame` of *signed_coc* with this render's border and plan, made by the caller beside
    other work (the render stage's early start), or None (classified here).
    """
    plan = plan_render(quality=quality) if plan is None else check_render_plan(plan)
    if not isinstance(lens, ThinLens):
        raise LensError(f"the physical method needs a ThinLens; got {type(lens).__name__}")
    if border_most is not None and (isinstance(border_most, bool) or not isinstance(border_most, (int, float, np.number))
                                    or not math.isfinite(border_most) or border_most <= 0):
        raise InputError(f"border_most must be None or a finite number > 0; got {border_most!r}")
    source_border_px = check_source_border(np.shape(color), np.shape(depth_m), source_border_px)
    given = color
    color = interior(given, source_border_px)
    coc = lens.signed_coc_px(depth_m, fx) if signed_coc is None else signed_coc
    cmax = float(np.fmax.reduce(np.abs(coc), axis=None, initial=0.0))  # NaN is unknown depth: in focus
    if cmax < SHARP_COC_PX:
        return color.copy(), {"skipped": True, "reason": f"largest circle of confusion {cmax:.3f} px < "
                                                         f"{SHARP_COC_PX} px: nothing to blur",
                              "max_coc_px": cmax, "layers": []}
    if cmax > MAX_COC_PX:
        warnings.warn(f"circle of confusion up to {cmax:.0f} px clamped to {MAX_COC_PX:.0f} px", stacklevel=3)
    src = as_channels(color)
    tiles = classify_tiles(coc, tile_px=plan.tile_px, sharp_px=float(LAYER_EDGES_PX[0]))
    # the scene beyond the frame is continued from its edge: rendered widened by the largest reach, then cut back
    pad = border_px(cmax, plan)
    if source_border_px == pad:  # continued by the caller: read as it is (read only: never written)
        wide = as_channels(given)
        wide_lin = to_float(wide) if linear else decode_to_linear(wide)
    else:
        lin = to_float(src) if linear else decode_to_linear(src)
        wide_lin = continue_border(lin, pad, most=border_most)
        del lin
    if layers is not None and (layers.border_px != pad or layers.radius.shape != wide_lin.shape[:2]):
        layers = None  # made for another border: classified anew (the same layers, as this render needs them)
    out_lin, info = render_layers_linear(wide_lin, coc, aperture=aperture_for(lens), quality=quality, plan=plan,
                                         coc_border_px=pad, layers=layers)
    del layers
    out_lin = interior_in_place(out_lin, pad)  # the render's own buffer: the frame without another copy of it
    # an in-focus structure's edge pixels that carry the depth behind it (pcdof.stages.render.mixed)
    info["mixed_edge_pixels"] = mix_edges(out_lin, np.ascontiguousarray(wide_lin, np.float32),
                                          np.ascontiguousarray(depth_m, np.float32),
                                          np.ascontiguousarray(coc, np.float32), pad)
    del wide_lin
    info["border_px"] = pad
    if linear:
        out = out_lin if color.dtype.kind == "f" else from_float(out_lin, color.dtype)
        out = out.astype(color.dtype, copy=False)
    else:
        out = encode_from_linear(out_lin, color.dtype)
    if plan.copy_tiles:
        copy_tiles(src, tiles, out)  # exactly the input there, whatever the dtype's round trip
    info.update(skipped=False, max_coc_px=cmax)
    return out.reshape(color.shape), info
