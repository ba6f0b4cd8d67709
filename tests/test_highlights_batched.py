"""The ``prior`` method's blobs solved together give what each blob solved alone gives, bit for bit.

:func:`plain_prior` below is the method written blob by blob and channel by channel: each blob's median CoC
with ``np.median``, each clipped channel's footprint blurred on its own and its level chosen on its own
(:func:`pcdof.stages.highlights.expected_best_level`). The module gathers every footprint's samples into one batch,
shares the blurs of a mask among the channels clipped in the same pixels and finds the medians of every blob
in one sort; the output must not change by a bit.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.lens import MAX_COC_PX
from pcdof.stages import highlights
from pcdof.stages.highlights import CLIP_LEVEL, MAX_FOOTPRINT_PX, MAX_KERNEL_PX, PRIOR_MAX, PRIOR_SAMPLES, footprints
from pcdof.stages.highlights.clipped import blob_components, run_medians


def _plain_edge(m):
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    return m & ~cv2.erode(m.astype(np.uint8), cross, borderType=cv2.BORDER_REPLICATE).astype(bool)


def _plain_footprint(chan, m, edge, keep, d):
    """One channel's (base, k, weight), every blur of its own."""
    scale = max(1.0, d / MAX_KERNEL_PX)
    if scale > 1.0:
        layers = np.stack([np.where(m, 0.0, chan), m & ~edge, edge], axis=-1).astype(np.float32)
        size = (max(1, round(chan.shape[1] / scale)), max(1, round(chan.shape[0] / scale)))
        layers = cv2.resize(layers, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], 3)
        kern = highlights.disc_kernel(d / scale)
        borders = (cv2.BORDER_REPLICATE, cv2.BORDER_CONSTANT, cv2.BORDER_CONSTANT)
        rest, inner, k_edge = (cv2.filter2D(layers[..., i], -1, kern, borderType=b).ravel().astype(np.float64)
                               for i, b in enumerate(borders))
    else:
        kern = highlights.disc_kernel(d)
        rest = cv2.filter2D(np.where(m, np.float32(0.0), chan).astype(np.float32), -1, kern,
                            borderType=cv2.BORDER_REPLICATE).ravel().astype(np.float64)
        inner, k_edge = (cv2.filter2D(a.astype(np.float32), -1, kern, borderType=cv2.BORDER_CONSTANT).ravel()
                         .astype(np.float64) for a in (m & ~edge, edge))
    base, k = rest + keep / 2 * k_edge, inner + k_edge / 2
    sel = np.flatnonzero(k > 1e-6)
    step = max(1, int(math.ceil(sel.size / MAX_FOOTPRINT_PX)))
    sel = sel[::step]
    return base[sel], k[sel], np.full(sel.size, step * scale * scale)


def _plain_channel_bound(block, clipped_ch, c, max_ratio):
    m = clipped_ch[..., c]
    others = [o for o in range(3) if o != c]
    measured = np.where(clipped_ch[..., others], 0.0, block[..., others]).max(axis=-1)
    has = m & ~clipped_ch[..., others].all(axis=-1)
    if math.isinf(max_ratio) or 2 * np.count_nonzero(has) <= np.count_nonzero(m):
        return math.inf  # no ratio: no bound (inf times a measured 0 is no number)
    return float(max_ratio * np.median(measured[has]))


def plain_prior(img, coc, *, clip_level=CLIP_LEVEL, prior_max=PRIOR_MAX, max_ratio=4.0, rim=False):
    """``reconstruct_prior`` blob by blob and channel by channel."""
    out = img.copy()
    clipped = (img >= clip_level).any(axis=2)
    n, labels = cv2.connectedComponents(clipped.astype(np.uint8), connectivity=8)
    h, w = clipped.shape
    for b in range(1, n):
        ys, xs = np.nonzero(labels == b)
        d = float(np.median(np.minimum(np.abs(coc[ys, xs].astype(np.float32)), MAX_COC_PX)))
        if d < 1.0:
            continue
        p = math.ceil(d / 2) + 1
        win = (slice(max(ys.min() - p, 0), min(ys.max() + 1 + p, h)),
               slice(max(xs.min() - p, 0), min(xs.max() + 1 + p, w)))
        block = img[win]
        clipped_ch = (labels[win] == b)[..., None] & (block >= clip_level)
        for c in range(3):
            m = clipped_ch[..., c]
            if not m.any():
                continue
            top = min(prior_max, _plain_channel_bound(block, clipped_ch, c, max_ratio))
            if top <= clip_level:
                continue
            levels = highlights.prior_levels(clip_level, top, PRIOR_SAMPLES)
            chan, edge = block[..., c], _plain_edge(m)
            keep = float(chan[m].max())
            base, k, weight = _plain_footprint(chan, m, edge, keep, d)
            lw = highlights.rim_likelihood(chan, m, clipped[win], levels, clip_level) if rim else None
            level = highlights.expected_best_level(base, k, weight, levels, keep, lw) if base.size else keep
            out[win][..., c][m] = np.maximum(chan, np.where(edge, (level + keep) / 2, level))[m]
    return out


