"""The physical thin-lens render on the GPU: layers, partial occlusion and front-to-back compositing.

The rules are those of :mod:`pcdof.stages.render.reference` (every source scattered at full resolution over its own
footprint; no tiles, no reduced resolution, no convolution), with the aperture's strips read from the table of
:func:`pcdof.stages.render.aperture_table` as the CPU renderer reads them. Per layer, near to far:

1. one thread per pixel decides whether it is a source of the layer: a member, or a hidden pixel the layer
   continues (rule 4: its nearest pixel of this or a farther layer, found by a search in growing square rings,
   ties to the first in raster order, is a member within reach, and no pixel that ends its surface -- of a
   farther layer, across a depth jump from this or a farther layer -- is nearer to that member than the hidden
   pixel is). An in-focus source is composited at once (an opaque copy); a blurred one adds,
   per footprint row, the four end weights of its interval to a row-difference buffer (atomic adds);
2. one thread per row and channel sums the row (the coverage of every pixel by every interval, exactly);
3. one thread per pixel composites the layer behind what is in front (rule 5).

Accumulation is float32 (atomic adds in any order): results agree with the reference to float32 rounding of sums.
"""

from __future__ import annotations

import math

import numpy as np
from numba import cuda

from ..apertures import Aperture
from ..errors import InputError
from ..lens import MAX_COC_PX
from ..stages.render import LAYER_EDGES_PX, MIN_SOURCE_RADIUS_PX, aperture_table
from ..stages.render.classify import JUMP_COC_PX, frame_edges
from .launch import grid_1d, grid_2d, on_device, to_device, zeros

_N_EDGES = len(LAYER_EDGES_PX)
#: layer keys run over -_N_EDGES .. _N_EDGES; bin = key + _N_EDGES
N_BINS = 2 * _N_EDGES + 1
_G_SAMPLES = 4096


@cuda.jit
def _classify(coc_in, max_coc, edges, radius, key_bin, count, r_max):
    """Cleaned radius (|c| / 2, NaN as 0, clipped), the layer bin of each pixel (*edges* (2, n): the frame's layer
    edges in front of the focus and behind it), and per bin its pixel count and largest radius (atomics)."""
    y, x = cuda.grid(2)
    H, W = coc_in.shape
    if y >= H or x >= W:
        return
    c = np.float64(coc_in[y, x])
    if c != c:
        c = 0.0
    c = min(max(c, -max_coc), max_coc)
    a = abs(c)
    side = 0 if c < 0 else 1
    k = 0
    for e in range(_N_EDGES):
        if edges[side, e] <= a:
            k += 1
    b = _N_EDGES - k if c < 0 else _N_EDGES + k
    r = np.float32(0.5 * a)
    radius[y, x] = r
    key_bin[y, x] = b
    cuda.atomic.add(count, b, 1)
    cuda.atomic.max(r_max, b, r)


@cuda.jit
def _ranks(key_bin, rank_of_bin, rank):
    y, x = cuda.grid(2)
    if y < rank.shape[0] and x < rank.shape[1]:
        rank[y, x] = rank_of_bin[key_bin[y, x]]


@cuda.jit(device=True)
def _nearest_behind(rank, li, y, x, reach):
    """(d^2, row, col) of the nearest pixel of rank >= li within *reach* (ties: first in raster order); d^2 < 0 when
    there is none."""
    H, W = rank.shape
    best, by, bx = -1, -1, -1
    k = 0
    while k <= reach:
        for dy in range(-k, k + 1):
            qy = y + dy
            if qy < 0 or qy >= H:
                continue
            stride = 1 if (dy == -k or dy == k) else 2 * k
            for dx in range(-k, k + 1, max(stride, 1)):
                qx = x + dx
                if qx < 0 or qx >= W or rank[qy, qx] < li:
                    continue
                d2 = dy * dy + dx * dx
                if best < 0 or d2 < best or (d2 == best and (qy < by or (qy == by and qx < bx))):
                    best, by, bx = d2, qy, qx
        if best >= 0 and best < (k + 1) * (k + 1):
            break
        k += 1
    return best, by, bx


