"""Fill at the frame border (outside the depth camera's view) and in narrow gaps, on the bundled
real frames and on random synthetic ones."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcdof.stages.fill import BORDER, fill_depth
from pcdof.stages.fill.directional import fill_directional

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
EDGE_RATIO = 0.04  # the default: two depths further apart than this (relative) are two surfaces


def registered(folder, color_name, depth_name):
    from pcdof.io import load_frame
    from pcdof.stages.register import register_depth

    frame = load_frame(folder / color_name, folder / depth_name, folder / "calib.json")
    return register_depth(frame), frame.color


def isolated(filled, holes, ratio=EDGE_RATIO):
    """Holes whose filled depth differs from every one of its (up to 8) neighbours by more than *ratio*."""
    pad = np.pad(filled.astype(np.float64), 1, mode="constant", constant_values=np.nan)
    h, w = filled.shape
    out = np.ones((h, w), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                nb = pad[1 + dy: 1 + dy + h, 1 + dx: 1 + dx + w]
                alike = np.maximum(nb, filled) <= (1 + ratio) * np.minimum(nb, filled)
                out &= ~alike  # NaN (outside the frame) compares False: never alike
    return out & holes


def inside_value(depth, y, x, step):
    """Median of the known depth in the 5 pixels from (y, x) on along *step* (dy, dx)."""
    vals = [depth[y + i * step[0], x + i * step[1]] for i in range(5)
            if 0 <= y + i * step[0] < depth.shape[0] and 0 <= x + i * step[1] < depth.shape[1]]
    vals = [v for v in vals if v > 0]
    return np.median(vals) if vals else np.nan


@pytest.fixture(scope="module")
def nyu():
    depth, color = registered(REAL / "nyu_v2_raw_open3d", "color.png", "depth.png")
    return depth, color, fill_depth(depth, color)


@pytest.fixture(scope="module")
def moto():
    depth, color = registered(REAL / "middlebury2014_evalQ" / "Motorcycle", "im1.png", "depth0.png")
    return depth, color, fill_depth(depth, color)


def constant_blocks(depth, out, k=8):
    """Windows k x k at the frame border (every second position) whose pixels are all holes filled with one
    value: a straight-edged constant block, what holding a depth constant leaves in the corners."""
    h, w = out.shape
    n = 0
    for y in range(0, h - k + 1, 2):
        for x in range(0, w - k + 1, 2):
            if not (y == 0 or x == 0 or y + k == h or x + k == w) or (depth[y:y + k, x:x + k] > 0).any():
                continue
            win = out[y:y + k, x:x + k]
            n += win.max() - win.min() <= 1e-6 * win.max()
    return n


class TestNyuBorder:
    """The raw NYU frame (`make demo`'s): after registration the right strip, the left strip and the top band
    are outside the depth camera's view. They must continue the surfaces just inside, with no constant
    blocks, and the near floor at the bottom right must not become the background."""

    def test_no_constant_block_at_the_border(self, nyu):
        depth, color, out = nyu
        assert constant_blocks(depth, out) == 0
        # holding the depth just inside (the rule before) leaves such blocks in the corners
        assert constant_blocks(depth, fill_depth(depth, color, border="hold")) > 10

    def test_right_strip_continues_the_surface_inside(self, nyu):
        """Per row, the strip's median within 3 % of the 5 known pixels just inside for half the rows, 8 % for
        90 % (the surfaces continue along their planes; colour picks among them where several reach)."""
        depth, _, out = nyu
        known = depth > 0
        devs = []
        for y in np.flatnonzero(known.any(axis=1)):
            last = np.flatnonzero(known[y])[-1]
            if last >= depth.shape[1] - 8:
                continue
            strip = out[y, last + 1:][~known[:, last + 1:].any(axis=0)]
            if strip.size:
                devs.append(abs(np.median(strip) / inside_value(depth, y, last, (0, -1)) - 1))
        assert len(devs) > 300  # the strip spans most rows
        assert np.percentile(devs, 50) < 0.03 and np.percentile(devs, 90) < 0.08

    def test_not_background(self, nyu):
        """The old rule filled the strip with 4.4-6 m background; the near floor and chair at the
        bottom right are within 3 m."""
        depth, _, out = nyu
        known = depth > 0
        y0 = 380
        last = [np.flatnonzero(known[y])[-1] for y in range(y0, 470)]
        assert np.all(out[y0:470, 630] < 3.0) and np.all(depth[np.arange(y0, 470), last] < 3.0)


class TestMotorcycleGap:
    """Middlebury Motorcycle, depth0 registered into im1: the disocclusions between the fork tubes."""

    def test_no_isolated_pixels(self, moto):
        """No filled pixel differs from all 8 neighbours by more than the surface gap (4 %)."""
        depth, _, out = moto
        assert isolated(out, depth == 0).sum() == 0

    def test_few_floating_foreground_islands_in_fork_gap(self, moto):
        """Foreground-depth components made of filled pixels only (touching no measured pixel)
        inside the box around the fork: the former per-pixel vote left 6, now at most 2."""
        depth, _, out = moto
        fg = (out < 2.4).astype(np.uint8)  # fork 2.06-2.27 m, the shelves behind it beyond 3 m
        n, lab = cv2.connectedComponents(fg, connectivity=8)
        measured = np.zeros(n, bool)
        measured[lab[(depth > 0) & (fg > 0)]] = True
        in_box = set(np.unique(lab[150:300, 420:540])) - {0}
        assert sum(1 for i in in_box if not measured[i]) <= 2


def scene(rng, h, w):
    """Far wall (a gentle plane) with 1-3 near boxes and random colour: (depth, colour)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    depth = (1.0 / (0.2 + 0.0003 * (xx - w / 2) + 0.0002 * (yy - h / 2))).astype(np.float32)
    for _ in range(int(rng.integers(1, 4))):
        y0, x0 = int(rng.integers(0, h - 10)), int(rng.integers(0, w - 10))
        depth[y0: y0 + int(rng.integers(8, h)), x0: x0 + int(rng.integers(8, w))] = rng.uniform(0.8, 2.0)
    color = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    return depth, color


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), sides=st.sets(st.sampled_from("lrtb"), min_size=1, max_size=4),
       width=st.integers(1, 12))