def _frame(seed, h, w, n_blobs, coc_max):
    """A random linear frame with *n_blobs* clipped discs and boxes (white, or clipped in some channels only,
    some touching the border or each other) and a CoC map of blobs at several blurs, up to *coc_max* px."""
    rng = np.random.default_rng(seed)
    img = (rng.random((h, w, 3)) * 0.7).astype(np.float32)
    coc = np.full((h, w), rng.uniform(0, coc_max), np.float32)
    yy, xx = np.mgrid[:h, :w]
    for _ in range(n_blobs):
        cy, cx, r = rng.integers(0, h), rng.integers(0, w), rng.uniform(0.5, 9)
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r if rng.random() < 0.6 else \
            (abs(yy - cy) <= r) & (abs(xx - cx) <= rng.uniform(0.5, 9))
        channels = [c for c in range(3) if rng.random() < 0.7] or [int(rng.integers(3))]
        for c in channels:
            img[..., c][inside] = rng.choice([1.0, CLIP_LEVEL, 0.999])
        coc[inside] = rng.uniform(0, coc_max) * rng.uniform(0.8, 1.2, np.count_nonzero(inside))
    return img, np.where(rng.random((h, w)) < 0.1, -coc, coc)  # (the sign is ignored)


class TestBatchedIsPerBlob:
    @settings(max_examples=40, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(8, 90), w=st.integers(8, 120), n=st.integers(1, 14),
           coc_max=st.sampled_from([0.8, 3.0, 12.0, 40.0, 120.0]))
    def test_random_frames(self, seed, h, w, n, coc_max):
        img, coc = _frame(seed, h, w, n, coc_max)
        got = highlights.reconstruct_prior(img, coc_px=coc)
        np.testing.assert_array_equal(got, plain_prior(img, coc))

    @settings(max_examples=15, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 14), coc_max=st.sampled_from([3.0, 12.0, 40.0]))
    def test_random_frames_with_the_rim_evidence(self, seed, n, coc_max):
        img, coc = _frame(seed, 60, 80, n, coc_max)
        got = highlights.reconstruct_prior_rim(img, coc_px=coc)
        np.testing.assert_array_equal(got, plain_prior(img, coc, rim=True))

    @pytest.mark.parametrize("ratio", [1.5, 4.0, math.inf])
    def test_coloured_lights_and_wide_blurs(self, ratio):
        """Many blobs, some larger than a batch's samples, blurs below and above the kernel bound."""
        img, coc = _frame(7, 240, 320, 60, 90.0)
        img[40:120, 30:150, 0] = 1.0  # one blob of more than MAX_FOOTPRINT_PX pixels, clipped in red only
        coc[40:120, 30:150] = 20.0
        got = highlights.reconstruct_prior(img, coc_px=coc, max_channel_ratio=ratio)
        np.testing.assert_array_equal(got, plain_prior(img, coc, max_ratio=ratio))
        assert not np.array_equal(got, img)  # something was raised


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 12))
def test_medians_are_numpys(seed, n):
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, 9, n)
    values = rng.choice(np.float32([0.0, 0.5, 1.0, 2.5, 7.0, 1e-3]), sizes.sum()) if rng.random() < 0.5 \
        else (rng.random(sizes.sum()) * 50).astype(np.float32)
    if rng.random() < 0.3:  # negative values and -0.0: sorted by value, not by their bits
        values = np.where(rng.random(values.size) < 0.5, -values, values)
    if rng.random() < 0.2:
        values = values.astype(np.float64)
    if rng.random() < 0.1:
        values[rng.integers(0, values.size)] = np.nan
    starts = np.concatenate(([0], np.cumsum(sizes)))
    got = run_medians(values, starts)
    want = [np.median(values[a:b]) for a, b in zip(starts[:-1], starts[1:])]
    assert got.dtype == values.dtype
    np.testing.assert_array_equal(got, np.array(want, values.dtype))


