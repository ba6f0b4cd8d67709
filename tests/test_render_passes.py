"""The renderer's per-frame passes against their definitions written plainly in numpy.

Each pass (layer classification, the reduced grid's cell means, the tiles' window ranges) is a kernel written
for speed (statistics per run of equal keys, scalar accumulators, a separable window); these tests state what
each computes, pixel by pixel, and compare bits on random and adversarial inputs (NaN, infinities, one row,
one column, long runs and single pixels).
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pcdof.stages.render as renderer
from pcdof.stages.render import tiles
from pcdof.errors import InputError
from pcdof.lens import MAX_COC_PX


def _coc_map(rng, h, w, kind):
    """A signed CoC map (H, W) float32: smooth noise, runs of one value, or a few levels; NaN and inf sprinkled."""
    if kind == "noise":
        raw = rng.normal(0, 20, (h, w))
    elif kind == "runs":
        raw = np.repeat(rng.normal(0, 20, (h, (w + 7) // 8)), 8, axis=1)[:, :w]
    else:
        raw = rng.integers(-3, 4, (h, w)) * 5.3
    raw = raw.astype(np.float32)
    raw[rng.random((h, w)) < 0.05] = np.nan
    raw[rng.random((h, w)) < 0.02] = np.inf
    raw[rng.random((h, w)) < 0.02] = -np.inf
    return raw


def _classify_plainly(raw, edges=None):
    """What _classify_layers returns, from its docstring, with numpy (*edges*: (2, n), front then back)."""
    edges = np.stack([renderer.LAYER_EDGES_PX] * 2) if edges is None else edges
    coc = np.clip(np.nan_to_num(raw, nan=0.0, posinf=np.inf, neginf=-np.inf), -MAX_COC_PX, MAX_COC_PX)
    coc = coc.astype(np.float32)
    a = np.abs(coc)
    front = np.searchsorted(edges[0], a.astype(np.float64), side="right")  # edges[j-1] <= |c| < edges[j]
    back = np.searchsorted(edges[1], a.astype(np.float64), side="right")
    key = np.where(coc < 0, -front, back)
    keys = np.unique(key)
    layer = np.searchsorted(keys, key).astype(np.int8)
    count = np.array([np.count_nonzero(key == k) for k in keys], np.int64)
    r_max = np.array([a[key == k].max() * np.float32(0.5) for k in keys], np.float32)
    boxes = []
    for k in keys:
        ys, xs = np.nonzero(key == k)
        boxes.append((ys.min(), ys.max(), xs.min(), xs.max()))
    return coc, a * np.float32(0.5), layer, keys.astype(np.int64), count, r_max, np.array(boxes, np.int64)


class TestClassifyLayers:
    @pytest.mark.parametrize("kind", ["noise", "runs", "levels"])
    @pytest.mark.parametrize("shape", [(1, 1), (1, 57), (61, 1), (37, 83), (130, 70)])
    def test_matches_the_definition(self, kind, shape):
        rng = np.random.default_rng(zlib.crc32(repr((kind, shape)).encode()))  # the same frames every run
        raw = _coc_map(rng, *shape, kind)
        got = renderer.classify.classify_layers(raw, MAX_COC_PX, renderer.LAYER_EDGES_PX)
        for name, g, e in zip(("coc", "radius", "layer", "keys", "count", "r_max", "box"), got,
                              _classify_plainly(raw)):
            assert g.dtype == e.dtype, name
            np.testing.assert_array_equal(g, e, err_msg=name)

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 80), w=st.integers(1, 80),
           kind=st.sampled_from(["noise", "runs", "levels"]))
    def test_property_any_map(self, seed, h, w, kind):
        raw = _coc_map(np.random.default_rng(seed), h, w, kind)
        got = renderer.classify.classify_layers(raw, MAX_COC_PX, renderer.LAYER_EDGES_PX)
        for g, e in zip(got, _classify_plainly(raw)):
            np.testing.assert_array_equal(g, e)

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 80), w=st.integers(1, 80),
           kind=st.sampled_from(["noise", "runs", "levels"]))
    def test_property_the_frames_edges_on_each_side(self, seed, h, w, kind):
        rng = np.random.default_rng(seed)
        raw = _coc_map(rng, h, w, kind)
        # values on the nominal edges and on the steps beside them: what the lookup per 1/8 px must get right
        on = rng.random((h, w)) < 0.3
        raw[on] = (rng.choice(renderer.LAYER_EDGES_PX[:-1], on.sum()) + rng.integers(-2, 3, on.sum()) / 8.0) * \
            rng.choice([-1, 1], on.sum())
        edges = renderer.classify.frame_edges(raw)
        got = renderer.classify.classify_layers(raw, MAX_COC_PX, edges)
        for g, e in zip(got, _classify_plainly(raw, edges)):
            np.testing.assert_array_equal(g, e)

    def test_edges_off_the_eighth_pixel_grid_are_refused(self):
        edges = renderer.LAYER_EDGES_PX.copy()
        edges[3] = 3.1
        with pytest.raises(InputError, match="edges must be multiples of 1/8 px"):
            renderer.classify.classify_layers(np.zeros((4, 4), np.float32), MAX_COC_PX, edges)


class TestFrameEdges:
    """The frame's layer edges: the nominal ones moved off the blur sizes the frame is full of."""

    def test_a_map_with_nothing_near_an_edge_keeps_the_nominal_edges(self):
        rng = np.random.default_rng(0)
        edges = renderer.LAYER_EDGES_PX
        mids = np.sqrt(edges[2:-2] * edges[3:-1])  # half-way between edges from 2 px (the bands' least width
        # is 1/4 px: no value between 1.5 and 2 is that far from both)
        raw = (rng.choice(mids, (60, 80)) * rng.choice([-1, 1], (60, 80))).astype(np.float32)
        raw[0, :5] = [np.nan, np.inf, -np.inf, 0.0, 0.3]
        edges = renderer.classify.frame_edges(raw)
        np.testing.assert_array_equal(edges, np.stack([renderer.LAYER_EDGES_PX] * 2))

    @pytest.mark.parametrize("ramp", ["linear", "log"])
    def test_a_slanted_surface_leaves_the_edges_in_place(self, ramp):
        """A floor whose blur runs smoothly through the edges has no valley to move them to (the thinnest part of
        its histogram would be noise, or the narrowest band where the density is flat)."""
        h, w = 2400, 100
        t = np.linspace(0, 1, h)[:, None] * np.ones((1, w))
        c = 1 + 59 * t if ramp == "linear" else np.exp(np.log(60) * t)  # 1 to 60 px: edges above it see nothing
        raw = (c * (1 + np.random.default_rng(1).normal(0, 0.002, (h, w)))).astype(np.float32)
        edges = renderer.classify.frame_edges(np.concatenate([raw, -raw]))
        np.testing.assert_array_equal(edges, np.stack([renderer.LAYER_EDGES_PX] * 2))

    @pytest.mark.parametrize("edge", [4.0, 6.0, 16.0, 64.0, 181.0])  # (an edge up to 3 px moves less than a band)
    @pytest.mark.parametrize("side", [-1, 1])
    def test_a_wall_on_an_edge_is_one_layer(self, edge, side):
        rng = np.random.default_rng(int(edge))
        wall = (edge * (1 + rng.uniform(-0.01, 0.01, (64, 96)))).astype(np.float32)  # a wall whose blur is on the edge
        raw = side * wall
        raw[:, :20] = -side * 5.0  # something on the other side, far from this edge
        edges = renderer.classify.frame_edges(raw)
        mine, other = edges[(side + 1) // 2], edges[(1 - side) // 2]
        keys = np.unique(renderer.classify.classify_layers(raw, MAX_COC_PX, edges)[3])
        assert np.count_nonzero(np.sign(keys) == side) == 1  # the whole wall in one layer
        k = list(renderer.LAYER_EDGES_PX).index(edge)
        assert mine[k] != edge and abs(np.log(mine[k] / edge)) <= np.log(renderer.classify.EDGE_MOVE) + 1e-12
        assert other[k] == edge  # the other side's edges are the other side's pixels' affair

    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), kind=st.sampled_from(["noise", "runs", "levels"]))
    def test_property_edges_stay_in_order_near_their_place_on_the_grid(self, seed, kind):
        raw = _coc_map(np.random.default_rng(seed), 50, 70, kind)
        edges = renderer.classify.frame_edges(raw, sample=1)
        nominal = renderer.LAYER_EDGES_PX
        for side in edges:
            assert side[0] == nominal[0] and side[-1] == np.inf
            assert np.all(np.diff(side) > 0)
            np.testing.assert_array_equal(side[:-1] * 8, np.round(side[:-1] * 8))
            ratio = np.abs(np.log(side[1:-1] / nominal[1:-1]))
            assert np.all(ratio <= np.log(renderer.classify.EDGE_MOVE) + 1e-12)

    def test_edges_given_to_the_render_are_checked(self):
        lin = np.zeros((8, 8, 3), np.float32)
        coc = np.full((8, 8), 5.0, np.float32)
        nominal = renderer.LAYER_EDGES_PX
        out, _ = renderer.render_layers_linear(lin, coc, edges=nominal)  # (n,): both sides
        assert out.shape == lin.shape
        off_grid, unsorted, first = nominal.copy(), nominal.copy(), nominal.copy()
        off_grid[4] = 4.01
        unsorted[4], unsorted[5] = 6.0, 4.0
        first[0] = 0.5
        for bad in (off_grid, unsorted, first, nominal[:-1], np.stack([nominal] * 3), "edges"):
            with pytest.raises(InputError, match="edges must be"):
                renderer.render_layers_linear(lin, coc, edges=bad)

    def test_non_maps_are_refused(self):
        with pytest.raises(InputError, match="signed_coc must be"):
            renderer.classify.frame_edges(np.zeros(5, np.float32))


