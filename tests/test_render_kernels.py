"""The renderer's blur-layer kernels against plain formulations of what they compute.

The scatter (:func:`pcdof.stages.render.scatter.scatter_packed`) is checked against a direct evaluation of its
definition: every source spreads over its aperture scaled to its radius, split into one strip per
pixel row (area and centre from the aperture's cumulative tables), each strip a box [a, a + area]
whose overlap with every pixel [x - 1/2, x + 1/2] is its weight there. Nothing of the kernel's
decomposition (strip tables, end pixels, difference arrays) is shared. The convolution path of
uniform tiles is checked against the scatter of the same cells.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pcdof.stages.render as renderer
from pcdof.apertures import Disc, Polygon
from pcdof.stages.render.tiles import classify_tiles

#: Apertures of both kinds of strip: centred (the disc) and off-centre (odd polygons, turned).
APERTURES = {"disc": Disc(), "pentagon": Polygon(blades=5, vertex_angle_rad=0.3),
             "triangle": Polygon(blades=3, vertex_angle_rad=-1.1), "hexagon": Polygon(blades=6, vertex_angle_rad=0.2)}


def _lookup(u: float, g: np.ndarray) -> float:
    """The table's linear interpolation at height u in [-1, 1] (float64)."""
    return float(np.interp(u, renderer.aperture.TABLE_U, g))


def _strips(r: float, dy: int, table: np.ndarray) -> tuple[float, float]:
    """(area, centre x) of the footprint of radius r on the row dy rows below its centre, from its definition."""
    lo, hi = max(dy - 0.5, -r), min(dy + 0.5, r)
    if hi <= lo:
        return 0.0, 0.0
    g = _lookup(hi / r, table[0]) - _lookup(lo / r, table[0])
    if g <= 0.0:
        return 0.0, 0.0
    return r * r * g, r * (_lookup(hi / r, table[1]) - _lookup(lo / r, table[1])) / g


def scatter_direct(xs, ys, radius, values, shape, table) -> np.ndarray:
    """(H, W, 4) float64: every source's strips as boxes, each pixel weighted by its overlap with the box."""
    h, w = shape
    out = np.zeros((h, w, 4))
    px = np.arange(w, dtype=np.float64)
    for x, y, r, v in zip(xs, ys, radius, values):
        reach = int(math.ceil(r + 0.5))
        for dy in range(-reach, reach + 1):
            if not 0 <= y + dy < h:
                continue
            area, centre = _strips(float(r), dy, table)
            if area <= 0.0:
                continue
            a = x + centre - 0.5 * area
            overlap = np.clip(np.minimum(a + area, px + 0.5) - np.maximum(a, px - 0.5), 0.0, None)
            out[y + dy] += overlap[:, None] * np.asarray(v, np.float64)[None, :]
    return out


def packed(xs, ys, radius, values, h):
    """Sources (sorted by row, then column) as :func:`pcdof.stages.render.scatter.pack_sources` gives them."""
    order = np.lexsort((xs, ys))
    counts = np.bincount(ys[order], minlength=h)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return (xs[order].astype(np.float32), radius[order].astype(np.float32),
            np.ascontiguousarray(values[order], np.float32), offsets)


def random_sources(rng, h, w, n, r_lo, r_hi):
    """n sources at distinct random pixels of an (h, w) grid (borders included), radii in [r_lo, r_hi]."""
    cells = rng.choice(h * w, size=min(n, h * w), replace=False)
    ys, xs = np.divmod(cells, w)
    # float32, as the kernel takes them (a thin strip at a footprint's edge moves with the radius' last bit)
    radius = rng.uniform(r_lo, r_hi, ys.size).astype(np.float32).astype(np.float64)
    values = rng.uniform(0.0, 1.0, (ys.size, 4)).astype(np.float32).astype(np.float64)
    return xs, ys, radius, values


def run_scatter(xs, ys, radius, values, shape, aperture, y_lo=None, y_hi=None, tasks=4, starts=None) -> np.ndarray:
    """The scatter of the rows y_lo..y_hi in up to *tasks* runs of equal work, or in the runs that begin at *starts*."""
    h, w = shape
    table = renderer.aperture_table(aperture)
    pxs, pr, pv, offsets = packed(xs, ys, radius, values, h)
    out = np.zeros((h, w, 4), np.float32)
    y_lo, y_hi = 0 if y_lo is None else y_lo, h - 1 if y_hi is None else y_hi
    if starts is None:
        starts = renderer.scatter.balanced_runs(offsets, w, math.ceil(float(pr.max()) + 0.5), y_lo, y_hi, tasks)
    renderer.scatter.scatter_packed(pxs, pr, pv, offsets, w, float(pr.max()), y_lo, y_hi, aperture.symmetric, table,
                                    out, np.asarray(starts, np.int64))
    return out