@cuda.jit(device=True)
def _clean(c, max_coc):
    """The signed CoC as the classification cleans it: NaN as 0, clipped to +-max_coc (float32)."""
    c = np.float32(c)
    if c != c:
        return np.float32(0.0)
    return np.float32(min(max(c, np.float32(-max_coc)), np.float32(max_coc)))


@cuda.jit
def _across_jumps(coc_in, max_coc, rank, across):
    """Per pixel, the largest rank among its four neighbours whose cleaned signed CoC (NaN as 0, clipped) is
    smaller than its own by more than JUMP_COC_PX, or -1 (:func:`pcdof.stages.render.classify.across_jumps`)."""
    y, x = cuda.grid(2)
    H, W = rank.shape
    if y >= H or x >= W:
        return
    best = -1
    c = _clean(coc_in[y, x], max_coc)
    for k in range(4):
        ny, nx = y, x
        if k < 2:
            ny = y - 1 if k == 0 else y + 1
        else:
            nx = x - 1 if k == 2 else x + 1
        if 0 <= ny < H and 0 <= nx < W and np.float32(c - _clean(coc_in[ny, nx], max_coc)) > JUMP_COC_PX:
            best = max(best, rank[ny, nx])
    across[y, x] = best


@cuda.jit(device=True)
def _farther_within(rank, across, li, y, x, d2):
    """Whether a pixel that ends the surface (rank > li, across >= li) lies at squared distance < d2 from (y, x)."""
    H, W = rank.shape
    k_max = int(math.ceil(math.sqrt(np.float64(d2))))
    for dy in range(-k_max, k_max + 1):
        qy = y + dy
        if qy < 0 or qy >= H:
            continue
        for dx in range(-k_max, k_max + 1):
            qx = x + dx
            if 0 <= qx < W and dy * dy + dx * dx < d2 and rank[qy, qx] > li and across[qy, qx] >= li:
                return True
    return False


@cuda.jit(device=True)
def _g(table, row, u):
    f = (u + 1.0) * (0.5 * _G_SAMPLES)
    i = int(f)
    if i >= _G_SAMPLES:
        return table[row, _G_SAMPLES]
    i = max(i, 0)
    return table[row, i] + (f - i) * (table[row, i + 1] - table[row, i])


@cuda.jit(device=True)
def _add_end(diff, y, t, wgt, sign, value, c):
    """Add the end t of an interval on row y to the row-difference buffer (see :func:`_scatter_source`)."""
    W = diff.shape[1]
    u = t + 0.5
    i = int(math.floor(u))
    f = u - i
    if i < W:
        cuda.atomic.add(diff, (y, max(i, 0), c), np.float32(sign * wgt * (1.0 - f) * value))
    if i + 1 < W:
        cuda.atomic.add(diff, (y, max(i + 1, 0), c), np.float32(sign * wgt * f * value))


@cuda.jit(device=True)
def _scatter_source(diff, lin, table, unit_area, y, x, sy, sx, r):
    """Spread (colour of (sy, sx), 1) / (unit_area r^2) over the footprint of radius r centred on (y, x): per row,
    the strip's area laid out as an interval about its centroid, each pixel getting its overlap with it.

    The overlap of [a, b] with pixel p is g_p(b) - g_p(a), g_p(t) = clamp(t + 0.5 - p, 0, 1); as a sequence in p,
    1 - g_p(t) is a step of height 1 - f at floor(t + 0.5) and f one pixel later (f the fraction), so each end
    adds two weights to the row's difference buffer and a running sum over the row gives every overlap."""
    H, W, C1 = diff.shape
    C = C1 - 1
    R = int(math.ceil(r + 0.5))
    wgt = 1.0 / (unit_area * r * r)
    for dy in range(-R, R + 1):
        row = y + dy
        if row < 0 or row >= H:
            continue
        lo, hi = max(dy - 0.5, -r), min(dy + 0.5, r)
        if hi <= lo:
            continue
        g0, g1 = _g(table, 0, lo / r), _g(table, 0, hi / r)
        dg = g1 - g0
        if not dg > 0.0:
            continue
        area = r * r * dg
        centre = x + r * (_g(table, 1, hi / r) - _g(table, 1, lo / r)) / dg
        a, b = centre - 0.5 * area, centre + 0.5 * area
        for c in range(C1):
            value = 1.0 if c == C else np.float64(lin[sy, sx, c])
            _add_end(diff, row, a, wgt, 1.0, value, c)
            _add_end(diff, row, b, wgt, -1.0, value, c)


