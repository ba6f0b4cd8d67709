"""Reference renderers: the physical thin-lens renderer as an exact per-source scatter, and the paper method.

Physical renderer, the rules stated here (those of :func:`pcdof.stages.render.render_layers_linear`):

1. The signed CoC is cleaned (NaN -> 0, clipped to +-``MAX_COC_PX``); a source's footprint radius is
   max(|c| / 2, ``MIN_SOURCE_RADIUS_PX``).
2. Layers: key 0 for |c| < ``LAYER_EDGES_PX[0]``, +-k for ``edges[k-1] <= |c| < edges[k]`` (negative in
   front of focus, with the edges of that side); the edges are the frame's (``frame_edges`` of the signed CoC
   as given: :data:`LAYER_EDGES_PX` moved off the blur sizes the frame is full of); layers are visited by
   ascending key, i.e. from near to far.
3. Each source spreads weight (colour, 1) / (aperture area) over its footprint: the aperture shape
   (:mod:`pcdof.apertures`: a disc, the regular polygon with ``blades`` vertices at angles
   rotation - 90 deg + 360 deg i / blades, or any registered shape) at circumradius r.
   The anti-aliased edge: on each pixel row the footprint's strip (area a, centroid x_c) is laid out as
   the interval [x_c - a/2, x_c + a/2] of that row, and each pixel gets its overlap with the interval.
   So every source carries exactly its energy (less what falls off the image).
4. A layer is first extended behind the nearer layers' pixels that are not yet opaque (partial
   occlusion): a hidden pixel within r_front + r_max + 1 pixels (Euclidean) of the layer takes the
   colour and radius of its nearest layer pixel (ties: first in raster order). r_front is the largest
   radius of the blurred layers composited so far; nothing is extended in front of the first layer
   or while r_front is 0. A hidden pixel is continued by one layer only (:func:`owned`): the layer of
   its nearest pixel among this and the farther layers, and only as far from that pixel as the pixel
   is from the nearest pixel that ends its surface (at least 1 px): a pixel of a farther layer with a
   4-neighbour of this or a farther layer nearer than it by more than ``JUMP_COC_PX`` (a depth jump,
   :func:`surface_ends`). So a small layer seen beside a blurred foreground (a lamp, a glint, a rod)
   reaches behind it no farther than its own width, instead of being copied over everything the
   foreground hides, while a slanted surface, cut into many thin layers, is continued as deep as it
   reaches whichever of its layers is seen next to the hidden pixel.
5. Compositing front to back: a blurred layer with coverage a at a pixel of transmittance t adds
   t * alpha / a times its premultiplied colour, alpha = min(1, a) (1 from a >= 1 - 1e-4; nothing below
   a = 1e-6); the in-focus layer is an opaque copy. The output is the accumulated colour over the
   accumulated opacity, or the input pixel where no light arrived (opacity <= 1e-6).

No tiles, no reduced resolution, no convolution: every source is scattered, at full resolution, with
the exact strip areas of :meth:`pcdof.apertures.Aperture.band` (closed form for the disc, polygon clipping
for the polygon) where the fast code interpolates a table.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ...apertures import Aperture, aperture_from_blades, as_aperture
from ...color import decode_to_linear, encode_from_linear, to_float
from ...lens import MAX_COC_PX, aperture_for
from ..coc.reference import paper_alpha, signed_coc_px
from .border import border_px
from .classify import JUMP_COC_PX, LAYER_EDGES_PX, MIN_SOURCE_RADIUS_PX, SHARP_COC_PX, frame_edges


# ----------------------------------------------------------------------------- aperture footprint
def strip(dy: int, r: float, aperture, rotation_rad: float = 0.0) -> tuple[float, float]:
    """(area, centroid x) of the aperture of radius r centred on a pixel, on the pixel row dy rows below.

    *aperture*: a :class:`pcdof.apertures.Aperture`, or a blade count with its first vertex at *rotation_rad*.
    """
    lo, hi = max(dy - 0.5, -r), min(dy + 0.5, r)
    if hi <= lo:
        return 0.0, 0.0
    return as_aperture(aperture, rotation_rad).band(r, lo, hi)


def unit_area(aperture) -> float:
    """Area of the aperture of circumradius 1: pi for the disc, (N / 2) sin(2 pi / N) for the N-gon."""
    return as_aperture(aperture).unit_area


@functools.lru_cache(maxsize=4096)
def footprint(r: float, aperture, rotation_rad: float = 0.0) -> np.ndarray:
    """Coverage of each pixel by the aperture of radius r centred on pixel (R, R): (2R+1, 2R+1), R = ceil(r + 0.5).

    *aperture*: a :class:`pcdof.apertures.Aperture`, or a blade count with its first vertex at
    *rotation_rad*. Row by row, the strip's area is laid out as an interval centred on its centroid
    and each pixel gets its overlap with it (rule 3 of the module docstring). Sums to the aperture's
    area. Cached (read-only result): the sources of a layer often share a radius.
    """
    shape = as_aperture(aperture, rotation_rad)
    R = int(math.ceil(r + 0.5))
    out = np.zeros((2 * R + 1, 2 * R + 1))
    px = np.arange(-R, R + 1, dtype=np.float64)
    for dy in range(-R, R + 1):
        area, centre = strip(dy, r, shape)
        if area <= 0.0:
            continue
        a, b = centre - 0.5 * area, centre + 0.5 * area
        out[dy + R] = np.clip(np.minimum(b, px + 0.5) - np.maximum(a, px - 0.5), 0.0, None)
    out.setflags(write=False)
    return out


# ----------------------------------------------------------------------------- layers
def layer_keys(signed_coc: np.ndarray, edges: np.ndarray | None = None) -> np.ndarray:
    """Signed layer key per pixel: 0 for |c| < edges[0], +-k for edges[k-1] <= |c| < edges[k], with *edges*
    (2, n) (in front of the focus, behind it) or (n,) (both sides; None: :data:`LAYER_EDGES_PX`)."""
    edges = np.stack([LAYER_EDGES_PX] * 2) if edges is None else np.asarray(edges)
    edges = edges if edges.ndim == 2 else np.stack([edges, edges])
    front = np.searchsorted(edges[0], np.abs(signed_coc), side="right")
    back = np.searchsorted(edges[1], np.abs(signed_coc), side="right")
    return np.where(signed_coc < 0, -front, back)


def scatter(lin: np.ndarray, radius: np.ndarray, member: np.ndarray, aperture: Aperture) -> np.ndarray:
    """Scatter every member pixel over its own footprint: (H, W, C + 1) premultiplied colour and coverage.

    Each source spreads (colour, 1) / (unit_area r^2) over :func:`footprint` (r at least
    ``MIN_SOURCE_RADIUS_PX``); what falls off the image is lost.
    """
    h, w, nc = lin.shape
    buf = np.zeros((h, w, nc + 1))
    unit = aperture.unit_area
    for y, x in zip(*np.nonzero(member)):
        r = max(float(radius[y, x]), MIN_SOURCE_RADIUS_PX)
        k = footprint(r, aperture) / (unit * r * r)
        R = k.shape[0] // 2
        y0, y1, x0, x1 = max(0, y - R), min(h, y + R + 1), max(0, x - R), min(w, x + R + 1)
        kk = k[y0 - y + R: y1 - y + R, x0 - x + R: x1 - x + R]
        buf[y0:y1, x0:x1, :nc] += kk[:, :, None] * lin[y, x]
        buf[y0:y1, x0:x1, nc] += kk
    return buf


def extend_behind(lin, radius, member, hidden, reach_px):
    """Give each hidden pixel within *reach_px* (Euclidean) of *member* its nearest member's colour and radius.

    Returns new (lin, radius, member); ties between equally near members go to the first in raster order.
    """
    src = np.flatnonzero(member.ravel())
    tgt = np.flatnonzero(hidden.ravel() & ~member.ravel())
    if src.size == 0 or tgt.size == 0:
        return lin, radius, member
    w = member.shape[1]
    sy, sx = np.divmod(src, w)
    lin, radius, member = lin.copy(), radius.copy(), member.copy()
    flat_lin, flat_r, flat_m = lin.reshape(-1, lin.shape[2]), radius.reshape(-1), member.reshape(-1)
    for part in np.array_split(tgt, max(1, tgt.size // 256)):
        ty, tx = np.divmod(part, w)
        d2 = (ty[:, None] - sy[None, :]) ** 2 + (tx[:, None] - sx[None, :]) ** 2
        best = np.argmin(d2, axis=1)  # the first of equal minima: raster order
        near = d2[np.arange(part.size), best] <= reach_px * reach_px
        chosen = src[best[near]]
        flat_lin[part[near]] = flat_lin[chosen]
        flat_r[part[near]] = flat_r[chosen]
        flat_m[part[near]] = True
    return lin, radius, member


def surface_ends(coc: np.ndarray, rank: np.ndarray, li: int) -> np.ndarray:
    """The pixels of layers farther than *li* that end the surfaces seen from layer *li*: those with a 4-neighbour
    of layer *li* or farther whose signed CoC is smaller than theirs by more than ``JUMP_COC_PX`` (a depth
    jump). (H, W) bool."""
    h, w = rank.shape
    out = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            if rank[y, x] <= li:
                continue
            for ny, nx in ((y - 1, x), (y + 1, x), (y, x - 1), (y, x + 1)):
                if 0 <= ny < h and 0 <= nx < w and rank[ny, nx] >= li and coc[y, x] - coc[ny, nx] > JUMP_COC_PX:
                    out[y, x] = True
    return out


def owned(rank: np.ndarray, li: int, ends: np.ndarray | None = None) -> np.ndarray:
    """The pixels that layer *li* continues when hidden: their nearest pixel of layer *li* or a farther
    layer (Euclidean; ties: the first in raster order) is one of layer *li*'s, and they are no farther
    from it than it is from the nearest pixel that ends its surface (*ends*, :func:`surface_ends`; None:
    every pixel of a farther layer) (at least 1 px; unlimited where there is none). (H, W) bool.
    """
    behind = np.flatnonzero(rank.ravel() >= li)
    farther = np.flatnonzero((rank > li).ravel() if ends is None else ends.ravel())
    h, w = rank.shape
    by, bx = np.divmod(behind, w)
    fy, fx = np.divmod(farther, w)
    out = np.zeros(h * w, bool)
    for part in np.array_split(np.arange(h * w), max(1, h * w // 256)):
        ty, tx = np.divmod(part, w)
        d2 = (ty[:, None] - by[None, :]) ** 2 + (tx[:, None] - bx[None, :]) ** 2
        best = np.argmin(d2, axis=1)  # the first of equal minima: raster order
        src = behind[best]
        mine = rank.ravel()[src] == li
        if farther.size:
            sy, sx = np.divmod(src, w)
            width2 = ((sy[:, None] - fy[None, :]) ** 2 + (sx[:, None] - fx[None, :]) ** 2).min(axis=1)
        else:
            width2 = np.full(part.size, np.inf)
        out[part] = mine & (d2[np.arange(part.size), best] <= np.maximum(width2, 1.0))
    return out.reshape(h, w)


def _composite_layer(buf, acc, acc_a, trans) -> None:
    """Front-to-back "over" of a scattered layer (premultiplied colour, coverage) behind acc."""
    cover = buf[:, :, -1]
    sel = (trans > 0) & (cover > 1e-6)
    alpha = np.where(cover >= 1.0 - 1e-4, 1.0, cover)
    f = np.where(sel, trans * alpha / np.where(sel, cover, 1.0), 0.0)
    acc += f[:, :, None] * buf[:, :, :-1]
    acc_a += np.where(sel, trans * alpha, 0.0)
    trans[sel] *= 1.0 - alpha[sel]


def render_layers_linear(lin, signed_coc, *, blades: int = 0, rotation_deg: float = 0.0,
                         aperture: Aperture | None = None, extend_behind_layers: bool = True,
                         edges=None) -> np.ndarray:
    """Physical depth of field in linear light (the rules of the module docstring).

    Parameters
    ----------
    lin : (H, W, C) float ndarray, linear radiance
    signed_coc : (H, W) float ndarray, signed CoC diameter, pixels (< 0 in front of focus; NaN = 0)
    blades, rotation_deg : aperture polygon (0 = disc), as :class:`pcdof.lens.ThinLens` has them
    aperture : a :class:`pcdof.apertures.Aperture` instead of *blades* and *rotation_deg* (any shape)
    extend_behind_layers : continue each layer behind nearer, not yet opaque layers (partial occlusion)
    edges : (2, n) layer edges in front of the focus and behind it, pixels (None: ``frame_edges`` of
        *signed_coc*)

    Returns
    -------
    (H, W, C) float64 ndarray, linear radiance
    """
    lin = np.asarray(lin, np.float64)
    coc = np.clip(np.nan_to_num(np.asarray(signed_coc, np.float32).astype(np.float64), nan=0.0),
                  -MAX_COC_PX, MAX_COC_PX)
    radius = 0.5 * np.abs(coc)
    keys = layer_keys(coc, frame_edges(np.asarray(signed_coc, np.float32)) if edges is None else edges)
    shape = aperture_from_blades(blades, rotation_deg) if aperture is None else as_aperture(aperture)
    h, w, nc = lin.shape
    acc, acc_a, trans = np.zeros((h, w, nc)), np.zeros((h, w)), np.ones((h, w))
    order = np.unique(keys)  # ascending: near to far
    rank = np.searchsorted(order, keys)
    r_front = 0.0
    for li, key in enumerate(order):
        member = rank == li
        r_max = float(radius[member].max())
        src, src_r = lin, radius
        hidden = (rank < li) & (trans > 0)
        if extend_behind_layers and li > 0 and r_front > 0 and hidden.any():
            hidden &= owned(rank, li, surface_ends(coc, rank, li))
            src, src_r, member = extend_behind(lin, radius, member, hidden, math.ceil(r_front + r_max + 1))
        if key == 0:  # in focus: an opaque copy
            sel = member & (trans > 0)
            acc[sel] += trans[sel, None] * src[sel]
            acc_a[sel] += trans[sel]
            trans[sel] = 0.0
            continue
        _composite_layer(scatter(src, src_r, member, shape), acc, acc_a, trans)
        r_front = max(r_front, r_max)
    lit = acc_a > 1e-6
    return np.where(lit[:, :, None], acc / np.where(lit, acc_a, 1.0)[:, :, None], lin)


def _continued(lin: np.ndarray, pad: int, most: float | None = None) -> np.ndarray:
    """*lin* (H, W, C) widened by *pad*: beyond the edge, the pixel d away is the mean of the edge's pixels
    within d of its foot along the edge (rows above and below first, then the columns beside them), at most
    *most* (None: no limit)."""
    cap = np.inf if most is None else most

    def beyond(edge, d):
        n = edge.shape[0]
        return np.minimum(np.stack([edge[max(0, i - d):min(n, i + d + 1)].mean(axis=0) for i in range(n)]), cap)

    tall = np.concatenate([np.stack([beyond(lin[0].astype(np.float64), d) for d in range(pad, 0, -1)]), lin,
                           np.stack([beyond(lin[-1].astype(np.float64), d) for d in range(1, pad + 1)])])
    left = np.stack([beyond(tall[:, 0], d) for d in range(pad, 0, -1)], axis=1)
    right = np.stack([beyond(tall[:, -1], d) for d in range(1, pad + 1)], axis=1)
    return np.concatenate([left, tall, right], axis=1)


def render_physical(color, depth_m, lens, *, fx: float, linear: bool = False, border_most=None) -> np.ndarray:
    """Thin-lens depth of field of an sRGB (or, with *linear*, linear) image; float64 in the image's encoding.
    Beyond the frame the colour is continued from its edge, no brighter than *border_most* (None: no limit).

    The image is returned unchanged when the largest |CoC| is below ``SHARP_COC_PX``. Decoding and
    encoding are those of :mod:`pcdof.color`; the result is not rounded to the input's dtype.
    """
    coc = signed_coc_px(depth_m, lens, fx)
    src = color[:, :, None] if color.ndim == 2 else color
    if np.abs(coc).max() < SHARP_COC_PX:
        return to_float(src).astype(np.float64)
    lin = to_float(src) if linear else decode_to_linear(src)
    # what lies beyond the frame is continued from its edge (pcdof.stages.render.border)
    pad = border_px(float(np.abs(coc).max()))
    out = render_layers_linear(_continued(lin, pad, border_most), np.pad(coc, pad, mode="edge"),
                               aperture=aperture_for(lens), edges=frame_edges(coc))[pad:-pad, pad:-pad]
    out = mixed_edges(out, lin, depth_m, coc)
    if linear:
        return out
    return to_float(encode_from_linear(out.astype(np.float32), np.float32)).astype(np.float64)


def mixed_edges(out, lin, depth_m, coc) -> np.ndarray:
    """The render *out* (H, W, C) with the mixed pixels at in-focus edges rendered as mixes
    (:mod:`pcdof.stages.render.mixed`), from the source *lin* (H, W, C), the depth and the signed CoC, (H, W): one
    whole-image pass per neighbour, right, left, below, above; a later neighbour that qualifies overrides an
    earlier one. Returns a new float64 array."""
    from .mixed import BLURRED_PX, MAX_OFF, MAX_SHARE, MIN_CONTRAST, NEARER_RATIO, SAME_SURFACE, SHARP_PX

    out, lin = np.asarray(out, np.float64), np.asarray(lin, np.float64)
    z, c = np.asarray(depth_m, np.float64), np.abs(np.asarray(coc, np.float64))
    h, w = z.shape
    res = out.copy()
    seen = np.minimum(lin, 1.0)  # the share is estimated from the colours as the camera saw them
    ys, xs = np.mgrid[0:h, 0:w]
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        qy, qx, ry, rx = ys + dy, xs + dx, ys - dy, xs - dx
        inside = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w) & (ry >= 0) & (ry < h) & (rx >= 0) & (rx < w)
        qy, qx, ry, rx = np.clip(qy, 0, h - 1), np.clip(qx, 0, w - 1), np.clip(ry, 0, h - 1), np.clip(rx, 0, w - 1)
        with np.errstate(invalid="ignore"):
            edge = (inside & (z > 0) & (c > BLURRED_PX) & (z[qy, qx] * NEARER_RATIO < z) & (c[qy, qx] < SHARP_PX)
                    & (np.abs(z[ry, rx] - z) < SAME_SURFACE * z))
        fore, back = seen[qy, qx], seen[ry, rx]
        d = fore - back
        dd = (d * d).sum(-1)
        a = ((seen - back) * d).sum(-1) / np.where(dd > 0, dd, 1.0)
        off = seen - back - a[..., None] * d
        mix = edge & (dd > MIN_CONTRAST ** 2) & (a > 0) & (a <= MAX_SHARE) & ((off * off).sum(-1) < MAX_OFF ** 2 * dd)
        a = np.minimum(a, 1.0)[..., None]
        res[mix] = np.where(a >= 1.0, lin, a * lin[qy, qx] + (1 - a) * out)[mix]
    return res


# ----------------------------------------------------------------------------- paper method
def gaussian_kernel(sigma_px: float) -> np.ndarray:
    """Sampled Gaussian of standard deviation *sigma_px* over +-ceil(3 sigma) pixels, summing to 1."""
    k = int(math.ceil(3.0 * sigma_px))
    x = np.arange(-k, k + 1, dtype=np.float64)
    g = np.exp(-x * x / (2.0 * sigma_px * sigma_px))
    return g / g.sum()


def _reflect(i: np.ndarray, n: int) -> np.ndarray:
    """Index reflected at the borders with the edge pixel repeated (fedcba|abcdef, OpenCV BORDER_REFLECT)."""
    if n == 1:
        return np.zeros_like(i)
    period = 2 * n
    i = np.mod(i, period)
    return np.where(i < n, i, period - 1 - i)


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Separable Gaussian blur (:func:`gaussian_kernel`) with reflected borders, float64, by explicit sums."""
    g = gaussian_kernel(sigma_px)
    k = g.size // 2
    out = np.asarray(image, np.float64)
    for axis in (0, 1):
        n = out.shape[axis]
        acc = np.zeros_like(out)
        for t, wt in enumerate(g):
            idx = _reflect(np.arange(n) + t - k, n)
            acc += wt * np.take(out, idx, axis=axis)
        out = acc
    return out


def render_paper(color, depth_m, lens, *, max_range_m: float = 10.0) -> np.ndarray:
    """Seed paper eq. 3: out = B alpha + O (1 - alpha) in the image's own encoding; float64 in [0, 1] units.

    B is :func:`gaussian_blur` with ``lens.blur_sigma_px``; alpha is :func:`pcdof.stages.coc.reference.paper_alpha`.
    """
    src = to_float(color[:, :, None] if color.ndim == 2 else color).astype(np.float64)
    blurred = gaussian_blur(src, lens.blur_sigma_px)
    alpha = paper_alpha(depth_m, lens, max_range_m)[:, :, None]
    return blurred * alpha + src * (1.0 - alpha)