def test_border_bands_are_held(seed, sides, width):
    """Cut bands off random sides: with the rule "hold", each band pixel outside along its row or column
    holds the depth of the surface just inside (flat boxes, a plane wall of gentle slope: within 4 % of its
    edge pixel), never the far wall. ("extend" does not always: a box whose edge pixel sees only a sliver
    of it gets a steep plane, and extrapolating it leaves the box: one reason the benchmark chose neither.)"""
    border = "hold"
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    truth, color = scene(rng, h, w)
    depth = truth.copy()
    cut = {"l": (slice(None), slice(0, width)), "r": (slice(None), slice(w - width, w)),
           "t": (slice(0, width), slice(None)), "b": (slice(h - width, h), slice(None))}
    for s in sides:
        depth[cut[s]] = 0
    out, kind = fill_directional(depth, color, use_color=True, edge_ratio=EDGE_RATIO, sigma_color=0.04,
                                 background_bias=6.0, with_kinds=True, border=border)
    hy, hx = np.nonzero(depth == 0)
    y_in, x_in = max(("t" in sides) * width, 0), max(("l" in sides) * width, 0)
    y_out, x_out = h - 1 - ("b" in sides) * width, w - 1 - ("r" in sides) * width
    for y, x, k in zip(hy, hx, kind):
        row_side = x < x_in or x > x_out
        col_side = y < y_in or y > y_out
        if row_side and not col_side:  # outside by its row only: the row's edge pixel inside
            ref = truth[y, x_in if x < x_in else x_out]
        elif col_side and not row_side:
            ref = truth[y_in if y < y_in else y_out, x]
        else:
            continue  # a corner: the nearest filled pixel
        assert k == BORDER
        # within the fill's surface resolution (two boxes within 4 % are one surface to its plane fit)
        assert abs(out[y, x] / ref - 1) < EDGE_RATIO, (y, x, out[y, x], ref)


@pytest.mark.xfail(strict=False, reason="known limitation: with one colour everywhere the bars' spatial support "
                   "can exceed background_bias times the wall's, so some gap pixels take the bars' depth")
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), gap=st.integers(2, 10), thick=st.integers(3, 12))
def test_narrow_gap_is_one_surface(seed, gap, thick):
    """Two near bars with a narrow gap between them, one colour everywhere (the colour vote cannot
    tell the surfaces apart): the gap's holes all take the wall behind, with no speckles of the bars' depth."""
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    wall, bar = 4.0, 1.2
    depth = np.full((h, w), wall, np.float32)
    x0 = 30
    depth[10:50, x0: x0 + thick] = bar
    depth[10:50, x0 + thick + gap: x0 + 2 * thick + gap] = bar
    color = np.full((h, w, 3), rng.integers(0, 256, 3), np.uint8)
    hole = np.zeros((h, w), bool)
    hole[14:46, x0 + thick: x0 + thick + gap] = True  # the wall is measured at both ends of the gap
    depth[hole] = 0
    out = fill_depth(depth, color)
    assert np.allclose(out[hole], wall, rtol=0.01), np.unique(out[hole])


