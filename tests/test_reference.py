"""Every fast path of every stage against the plain reference of its stage (``reference.py``).

The references are whole-frame numpy code stating each stage's rules; the fast paths (numba kernels,
threads, tiles, block and scanline rasterisation, reduced-resolution layers, convolution of uniform
tiles) must give their answer within the tolerance stated for that path below. Paths that are exact
by design get float-rounding tolerances; approximations by design get the bound they are built to.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
import zlib

import cv2
import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcdof.metrics import psnr
from pcdof.stages import fill as fast_fill
from pcdof.stages.fill.directional import fill_directional
import pcdof.stages.render as renderer
from pcdof.camera import Intrinsics, Rig
from pcdof.color import decode_to_linear, srgb_to_linear
from pcdof.errors import InputError
from pcdof.lens import PaperLens, ThinLens
from pcdof.plans import plan_render
from pcdof.stages.coc import reference as ref_coc
from pcdof.stages.fill import reference as ref_fill
from pcdof.stages.register import reference as ref_register
from pcdof.stages.register import reproject_depth
from pcdof.stages.register.reproject import default_depth_ratio
from pcdof.stages.render import reference as ref_render
from pcdof.stages.render.tiles import TileMap, classify_tiles

# ---------------------------------------------------------------------------------------------
# Tolerances, one per path (README developer section, "Reference implementations").

#: registration, all paths (threads, bands, per-centre / 4x4 block / scanline rasterisation): relative
#: depth error where both have depth, and the number of colour pixels allowed to differ beyond it or in
#: coverage: the fast path stores projected vertices in float32, so a pixel centre within that rounding
#: of a triangle edge may go either way (seen: 1 pixel in 370 random frames, the rest bit-for-bit within 2e-7)
REG_REL_TOL = 1e-5
REG_MAX_DIFFERING_PX = 2
#: fill, serial and parallel kernels: relative depth error (float32 rounding of the same arithmetic)
FILL_REL_TOL = 1e-6
#: CoC: relative error of the float32 result
COC_REL_TOL = 1e-6
#: render, exact scatter (no tiles, full resolution): absolute error in linear light (values <= 1); the
#: fast path interpolates a 4096-entry table of the aperture's strip areas and accumulates in float32
RENDER_EXACT_ATOL = 1e-5
#: render, partial-occlusion extension: the fast path finds the nearest layer pixel with OpenCV's
#: distance transform, whose choice among equally near pixels differs from the reference's (first in
#: raster order); on colour varying by at most 0.004 per pixel the chosen colours differ by a few steps
RENDER_EXTEND_ATOL = 0.02
#: render, tiles (copy tiles bit-exact; uniform tiles convolved with one kernel per 4 % radius bin) and
#: reduced-resolution quality tiers: PSNR (dB, peak 1) against the reference
RENDER_MIN_PSNR_DB = {"exact": 60.0, "high": 50.0, "balanced": 44.0, "fast": 36.0}
#: paper method: absolute error of the float32 result (values in [0, 1])
PAPER_ATOL = 1e-5


# ---------------------------------------------------------------------------------------------
# registration


def _rig(depth_size, color_size, *, fd, fc, distorted, rng) -> Rig:
    """A rig with a random small rotation, a few-cm baseline and sub-pixel principal points."""
    (dw, dh), (cw, ch) = depth_size, color_size
    ddist = (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103) if distorted else ()
    cdist = (0.2080, -0.5861, 0.0007, 0.0010, 0.4986) if distorted else ()
    depth = Intrinsics(dw, dh, fd, fd * 1.002, dw / 2 + rng.uniform(-1, 1), dh / 2 + rng.uniform(-1, 1), ddist)
    color = Intrinsics(cw, ch, fc, fc * 0.998, cw / 2 + rng.uniform(-1, 1), ch / 2 + rng.uniform(-1, 1), cdist)
    rvec = rng.normal(0, 0.01, 3)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = (rng.uniform(-0.06, -0.02), rng.uniform(-0.005, 0.005), rng.uniform(-0.005, 0.005))
    return Rig(color, depth, T)


def _depth_scene(shape, rng) -> np.ndarray:
    """A slanted plane with a box in front, thin structures, an isolated pixel, holes, NaN, inf, negatives."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    d = (rng.uniform(0.8, 3.0) + rng.uniform(-0.02, 0.02) * xx + rng.uniform(-0.02, 0.02) * yy).astype(np.float32)
    d = np.maximum(d, 0.3)
    y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
    d[y0:y0 + h // 3, x0:x0 + w // 3] = rng.uniform(0.4, 0.7)  # a depth step
    d[:, rng.integers(0, w)] = rng.uniform(0.4, 0.9)  # one-pixel-wide structures
    d[rng.integers(0, h), :] = rng.uniform(0.4, 0.9)
    d[rng.integers(0, h), rng.integers(0, w)] = 0.35  # an isolated near pixel
    d[rng.random((h, w)) < 0.05] = 0.0
    d[rng.random((h, w)) < 0.01] = np.nan
    d[rng.random((h, w)) < 0.005] = np.inf
    d[rng.random((h, w)) < 0.005] = -1.0
    return d


#: a triangle whose depth ratio (max / min of its corners' 1/z) is this close to the limit, relatively, is kept or
#: dropped by float32 rounding: the fast path computes in float32, the reference in float64
REG_RATIO_ROUNDING = 1e-6
#: pixel centres this close (px) outside a kept triangle's edge: the fast path draws centres up to 1e-4 px outside an
#: edge, measured along the row (scanlines) or scaled by the triangle's size (blocks), the reference up to 1e-9 of the
#: edge function; either may draw them
REG_EDGE_PX = 1e-3


def _undecided(depth, rig, ratio, shape):
    """(H, W) bool: colour pixels whose value the fast path and the reference may decide apart by their stated
    tolerances: near a quad with a triangle that float32 rounding may keep or drop (its depth ratio within
    :data:`REG_RATIO_ROUNDING` of the limit; the quad's projection widened by the footprint's reach, rules 2 and 4
    of :mod:`pcdof.stages.register.reference`), and centres within :data:`REG_EDGE_PX` outside a kept triangle."""
    limit = 1.0 + (default_depth_ratio(rig.depth) if ratio is None else float(ratio))
    U, V, IZ = ref_register.project_depth(depth, rig)
    out = np.zeros(shape, bool)
    reach = 2.0 + max(rig.color.fx / rig.depth.fx, rig.color.fy / rig.depth.fy)
    for i in range(IZ.shape[0] - 1):
        for j in range(IZ.shape[1] - 1):
            w = IZ[i:i + 2, j:j + 2].ravel()  # a, b, c, d
            for tri in ((0, 1, 3), (0, 3, 2), (0, 1, 2), (1, 3, 2)):
                lo, hi = w[list(tri)].min(), w[list(tri)].max()
                if lo > 0 and abs(hi / lo - limit) <= REG_RATIO_ROUNDING * limit:
                    us, vs = U[i:i + 2, j:j + 2], V[i:i + 2, j:j + 2]
                    y0, y1 = int(np.floor(vs.min() - reach)), int(np.ceil(vs.max() + reach))
                    x0, x1 = int(np.floor(us.min() - reach)), int(np.ceil(us.max() + reach))
                    out[max(y0, 0):max(y1 + 1, 0), max(x0, 0):max(x1 + 1, 0)] = True
            for tri in ref_register.quad_triangles(IZ, i, j, limit)[0]:
                _near_edges(out, [(U[p], V[p]) for p in tri])
    _near_footprints(out, depth, rig, U, V, IZ, limit)
    return out


def _near_footprints(out, depth, rig, U, V, IZ, limit):
    """Set in *out* the pixel centres within :data:`REG_EDGE_PX` of a footprint's edge (rule 4 of
    :mod:`pcdof.stages.register.reference`, the same rectangles), on either side: float32 rounding of its reach
    decides them."""
    h, w = IZ.shape
    whole = np.zeros((h + 1, w + 1), bool)
    for i in range(h - 1):
        for j in range(w - 1):
            whole[i + 1, j + 1] = ref_register.quad_triangles(IZ, i, j, limit)[1]
    foot_u, foot_v = 0.5 * rig.color.fx / rig.depth.fx, 0.5 * rig.color.fy / rig.depth.fy
    d = np.asarray(depth, np.float32).astype(np.float64)
    for i, j in zip(*np.nonzero(IZ > 0)):
        if whole[i:i + 2, j:j + 2].all():
            continue
        s, wij = d[i, j] * IZ[i, j], IZ[i, j]
        lo_u, hi_u = (foot_u * s * ref_register._reach(IZ, i, j + k, wij, limit) for k in (-1, 1))
        lo_v, hi_v = (foot_v * s * ref_register._reach(IZ, i + k, j, wij, limit) for k in (-1, 1))
        rows = _near_span(V[i, j], lo_v, hi_v, out.shape[0])
        cols = _near_span(U[i, j], lo_u, hi_u, out.shape[1])
        inner_rows = range(max(int(np.ceil(V[i, j] - lo_v)), 0), min(int(np.floor(V[i, j] + hi_v)), out.shape[0] - 1) + 1)
        inner_cols = range(max(int(np.ceil(U[i, j] - lo_u)), 0), min(int(np.floor(U[i, j] + hi_u)), out.shape[1] - 1) + 1)
        for y in rows:
            out[y, [x for x in set(cols) | set(inner_cols) if 0 <= x < out.shape[1]]] = True
        for x in cols:
            out[[y for y in set(rows) | set(inner_rows) if 0 <= y < out.shape[0]], x] = True


def _near_span(centre, lo, hi, n):
    """Pixel centres (in [0, n)) within :data:`REG_EDGE_PX` of the span [centre - lo, centre + hi]'s ends, or of the
    half-way point that picks the pixel containing *centre* when the span holds no centre."""
    near = set()
    for edge in (centre - lo, centre + hi, centre + 0.5):
        k = round(edge)
        if abs(edge - k) <= REG_EDGE_PX and 0 <= k < n:
            near.update(x for x in (k - 1, k) if 0 <= x < n)
    return sorted(near)


def _near_edges(out, corners):
    """Set in *out* the pixel centres outside the triangle *corners* ((u, v) x 3) by at most :data:`REG_EDGE_PX`."""
    (u0, v0), (u1, v1), (u2, v2) = corners
    h, w = out.shape
    xa, xb = max(int(np.ceil(min(u0, u1, u2) - REG_EDGE_PX)), 0), min(int(np.floor(max(u0, u1, u2) + REG_EDGE_PX)), w - 1)
    ya, yb = max(int(np.ceil(min(v0, v1, v2) - REG_EDGE_PX)), 0), min(int(np.floor(max(v0, v1, v2) + REG_EDGE_PX)), h - 1)
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    if xa > xb or ya > yb or area == 0.0:
        return
    y, x = np.mgrid[ya:yb + 1, xa:xb + 1].astype(np.float64)
    s = np.sign(area)
    dist = []  # signed distance inside each edge, px
    for (pu, pv), (qu, qv) in (((u1, v1), (u2, v2)), ((u2, v2), (u0, v0)), ((u0, v0), (u1, v1))):
        e = (pu - x) * (qv - y) - (qu - x) * (pv - y)
        dist.append(s * e / max(np.hypot(qu - pu, qv - pv), 1e-12))
    worst = np.minimum.reduce(dist)
    out[ya:yb + 1, xa:xb + 1] |= (worst < 0) & (worst >= -REG_EDGE_PX)


def _assert_registration_matches(out, ref, min_coverage=0.2, undecided=None):
    """*out* (the fast path) agrees with *ref* (the reference) but for :data:`REG_MAX_DIFFERING_PX` pixels, outside
    the *undecided* pixels ((H, W) bool or None: see :func:`_undecided`)."""
    assert out.shape == ref.shape and np.count_nonzero(ref) > min_coverage * ref.size
    with np.errstate(divide="ignore", invalid="ignore"):
        differs = ((out > 0) != (ref > 0)) | (np.abs(out - ref) > REG_REL_TOL * ref)
    if undecided is not None:
        differs &= ~undecided
    assert np.count_nonzero(differs) <= REG_MAX_DIFFERING_PX, [(tuple(p), out[tuple(p)], ref[tuple(p)])
                                                               for p in np.argwhere(differs)[:5]]


#: (depth size, colour size, depth f, colour f): a depth grid 4x coarser than the colour grid (quads
#: drawn by scanlines), 2x coarser (4x4 blocks), equal, and 2x finer (pixel centres tested one by one)
REG_GEOMETRIES = {
    "coarse4x-scanline": ((24, 20), (96, 80), 22.0, 84.0),
    "coarse2x-block": ((48, 40), (96, 80), 44.0, 84.0),
    "equal": ((64, 48), (64, 48), 58.0, 56.0),
    "finer-centres": ((96, 80), (48, 40), 88.0, 42.0),
}


@pytest.fixture
def threads(request):
    """Run with numba.set_num_threads(request.param) (clipped to the pool), restored afterwards."""
    before = numba.get_num_threads()
    numba.set_num_threads(min(request.param, numba.config.NUMBA_NUM_THREADS))
    yield numba.get_num_threads()
    numba.set_num_threads(before)


@pytest.mark.parametrize("threads", [1, 2], indirect=True, ids=["1-thread", "2-threads"])
@pytest.mark.parametrize("geometry", list(REG_GEOMETRIES))
@pytest.mark.parametrize("distorted", [False, True], ids=["pinhole", "distorted"])
def test_registration_matches_reference(geometry, distorted, threads):
    depth_size, color_size, fd, fc = REG_GEOMETRIES[geometry]
    rng = np.random.default_rng(zlib.crc32(f"{geometry} {distorted}".encode()))
    rig = _rig(depth_size, color_size, fd=fd, fc=fc, distorted=distorted, rng=rng)
    depth = _depth_scene(rig.depth.shape, rng)
    _assert_registration_matches(reproject_depth(depth, rig), ref_register.reproject_depth(depth, rig))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), geometry=st.sampled_from(list(REG_GEOMETRIES)), distorted=st.booleans(),
       ratio=st.sampled_from([None, 0.005, 0.03, 0.3]))