@pytest.mark.parametrize("d", [1.5, 12.0, 45.0])
def test_samples_of_many_footprints_are_each_ones(d):
    """Footprints gathered into one array: each one's samples and weights as it gives them alone (a small blob,
    one of more than MAX_FOOTPRINT_PX samples, subsampled, and a ring)."""
    rng = np.random.default_rng(int(d))
    layers, keeps, alone = [], [], []
    for shape, box in (((9, 11), (3, 6, 4, 8)), ((60, 110), (5, 55, 10, 100)), ((30, 30), (8, 22, 8, 22))):
        chan = rng.random(shape).astype(np.float32)
        m = np.zeros(shape, bool)
        m[box[0]:box[1], box[2]:box[3]] = True
        if shape == (30, 30):
            m[12:18, 12:18] = False
        edge, keep = _plain_edge(m), float(rng.uniform(0.9, 1.0))
        layers.append(footprints.footprint_layers(chan, m, edge, d))
        keeps.append(keep)
        alone.append(_plain_footprint(chan, m, edge, keep, d))
    base, k, weight, counts = footprints.footprint_samples(layers, keeps)
    assert counts.tolist() == [a[0].size for a in alone]
    assert alone[1][2][0] > max(1.0, d / MAX_KERNEL_PX) ** 2  # (the large one was subsampled)
    for got, want in zip((base, k, weight), zip(*alone)):
        np.testing.assert_array_equal(got, np.concatenate(want))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 300), w=st.integers(1, 300), n=st.integers(0, 12))
def test_components_labelled_in_their_box_are_the_whole_frames(seed, h, w, n):
    """Blobs labelled inside the box around every clipped pixel: the labels, boxes and pixels of the whole frame
    labelled by OpenCV (numbered in raster order of their first pixel either way)."""
    rng = np.random.default_rng(seed)
    clipped = np.zeros((h, w), bool)
    for _ in range(n):
        y, x = rng.integers(0, h), rng.integers(0, w)
        clipped[y:y + rng.integers(1, 12), x:x + rng.integers(1, 12)] = rng.random() < 0.9
        clipped[rng.integers(0, h), rng.integers(0, w)] = True
    labels, boxes, pixels = blob_components(clipped)
    _, want = cv2.connectedComponents(clipped.astype(np.uint8), connectivity=8)
    np.testing.assert_array_equal(labels, want)
    assert len(boxes) == len(pixels) == want.max()
    for b, (ys, xs) in enumerate(pixels, start=1):
        wy, wx = np.nonzero(want == b)
        np.testing.assert_array_equal(ys, wy)
        np.testing.assert_array_equal(xs, wx)
        assert boxes[b - 1].tolist() == [wy.min(), wy.max() + 1, wx.min(), wx.max() + 1]


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 20), w=st.integers(1, 20),
       ratio=st.sampled_from([1.0, 4.0, math.inf]), dtype=st.sampled_from([np.float32, np.float64]))
def test_channel_bound_is_the_plain_formula(seed, h, w, ratio, dtype):
    rng = np.random.default_rng(seed)
    block = rng.choice([0.0, 0.2, 0.5, 0.9, CLIP_LEVEL, 1.0], (h, w, 3)).astype(dtype)
    if rng.random() < 0.5:
        block = (rng.random((h, w, 3)) * 1.2).astype(dtype)
    clipped_ch = (block >= CLIP_LEVEL) & (rng.random((h, w, 1)) < 0.8)
    for c in range(3):
        got, want = highlights.channel_bound(block, clipped_ch, c, ratio), \
            _plain_channel_bound(block, clipped_ch, c, ratio)
        assert got == want or (math.isnan(got) and math.isnan(want))


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 40), dtype=st.sampled_from([np.float32, np.float64]))
def test_median_is_numpys(seed, n, dtype):
    rng = np.random.default_rng(seed)
    values = rng.choice([-1.0, -0.0, 0.0, 0.25, 0.5, 3.0], n) if rng.random() < 0.5 else rng.normal(size=n)
    values = values.astype(dtype)
    if rng.random() < 0.1:
        values[rng.integers(0, n)] = np.nan
    got, want = footprints.median_1d(values), np.median(values)
    assert got.dtype == want.dtype and (got == want or (np.isnan(got) and np.isnan(want)))