@cuda.jit
def _layer_sources(rank, across, li, in_focus, lin, radius, trans, reach, table, unit_area, diff, acc, acc_a):
    """Each pixel that is a source of layer *li* (a member, or a hidden pixel it continues when *reach* >= 0):
    composited at once when *in_focus*, else scattered into *diff*."""
    y, x = cuda.grid(2)
    H, W = rank.shape
    if y >= H or x >= W:
        return
    sy, sx = y, x
    rk = rank[y, x]
    if rk != li:
        if reach < 0 or rk > li or not trans[y, x] > 0.0:
            return
        d2, sy, sx = _nearest_behind(rank, li, y, x, reach)
        if d2 < 0 or d2 > reach * reach or rank[sy, sx] != li:
            return
        if d2 > 1 and _farther_within(rank, across, li, sy, sx, d2):
            return
    if in_focus:
        t = trans[y, x]
        if t > 0.0:
            for c in range(lin.shape[2]):
                acc[y, x, c] += t * lin[sy, sx, c]
            acc_a[y, x] += t
            trans[y, x] = 0.0
        return
    r = max(np.float64(radius[sy, sx]), MIN_SOURCE_RADIUS_PX)
    _scatter_source(diff, lin, table, unit_area, y, x, sy, sx, r)


@cuda.jit
def _row_sums(diff):
    """Running sum along each row of each channel, in place."""
    i = cuda.grid(1)
    H, W, C1 = diff.shape
    if i >= H * C1:
        return
    y, c = i // C1, i % C1
    s = np.float32(0.0)
    for x in range(W):
        s += diff[y, x, c]
        diff[y, x, c] = s


@cuda.jit
def _composite(diff, acc, acc_a, trans):
    """Front-to-back "over" of the scattered layer (premultiplied colour, coverage) behind the accumulation."""
    y, x = cuda.grid(2)
    H, W, C1 = diff.shape
    if y >= H or x >= W:
        return
    cover = diff[y, x, C1 - 1]
    t = trans[y, x]
    if not (t > 0.0 and cover > 1e-6):
        return
    alpha = np.float32(1.0) if cover >= 1.0 - 1e-4 else cover
    f = t * alpha / cover
    for c in range(C1 - 1):
        acc[y, x, c] += f * diff[y, x, c]
    acc_a[y, x] += t * alpha
    trans[y, x] = t * (1.0 - alpha)


@cuda.jit
def _normalise(acc, acc_a, lin, out):
    y, x = cuda.grid(2)
    H, W, C = out.shape
    if y >= H or x >= W:
        return
    a = acc_a[y, x]
    for c in range(C):
        out[y, x, c] = acc[y, x, c] / a if a > 1e-6 else lin[y, x, c]


class ApertureOnDevice:
    """An aperture's strip table (:func:`pcdof.stages.render.aperture_table`) on the device, and its unit area."""

    def __init__(self, aperture: Aperture, stream=0):
        if not isinstance(aperture, Aperture):
            raise InputError(f"aperture must be a pcdof.apertures.Aperture; got {type(aperture).__name__}")
        self.table = to_device(np.asarray(aperture_table(aperture), np.float64), stream)
        self.unit_area = float(aperture.unit_area)


_APERTURES: dict = {}


def aperture_on_device(aperture: Aperture, stream=0) -> ApertureOnDevice:
    """:class:`ApertureOnDevice` of *aperture*, cached (a few shapes at most)."""
    if aperture not in _APERTURES:
        if len(_APERTURES) >= 16:
            _APERTURES.clear()
        _APERTURES[aperture] = ApertureOnDevice(aperture, stream)
    return _APERTURES[aperture]


