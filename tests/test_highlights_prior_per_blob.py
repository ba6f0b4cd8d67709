"""The ``prior`` method's blobs solved together give what each blob solved alone gives, bit for bit.

The stage's plain reference (:mod:`pcdof.stages.highlights.reference`) writes the method blob by blob and
channel by channel; the stage gathers every footprint's samples into one batch, shares the blurs of a mask among
the channels clipped in the same pixels and finds the medians of every blob in one sort; the output must not
change by a bit.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import highlight_frame

from pcdof.stages import highlights
from pcdof.stages.highlights import CLIP_LEVEL, MAX_KERNEL_PX, footprints
from pcdof.stages.highlights.reference import plain_channel_bound, plain_edge, plain_footprint, plain_prior
from pcdof.stages.highlights.clipped import blob_components, run_medians


class TestBatchedIsPerBlob:
    @settings(max_examples=40, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(8, 90), w=st.integers(8, 120), n=st.integers(1, 14),
           coc_max=st.sampled_from([0.8, 3.0, 12.0, 40.0, 120.0]))
    def test_random_frames(self, seed, h, w, n, coc_max):
        img, coc = highlight_frame(seed, h, w, n, coc_max)
        got = highlights.reconstruct_prior(img, coc_px=coc)
        np.testing.assert_array_equal(got, plain_prior(img, coc))

    @settings(max_examples=15, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 14), coc_max=st.sampled_from([3.0, 12.0, 40.0]))
    def test_random_frames_with_the_rim_evidence(self, seed, n, coc_max):
        img, coc = highlight_frame(seed, 60, 80, n, coc_max)
        got = highlights.reconstruct_prior_rim(img, coc_px=coc)
        np.testing.assert_array_equal(got, plain_prior(img, coc, rim=True))

    @pytest.mark.parametrize("ratio", [1.5, 4.0, math.inf])
    def test_coloured_lights_and_wide_blurs(self, ratio):
        """Many blobs, some larger than a batch's samples, blurs below and above the kernel bound."""
        img, coc = highlight_frame(7, 240, 320, 60, 90.0)
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
        edge, keep = plain_edge(m), float(rng.uniform(0.9, 1.0))
        layers.append(footprints.footprint_layers(chan, m, edge, d))
        keeps.append(keep)
        alone.append(plain_footprint(chan, m, edge, keep, d))
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
            plain_channel_bound(block, clipped_ch, c, ratio)
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