def _reduce_plainly(lin, radius, member, s):
    """Member-weighted cell means of colour and radius, and the member share, cell by cell, pixels in raster
    order with float64 sums (as the kernel's docstring states)."""
    h, w, nc = lin.shape
    hs, ws = -(-h // s), -(-w // s)
    lin_s = np.zeros((hs, ws, nc), np.float32)
    r_s = np.zeros((hs, ws), np.float32)
    m_s = np.zeros((hs, ws), np.float32)
    for cy in range(hs):
        for cx in range(ws):
            cell = (slice(cy * s, (cy + 1) * s), slice(cx * s, (cx + 1) * s))
            m = 0.0
            r = 0.0
            acc = np.zeros(nc, np.float64)
            for y, x in zip(*np.nonzero(member[cell])):
                m += 1.0
                r += float(radius[cell][y, x])
                acc += lin[cell][y, x].astype(np.float64)
            if m > 0:
                inv = 1.0 / m  # float64 products, rounded once to float32
                r_s[cy, cx] = r * inv
                lin_s[cy, cx] = acc * inv
            m_s[cy, cx] = float(m) * (1.0 / (s * s))
    return lin_s, r_s, m_s


class TestReduceCells:
    @pytest.mark.parametrize("nc", [1, 2, 3])
    @pytest.mark.parametrize("s", [2, 4, 8])
    def test_matches_the_definition(self, nc, s):
        rng = np.random.default_rng(10 * nc + s)
        h, w = 37, 53  # cells cut by both borders
        lin = rng.random((h, w, nc)).astype(np.float32) * 3
        radius = rng.random((h, w)).astype(np.float32) * 10
        member = rng.random((h, w)) < 0.6
        member[:s, :s] = False  # an empty cell
        for g, e in zip(renderer.grids.reduce_cells(lin, radius, member, s), _reduce_plainly(lin, radius, member, s)):
            assert g.dtype == e.dtype
            np.testing.assert_array_equal(g, e)


def _window_plainly(lo, hi, k):
    th, tw = lo.shape
    wlo, whi = np.empty_like(lo), np.empty_like(hi)
    for ty in range(th):
        for tx in range(tw):
            win = (slice(max(0, ty - k), ty + k + 1), slice(max(0, tx - k), tx + k + 1))
            wlo[ty, tx], whi[ty, tx] = lo[win].min(), hi[win].max()
    return wlo, whi


class TestWindowRange:
    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(seed=st.integers(0, 2 ** 32 - 1), th=st.integers(1, 30), tw=st.integers(1, 30), k=st.integers(0, 8))
    def test_min_and_max_over_the_window(self, seed, th, tw, k):
        rng = np.random.default_rng(seed)
        lo = rng.normal(0, 10, (th, tw)).astype(np.float32)
        hi = lo + rng.random((th, tw)).astype(np.float32)
        lo[rng.random((th, tw)) < 0.05] = -np.inf
        hi[rng.random((th, tw)) < 0.05] = np.inf
        for g, e in zip(tiles.window_range(lo, hi, k), _window_plainly(lo, hi, k)):
            assert g.dtype == e.dtype
            np.testing.assert_array_equal(g, e)


class TestSerialIf:
    def test_one_thread_inside_and_the_count_restored_after(self):
        import numba

        before = numba.get_num_threads()
        with renderer.serial.serial_if(True):
            assert numba.get_num_threads() == 1
        assert numba.get_num_threads() == before
        with renderer.serial.serial_if(False):
            assert numba.get_num_threads() == before
        with pytest.raises(ValueError), renderer.serial.serial_if(True):
            raise ValueError("restored all the same")
        assert numba.get_num_threads() == before

    def test_a_frame_renders_alike_with_small_kernels_on_one_thread_or_not(self, monkeypatch):
        """The thresholds only choose threads: every kernel's output is the same whatever the threads."""
        rng = np.random.default_rng(4)
        lin = rng.random((96, 128, 3)).astype(np.float32)
        coc = np.repeat(np.linspace(-14, 20, 128, dtype=np.float32)[None], 96, axis=0)
        coc[:, 60:70] = 0.2
        serial, _ = renderer.render_layers_linear(lin, coc)
        monkeypatch.setattr(renderer.serial, "SERIAL_BELOW_PX", 0)
        monkeypatch.setattr(renderer.serial, "SERIAL_BELOW_STRIPS", 0)
        parallel, _ = renderer.render_layers_linear(lin, coc)
        np.testing.assert_array_equal(serial, parallel)


class TestConvolveRuns:
    def test_any_number_of_runs_gives_the_same_bits(self):
        """The convolution's rows cut into 1 .. 7 runs (each summing its ring of source rows afresh)."""
        rng = np.random.default_rng(11)
        hs, ws = 140, 90
        lin = rng.random((hs, ws, 3)).astype(np.float32)
        share = np.ones((hs, ws), np.float32)
        radius = np.full((hs, ws), 3.0, np.float32)
        fast = np.ones((hs, ws), bool)
        fast[:, :10] = False
        bins, groups = renderer.uniform.uniform_plan(fast, radius)
        (b, r, (ya, yb, xa, xb)), = groups
        table = renderer.aperture_table(0)
        taps, weights = renderer.uniform.footprint_taps(renderer.uniform.footprint_kernel(r, True, table))
        outs = []
        for tasks in range(1, 8):
            buf = np.zeros((hs, ws, 4), np.float32)
            renderer.uniform.convolve_rows(lin, share, bins, b, ya, yb, xa, xb, taps, weights, tasks, buf)
            outs.append(buf)
        assert outs[0][ya:yb, xa:xb].any()
        for buf in outs[1:]:
            np.testing.assert_array_equal(buf, outs[0])


class TestReduceCellsInPlace:
    """The reduction of a box of the frame with the extension read through source indices equals the reduction
    of the extended copy, bit for bit (what :func:`reduced_grid` relies on to copy nothing)."""

    @pytest.mark.parametrize("s", [2, 4])
    def test_source_indices_read_as_the_extended_copy(self, s):
        rng = np.random.default_rng(s)
        h, w, nc = 45, 61, 3
        lin = rng.random((h, w, nc)).astype(np.float32) * 3
        radius = rng.random((h, w)).astype(np.float32) * 10
        box = (slice(6, 39), slice(9, 52))  # cells cut by the box's border
        member = rng.random((33, 43)) < 0.4
        hidden = ~member & (rng.random(member.shape) < 0.5)
        dst, src = renderer.extend.behind_sources(member, hidden, 6.0)
        assert dst.size > 50
        source = np.full(member.shape, -1, np.int32)
        source.ravel()[dst] = src
        want = renderer.grids.reduce_cells(*renderer.extend.extend_layer_behind(
            np.ascontiguousarray(lin[box]), np.ascontiguousarray(radius[box]), member,
            renderer.extend.Behind(dst, src), 6.0), s)
        got = renderer.grids.reduce_cells(lin, radius, member, s, source, (box[0].start, box[1].start))
        for g, e in zip(got, want):
            np.testing.assert_array_equal(g, e)
        # and without the extension the copied pixels are not counted
        bare = renderer.grids.reduce_cells(lin, radius, member, s, None, (box[0].start, box[1].start))
        assert bare[2].sum() < got[2].sum()


def _across_plainly(coc, layer, jump_px):
    h, w = layer.shape
    out = np.full((h, w), -1, np.int8)
    for y in range(h):
        for x in range(w):
            for ny, nx in ((y - 1, x), (y + 1, x), (y, x - 1), (y, x + 1)):
                if 0 <= ny < h and 0 <= nx < w and np.float32(coc[y, x] - coc[ny, nx]) > jump_px:
                    out[y, x] = max(out[y, x], layer[ny, nx])
    return out


class TestAcrossJumps:
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_matches_the_definition(self, seed):
        rng = np.random.default_rng(seed)
        h, w = 23, 31
        coc = (rng.integers(-12, 13, (h, w)) * 0.5).astype(np.float32)  # differences of exactly 2 px: not a jump
        layer = rng.integers(0, 35, (h, w)).astype(np.int32)
        got = renderer.classify.across_jumps(coc, layer)
        assert got.dtype == np.int8
        np.testing.assert_array_equal(got, _across_plainly(coc, layer, 2.0))
        assert (got >= 0).any() and (got < 0).any()