def test_registration_matches_reference_on_random_frames(seed, geometry, distorted, ratio):
    depth_size, color_size, fd, fc = REG_GEOMETRIES[geometry]
    rng = np.random.default_rng(seed)
    rig = _rig(depth_size, color_size, fd=fd, fc=fc, distorted=distorted, rng=rng)
    depth = _depth_scene(rig.depth.shape, rng)
    _assert_registration_matches(reproject_depth(depth, rig, max_depth_ratio=ratio),
                                 ref_register.reproject_depth(depth, rig, max_depth_ratio=ratio),
                                 undecided=_undecided(depth, rig, ratio, rig.color.shape))


@pytest.mark.parametrize("seed,geometry,ratio", [(1317, "coarse2x-block", 0.005), (1014832613, "finer-centres", 0.3),
                                                (478373773, "coarse4x-scanline", 0.3)])
def test_undecided_pixels_are_where_the_stated_tolerances_differ(seed, geometry, ratio):
    """Three cases where the fast path and the reference disagree by their tolerances: a slanted plane whose rows step
    by the limit (a triangle's depth ratio is the limit within 5e-8), a pixel centre 6e-5 px outside a triangle's
    edge beside a hole, and the last depth row's footprints reaching a row of centres within rounding. Every differing
    pixel is undecided, and few pixels are."""
    depth_size, color_size, fd, fc = REG_GEOMETRIES[geometry]
    rng = np.random.default_rng(seed)
    rig = _rig(depth_size, color_size, fd=fd, fc=fc, distorted=False, rng=rng)
    depth = _depth_scene(rig.depth.shape, rng)
    out = reproject_depth(depth, rig, max_depth_ratio=ratio)
    ref = ref_register.reproject_depth(depth, rig, max_depth_ratio=ratio)
    undecided = _undecided(depth, rig, ratio, rig.color.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        differs = ((out > 0) != (ref > 0)) | (np.abs(out - ref) > REG_REL_TOL * ref)
    assert np.count_nonzero(differs) > REG_MAX_DIFFERING_PX and not (differs & ~undecided).any()
    assert undecided.sum() < 0.05 * undecided.size  # a few quads and edges, not the frame


def test_registration_bands_and_chunks_match_reference():
    """Every split of the work into bands of colour rows and chunks of depth rows gives the reference."""
    from pcdof.plans import RegisterPlan

    rng = np.random.default_rng(7)
    rig = _rig((48, 40), (96, 80), fd=44.0, fc=84.0, distorted=True, rng=rng)
    depth = _depth_scene(rig.depth.shape, rng)
    ref = ref_register.reproject_depth(depth, rig)
    for n in (1, 3, 80):
        for block_kernel in (True, False):
            plan = RegisterPlan(threads=min(n, 2, numba.config.NUMBA_NUM_THREADS), chunks=min(n, 40), bands=n,
                                block_kernel=block_kernel)
            _assert_registration_matches(reproject_depth(depth, rig, plan=plan), ref)


def test_registration_adversarial_frames_match_reference():
    """Points behind the colour camera, an all-unknown row, a lone known pixel, depth at 1 mm."""
    rng = np.random.default_rng(11)
    rig = _rig((48, 40), (64, 48), fd=44.0, fc=56.0, distorted=True, rng=rng)
    T = np.array(rig.T_color_from_depth)
    T[2, 3] = -0.5  # colour camera 0.5 m in front of the depth camera: near points fall behind it
    rig = Rig(rig.color, rig.depth, T)
    depth = _depth_scene(rig.depth.shape, rng)
    depth[:, :10] = 0.3  # behind the colour camera
    depth[20, :] = 0.0
    depth[30:33, 30:33] = 0.0
    depth[31, 31] = 1.1  # alone in a hole
    depth[0, :5] = 0.001
    _assert_registration_matches(reproject_depth(depth, rig), ref_register.reproject_depth(depth, rig), 0.05)


# ---------------------------------------------------------------------------------------------
# fill


def _fill_frame(rng, h=40, w=48):
    """Slanted wall, a nearer box of another colour, a disocclusion beside it, a sensor hole, speckle, NaN."""
    yy, xx = np.mgrid[0:h, 0:w]
    depth = (rng.uniform(1.2, 3.0) + rng.uniform(-0.01, 0.01) * xx + 0.004 * yy).astype(np.float32)
    color = np.empty((h, w, 3), np.float64)
    color[...] = rng.uniform(0.5, 0.9, 3)
    y0, x0 = rng.integers(2, h // 2), rng.integers(2, w // 2)
    box = (slice(y0, y0 + h // 3), slice(x0, x0 + w // 3))
    depth[box] = rng.uniform(0.5, 0.9) + 0.002 * xx[box]
    color[box] = rng.uniform(0.05, 0.4, 3)
    color = np.clip(color + rng.normal(0, 0.02, color.shape), 0, 1)
    depth[y0 - 2: y0 + h // 3 + 2, x0 + w // 3: x0 + w // 3 + rng.integers(3, 9)] = 0.0  # disocclusion
    depth[rng.random((h, w)) < rng.uniform(0.0, 0.2)] = 0.0
    hy, hx = rng.integers(0, h - 8), rng.integers(0, w - 12)
    depth[hy:hy + 8, hx:hx + 12] = 0.0  # a large sensor hole: the median cleanup runs inside it
    depth[rng.integers(0, h), rng.integers(0, w)] = np.nan
    if not (depth > 0).any():
        depth[0, 0] = 1.0
    return depth, color


def _assert_fill_matches(out, ref):
    assert out.dtype == np.float32 and np.all(out > 0)
    rel = np.abs(out.astype(np.float64) - ref) / ref
    assert rel.max() <= FILL_REL_TOL, (rel.max(), np.unravel_index(np.argmax(rel), rel.shape))


FILL_PATHS = {
    "public": lambda d, c, use_color: fast_fill.FILL_METHODS["joint-bilateral" if use_color else "nearest-background"](
        d, (c * 255).round().astype(np.uint8) if use_color else None),
    "serial": lambda d, c, use_color: fill_directional(
        d, c, use_color=use_color, edge_ratio=fast_fill.DEFAULT_EDGE_RATIO, sigma_color=fast_fill.DEFAULT_SIGMA_COLOR,
        background_bias=fast_fill.DEFAULT_BACKGROUND_BIAS, parallel=False),
    "parallel": lambda d, c, use_color: fill_directional(
        d, c, use_color=use_color, edge_ratio=fast_fill.DEFAULT_EDGE_RATIO, sigma_color=fast_fill.DEFAULT_SIGMA_COLOR,
        background_bias=fast_fill.DEFAULT_BACKGROUND_BIAS, parallel=True),
}


def _ref_fill(depth, color, use_color, path):
    if path == "public" and use_color:
        color = (color * 255).round() / 255  # the uint8 guide the public path was given
    return ref_fill.fill_directional(depth, color if use_color else None, use_color=use_color)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), use_color=st.booleans(), path=st.sampled_from(list(FILL_PATHS)))
def test_fill_matches_reference_on_random_frames(seed, use_color, path):
    depth, color = _fill_frame(np.random.default_rng(seed))
    _assert_fill_matches(FILL_PATHS[path](depth, color, use_color), _ref_fill(depth, color, use_color, path))


def _slanted_wall(h, w, rng):
    """A slanted plane (every known pixel a different depth, so a wrong choice of pixel shows) and noise colour."""
    yy, xx = np.mgrid[0:h, 0:w]
    depth = (rng.uniform(1.5, 2.5) + rng.uniform(0.02, 0.05) * xx + rng.uniform(0.02, 0.05) * yy).astype(np.float32)
    return depth, rng.uniform(0, 1, (h, w, 3))


def _border_band(side):
    def build(rng, h=24, w=30):
        """A wall with a nearer box, sparse dropouts, and a band cut off one side (outside the view)."""
        depth, color = _slanted_wall(h, w, rng)
        depth[8:16, 10:20] = 0.8
        depth[rng.random((h, w)) < 0.05] = 0.0
        band = {"top": (slice(0, 5), slice(None)), "bottom": (slice(h - 5, h), slice(None)),
                "left": (slice(None), slice(0, 5)), "right": (slice(None), slice(w - 5, w))}[side]
        depth[band] = 0.0
        return depth, color
    return build


def _corner(rng, h=24, w=30):
    """Known depth only in a diamond in the middle: the four corners have no known pixel on their row or
    column (with border="hold", the nearest-filled fallback, whose tied choices, a row's pixel or a column's,
    differ in depth; by default the diagonal candidates reach them)."""
    depth, color = _slanted_wall(h, w, rng)
    yy, xx = np.mgrid[0:h, 0:w]
    depth[np.abs(yy - 12) + np.abs(xx - 15) > 6] = 0.0
    return depth, color


def _speckle(rng, h=24, w=30):
    """A disocclusion band between a near and a far surface in the far one's colour, but for one pixel in the
    near one's colour: that pixel alone takes the near depth (a speckle) until the despeckle pass."""
    depth = np.where(np.arange(w) < 12, 1.0, 3.0)[None, :].repeat(h, 0).astype(np.float32)
    color = np.where(np.arange(w)[None, :, None] < 12, 0.2, 0.8).repeat(h, 0).repeat(3, 2)
    color = color + rng.normal(0, 0.01, color.shape)
    depth[:, 12:17] = 0.0
    color[:, 12:17] = color[0, 20]
    color[12, 14] = color[0, 5]
    return depth, color


def _known_border_only(rng, h=24, w=30):
    depth = np.zeros((h, w), np.float32)
    depth[0, :], depth[-1, :], depth[:, 0], depth[:, -1] = 1.0, 3.0, 2.0, 0.7
    return depth, rng.uniform(0, 1, (h, w, 3))


def _lone_known_pixel(rng, h=24, w=30):
    """Most holes see the pixel on no line: the nearest-filled fallback."""
    depth = np.zeros((h, w), np.float32)
    depth[7, 11] = 2.0
    return depth, rng.uniform(0, 1, (h, w, 3))


def _checkerboard(rng, h=24, w=30):
    yy, xx = np.mgrid[0:h, 0:w]
    depth = np.where((yy + xx) % 2 == 0, 1.0 + 0.5 * (xx > w // 2), 0.0).astype(np.float32)
    return depth, rng.uniform(0, 1, (h, w, 3))


def _one_row(rng, h=1, w=40):
    depth = np.zeros((h, w), np.float32)
    color = rng.uniform(0, 1, (h, w, 3))
    depth[0, ::7] = rng.uniform(0.5, 4.0, depth[0, ::7].shape)
    return depth, color


#: adversarial fill frames by name, and the kinds of hole (pcdof.stages.fill's classification, with colour) each
#: must have
FILL_CASES = {
    "lone-known-pixel": (_lone_known_pixel, {fast_fill.BORDER, fast_fill.LOST}),
    "known-border-only": (_known_border_only, {fast_fill.SURFACE}),
    "checkerboard": (_checkerboard, {fast_fill.SURFACE}),
    "one-row": (_one_row, {fast_fill.SURFACE, fast_fill.BORDER}),
    **{f"border-{side}": (_border_band(side), {fast_fill.BORDER, fast_fill.SURFACE})
       for side in ("top", "bottom", "left", "right")},
    "corner": (_corner, {fast_fill.BORDER}),  # lost only with border="hold" (the diagonals reach the corners)
    "speckle": (_speckle, {fast_fill.SURFACE}),
}


@pytest.mark.parametrize("path", list(FILL_PATHS))
@pytest.mark.parametrize("use_color", [True, False], ids=["joint-bilateral", "nearest-background"])
@pytest.mark.parametrize("case", list(FILL_CASES))
def test_fill_adversarial_frames_match_reference(case, use_color, path):
    build, kinds = FILL_CASES[case]
    depth, color = build(np.random.default_rng(5))
    _, kind = fill_directional(depth, color, use_color=True, edge_ratio=fast_fill.DEFAULT_EDGE_RATIO,
                               sigma_color=fast_fill.DEFAULT_SIGMA_COLOR,
                               background_bias=fast_fill.DEFAULT_BACKGROUND_BIAS, with_kinds=True)
    assert kinds <= set(kind.tolist()), f"the {case} frame no longer has the holes it is named for"
    _assert_fill_matches(FILL_PATHS[path](depth, color, use_color), _ref_fill(depth, color, use_color, path))


def test_reference_fill_rules_decide_the_adversarial_frames():
    """The rules the adversarial frames are built for change their answer (so matching there tests those rules)."""
    depth, color = _speckle(np.random.default_rng(5))
    out = ref_fill.fill_directional(depth, color)
    assert out[12, 14] == pytest.approx(3.0) and np.allclose(out[:, 12:17], 3.0)
    depth, _ = _corner(np.random.default_rng(5))
    out = ref_fill.fill_directional(depth, None, use_color=False, border="hold")
    # corner pixel (5, 8): down, (6, 8), held from row 6's known pixel (6, 15), and right, (5, 9), held from
    # column 9's known pixel (12, 9), are the nearest filled pixels, both 1 away: down comes before right
    assert out[5, 8] == out[6, 8] != out[5, 9]
    # the border rules differ where a band is cut off a slanted wall: holding, extending, and the candidates
    depth, color = _border_band("left")(np.random.default_rng(5))
    outs = [ref_fill.fill_directional(depth, color, border=b) for b in fast_fill.BORDER_RULES]
    assert not np.allclose(outs[0][:, :5], outs[1][:, :5]) and not np.allclose(outs[1][:, :5], outs[2][:, :5])


@pytest.mark.parametrize("border", list(fast_fill.BORDER_RULES))
@pytest.mark.parametrize("use_color", [True, False], ids=["joint-bilateral", "nearest-background"])
@pytest.mark.parametrize("case", ["lone-known-pixel", "one-row", "border-top", "border-right", "corner"])
def test_fill_border_rules_match_reference(case, use_color, border):
    """Every rule outside the depth camera's view, fast path against the reference."""
    depth, color = FILL_CASES[case][0](np.random.default_rng(5))
    guide = color if use_color else None
    fast = fill_directional(depth, guide, use_color=use_color, edge_ratio=fast_fill.DEFAULT_EDGE_RATIO,
                            sigma_color=fast_fill.DEFAULT_SIGMA_COLOR,
                            background_bias=fast_fill.DEFAULT_BACKGROUND_BIAS, border=border)
    _assert_fill_matches(fast, ref_fill.fill_directional(depth, guide, use_color=use_color, border=border))


# ---------------------------------------------------------------------------------------------
# circle of confusion


@settings(max_examples=60, deadline=None)
@given(focal_mm=st.floats(1.0, 1000.0), f_number=st.floats(0.5, 64.0), focus_m=st.floats(0.05, 100.0),
       fx=st.floats(10.0, 5000.0), seed=st.integers(0, 2**32 - 1))
def test_coc_matches_reference(focal_mm, f_number, focus_m, fx, seed):
    rng = np.random.default_rng(seed)
    z = np.exp(rng.uniform(np.log(1e-4), np.log(1e4), (8, 9))).astype(np.float32)
    z.flat[:6] = [0.0, np.nan, np.inf, -1.0, focus_m, 1e-30]
    lens = ThinLens(focal_mm, f_number, focus_m)
    fast, ref = lens.signed_coc_px(z, fx), ref_coc.signed_coc_px(z, lens, fx)
    assert fast.dtype == np.float32 and np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, ref, rtol=COC_REL_TOL, atol=1e-30)


@settings(max_examples=30, deadline=None)
@given(focus_m=st.floats(0.1, 20.0), sigma=st.floats(0.01, 2.0), weight=st.sampled_from(["eq1", "eq2"]),
       aperture=st.floats(0.1, 10.0), max_range=st.floats(1.0, 20.0), seed=st.integers(0, 2**32 - 1))
def test_paper_weights_match_reference(focus_m, sigma, weight, aperture, max_range, seed):
    z = np.random.default_rng(seed).uniform(0.0, 25.0, (6, 7)).astype(np.float32)
    z.flat[:4] = [0.0, np.nan, np.inf, focus_m]
    lens = PaperLens(focus_m, sigma=sigma, weight=weight, eq1_aperture=aperture)
    # the fast weights are float32: depth normalised by the range carries a rounding of eps32 * z / range,
    # and eq. 2's slope |d alpha / d u| <= 1 / sigma (u = normalised depth) carries it into alpha
    tol = 1e-6 + 2 * float(np.finfo(np.float32).eps) * (25.0 / max_range + 1.0) / sigma
    np.testing.assert_allclose(lens.alpha(z, max_range), ref_coc.paper_alpha(z, lens, max_range), atol=tol)


# ---------------------------------------------------------------------------------------------
# render


def _untiled(shape) -> TileMap:
    """A tile map with no copy tiles and no uniform tiles: the renderer scatters every pixel."""
    th, tw = -(-shape[0] // 16), -(-shape[1] // 16)
    inf = np.full((th, tw), np.inf, np.float32)
    return TileMap(shape, 16, -inf, inf, np.zeros((th, tw), bool))


def _coc_scene(name, h, w, rng) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    if name == "box":  # a blurred foreground over a blurred background, an in-focus stripe
        c = np.full((h, w), 9.0, np.float32)
        c[h // 4: 3 * h // 4, w // 3: 2 * w // 3] = -20.0
        c[:, -w // 5: -w // 5 + 4] = 0.3
    elif name == "thin":  # one-pixel lines in front of focus
        c = np.full((h, w), 5.0, np.float32)
        c[h // 2, :], c[:, w // 2] = -15.0, -15.0
    elif name == "ramp":  # a slanted plane through the focus plane: every layer, both sides
        c = np.tile(np.linspace(-30, 30, w, dtype=np.float32), (h, 1))
    elif name == "random":  # independent depth per pixel: layers interleave everywhere
        c = rng.uniform(-12, 12, (h, w)).astype(np.float32)
    elif name == "extreme":  # beyond MAX_COC_PX (clamped), NaN, in focus elsewhere
        c = np.full((h, w), 0.2, np.float32)
        c[10:14, 10:14] = -600.0
        c[-8:, -8:] = np.nan
    else:  # "large": one large blur everywhere
        c = np.full((h, w), 40.0, np.float32)
    return c


def _texture(rng, h, w, smooth=1.5):
    return cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), smooth)


def _render_fast(lin, coc, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # CoC clamped to MAX_COC_PX
        return renderer.render_layers_linear(lin, coc, **kwargs)


APERTURES = {"disc": (0, 0.0), "pentagon": (5, 17.0), "octagon": (8, 0.0)}
SCENES = ["box", "thin", "ramp", "random", "extreme", "large"]


@pytest.mark.parametrize("aperture", list(APERTURES))
@pytest.mark.parametrize("scene", SCENES)
def test_exact_scatter_matches_reference(scene, aperture):
    """quality="exact", no tiles, no extension: only table interpolation and float32 accumulation differ."""
    h, w = 48, 56
    rng = np.random.default_rng(SCENES.index(scene))
    lin, coc = _texture(rng, h, w), _coc_scene(scene, h, w, rng)
    blades, rot = APERTURES[aperture]
    out, info = _render_fast(lin, coc, blades=blades, rotation_deg=rot, quality="exact", tiles=_untiled((h, w)),
                             extend_behind=False)
    ref = ref_render.render_layers_linear(lin, coc, blades=blades, rotation_deg=rot, extend_behind_layers=False)
    assert all(layer["scale"] == 1 and layer.get("kernels", 0) == 0 for layer in info["layers"])
    np.testing.assert_allclose(out, ref, atol=RENDER_EXACT_ATOL, rtol=0)


@pytest.mark.parametrize("scene", ["box", "thin", "ramp", "random"])
def test_extension_behind_foreground_matches_reference(scene):
    """Partial occlusion on, smooth colour: differs only by which of equally near layer pixels is continued."""
    h, w = 48, 56
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:h, 0:w]
    lin = np.stack([0.2 + 0.004 * xx, 0.3 + 0.004 * yy, 0.5 + 0.002 * (xx - yy)], axis=-1).astype(np.float32)
    coc = _coc_scene(scene, h, w, rng)
    out, info = _render_fast(lin, coc, quality="exact", tiles=_untiled((h, w)))
    ref = ref_render.render_layers_linear(lin, coc)
    assert scene == "ramp" or any(layer.get("extended") for layer in info["layers"])
    np.testing.assert_allclose(out, ref, atol=RENDER_EXTEND_ATOL, rtol=0)
    assert psnr(out, ref) > 60.0


@pytest.mark.parametrize("quality", list(RENDER_MIN_PSNR_DB))
@pytest.mark.parametrize("scene", ["box", "ramp", "large", "random"])
def test_tiled_and_reduced_resolution_paths_approximate_reference(scene, quality):
    """Default tiles (copy + convolved uniform tiles) and each quality tier's reduced-resolution layers."""
    h, w = 64, 80
    rng = np.random.default_rng(20 + SCENES.index(scene))
    lin, coc = _texture(rng, h, w), _coc_scene(scene, h, w, rng)
    out, info = _render_fast(lin, coc, quality=quality, extend_behind=False)
    ref = ref_render.render_layers_linear(lin, coc, extend_behind_layers=False)
    assert psnr(out, ref) > RENDER_MIN_PSNR_DB[quality], (psnr(out, ref), info["layers"])
    # each layer at the scale the tier's plan gives its lower CoC edge
    plan = plan_render(quality=quality)
    assert all(layer["scale"] == plan.scale(layer["coc_px"][0]) for layer in info["layers"] if layer["blurred"])
    if scene == "large" and quality == "exact":
        assert sum(layer.get("kernels", 0) for layer in info["layers"]) > 0  # the convolution path ran


#: reduced-resolution layers: PSNR (dB, peak 1) against the reference, per threshold
#: (``RenderPlan.reduce_min_coc_px``: a layer runs at 1/s from CoC 2 s times this)
REDUCED_MIN_PSNR_DB = {8.0: 50.0, 4.0: 44.0, 2.0: 36.0}


@pytest.mark.parametrize("threshold", list(REDUCED_MIN_PSNR_DB))
@pytest.mark.parametrize("scene", ["box", "ramp", "large"])
def test_reduced_resolution_layers_approximate_reference(scene, threshold):
    """Every reduction factor, whatever the tiers' thresholds: 1/2 .. 1/16 of the resolution."""
    h, w = 64, 80
    rng = np.random.default_rng(20 + SCENES.index(scene))
    lin, coc = _texture(rng, h, w), _coc_scene(scene, h, w, rng)
    plan = dataclasses.replace(plan_render(), reduce_min_coc_px=threshold)
    out, info = _render_fast(lin, coc, plan=plan, extend_behind=False)
    ref = ref_render.render_layers_linear(lin, coc, extend_behind_layers=False)
    assert psnr(out, ref) > REDUCED_MIN_PSNR_DB[threshold], (psnr(out, ref), info["layers"])
    assert any(layer["scale"] > 1 for layer in info["layers"])  # the reduced path ran


@pytest.mark.parametrize("quality", list(RENDER_MIN_PSNR_DB))
def test_every_path_conserves_a_point_source_like_reference(quality):
    h, w = 64, 80
    lin = np.zeros((h, w, 1), np.float32)
    lin[31, 40] = 1.0
    coc = np.full((h, w), 24.0, np.float32)
    out, _ = _render_fast(lin, coc, quality=quality)
    ref = ref_render.render_layers_linear(lin, coc)
    assert ref.sum() == pytest.approx(1.0, rel=1e-9)
    assert out.sum() == pytest.approx(ref.sum(), rel=1e-3)


def test_copy_tiles_are_the_input_in_fast_path_and_reference():
    """Copy tiles are exact by design: the reference also returns the input there (no blur reaches them)."""
    h, w = 64, 80
    rng = np.random.default_rng(9)
    lin, coc = _texture(rng, h, w), np.full((h, w), 0.4, np.float32)
    coc[40:, 50:] = -14.0  # a blurred foreground corner; its reach keeps the tiles around it from being copied
    coc[:20, :30] = 6.0
    tiles = classify_tiles(coc)
    assert tiles.copy.any() and not tiles.copy.all()
    mask = tiles.pixel_mask(tiles.copy)
    out, _ = _render_fast(lin, coc, quality="exact", tiles=tiles)
    ref = ref_render.render_layers_linear(lin, coc)
    np.testing.assert_array_equal(out[mask], lin[mask])
    np.testing.assert_array_equal(ref[mask], lin[mask].astype(np.float64))
    np.testing.assert_allclose(out, ref, atol=RENDER_EXTEND_ATOL)


@pytest.mark.parametrize("blades", [0, 6])
def test_render_physical_uint8_matches_reference(blades):
    """The whole physical renderer on an sRGB uint8 frame: decoding, tiles, scatter, encoding (within 1 code)."""
    h, w = 48, 64
    rng = np.random.default_rng(4)
    color = (_texture(rng, h, w) * 255).round().astype(np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    depth = (1.2 + 0.045 * xx).astype(np.float32)  # a plane slanting away from the focus plane
    lens = ThinLens(50.0, 1.4, 1.2, aperture_blades=blades, aperture_rotation_deg=10.0)
    out, info = renderer.render_physical(color, depth, lens, fx=600.0, quality="exact")
    ref = ref_render.render_physical(color, depth, lens, fx=600.0)
    assert len(info["layers"]) > 5
    assert np.abs(out.astype(np.float64) - ref * 255).max() <= 1.0


@pytest.mark.parametrize("lens", [PaperLens(1.5), PaperLens(1.5, weight="eq1", eq1_aperture=3.0),
                                  PaperLens(2.0, sigma=0.05, blur_sigma_px=2.3, max_range_m=4.0)],
                         ids=["eq2", "eq1", "narrow"])
@pytest.mark.parametrize("grey", [False, True], ids=["rgb", "grey"])
def test_paper_method_matches_reference(lens, grey):
    rng = np.random.default_rng(2)
    h, w = 40, 48
    color = rng.random((h, w) if grey else (h, w, 3)).astype(np.float32)
    depth = rng.uniform(0.3, 6.0, (h, w)).astype(np.float32)
    depth[0, :3] = [0.0, np.nan, np.inf]
    out, _ = renderer.render_paper(color, depth, lens, max_range_m=10.0)
    ref = ref_render.render_paper(color, depth, lens, max_range_m=10.0)
    np.testing.assert_allclose(out, ref.reshape(out.shape), atol=PAPER_ATOL, rtol=0)


# ---------------------------------------------------------------------------------------------
# the references themselves against independent answers


@pytest.mark.parametrize("blades, rotation", [(0, 0.0), (3, 0.0), (5, 0.4), (8, 1.0), (64, 0.0)])
@pytest.mark.parametrize("r", [0.5, 1.7, 6.3])
def test_reference_footprint_carries_the_aperture_area(blades, rotation, r):
    k = ref_render.footprint(r, blades, rotation)
    assert k.sum() == pytest.approx(ref_render.unit_area(blades) * r * r, rel=1e-12)
    table = renderer.aperture_table(blades, rotation)  # the fast path's numerical integration
    assert table[0, -1] - table[0, 0] == pytest.approx(ref_render.unit_area(blades), rel=1e-6)


def test_reference_gaussian_is_opencvs():
    img = np.random.default_rng(0).random((30, 37, 3)).astype(np.float32)
    for sigma in (0.7, 2.0, 4.0):
        k = 2 * int(math.ceil(3 * sigma)) + 1
        cvb = cv2.GaussianBlur(img, (k, k), sigma, borderType=cv2.BORDER_REFLECT)
        np.testing.assert_allclose(ref_render.gaussian_blur(img, sigma), cvb, atol=2e-6)


def test_reference_registration_of_a_fronto_parallel_plane_is_its_depth():
    """Analytic check of the reference: a plane z = 2 m seen by a pure-translation rig stays at 2 m."""
    depth_i = Intrinsics(40, 30, 36.0, 36.0, 19.5, 14.5)
    color_i = Intrinsics(48, 36, 44.0, 44.0, 23.5, 17.5)
    T = np.eye(4)
    T[0, 3] = -0.05
    ref = ref_register.reproject_depth(np.full((30, 40), 2.0, np.float32), Rig(color_i, depth_i, T))
    assert np.count_nonzero(ref) > 0.7 * ref.size
    np.testing.assert_allclose(ref[ref > 0], 2.0, rtol=1e-12)


def test_reference_linear_light_round_trip():
    color = np.random.default_rng(1).integers(0, 256, (8, 9, 3), dtype=np.uint8)
    lens = ThinLens(50.0, 8.0, 2.0)
    out = ref_render.render_physical(color, np.full((8, 9), 2.0, np.float32), lens, fx=50.0)
    np.testing.assert_allclose(out, color / 255.0, atol=1e-7)  # in focus everywhere: the input
    assert decode_to_linear(color).dtype == np.float32


class TestFrameBorder:
    """What lies beyond the frame is continued from its edge (pcdof.stages.render.border)."""

    @pytest.mark.parametrize("module", ["renderer", "reference"])
    def test_a_pattern_running_out_of_the_frame_blurs_as_if_it_went_on(self, module):
        # rows of one colour each, running out at the top and bottom: continued from the edge, the frame renders
        # as the crop of a taller frame whose extra rows repeat the edge rows (rendered here explicitly), away from
        # the left and right edges (beyond which the continuation mixes the rows)
        rng = np.random.default_rng(3)
        rows = (rng.random((30, 1, 3)) < 0.5).astype(np.uint8) * 255
        color = np.repeat(rows, 40, axis=1)
        depth = np.full((30, 40), 4.0, np.float32)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        fx = 400.0
        coc = lens.signed_coc_px(depth, fx)
        assert np.abs(coc).max() > 8  # a blur that reaches well past the border rows
        m = 20
        tall = np.pad(decode_to_linear(color), ((m, m), (m, m), (0, 0)), mode="edge")
        want, _ = renderer.render_layers_linear(tall, np.pad(coc, m, mode="edge"), quality="exact")
        want = want[m:-m, m:-m][:, 12:28]
        if module == "renderer":
            got = decode_to_linear(renderer.render_physical(color, depth, lens, fx=fx, quality="exact")[0])[:, 12:28]
            np.testing.assert_allclose(got, want, atol=5e-3)  # half an 8-bit code near white
        else:
            got = srgb_to_linear(ref_render.render_physical(color, depth, lens, fx=fx))[:, 12:28]
            np.testing.assert_allclose(got, want, atol=5e-3)  # the fast renderer and the reference agree to that
        # without the continuation the border rows differ by several codes
        inside, _ = renderer.render_layers_linear(decode_to_linear(color), coc, quality="exact")
        assert np.abs(inside[0, 12:28] - want[0]).max() > 0.01

    def test_the_continuation_is_the_mean_along_the_edge(self):
        from pcdof.stages.render.border import continue_border

        a = np.random.default_rng(0).random((7, 9, 3)).astype(np.float32)
        for p in (0, 1, 3, 12):
            got = continue_border(a, p)
            assert got.shape == (7 + 2 * p, 9 + 2 * p, 3)
            np.testing.assert_array_equal(got[p:p + 7, p:p + 9], a)
            if p:
                np.testing.assert_allclose(got, ref_render._continued(a, p), atol=1e-6)
                bright = continue_border(a * 3, p, most=1.0)
                np.testing.assert_allclose(bright, ref_render._continued(a * 3, p, 1.0), atol=1e-6)
                np.testing.assert_array_equal(bright[p:p + 7, p:p + 9], a * 3)  # the frame itself is not capped
                assert bright[:p].max() <= 1.0 and bright[:, :p].max() <= 1.0
            if p >= 2:
                np.testing.assert_allclose(got[p - 2, p + 4], a[0, 2:7].mean(axis=0), atol=1e-6)  # 2 rows up: 5 px

    def test_edge_continuation_is_the_windowed_mean_of_the_running_sums(self):
        """Line k at i: the float64 running sums' difference over the edge's pixels i - k .. i + k (cut at its ends),
        divided by their count and rounded to float32, bit for bit; and that is their mean."""
        from pcdof.stages.render.border import edge_continuation

        rng = np.random.default_rng(5)
        for n, pad, channels in ((1, 4, 3), (9, 3, 3), (9, 12, 1), (40, 7, 3)):
            edge = (rng.random((n, channels)) * 40).astype(np.float32)
            sums = np.concatenate([np.zeros((1, channels)), np.cumsum(edge, axis=0, dtype=np.float64)])
            want = np.empty((pad, n, channels), np.float32)
            for k in range(1, pad + 1):
                for i in range(n):
                    lo, hi = max(i - k, 0), min(i + k + 1, n)
                    want[k - 1, i] = (sums[hi] - sums[lo]) / (hi - lo)
                    np.testing.assert_allclose(want[k - 1, i], edge[lo:hi].mean(axis=0), rtol=1e-5)
            np.testing.assert_array_equal(edge_continuation(edge, pad), want)
            np.testing.assert_array_equal(edge_continuation(edge[:, 0], pad), want[:, :, 0])  # one channel, (N,)

    def test_continue_border_is_each_edges_continuation_bit_for_bit(self):
        """The compiled margin (a side a task, on two threads where the frame is large) is the plain composition of
        :func:`edge_continuation`: rows above and below, capped, then the columns left and right of them, capped."""
        from pcdof.stages.render.border import continue_border, edge_continuation

        rng = np.random.default_rng(8)
        for shape, p, most in (((300, 260, 3), 40, 1.0), ((5, 300, 1), 9, None), ((256, 300, 4), 3, 0.5),
                               ((2, 3, 3), 7, None), ((40, 30, 3), 25, 1.2)):
            a = (rng.random(shape) * 2).astype(np.float32)
            h, w = shape[:2]
            want = np.zeros((h + 2 * p, w + 2 * p, shape[2]), np.float32)
            want[p:p + h, p:p + w] = a
            want[:p, p:p + w] = edge_continuation(a[0], p)[::-1]
            want[p + h:, p:p + w] = edge_continuation(a[-1], p)
            if most is not None:
                for part in (want[:p], want[p + h:]):
                    np.minimum(part, np.float32(most), out=part)
            want[:, :p] = edge_continuation(want[:, p], p)[::-1].transpose(1, 0, 2)
            want[:, p + w:] = edge_continuation(want[:, p + w - 1], p).transpose(1, 0, 2)
            if most is not None:
                for part in (want[:, :p], want[:, p + w:]):
                    np.minimum(part, np.float32(most), out=part)
            np.testing.assert_array_equal(continue_border(a, p, most=most), want)

    def test_replicate_border(self):
        from pcdof.stages.render.border import border_px, replicate_border

        a = np.arange(12, dtype=np.float32).reshape(3, 4)
        np.testing.assert_array_equal(replicate_border(a, 2), np.pad(a, 2, mode="edge"))
        rgb = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
        np.testing.assert_array_equal(replicate_border(rgb, 1), np.pad(rgb, ((1, 1), (1, 1), (0, 0)), mode="edge"))
        one = np.ones((2, 3, 1), np.float32)
        assert replicate_border(one, 2).shape == (6, 7, 1)
        assert border_px(0.0) == 2 and border_px(9.0) == 7

    @pytest.mark.parametrize("shape", [(9, 11, 3), (9, 11), (40, 6, 1), (6, 40, 3)])
    def test_interior_in_place_is_the_interior_without_a_copy(self, shape):
        from pcdof.stages.render.border import interior, interior_in_place

        for b in (0, 1, 2):
            a = np.random.default_rng(b).random(shape).astype(np.float32)
            want = interior(a, b).copy()
            got = interior_in_place(a, b)
            assert got.flags.c_contiguous and np.shares_memory(got, a)
            np.testing.assert_array_equal(got, want)

    def test_widened_coc_given_as_the_frames_is_the_same_render(self):
        from pcdof.stages.render.border import continue_border, replicate_border

        rng = np.random.default_rng(4)
        lin = continue_border(rng.random((30, 40, 3)).astype(np.float32), 6)
        coc = np.where(rng.random((30, 40)) < 0.5, 9.0, -4.0).astype(np.float32)
        coc[3, 4] = np.nan
        edges = renderer.classify.frame_edges(coc)  # the frame's (the default of the second call)
        want, _ = renderer.render_layers_linear(lin, replicate_border(coc, 6), quality="exact", edges=edges)
        got, _ = renderer.render_layers_linear(lin, coc, quality="exact", coc_border_px=6)
        np.testing.assert_array_equal(got, want)
        for bad, border in ((coc, 5), (coc, -1), (coc, True), (replicate_border(coc, 6), 6), (coc[:, :-1], 6)):
            with pytest.raises(InputError, match="signed_coc must be"):
                renderer.render_layers_linear(lin, bad, coc_border_px=border)


class TestBorderAboveWhite:
    def test_light_above_white_is_continued_only_without_a_limit(self):
        lin = np.full((24, 32, 3), 0.2, np.float32)
        lin[0, 14:18] = 20.0  # a lamp cut by the top edge
        depth = np.full((24, 32), 4.0, np.float32)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        fx = float(9.0 / (lens.aperture_m * 0.75))
        assert abs(float(lens.coc_px(depth, fx).max()) - 9.0) < 1e-3
        free = renderer.render_physical(lin, depth, lens, fx=fx, linear=True, quality="exact")[0]
        capped = renderer.render_physical(lin, depth, lens, fx=fx, linear=True, quality="exact", border_most=1.0)[0]
        assert capped[:3, 10:22].sum() < 0.8 * free[:3, 10:22].sum()  # the lamp is not repeated above the frame
        np.testing.assert_allclose(capped[12:, :], free[12:, :], atol=1e-6)  # out of the margin's reach: the same

    def test_the_pipeline_limits_it_where_the_highlights_stage_estimated_it(self, monkeypatch):
        import pcdof.stages.render as render_pkg
        from pcdof.camera import RGBDFrame
        from pcdof.pipeline import run as run_pipeline
        from pcdof.synth.rig import pinhole

        seen = []
        real = render_pkg.METHODS["physical"]

        def spy(*args, **kwargs):
            seen.append(kwargs.get("border_most"))
            return real(*args, **kwargs)

        monkeypatch.setitem(render_pkg.METHODS, "physical", spy)  # what the render stage calls
        color = np.full((40, 60, 3), 90, np.uint8)
        color[0:3, 20:26] = 255  # clipped: the highlights stage estimates light above white there
        rig = Rig.registered(pinhole((60, 40), 60.0), max_range_m=10.0)
        depth = np.full((40, 60), 4.0, np.float32)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        frame = RGBDFrame(color, depth, rig)
        run_pipeline(frame, lens)
        run_pipeline(frame, lens, highlights="off")
        assert seen == [1.0, None]

    def test_the_highlights_stage_hands_its_estimate_over_widened_and_keeps_no_other_copy(self, monkeypatch):
        """The estimated radiance reaches the render widened by the render's border (so the render copies nothing),
        and the colour that the stage's early half decoded is not kept through the render."""
        import gc

        import pcdof.stages.render as render_pkg
        from pcdof.camera import RGBDFrame
        from pcdof.pipeline import run as run_pipeline
        from pcdof.stages.highlights import ClippedColor
        from pcdof.stages.render.border import border_px
        from pcdof.synth.rig import pinhole

        seen = []
        real = render_pkg.METHODS["physical"]

        def spy(color, depth_m, *args, **kwargs):
            gc.collect()
            alive = sum(type(o) is ClippedColor for o in gc.get_objects())  # type(): a dead weak proxy raises on isinstance
            seen.append((color.shape, depth_m.shape, kwargs.get("source_border_px"), alive))
            return real(color, depth_m, *args, **kwargs)

        monkeypatch.setitem(render_pkg.METHODS, "physical", spy)  # what the render stage calls
        color = np.full((40, 60, 3), 90, np.uint8)
        color[0:3, 20:26] = 255
        rig = Rig.registered(pinhole((60, 40), 60.0), max_range_m=10.0)
        depth = np.full((40, 60), 4.0, np.float32)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        got = run_pipeline(RGBDFrame(color, depth, rig), lens)
        want = run_pipeline(RGBDFrame(color, depth, rig), lens, highlights="off")
        b = border_px(float(got.coc_px.max()))
        assert seen[0] == ((40 + 2 * b, 60 + 2 * b, 3), (40, 60), b, 0)
        assert seen[1] == ((40, 60, 3), (40, 60), 0, 0)
        assert got.image.shape == want.image.shape == color.shape


class TestColourGivenWidened:
    """``render_image(..., source_border_px=b)``: a colour whose border is continued already renders as its frame."""

    @staticmethod
    def _scene(seed):
        rng = np.random.default_rng(seed)
        lin = rng.uniform(0.0, 1.0, (30, 44, 3)).astype(np.float32)
        lin[0, 10:14] = 6.0  # light above white at the edge: capped beyond it
        depth = rng.uniform(0.8, 6.0, (30, 44)).astype(np.float32)
        depth[8:20, 12:30] = 1.0
        return lin, depth, ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_the_same_bits_as_the_frame_continued_by_the_render(self, seed):
        from pcdof.stages.render import render_image
        from pcdof.stages.render.border import border_px, continue_border

        lin, depth, lens = self._scene(seed)
        fx = 300.0
        want, _ = render_image(lin, depth, lens, fx=fx, linear=True, quality="exact", border_most=1.0)
        pad = border_px(float(lens.coc_px(depth, fx).max()))
        for b in (pad, pad + 3, pad - 1, 1):  # the render's own border is read as it is; any other is cut and redone
            wide = continue_border(lin, b, most=1.0)
            got, info = render_image(wide, depth, lens, fx=fx, linear=True, quality="exact", border_most=1.0,
                                     source_border_px=b)
            assert got.shape == lin.shape and info["border_px"] == pad
            np.testing.assert_array_equal(got, want)
        paper, _ = render_image(lin, depth, lens, fx=fx, method="paper", linear=True)
        got, _ = render_image(continue_border(lin, 5), depth, lens, fx=fx, method="paper", linear=True,
                              source_border_px=5)
        np.testing.assert_array_equal(got, paper)

    def test_nothing_to_blur_returns_the_frame(self):
        from pcdof.stages.render import render_image
        from pcdof.stages.render.border import continue_border

        lin, depth, lens = self._scene(3)
        depth[:] = lens.focus_distance_m
        got, info = render_image(continue_border(lin, 4), depth, lens, fx=300.0, linear=True, source_border_px=4)
        assert info["skipped"]
        np.testing.assert_array_equal(got, lin)

    def test_bad_borders_are_one_line(self):
        from pcdof.stages.render import render_image

        lin, depth, lens = self._scene(4)
        for bad in (-1, True, 1.5, "2", None):
            with pytest.raises(InputError, match="source_border_px must be an int >= 0"):
                render_image(lin, depth, lens, fx=300.0, linear=True, source_border_px=bad)
        with pytest.raises(InputError, match=r"depth_m must be \(H, W\) = \(26, 40\) \(the colour's \(30, 44\) less "
                                             r"its border of 2 px\)"):
            render_image(lin, depth, lens, fx=300.0, linear=True, source_border_px=2)
        for render in (renderer.render_physical, renderer.render_paper):  # the methods themselves check it too
            with pytest.raises(InputError, match="source_border_px must be an int >= 0"):
                render(lin, depth, lens, fx=300.0, linear=True, source_border_px=-2)
            with pytest.raises(InputError, match="depth_m must be"):
                render(lin, depth, lens, fx=300.0, linear=True, source_border_px=3)


class TestRenderPhysicalArguments:
    def test_border_most_is_checked(self):
        color = np.zeros((8, 9, 3), np.uint8)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        for bad in (0.0, -1.0, float("nan"), float("inf"), True, "1"):
            with pytest.raises(InputError, match="border_most must be None or a finite number > 0"):
                renderer.render_physical(color, np.full((8, 9), 4.0, np.float32), lens, fx=400.0, border_most=bad)

    def test_unknown_coc_is_in_focus(self):
        color = np.random.default_rng(2).integers(0, 256, (8, 9, 3), dtype=np.uint8)
        lens = ThinLens(focal_length_mm=50, f_number=1.4, focus_distance_m=1.0)
        depth = np.full((8, 9), 4.0, np.float32)
        out, info = renderer.render_physical(color, depth, lens, fx=400.0, signed_coc=np.full((8, 9), np.nan, np.float32))
        assert info["skipped"] and np.array_equal(out, color)
        coc = lens.signed_coc_px(depth, 400.0)
        coc[0, :3] = np.nan
        out, info = renderer.render_physical(color, depth, lens, fx=400.0, signed_coc=coc, quality="exact")
        assert not info["skipped"] and info["border_px"] == border_px_of(coc)


def border_px_of(coc):
    from pcdof.stages.render.border import border_px

    return border_px(float(np.nanmax(np.abs(coc))))
