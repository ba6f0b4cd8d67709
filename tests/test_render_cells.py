"""The cell grid a reduced layer finds its hidden pixels on (:mod:`pcdof.stages.render.cells`), against plain numpy."""

from __future__ import annotations

import numpy as np
import pytest

from pcdof.stages.render.cells import expand_cells, pool_cells


def _pooled(a, s, fn, fill):
    h, w = a.shape
    hr, wr = -(-h // s), -(-w // s)
    pad = np.full((hr * s, wr * s), fill, a.dtype)
    pad[:h, :w] = a
    return fn(pad.reshape(hr, s, wr, s), axis=(1, 3))


def _random_box(seed, h, w):
    rng = np.random.default_rng(seed)
    layer = rng.integers(0, 6, (h, w)).astype(np.int8)
    layer[rng.random((h, w)) < 0.6] = 3  # mostly one layer, so that cells are mixed and pure
    hidden = (layer < 3) & (rng.random((h, w)) < 0.8)
    across = rng.integers(-1, 6, (h, w)).astype(np.int8)
    return layer, hidden, across


@pytest.mark.parametrize("s, h, w", [(2, 17, 23), (4, 40, 37), (8, 33, 64), (1, 5, 6)])
def test_pooled_grid_is_the_cells_any_and_max(s, h, w):
    layer, hidden, across = _random_box(s * h + w, h, w)
    li = 3
    lay_c, hid_c, acr_c = pool_cells(layer, hidden, across, True, np.int8(li), s)
    member = _pooled(layer == li, s, np.any, False)
    np.testing.assert_array_equal(lay_c, np.where(member, li, _pooled(layer, s, np.max, np.int8(-128))))
    np.testing.assert_array_equal(hid_c, _pooled(hidden, s, np.any, False) & ~member)
    np.testing.assert_array_equal(acr_c, _pooled(across, s, np.max, np.int8(-1)))
    _, _, none = pool_cells(layer, hidden, np.zeros((1, 1), np.int8), False, np.int8(li), s)
    assert (none == -1).all()


@pytest.mark.parametrize("s, h, w", [(2, 17, 23), (4, 40, 37), (8, 33, 64)])
def test_expansion_copies_the_source_cells_pixel_nearest_its_centre(s, h, w):
    layer, hidden, _ = _random_box(h + w, h, w)
    li = 3
    lay_c, hid_c, _ = pool_cells(layer, hidden, np.zeros((1, 1), np.int8), False, np.int8(li), s)
    wr = lay_c.shape[1]
    sources = np.flatnonzero(lay_c.ravel() == li)
    targets = np.flatnonzero(hid_c.ravel())
    rng = np.random.default_rng(s)
    dst_c = rng.permutation(targets)[:12].astype(np.int64)
    src_c = rng.choice(sources, dst_c.size).astype(np.int64)
    dst, src = expand_cells(dst_c, src_c, layer, hidden, np.int8(li), s)
    want_dst, want_src = [], []
    for dc, sc in zip(dst_c, src_c):
        sy, sx = divmod(int(sc), wr)
        block = layer[sy * s:(sy + 1) * s, sx * s:(sx + 1) * s] == li
        ys, xs = np.nonzero(block)  # raster order: argmin keeps the first at a tie
        k = np.argmin((ys - (s - 1) / 2) ** 2 + (xs - (s - 1) / 2) ** 2)
        at = (sy * s + ys[k]) * w + sx * s + xs[k]
        dy, dx = divmod(int(dc), wr)
        part = hidden[dy * s:(dy + 1) * s, dx * s:(dx + 1) * s] & (layer[dy * s:(dy + 1) * s, dx * s:(dx + 1) * s] != li)
        py, px = np.nonzero(part)
        want_dst += ((dy * s + py) * w + dx * s + px).tolist()
        want_src += [at] * py.size
    assert dst.dtype == src.dtype == np.int64
    np.testing.assert_array_equal(dst, want_dst)
    np.testing.assert_array_equal(src, want_src)
    assert (layer.ravel()[src] == li).all() and not (layer.ravel()[dst] == li).any()