def classify_layers(signed_coc, stream=0, edges=None):
    """(radius (H, W) float32, bin (H, W) int32 device arrays, counts (N_BINS,) int64, r_max (N_BINS,) float32 host
    arrays) of a signed CoC map; bin - ``N_BINS // 2`` is the layer key of
    :func:`pcdof.stages.render.reference.layer_keys` with *edges* ((2, n) px: in front of the focus, behind it;
    None: the frame's, :func:`pcdof.stages.render.classify.frame_edges`, from a copy of the map on the host).
    The per-bin counts come back to the host (a few hundred bytes) to plan the layers."""
    coc = to_device(signed_coc if on_device(signed_coc) else np.asarray(signed_coc, np.float32), stream)
    if len(coc.shape) != 2:
        raise InputError(f"signed_coc must be (H, W); got shape {tuple(coc.shape)}")
    if edges is None:
        edges = frame_edges(coc.copy_to_host(stream=stream) if on_device(signed_coc)
                            else np.asarray(signed_coc, np.float32))
    radius = cuda.device_array(coc.shape, np.float32, stream=stream)
    key_bin = cuda.device_array(coc.shape, np.int32, stream=stream)
    count = zeros(N_BINS, np.int64, stream)
    r_max = zeros(N_BINS, np.float32, stream)
    blocks, threads = grid_2d(*coc.shape)
    _classify[blocks, threads, stream](coc, MAX_COC_PX, to_device(np.asarray(edges, np.float64), stream), radius,
                                       key_bin, count, r_max)
    return radius, key_bin, count.copy_to_host(stream=stream), r_max.copy_to_host(stream=stream)


@cuda.jit
def _clamped_window(src, oy, ox, out):
    """out[y, x, c] = src[y + oy, x + ox, c], the indices clamped to *src* (its edge pixels repeated outward)."""
    y, x = cuda.grid(2)
    h, w, nc = src.shape
    if y < out.shape[0] and x < out.shape[1]:
        sy = min(max(y + oy, 0), h - 1)
        sx = min(max(x + ox, 0), w - 1)
        for c in range(nc):
            out[y, x, c] = src[sy, sx, c]


def clamped_window(image, oy: int, ox: int, shape, stream=0):
    """The window of *shape* (H', W') at row *oy*, column *ox* of the (H, W) or (H, W, C) device *image*, read
    with its edge pixels repeated beyond it (negative offsets widen it: :mod:`pcdof.stages.render.border`)."""
    src = image.reshape(tuple(image.shape) + (1,)) if len(image.shape) == 2 else image
    out = cuda.device_array(tuple(shape) + (src.shape[2],), src.dtype, stream=stream)
    blocks, threads = grid_2d(int(shape[0]), int(shape[1]))
    _clamped_window[blocks, threads, stream](src, int(oy), int(ox), out)
    return out.reshape(tuple(shape)) if len(image.shape) == 2 else out


@cuda.jit
def _continue_rows(lin, pad, most, out):
    """The middle columns of :func:`continued_border`: the image, and above and below it the mean of the edge row's
    pixels within d of each one's column, d rows beyond the edge, at most *most*."""
    y, x = cuda.grid(2)
    h, w, nc = lin.shape
    if y >= h + 2 * pad or x >= w:
        return
    if pad <= y < pad + h:
        for c in range(nc):
            out[y, x + pad, c] = lin[y - pad, x, c]
        return
    row, d = (0, pad - y) if y < pad else (h - 1, y - pad - h + 1)
    lo, hi = max(0, x - d), min(w, x + d + 1)
    for c in range(nc):
        acc = 0.0
        for i in range(lo, hi):
            acc += lin[row, i, c]
        out[y, x + pad, c] = min(acc / (hi - lo), most)