class TestScatterPacked:
    """The exact scatter equals the direct evaluation of its definition within float32 rounding: at most
    2e-6 of the largest output value (float32 sums over the row's difference array)."""

    @pytest.mark.parametrize("name", list(APERTURES))
    @pytest.mark.parametrize("r_lo, r_hi", [(0.5, 1.6), (2.0, 5.5), (4.0, 9.0)])
    def test_random_sources_match_the_definition(self, name, r_lo, r_hi):
        rng = np.random.default_rng(int(r_hi * 10) + len(name))
        h, w = 23, 31
        xs, ys, radius, values = random_sources(rng, h, w, 90, r_lo, r_hi)
        aperture = APERTURES[name]
        fast = run_scatter(xs, ys, radius, values, (h, w), aperture)
        ref = scatter_direct(xs, ys, radius, values, (h, w), renderer.aperture_table(aperture))
        np.testing.assert_allclose(fast, ref, rtol=0, atol=2e-6 * np.abs(ref).max())

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(seed=st.integers(0, 2 ** 32 - 1), name=st.sampled_from(sorted(APERTURES)),
           h=st.integers(1, 18), w=st.integers(1, 24), n=st.integers(1, 60), r_hi=st.floats(0.5, 8.0))
    def test_property_any_sources_any_frame(self, seed, name, h, w, n, r_hi):
        """Any grid (one pixel wide or tall included), any number of sources, footprints far past the borders."""
        rng = np.random.default_rng(seed)
        xs, ys, radius, values = random_sources(rng, h, w, n, 0.5, max(0.5, r_hi))
        aperture = APERTURES[name]
        fast = run_scatter(xs, ys, radius, values, (h, w), aperture)
        ref = scatter_direct(xs, ys, radius, values, (h, w), renderer.aperture_table(aperture))
        np.testing.assert_allclose(fast, ref, rtol=0, atol=2e-6 * max(np.abs(ref).max(), 1e-30))

    def test_only_the_rows_asked_for_are_written(self):
        rng = np.random.default_rng(5)
        h, w = 30, 20
        xs, ys, radius, values = random_sources(rng, h, w, 80, 1.0, 4.0)
        full = run_scatter(xs, ys, radius, values, (h, w), APERTURES["pentagon"])
        part = run_scatter(xs, ys, radius, values, (h, w), APERTURES["pentagon"], y_lo=7, y_hi=19)
        np.testing.assert_array_equal(part[7:20], full[7:20])
        assert not part[:7].any() and not part[20:].any()

    @pytest.mark.parametrize("name", ["disc", "pentagon"])
    def test_any_split_of_the_rows_gives_the_same_bits(self, name):
        """The rows cut into 1 .. 8 runs (each starting its ring of strips afresh): the same output, bit for bit."""
        rng = np.random.default_rng(8)
        h, w = 128, 30  # reach 4: up to 128 // 16 = 8 runs
        xs, ys, radius, values = random_sources(rng, h, w, 900, 0.5, 3.2)
        one = run_scatter(xs, ys, radius, values, (h, w), APERTURES[name], tasks=1)
        assert one.any()
        for tasks in (2, 3, 5, 8, 20):
            np.testing.assert_array_equal(run_scatter(xs, ys, radius, values, (h, w), APERTURES[name], tasks=tasks), one)
        # runs of any length, one row and empty ones included
        for starts in ([0, 1, 2, 60, 60, 127, 128], [0, 3, 128], [0, 128, 128]):
            np.testing.assert_array_equal(run_scatter(xs, ys, radius, values, (h, w), APERTURES[name], starts=starts),
                                          one)

    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), n_rows=st.integers(1, 400), reach=st.integers(1, 20),
           runs=st.integers(1, 16), width=st.integers(1, 2000))
    def test_balanced_runs_cut_the_rows_into_runs_of_about_equal_work(self, seed, n_rows, reach, runs, width):
        rng = np.random.default_rng(seed)
        h = n_rows + int(rng.integers(0, 30))
        y_lo = int(rng.integers(0, h - n_rows + 1))
        y_hi = y_lo + n_rows - 1
        counts = rng.integers(0, 50, h) * (rng.random(h) < 0.5)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        starts = renderer.scatter.balanced_runs(offsets, width, reach, y_lo, y_hi, runs)
        n = starts.size - 1
        assert starts[0] == y_lo and starts[-1] == y_hi + 1 and np.all(np.diff(starts) >= 0)
        assert n == max(1, min(runs, n_rows // (2 * reach)))
        # a row's work: the sources within reach plus the pass over its width; every run within one row's work of
        # an equal share
        ys = np.arange(y_lo, y_hi + 1)
        near = offsets[np.minimum(h - 1, ys + reach) + 1] - offsets[np.maximum(0, ys - reach)]
        work = near + renderer.scatter.ROW_PASS_STRIPS_PER_PX * width
        cum = np.concatenate([[0.0], np.cumsum(work)])
        shares = cum[starts[1:] - y_lo] - cum[starts[:-1] - y_lo]
        assert np.all(np.abs(shares - cum[-1] / n) <= work.max() + 1e-9 * cum[-1])

    @pytest.mark.parametrize("name", list(APERTURES))
    def test_energy_of_sources_inside_the_frame(self, name):
        """A source whose footprint lies inside the frame puts exactly area r^2 * unit_area times its value."""
        aperture = APERTURES[name]
        table = renderer.aperture_table(aperture)
        rng = np.random.default_rng(11)
        h, w = 40, 40
        ys, xs = rng.integers(12, 28, 25), rng.integers(12, 28, 25)
        radius = rng.uniform(0.5, 7.5, 25)
        values = rng.uniform(0.1, 1.0, (25, 4))
        out = run_scatter(xs, ys, radius, values, (h, w), aperture)
        unit = table[0, -1] - table[0, 0]
        expected = (values * (unit * radius ** 2)[:, None]).sum(axis=0)
        np.testing.assert_allclose(out.sum(axis=(0, 1), dtype=np.float64), expected, rtol=2e-6)

    def test_row_strips_are_the_rows_of_each_footprint(self):
        """_row_strips: per source, the rows' areas sum to r^2 * unit_area, and each is the definition's."""
        for name, aperture in APERTURES.items():
            table = renderer.aperture_table(aperture)
            radius = np.array([0.5, 0.73, 1.0, 2.5, 4.49, 4.5, 4.51, 6.2], np.float32)
            reach = int(math.ceil(float(radius.max()) + 0.5)) + 1  # one row more than any footprint needs
            nd = 2 * reach + 1
            area = np.full((nd, 8), np.nan)
            centre = np.full((nd, 8), np.nan)
            renderer.scatter.row_strips(radius, 2, 6, reach, aperture.symmetric, table, area, centre)  # sources 2 .. 7
            assert np.isnan(area[:, 6:]).all()  # only n sources written
            assert np.isnan(centre).all() == aperture.symmetric  # centres only for off-centre strips
            area = area[:, :6]
            unit = table[0, -1] - table[0, 0]
            r = radius[2:]
            # the rows telescope to G(1) - G(-1); r^2 is taken in float32, as the kernel takes it
            np.testing.assert_allclose(area.sum(axis=0), unit * (r * r).astype(np.float64), rtol=1e-12)
            for k in range(6):
                for d in range(nd):
                    a, c = _strips(float(r[k]), d - reach, table)
                    assert area[d, k] == pytest.approx(a, rel=1e-7, abs=1e-12), (name, r[k], d)  # r^2 in float32
                    if not aperture.symmetric:
                        assert centre[d, k] == pytest.approx(c, rel=1e-7, abs=1e-9), (name, r[k], d)


def uniform_plan_direct(fast, radius):
    """The radius bins of the fast cells and the kept groups, bin by bin with numpy (the plan's definition)."""
    step = math.log1p(renderer.UNIFORM_BIN)
    with np.errstate(divide="ignore"):
        b_all = np.rint(np.log(np.maximum(radius, renderer.MIN_SOURCE_RADIUS_PX)) / step)
    bins = np.where(fast, b_all, renderer.uniform.NO_BIN).astype(np.int64)
    groups = []
    for b in np.unique(bins[fast]):
        cells = bins == b
        rows, cols = np.flatnonzero(cells.any(axis=1)), np.flatnonzero(cells.any(axis=0))
        win = (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
        if (win[1] - win[0]) * (win[3] - win[2]) > renderer.UNIFORM_MAX_WASTE * cells.sum():
            bins[cells] = renderer.uniform.NO_BIN
        else:
            groups.append((int(b), math.exp(int(b) * step), tuple(int(v) for v in win)))
    return bins, groups


class TestUniformPlan:
    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
           density=st.floats(0.0, 1.0), spread=st.floats(0.0, 0.5))
    def test_matches_the_bin_by_bin_definition(self, seed, h, w, density, spread):
        rng = np.random.default_rng(seed)
        fast = rng.random((h, w)) < density
        if rng.random() < 0.3:  # a thin diagonal band of one radius: its bins waste their window and are dropped
            fast = np.eye(h, w, dtype=bool) | (rng.random((h, w)) < 0.02)
        radius = (rng.uniform(0.3, 9.0) * np.exp(rng.uniform(-spread, spread, (h, w)))).astype(np.float32)
        bins, groups = renderer.uniform.uniform_plan(fast, radius)
        ref_bins, ref_groups = uniform_plan_direct(fast, radius)
        np.testing.assert_array_equal(bins, ref_bins)
        assert groups == ref_groups


class TestConvolveUniform:
    """At the cells of a radius bin, the banded convolution equals the scatter of every source with the bin's
    radius (the footprint it convolves with), within float32 rounding (2e-6 of the largest value)."""

    @pytest.mark.parametrize("name", ["disc", "pentagon"])
    @pytest.mark.parametrize("hs, ws, r", [(150, 37, 3.1), (70, 90, 5.6), (9, 12, 2.2), (200, 16, 7.9)])
    def test_equals_the_scatter_of_the_same_sources(self, name, hs, ws, r):
        aperture = APERTURES[name]
        table = renderer.aperture_table(aperture)
        rng = np.random.default_rng(hs + ws)
        lin = rng.random((hs, ws, 3)).astype(np.float32)
        share = (rng.random((hs, ws)) < 0.8).astype(np.float32)
        radius = np.full((hs, ws), r, np.float32)
        fast = np.zeros((hs, ws), bool)
        fast[hs // 5:hs - hs // 6, ws // 7:ws - 1] = True  # the cells convolved, some at the border
        bins, groups = renderer.uniform.uniform_plan(fast, radius)
        assert len(groups) == 1 and groups[0][2] == (hs // 5, hs - hs // 6, ws // 7, ws - 1)
        buf = np.zeros((hs, ws, 4), np.float32)
        renderer.uniform.convolve_uniform(lin, share, bins, groups, aperture.symmetric, table, buf)
        # the same sources scattered with the group's kernel radius
        ys, xs = np.nonzero(share > 0)
        values = np.concatenate([lin[ys, xs], np.ones((ys.size, 1), np.float32)], axis=1)
        values /= (table[0, -1] - table[0, 0]) * groups[0][1] ** 2
        scattered = run_scatter(xs, ys, np.full(ys.size, groups[0][1]), values, (hs, ws), aperture)
        cells = bins == groups[0][0]
        np.testing.assert_allclose(buf[cells], scattered[cells], rtol=0, atol=2e-6 * np.abs(scattered).max())
        assert not buf[~cells].any()  # nothing written elsewhere


class TestFastCells:
    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
           s=st.sampled_from([1, 2, 3, 4]), tile_px=st.sampled_from([1, 2, 3, 5, 8]))
    def test_cells_whose_pixels_are_all_fast(self, seed, h, w, s, tile_px):
        """The member cells of a box's 1/s grid whose s x s pixels all lie in uniform tiles (decided from the
        tiles), against the tiles' pixel mask cell by cell; cells cut by the box's border are never fast."""
        rng = np.random.default_rng(seed)
        y0, x0 = (int(v) for v in rng.integers(0, 9, 2))
        tile_map = classify_tiles(np.zeros((h + y0 + 4, w + x0 + 3), np.float32), tile_px=tile_px)
        uniform = rng.random(tile_map.copy.shape) < 0.8
        box = (slice(y0, y0 + h), slice(x0, x0 + w))
        fast = tile_map.pixel_mask(uniform, box)
        hs, ws = -(-h // s), -(-w // s)
        member = rng.random((hs, ws)) < 0.8
        expected = np.zeros((hs, ws), bool)
        for cy in range(hs):
            for cx in range(ws):
                block = fast[cy * s:(cy + 1) * s, cx * s:(cx + 1) * s]
                expected[cy, cx] = member[cy, cx] and block.shape == (s, s) and block.all()
        np.testing.assert_array_equal(renderer.uniform.UniformTiles(uniform, tile_map, box).cells(member, s), expected)


class TestCompositeUnder:
    @settings(max_examples=40, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), nc=st.integers(1, 3))
    def test_front_to_back_over_operator(self, seed, nc):
        """The layer (placed at row 3, column 2) goes behind the canvas: where the canvas is not yet opaque and
        the layer covers more than 1e-6, colour / coverage times min(coverage, 1) times the transmittance
        (1 - opacity) is added, and so is that opacity; a full cover makes the pixel opaque (1) exactly;
        nothing changes elsewhere."""
        rng = np.random.default_rng(seed)
        h, w, hb, wb = 12, 15, 7, 9
        layer = rng.random((hb, wb, nc + 1)).astype(np.float32)
        cover = rng.choice([0.0, 1e-7, 0.3, 0.99995, 1.0, 1.7], size=(hb, wb)) * rng.uniform(0.9, 1.0, (hb, wb))
        cover[0, :3] = (1.0, 1.7, 0.99995)  # full covers, whatever the draw
        layer[:, :, nc] = cover
        acc = rng.random((h, w, nc)).astype(np.float32)
        opacity = np.where(rng.random((h, w)) < 0.3, 1.0, rng.random((h, w))).astype(np.float32)
        opacity[3, 2:5] = 0.25  # not opaque under the full covers
        want_acc, want_a = acc.astype(np.float64), opacity.astype(np.float64)
        win = (slice(3, 3 + hb), slice(2, 2 + wb))
        t = 1.0 - want_a[win]
        c = layer[:, :, nc].astype(np.float64)
        on = (t > 0) & (c > 1e-6)
        alpha = np.where(c >= 1.0 - 1e-4, 1.0, c)
        f = np.where(on, t * alpha / np.where(on, c, 1.0), 0.0)
        want_acc[win] += f[:, :, None] * layer[:, :, :nc]
        want_a[win] += np.where(on, t * alpha, 0.0)
        before_acc, before_a = acc.copy(), opacity.copy()
        wide = np.concatenate([layer, rng.random((hb, 3, nc + 1)).astype(np.float32)], axis=1)  # 3 columns beyond
        renderer.composite.composite_under(wide, 3, 2, before_acc, before_a, width=wb)  # reads the first wb only
        renderer.composite.composite_under(layer, 3, 2, acc, opacity)
        np.testing.assert_array_equal(before_acc, acc)
        np.testing.assert_array_equal(before_a, opacity)
        np.testing.assert_allclose(acc, want_acc, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(opacity, want_a, rtol=1e-6, atol=1e-7)
        full = np.zeros((h, w), bool)
        full[win] = on & (alpha == 1.0)
        assert full[3, 2:5].all() and (opacity[full] == 1.0).all()


class TestNormalise:
    @pytest.mark.parametrize("nc", [1, 3])
    def test_colour_over_the_opacity_composited(self, nc):
        """out = acc / opacity where more than 1e-6 of opacity was composited, else the input pixel."""
        rng = np.random.default_rng(nc)
        h, w = 9, 11
        acc = rng.random((h, w, nc)).astype(np.float32)
        opacity = rng.choice([0.0, 1e-7, 0.003, 0.75, 1.0], size=(h, w)).astype(np.float32)
        lin = rng.random((h, w, nc)).astype(np.float32)
        out = np.empty_like(acc)
        renderer.composite.normalise(acc, opacity, lin, out)
        a = opacity.astype(np.float64)
        want = np.where((a > 1e-6)[:, :, None], acc / np.where(a > 1e-6, a, 1.0)[:, :, None], lin)
        np.testing.assert_allclose(out, want, rtol=1e-6)
        assert np.array_equal(out[a <= 1e-6], lin[a <= 1e-6])

    def test_copy_tiles_come_out_as_the_input(self):
        """A canvas started with copy tiles is opaque there with the input's colour: normalised, exactly the input."""
        rng = np.random.default_rng(5)
        lin = rng.random((40, 56, 3)).astype(np.float32)
        coc = np.full((40, 56), 9.0, np.float32)
        coc[:, 28:] = 0.0  # in focus, far from the blur: copy tiles
        tiles = renderer.classify_tiles(coc, tile_px=8, sharp_px=1.0)
        assert tiles.copy.any()
        canvas = renderer.frame.Canvas.start(lin, tiles, True)
        out = np.empty_like(lin)
        renderer.composite.normalise(canvas.acc, canvas.opacity, lin, out)
        copied = tiles.pixel_mask(tiles.copy)
        assert np.array_equal(out[copied], lin[copied])
        assert (canvas.opacity[~copied] == 0.0).all() and (canvas.acc[~copied] == 0.0).all()