def lost_frame(h: int, w: int, seed: int):
    """Random depth (h, w) and a lost mask: whole rows without a known pixel crossed with whole columns without
    one (never every pixel)."""
    rng = np.random.default_rng(seed)
    rows, cols = rng.random(h) < 0.5, rng.random(w) < 0.5
    lost = rows[:, None] & cols[None, :]
    if lost.all():
        rows[rng.integers(h)] = False
        lost = rows[:, None] & cols[None, :]
    return rng.uniform(0.5, 5.0, (h, w)).astype(np.float32), lost


@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), seed=st.integers(0, 2**32 - 1))
def test_lost_pixels_take_the_nearest_straight_pixel(h, w, seed):
    """Lost pixels (rows without a known pixel crossed with columns without one) take the nearest pixel
    that is not lost, Euclidean, ties up, left, down, right: checked against a brute-force search."""
    from pcdof.stages.fill.lost import nearest_not_lost

    depth, lost = lost_frame(h, w, seed)
    got = nearest_not_lost(depth, lost)
    ny, nx = np.nonzero(~lost)
    order = {(-1, 0): 0, (0, -1): 1, (1, 0): 2, (0, 1): 3}
    for y, x in zip(*np.nonzero(lost)):
        d2 = (ny - y) ** 2 + (nx - x) ** 2
        tied = np.flatnonzero(d2 == d2.min())
        best = min(tied, key=lambda i: order.get((int(np.sign(ny[i] - y)), int(np.sign(nx[i] - x))), 9))
        assert got[y, x] == depth[ny[best], nx[best]]
    np.testing.assert_array_equal(got[~lost], depth[~lost])


@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), seed=st.integers(0, 2**32 - 1))
def test_lost_pixels_blend_the_nearest_straight_pixels(h, w, seed):
    """With the rules "candidates" and "extend", lost pixels take 1/d weights on 1/z of the nearest pixels that
    are not lost up, left, down and right: the fast searches against the reference's walks."""
    from pcdof.stages.fill.lost import blend_not_lost
    from pcdof.stages.fill import reference

    depth, lost = lost_frame(h, w, seed)
    got = blend_not_lost(depth, lost)
    for y, x in zip(*np.nonzero(lost)):
        assert got[y, x] == pytest.approx(reference.blend_not_lost(depth, lost, y, x), rel=1e-6)
    np.testing.assert_array_equal(got[~lost], depth[~lost])


@pytest.mark.parametrize("slope", [0.003, -0.003])
def test_strip_past_the_measured_range_is_not_held_at_its_end(slope):
    """A plane wall cut by a strip outside the view (x < 16) in which it runs past every measured depth:
    nearer (slope > 0: 1/z grows to the left) the strip continues the plane, down to 1.1 times nearer than the
    nearest measured depth, here exactly; farther, each row keeps about the depth its edge pixel measured, inside
    the measured range. Clamping each candidate to the measured range would hold its end over the area."""
    h, w, edge = 40, 64, 16
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = (1.0 / (0.5 + slope * (edge - xx) + 0.0005 * yy)).astype(np.float32)
    depth = truth.copy()
    depth[:, :edge] = 0
    out, kind = fill_directional(depth, np.full((h, w, 3), 128, np.uint8), use_color=True, edge_ratio=EDGE_RATIO,
                                 sigma_color=0.04, background_bias=6.0, with_kinds=True)
    assert np.all(kind == BORDER)
    strip = out[:, :edge]
    known = depth[depth > 0]
    same_x, same_y = np.diff(strip, axis=1) == 0, np.diff(strip, axis=0) == 0
    assert not (same_x[:-1] & same_y[:, :-1]).any()  # no value held over an area
    if slope > 0:
        assert strip.min() < known.min() and strip.min() >= known.min() / 1.1
        np.testing.assert_allclose(strip, truth[:, :edge], rtol=1e-4)
    else:
        assert strip.min() >= known.min() and strip.max() <= known.max()
        assert np.all(np.abs(strip / truth[:, edge:edge + 1] - 1) < EDGE_RATIO)