@cuda.jit
def _continue_columns(pad, most, out):
    """The columns left and right of the middle ones (:func:`_continue_rows`), from its first and last column, at
    most *most*."""
    y, x = cuda.grid(2)
    hh, ww, nc = out.shape
    if y >= hh or x >= 2 * pad:
        return
    col, d, dst = (pad, pad - x, x) if x < pad else (ww - pad - 1, x - pad + 1, ww - pad + x - pad)
    lo, hi = max(0, y - d), min(hh, y + d + 1)
    for c in range(nc):
        acc = 0.0
        for i in range(lo, hi):
            acc += out[i, col, c]
        out[y, dst, c] = min(acc / (hi - lo), most)


def continued_border(lin, pad: int, most: float | None = None, stream=0):
    """The (H, W, C) device image *lin* widened by *pad* on every side, its colour beyond the edge continued (no
    brighter than *most*, None: no limit) as :func:`pcdof.stages.render.border.continue_border` says:
    (H + 2 pad, W + 2 pad, C) float32 device array."""
    h, w, nc = lin.shape
    cap = np.float32(np.inf if most is None else most)
    out = cuda.device_array((h + 2 * pad, w + 2 * pad, nc), np.float32, stream=stream)
    blocks, threads = grid_2d(h + 2 * pad, w)
    _continue_rows[blocks, threads, stream](lin, int(pad), cap, out)
    if pad > 0:
        blocks, threads = grid_2d(h + 2 * pad, 2 * pad)
        _continue_columns[blocks, threads, stream](int(pad), cap, out)
    return out


def render_layers_linear(lin, signed_coc, aperture: Aperture, *, extend_behind: bool = True, stream=0, edges=None):
    """Physical depth of field in linear light on the device (the rules of :mod:`pcdof.stages.render.reference`).

    Parameters
    ----------
    lin : (H, W, C) float32 array (host or device), linear radiance
    signed_coc : (H, W) float32 array (host or device), pixels (< 0 in front of focus; NaN = 0)
    aperture : pcdof.apertures.Aperture
    extend_behind : continue each layer behind nearer, not yet opaque layers (partial occlusion)
    edges : (2, n) layer edges in front of the focus and behind it, pixels (None: the frame's,
        :func:`pcdof.stages.render.classify.frame_edges` of *signed_coc*)

    Returns
    -------
    ((H, W, C) float32 device array of linear radiance, list of the layers run: dicts with the layer's key,
    side ("front", "focus", "back"), pixels and largest radius)
    """
    lin = to_device(lin if on_device(lin) else np.asarray(lin, np.float32), stream)
    if len(lin.shape) != 3:
        raise InputError(f"lin must be (H, W, C); got shape {tuple(lin.shape)}")
    H, W, C = lin.shape
    if tuple(signed_coc.shape) != (H, W):
        raise InputError(f"signed_coc must be (H, W) = {(H, W)}; got {tuple(signed_coc.shape)}")
    ap = aperture_on_device(aperture, stream)
    radius, key_bin, count, r_max = classify_layers(signed_coc, stream, edges)
    present = np.flatnonzero(count)
    rank_of_bin = np.full(N_BINS, -1, np.int32)
    rank_of_bin[present] = np.arange(present.size, dtype=np.int32)
    rank = cuda.device_array((H, W), np.int32, stream=stream)
    blocks, threads = grid_2d(H, W)
    _ranks[blocks, threads, stream](key_bin, to_device(rank_of_bin, stream), rank)
    across = cuda.device_array((H, W), np.int32, stream=stream)
    _across_jumps[blocks, threads, stream](signed_coc if on_device(signed_coc) else
                                           to_device(np.asarray(signed_coc, np.float32), stream),
                                           MAX_COC_PX, rank, across)
    acc = zeros((H, W, C), np.float32, stream)
    acc_a = zeros((H, W), np.float32, stream)
    trans = cuda.device_array((H, W), np.float32, stream=stream)
    from .launch import fill_value

    fill_value(trans.reshape(H * W), 1.0, stream)
    diff = cuda.device_array((H, W, C + 1), np.float32, stream=stream)
    r_front = 0.0
    layers = []
    for li, b in enumerate(present):
        key = int(b) - _N_EDGES
        rm = float(r_max[b])
        reach = int(math.ceil(r_front + rm + 1)) if extend_behind and li > 0 and r_front > 0 else -1
        if key != 0:
            fill_value(diff.reshape(diff.size), 0.0, stream)
        _layer_sources[blocks, threads, stream](rank, across, li, key == 0, lin, radius, trans, reach, ap.table,
                                                ap.unit_area, diff, acc, acc_a)
        if key != 0:
            rblocks, rthreads = grid_1d(H * (C + 1))
            _row_sums[rblocks, rthreads, stream](diff)
            _composite[blocks, threads, stream](diff, acc, acc_a, trans)
            r_front = max(r_front, rm)
        layers.append({"key": key, "side": "focus" if key == 0 else "front" if key < 0 else "back",
                       "pixels": int(count[b]), "max_radius_px": rm, "extended": reach >= 0})
    out = cuda.device_array((H, W, C), np.float32, stream=stream)
    _normalise[blocks, threads, stream](acc, acc_a, lin, out)
    return out, layers


