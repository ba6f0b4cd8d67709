"""The extension behind nearer layers (partial occlusion) against its plain statement.

The renderer finds the hidden pixels a layer continues (:func:`pcdof.stages.render.ownership.owned_mask`) and each one's
nearest pixel of the layer (:func:`pcdof.stages.render.extend.behind_sources`) with compiled kernels that read
OpenCV's transforms in place, and composites the in-focus layer straight from the frame. Here each step
is checked bit for bit against the same rule written plainly with numpy on the same OpenCV transforms:
whole windows copied, masks and index arrays built in full.
"""

from __future__ import annotations

import math
from unittest import mock

import cv2
import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given, settings

import pcdof.stages.render as renderer


def _extend_plain(lin, radius, member, hidden, reach_px):
    """The extension stated plainly: one transform on the hidden pixels' bounding box widened by the reach,
    every hidden pixel within reach takes its nearest member's colour and radius (copies of the inputs)."""
    rows = np.flatnonzero(hidden.any(axis=1))
    if rows.size == 0:
        return lin, radius, member
    cols = np.flatnonzero(hidden.any(axis=0))
    pad = int(math.ceil(reach_px)) + 1
    h, w = member.shape
    win = (slice(max(0, rows[0] - pad), min(h, rows[-1] + pad + 1)),
           slice(max(0, cols[0] - pad), min(w, cols[-1] + pad + 1)))
    m_win = member[win]
    if not m_win.any():
        return lin, radius, member
    dist, labels = cv2.distanceTransformWithLabels((~m_win).astype(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    band = hidden[win] & (dist <= reach_px)
    if not band.any():
        return lin, radius, member
    nearest = np.flatnonzero(m_win.ravel())[labels[band] - 1]
    lin, radius, member = lin.copy(), radius.copy(), member.copy()
    lin_win, r_win = lin[win], radius[win]
    lin_win[band] = lin_win.reshape(-1, lin.shape[2])[nearest]
    r_win[band] = r_win.ravel()[nearest]
    member[win] |= band
    return lin, radius, member


def _owned_plain(layer, li, box, bbox, hidden, reach_px):
    """:func:`pcdof.stages.render.ownership.owned_mask` (one thread, cells of 1 px) with full-window masks and numpy
    indexing."""
    h, w = layer.shape
    (by, ey), (bx, ex) = (box[0].start, box[0].stop), (box[1].start, box[1].stop)
    rd = int(math.ceil(reach_px))
    pad = 2 * rd + 2
    whole = (slice(max(0, by - pad), min(h, ey + pad)), slice(max(0, bx - pad), min(w, ex + pad)))
    span = renderer.ownership.widened_span
    out = np.zeros_like(hidden)
    reach_box = (span(bbox[0] - by, bbox[1] - by, rd, slice(0, ey - by)),
                 span(bbox[2] - bx, bbox[3] - bx, rd, slice(0, ex - bx)))
    sub = hidden[reach_box]
    rows, cols = np.flatnonzero(sub.any(axis=1)), np.flatnonzero(sub.any(axis=0))
    if rows.size == 0:
        return out
    y0, y1 = rows[0] + reach_box[0].start + by, rows[-1] + reach_box[0].start + by
    x0, x1 = cols[0] + reach_box[1].start + bx, cols[-1] + reach_box[1].start + bx
    part = (slice(y0 - by, y1 + 1 - by), slice(x0 - bx, x1 + 1 - bx))
    if not (layer[span(y0, y1, 2 * rd + 3, whole[0]), span(x0, x1, 2 * rd + 3, whole[1])] > li).any():
        out[part] = hidden[part]
        return out
    win = (span(y0, y1, rd + 3, whole[0]), span(x0, x1, rd + 3, whole[1]))
    at = np.zeros((win[0].stop - win[0].start, win[1].stop - win[1].start), bool)
    at[y0 - win[0].start:y1 + 1 - win[0].start, x0 - win[1].start:x1 + 1 - win[1].start] = hidden[part]
    lay = layer[win]
    behind = lay >= li
    if not behind.any():
        return out
    dist, labels = cv2.distanceTransformWithLabels((~behind).astype(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    at = np.flatnonzero(at)
    d = dist.ravel()[at]
    q = np.flatnonzero(behind)[labels.ravel()[at] - 1]
    own = (d <= rd) & (lay.ravel()[q] == li)
    test = own & (d > 1.0)
    if test.any():
        qy, qx = np.divmod(q[test], behind.shape[1])
        qy, qx = qy + win[0].start, qx + win[1].start
        far = int(math.ceil(float(d[test].max()))) + 3
        fwin = (span(int(qy.min()), int(qy.max()), far, whole[0]), span(int(qx.min()), int(qx.max()), far, whole[1]))
        width = cv2.distanceTransform((layer[fwin] <= li).astype(np.uint8), cv2.DIST_L2, 5)
        own[test] = d[test] <= np.maximum(width[qy - fwin[0].start, qx - fwin[1].start], 1.0)
    res = np.zeros(behind.shape, bool)
    res.ravel()[at] = own
    out[part] = res[y0 - win[0].start:y1 + 1 - win[0].start, x0 - win[1].start:x1 + 1 - win[1].start]
    return out


def _random_layers(rng, h, w, n_layers):
    """Layer ids (h, w) int32 from random blocks, bars and specks (straight edges, corners, ties)."""
    k = int(rng.integers(2, 10))
    layer = cv2.resize(rng.integers(0, n_layers, (k, k)).astype(np.float32), (w, h),
                       interpolation=cv2.INTER_NEAREST).astype(np.int32)
    for _ in range(int(rng.integers(0, 8))):
        y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
        layer[y:y + int(rng.integers(1, 6)), x:x + int(rng.integers(1, 40))] = int(rng.integers(0, n_layers))
    if rng.random() < 0.4:
        specks = rng.random((h, w)) < 0.05
        layer[specks] = rng.integers(0, n_layers, int(specks.sum()))
    return layer


def _layer_case(seed):
    """A random frame's layer li, its box (the frame or a part touching some borders) and hidden pixels."""
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(8, 140, 2))
    layer = _random_layers(rng, h, w, int(rng.integers(2, 6)))
    li = int(rng.integers(1, max(2, int(layer.max()) + 1)))
    y0, x0 = int(rng.integers(0, h // 2 + 1)) * int(rng.random() < 0.5), int(rng.integers(0, w // 2 + 1)) * int(rng.random() < 0.5)
    y1, x1 = int(rng.integers(y0 + 1, h + 1)), int(rng.integers(x0 + 1, w + 1))
    box = (slice(y0, y1), slice(x0, x1))
    hidden = (layer[box] < li) & (rng.random((y1 - y0, x1 - x0)) < rng.choice([0.3, 1.0]))
    # whole pixels as the renderer's reaches are (distances along a row or column equal them), or any
    reach = float(rng.integers(1, 26)) if rng.random() < 0.5 else float(rng.uniform(0.5, 25.0))
    return rng, layer, li, box, hidden, reach


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_extension_is_the_plain_rule_bit_for_bit(seed):
    """Random layers, boxes at and off the borders, reaches from under a pixel to 25 px: the same colours,
    radii and members as the whole-window statement, and the inputs untouched."""
    rng, layer, li, box, hidden, reach = _layer_case(seed)
    member = layer[box] == li
    nc = int(rng.integers(1, 4))
    lin = rng.random((layer.shape[0], layer.shape[1], nc), dtype=np.float32)[box]  # a view, as the renderer's
    radius = rng.uniform(0.5, 20.0, layer.shape).astype(np.float32)[box]
    before = (lin.copy(), radius.copy(), member.copy(), hidden.copy())
    got = renderer.extend.extend_layer_behind(lin, radius, member, hidden, reach)
    want = _extend_plain(lin, radius, member, hidden, reach)
    for g, x in zip(got, want):
        np.testing.assert_array_equal(g, x)
    for a, b in zip((lin, radius, member, hidden), before):
        np.testing.assert_array_equal(a, b)
    found = renderer.extend.behind_sources(member, hidden, reach)
    added = want[2] & ~member
    if found is None:
        assert not added.any()
    else:  # every added pixel once, each from a member pixel
        dst, src = found
        np.testing.assert_array_equal(np.sort(dst), np.flatnonzero(added))
        assert member.ravel()[src].all()


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_extension_in_strips_is_the_whole_windows(seed):
    """Cut into the smallest strips of rows (four reaches each), the nearest pixels found are the whole
    window's: the same pixels, the same sources (ties included), in the same order."""
    _, layer, li, box, hidden, reach = _layer_case(seed)
    member = layer[box] == li
    whole = renderer.extend.behind_sources(member, hidden, reach, strip_px=1 << 40)
    strips = renderer.extend.behind_sources(member, hidden, reach, strip_px=1)
    assert (whole is None) == (strips is None)
    if whole is not None:
        for g, x in zip(strips, whole):
            np.testing.assert_array_equal(g, x)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), threads=st.integers(2, 5))
def test_extension_in_strips_on_threads_is_the_whole_windows(seed, threads):
    """Cut into strips for threads (every window: the threshold lowered to nothing), decided at once, the
    nearest pixels found are the whole window's, in the same order."""
    _, layer, li, box, hidden, reach = _layer_case(seed)
    member = layer[box] == li
    whole = renderer.extend.behind_sources(member, hidden, reach, strip_px=1 << 40)
    with mock.patch.object(renderer.extend, "THREADED_WINDOW_PX", 0):
        for strip_px in (1 << 40, 1):
            found = renderer.extend.behind_sources(member, hidden, reach, strip_px=strip_px, threads=threads)
            assert (whole is None) == (found is None)
            if whole is not None:
                for g, x in zip(found, whole):
                    np.testing.assert_array_equal(g, x)


def test_a_large_window_is_cut_into_strips_for_threads():
    """A layer beside a wide hidden band (0.6 megapixels): on two threads its window is decided in two strips
    or more, at once, with the one thread's answer."""
    h, w = 600, 1000
    member = np.zeros((h, w), bool)
    member[:, :40] = True
    hidden = np.zeros((h, w), bool)
    hidden[:, 40:] = True
    calls = []
    real = renderer.extend.cv2.distanceTransformWithLabels
    with mock.patch.object(renderer.extend.cv2, "distanceTransformWithLabels",
                           side_effect=lambda *a, **k: calls.append(a[0].shape) or real(*a, **k)):
        two = renderer.extend.behind_sources(member, hidden, 30.0, threads=2)
    one = renderer.extend.behind_sources(member, hidden, 30.0, threads=1)
    assert len(calls) >= 2 and all(s[0] < h for s in calls)
    for g, x in zip(two, one):
        np.testing.assert_array_equal(g, x)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_ownership_is_the_plain_rule_bit_for_bit(seed):
    """The ownership kernel (candidates read from OpenCV's labels in place) against the same windows'
    rule written with numpy masks, on random layers with every layer id behind and in front."""
    _, layer, li, box, hidden, reach = _layer_case(seed)
    ys, xs = np.nonzero(layer == li)
    if ys.size == 0:
        return
    bbox = (ys.min(), ys.max(), xs.min(), xs.max())
    np.testing.assert_array_equal(renderer.ownership.owned_mask(layer, li, box, bbox, hidden, reach),
                                  _owned_plain(layer, li, box, bbox, hidden, reach))


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_in_focus_layer_composited_in_place_is_the_extended_copy(seed):
    """The in-focus layer composited straight from the frame, its extension by index, equals compositing
    the extended copy (opaque, over what is already there)."""
    rng, layer, li, box, hidden, reach = _layer_case(seed)
    h, w = layer.shape
    lin = rng.random((h, w, 3), dtype=np.float32)
    member = layer[box] == li
    opacity = np.where(rng.random((h, w)) < 0.3, 1.0, rng.random((h, w))).astype(np.float32)
    acc = rng.random((h, w, 3), dtype=np.float32)
    found = renderer.extend.behind_sources(member, hidden, reach)
    dst, src = found if found is not None else (renderer.extend.NO_PIXELS, renderer.extend.NO_PIXELS)
    got = (acc.copy(), opacity.copy())
    renderer.composite.composite_sharp(lin, member, box[0].start, box[1].start, dst, src, *got)
    ext, _, m = _extend_plain(lin[box], np.zeros(member.shape, np.float32), member, hidden, reach)
    want = (acc.copy(), opacity.copy())
    a = want[1][box]
    on = m & (a < 1)
    want[0][box][on] += (np.float32(1.0) - a[on])[:, None] * ext[on]
    a[on] = 1.0
    for g, x in zip(got, want):
        np.testing.assert_array_equal(g, x)


def _holding_bbox(layer, li, box):
    """(bbox, box): layer *li*'s bounding box (row0, row1, col0, col1 inclusive) and *box* widened to hold it, as
    the renderer's box does; None when the layer has no pixel."""
    ys, xs = np.nonzero(layer == li)
    if ys.size == 0:
        return None
    bbox = (ys.min(), ys.max(), xs.min(), xs.max())
    return bbox, (slice(min(box[0].start, bbox[0]), max(box[0].stop, bbox[1] + 1)),
                  slice(min(box[1].start, bbox[2]), max(box[1].stop, bbox[3] + 1)))


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), threads=st.integers(1, 3))
def test_ownership_transform_labels_the_pixel_the_extension_copies(seed, threads):
    """One transform serves ownership and extension: each owned pixel within reach copies the candidate
    that ownership's transform labels nearest, and that is the pixel the transform of the layer's pixels
    alone (on the extension's own window) labels nearest, ties included, on every thread's strip."""
    rng, layer, li, box, hidden, reach = _layer_case(seed)
    placed = _holding_bbox(layer, li, box)
    if placed is None:
        return
    bbox, box = placed
    hidden = (layer[box] < li) & (rng.random((box[0].stop - box[0].start, box[1].stop - box[1].start)) < 0.9)
    found = renderer.ownership.owners_of_hidden(layer, li, box, bbox, hidden, reach, 1, threads)
    if found is None or isinstance(found, np.ndarray):
        return
    dst, src, d = found
    owned = renderer.ownership.owned_mask(layer, li, box, bbox, hidden, reach)
    alone = renderer.extend.behind_sources(layer[box] == li, owned, reach)
    near = d <= reach
    if alone is None:
        assert not near.any()
        return
    order = np.argsort(dst[near])
    np.testing.assert_array_equal(dst[near][order], np.sort(alone[0]))
    np.testing.assert_array_equal(src[near][order], alone[1][np.argsort(alone[0])])


def _bbox(mask):
    """(r0, r1, c0, c1) inclusive of the True pixels of *mask*, or None."""
    if not mask.any():
        return None
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return rows[0], rows[-1], cols[0], cols[-1]


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_cut_window_holds_its_seeds_in_opencv_label_order(seed):
    """A window cut to its seeds and the pixels kept (the renderer's view into the seeds' mask, as OpenCV gets
    it): the kept pixels and every seed are inside it, and OpenCV numbers its seeds in raster order (label k
    is the k-th seed), the order the renderer reads each label's candidate in."""
    rng, layer, li, _, _, _ = _layer_case(seed)
    h, w = layer.shape
    y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
    y1, x1 = int(rng.integers(y0 + 1, h + 1)), int(rng.integers(x0 + 1, w + 1))
    ky0, kx0 = int(rng.integers(y0, y1)), int(rng.integers(x0, x1))
    keep = (ky0, int(rng.integers(ky0, y1)), kx0, int(rng.integers(kx0, x1)))
    seeds = layer[y0:y1, x0:x1] >= li
    found = renderer.ownership.cut_to_seeds(seeds, (y0, y1, x0, x1), keep)
    if not seeds.any():
        assert found is None
        return
    (cy0, cy1, cx0, cx1), cut = found
    assert y0 <= cy0 <= keep[0] and keep[1] < cy1 <= y1 and x0 <= cx0 <= keep[2] and keep[3] < cx1 <= x1
    assert cut.sum() == seeds.sum()  # every seed of the window
    np.testing.assert_array_equal(cut, layer[cy0:cy1, cx0:cx1] >= li)
    _, labels = cv2.distanceTransformWithLabels(np.logical_not(cut).view(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    np.testing.assert_array_equal(labels.ravel()[np.flatnonzero(cut)] - 1, np.arange(int(cut.sum())))


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_transforms_of_the_cut_window_are_the_windows_own(seed):
    """OpenCV's 5x5 chamfer transforms (with labels, and without) of a window cut to its seeds and the pixels
    kept give each kept pixel the window's own distance and nearest seed, ties included, wherever that seed is
    within the reach the window is made for (random layers: straight edges, corners, specks, equal distances)."""
    rng, layer, li, _, _, _ = _layer_case(seed)
    h, w = layer.shape
    seeds = layer >= li if rng.random() < 0.5 else layer > li
    if not seeds.any():
        return
    reach = int(rng.integers(1, 30))
    ky0, kx0 = int(rng.integers(0, h)), int(rng.integers(0, w))
    ky1, kx1 = int(rng.integers(ky0, min(h, ky0 + 30))), int(rng.integers(kx0, min(w, kx0 + 30)))
    win = (max(0, ky0 - reach - 3), min(h, ky1 + reach + 4), max(0, kx0 - reach - 3), min(w, kx1 + reach + 4))
    box = seeds[win[0]:win[1], win[2]:win[3]]
    found = _bbox(box)
    if found is None:
        return
    cut = renderer.ownership.cut_window(win, found, (ky0, ky1, kx0, kx1))
    keep = (slice(ky0, ky1 + 1), slice(kx0, kx1 + 1))

    def transforms(y0, y1, x0, x1):
        src = (~seeds[y0:y1, x0:x1]).astype(np.uint8)
        d, lab = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
        ys, xs = np.nonzero(src == 0)
        nearest = (ys[lab - 1] + y0) * w + xs[lab - 1] + x0  # each pixel's nearest seed, frame flat index
        at = (slice(ky0 - y0, ky1 + 1 - y0), slice(kx0 - x0, kx1 + 1 - x0))
        return d[at], nearest[at], cv2.distanceTransform(src, cv2.DIST_L2, 5)[at]

    d_win, q_win, f_win = transforms(*win)
    d_cut, q_cut, f_cut = transforms(*cut)
    near = d_win <= reach
    np.testing.assert_array_equal(d_cut[near], d_win[near])
    np.testing.assert_array_equal(q_cut[near], q_win[near])
    near = f_win <= reach
    np.testing.assert_array_equal(f_cut[near], f_win[near])
    assert (keep[0].start >= cut[0] and keep[0].stop <= cut[1] and keep[1].start >= cut[2]
            and keep[1].stop <= cut[3])


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), threads=st.integers(1, 2))
def test_continued_pixels_of_an_earlier_mask_cut_to_the_later_one_are_the_later_answer(seed, threads):
    """A layer's continued pixels found ahead (the mask taken before a nearer layer made more pixels opaque) and
    cut to the pixels still hidden are those found on the later mask: each pixel's answer is its own."""
    from pcdof.plans import plan_render
    from pcdof.stages.render.frame import Canvas, RenderFrame

    rng, layer, li, box, _, reach = _layer_case(seed)
    placed = _holding_bbox(layer, li, box)
    if placed is None:
        return
    bbox, box = placed
    h, w = layer.shape
    across = rng.integers(-1, int(layer.max()) + 1, (h, w)).astype(np.int8) if rng.random() < 0.5 else None
    edges = np.stack([renderer.LAYER_EDGES_PX] * 2)  # not read: the ownership reads the layer ids
    frame = RenderFrame(None, None, layer.astype(np.int8), None, plan_render(threads=threads), None, True, across,
                        edges)
    early = np.where(rng.random((h, w)) < 0.3, 1.0, rng.random((h, w)) * 0.99).astype(np.float32)
    late = np.where(rng.random((h, w)) < rng.choice([0.1, 0.5]), 1.0, early).astype(np.float32)
    ownership = renderer.ownership
    found_early = ownership.continued_pixels(frame, ownership.hidden_pixels(frame, Canvas(None, early), li, box), li,
                                             box, bbox, reach)
    cut = ownership.still_hidden(found_early, Canvas(None, late), box)
    want = ownership.continued_pixels(frame, ownership.hidden_pixels(frame, Canvas(None, late), li, box), li, box,
                                      bbox, reach)
    assert (cut is None) == (want is None)
    if want is not None:
        order, want_order = np.argsort(cut.dst), np.argsort(want.dst)
        np.testing.assert_array_equal(cut.dst[order], want.dst[want_order])
        np.testing.assert_array_equal(cut.src[order], want.src[want_order])


@pytest.mark.parametrize("box", [(slice(3, 17), slice(0, 23)), (slice(0, 20), slice(5, 11)), (slice(19, 20), slice(22, 23))])
def test_values_at_flat_indices_of_a_box_are_the_box_pixels(box):
    """The opacity at a box's flat indices, gathered from the frame's flat buffer (a box as wide as the frame and a
    narrower one), is the box's own pixel at each (row, column)."""
    rng = np.random.default_rng(7)
    image = rng.random((20, 23)).astype(np.float32)
    hb, wb = box[0].stop - box[0].start, box[1].stop - box[1].start
    flat = rng.choice(hb * wb, min(hb * wb, 40), replace=False).astype(np.int64)
    rows, cols = np.divmod(flat, wb)
    np.testing.assert_array_equal(renderer.ownership._values_at(image, box, flat), image[box][rows, cols])