@cuda.jit
def _mix_edges(out, lin, depth, coc, b, sharp, blurred, nearer, same, contrast2, off2, most_share):
    y, x = cuda.grid(2)
    h, w = depth.shape
    if y >= h or x >= w:
        return
    nc = out.shape[2]
    zp = depth[y, x]
    if not (zp > 0.0 and abs(coc[y, x]) > blurred):
        return
    for k in range(4):  # above, below, left, right: the first that qualifies (the CPU's last of right ... above)
        dy = -1 if k == 0 else 1 if k == 1 else 0
        dx = 0 if k < 2 else -1 if k == 2 else 1
        qy, qx, ry, rx = y + dy, x + dx, y - dy, x - dx
        if not (0 <= qy < h and 0 <= qx < w and 0 <= ry < h and 0 <= rx < w):
            continue
        if not (depth[qy, qx] * nearer < zp and abs(coc[qy, qx]) < sharp and abs(depth[ry, rx] - zp) < same * zp):
            continue
        dd = 0.0
        dot = 0.0
        for c in range(nc):  # the share from the colours as the camera saw them (light above white at white)
            f = min(float(lin[qy + b, qx + b, c]), 1.0) - min(float(lin[ry + b, rx + b, c]), 1.0)
            dd += f * f
            dot += (min(float(lin[y + b, x + b, c]), 1.0) - min(float(lin[ry + b, rx + b, c]), 1.0)) * f
        if not dd > contrast2:
            continue
        a = dot / dd
        if not (0.0 < a <= most_share):
            continue
        off = 0.0
        for c in range(nc):
            f = min(float(lin[qy + b, qx + b, c]), 1.0) - min(float(lin[ry + b, rx + b, c]), 1.0)
            e = min(float(lin[y + b, x + b, c]), 1.0) - min(float(lin[ry + b, rx + b, c]), 1.0) - a * f
            off += e * e
        if not off < off2 * dd:
            continue
        for c in range(nc):
            if a >= 1.0:
                out[y, x, c] = lin[y + b, x + b, c]
            else:
                out[y, x, c] = a * float(lin[qy + b, qx + b, c]) + (1.0 - a) * float(out[y, x, c])
        return


def mix_edges(out, lin, depth, signed_coc, border: int = 0, stream=0) -> None:
    """:func:`pcdof.stages.render.mixed.mix_edges` on the device, in place: *out* (H, W, C) float32 device array, the
    linear source *lin* (H + 2 border, W + 2 border, C), *depth* and *signed_coc* (H, W) float32 (host or device)."""
    from ..stages.render import mixed

    depth = depth if on_device(depth) else to_device(np.asarray(depth, np.float32), stream)
    coc = signed_coc if on_device(signed_coc) else to_device(np.asarray(signed_coc, np.float32), stream)
    h, w = depth.shape
    blocks, threads = grid_2d(h, w)
    _mix_edges[blocks, threads, stream](out, lin, depth, coc, int(border), mixed.SHARP_PX, mixed.BLURRED_PX,
                                        mixed.NEARER_RATIO,
                                        mixed.SAME_SURFACE, mixed.MIN_CONTRAST ** 2, mixed.MAX_OFF ** 2,
                                        mixed.MAX_SHARE)
