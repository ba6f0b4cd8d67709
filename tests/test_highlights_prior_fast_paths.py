"""The ``prior`` method's faster paths give what their plain formulations give, bit for bit.

Each test writes the plain formulation out (blob by blob, channel by channel, footprint by footprint) and
compares on random inputs: the expected loss of one prior for every footprint (its T weights, not one per
sample), the display curve of a table with nothing on its linear segment, every channel's interior from one
erosion and each channel's blurs from its mask and interior, the channel bounds of every blob from one sort
(found with the colour, before the circle of confusion), the blurs of channels clipped alike counted once, the
levels written in one go, the blobs found from numpy's nonzero pixels, and the whole stage from 8-bit codes.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import highlight_frame

from pcdof.color import decode_to_linear
from pcdof.stages import highlights
from pcdof.stages.highlights import CLIP_LEVEL, MAX_KERNEL_PX, PRIOR_MAX, footprints, loss, prior
from pcdof.stages.highlights.reference import plain_channel_bound, plain_edge, plain_footprint, plain_prior
from pcdof.stages.highlights.clipped import find_blobs



def _plain_display(v):
    """The display curve as the module wrote it first: every value through the power, the linear segment put back."""
    v = np.clip(v, 0.0, 1.0)
    low = v <= 0.0031308
    linear = v[low] * 12.92
    v = np.power(v, 1 / 2.4)
    v *= 1.055
    v -= 0.055
    v[low] = linear
    return v


def _plain_best_levels(base, k, weight, starts, cands, probs):
    """:func:`pcdof.loss.best_levels` with every sample's probabilities repeated (one row per footprint)."""
    counts = np.diff(starts)
    table = np.repeat(cands.T, counts, axis=1)
    table *= k
    table += base
    shown = _plain_display(table)
    mean_shown = np.einsum("tn,tn->n", np.repeat(probs.T, counts, axis=1), shown[1:])
    first = starts[:-1]
    ws = shown * weight
    a2 = np.add.reduceat(ws * shown, first, axis=1)
    cross = np.add.reduceat(ws * mean_shown, first, axis=1)
    expected = a2 - 2 * cross + np.einsum("jt,tj->j", probs, a2[1:])
    near = expected <= expected.min(axis=0) + 1e-7 * np.maximum(np.add.reduceat(weight, first), 1.0)
    return cands[np.arange(len(cands)), np.argmax(near, axis=0)]


@settings(max_examples=120, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), t=st.integers(1, 40), n=st.sampled_from([1, 2, 3, 7, 8, 9, 63, 500, 4099]))
def test_mean_over_truths_is_the_einsum_of_repeated_weights(seed, t, n):
    rng = np.random.default_rng(seed)
    probs = rng.random(t) if rng.random() < 0.5 else np.ones(t)
    probs /= probs.sum()
    shown = rng.random((t + 1, n)) * (rng.random((t + 1, n)) < 0.9)  # (row 0 is the keep's: left out)
    counts = rng.multinomial(n, np.ones(3) / 3)
    repeated = np.repeat(np.repeat(probs[None, :], 3, axis=0).T, counts, axis=1)
    np.testing.assert_array_equal(loss.mean_over_truths(probs, shown[1:]),
                                  np.einsum("tn,tn->n", repeated, shown[1:]))


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), j=st.integers(1, 8), t=st.integers(1, 33), one_prior=st.booleans(),
       weighted=st.booleans(), dark=st.booleans())
def test_best_levels_are_the_plain_ones(seed, j, t, one_prior, weighted, dark):
    """One prior for all footprints or one each, unit weights or not, tables with values on the display curve's
    linear segment (a dark background) or none."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(1, 300, j)
    starts = np.concatenate(([0], np.cumsum(counts)))
    n = int(starts[-1])
    base = rng.uniform(0.0, 0.002, n) if dark else rng.uniform(0.01, 0.9, n)
    k = rng.uniform(1e-6, 1.0, n) ** 3 * (1e-4 if dark and rng.random() < 0.5 else 1.0)
    weight = rng.integers(1, 5, n).astype(float) if weighted else np.ones(n)
    levels = np.sort(rng.uniform(1.0, 30.0, (j, t)), axis=1)
    cands = np.column_stack((rng.uniform(CLIP_LEVEL, 1.0, j), levels))
    probs = np.repeat(rng.random((1, t)), j, axis=0) if one_prior else rng.random((j, t))
    probs /= probs.sum(axis=1, keepdims=True)
    got = loss.best_levels(base, k, weight, starts, cands, probs)
    np.testing.assert_array_equal(got, _plain_best_levels(base, k, weight, starts, cands, probs))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), j=st.integers(1, 40), threads=st.integers(2, 4))
def test_levels_of_batches_shared_among_threads_are_those_of_one(seed, j, threads):
    """Batches of a few footprints each (max_samples small), solved on several threads: each footprint's level as
    one thread gives it, a footprint of no samples keeping its value."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 120, j)
    n = int(counts.sum())
    base, k, weight = rng.uniform(0.01, 0.9, n), rng.uniform(1e-6, 1.0, n) ** 3, np.ones(n)
    cands = np.column_stack((rng.uniform(CLIP_LEVEL, 1.0, j), np.sort(rng.uniform(1.0, 30.0, (j, 8)), axis=1)))
    probs = rng.random((j, 8))
    probs /= probs.sum(axis=1, keepdims=True)
    one = loss.levels_of(base, k, weight, counts, cands, probs, max_samples=150, threads=1)
    assert loss.levels_of(base, k, weight, counts, cands, probs, max_samples=150, threads=threads) == one
    assert [one[i] for i in np.flatnonzero(counts == 0)] == cands[counts == 0, 0].tolist()


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), rows=st.integers(1, 40), n=st.integers(1, 300))
def test_display_of_tables_above_the_linear_segment(seed, rows, n):
    rng = np.random.default_rng(seed)
    v = rng.uniform(0.0031308, 1.5, (rows, n))
    v[rng.random((rows, n)) < 0.2] = 1.0
    if rng.random() < 0.5:
        v[rng.integers(rows), rng.integers(n)] = rng.choice([0.0, 0.0031308, 0.001, -0.5])  # one on it
    v = np.nextafter(v, 2.0) if rng.random() < 0.3 else v
    np.testing.assert_array_equal(loss.display(v), _plain_display(v))


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 25), w=st.integers(1, 25))
def test_interior_of_every_channel_is_each_mask_less_its_edge(seed, h, w):
    rng = np.random.default_rng(seed)
    clipped_ch = rng.random((h, w, 3)) < rng.uniform(0.2, 0.95)
    interior = footprints.interior_of(clipped_ch)
    assert interior.shape == (h, w, 3) and interior.dtype == bool
    for c in range(3):
        m = clipped_ch[..., c]
        np.testing.assert_array_equal(interior[..., c], m & ~plain_edge(m))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
       d=st.sampled_from([1.0, 2.5, 9.0, 20.0, 32.0, 33.0, 70.0]))
def test_channel_layers_from_the_interior_are_the_plain_blurs(seed, h, w, d):
    """A channel's blurs made from its mask and interior: the arrays :func:`_layers` makes from the mask and its
    edge, the second channel of the same mask reusing the first one's blurred interior and edge."""
    rng = np.random.default_rng(seed)
    block = rng.random((h, w, 2)).astype(np.float32)
    m = rng.random((h, w)) < rng.uniform(0.1, 0.9)
    inner = footprints.interior_of(np.repeat(m[..., None], 3, axis=2))[..., 0]
    cover = {}
    for c in range(2):
        got = footprints.channel_layers(block[..., c], m, inner, d, cover, "mask")
        want = footprints.footprint_layers(block[..., c], m, plain_edge(m), d)
        assert got[3] == want[3]
        for a, b in zip(got[:3], want[:3]):
            np.testing.assert_array_equal(a, b)
    assert len(cover) == 1


def _blob_windows(img, found):
    """Per blob: (window, per-channel clipped mask in it), its box widened by 3 px."""
    h, w = found.clipped.shape
    for (y0, y1, x0, x1), a, b in zip(found.boxes.tolist(), found.starts[:-1].tolist(), found.starts[1:].tolist()):
        win = (slice(max(y0 - 3, 0), min(y1 + 3, h)), slice(max(x0 - 3, 0), min(x1 + 3, w)))
        clipped_ch = np.zeros((win[0].stop - win[0].start, win[1].stop - win[1].start, 3), bool)
        clipped_ch[found.ys[a:b] - win[0].start, found.xs[a:b] - win[1].start] = found.flags[a:b]
        yield win, clipped_ch


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 14), ratio=st.sampled_from([1.0, 1.5, 4.0, math.inf]),
       prior_max=st.sampled_from([PRIOR_MAX, 2.0, 16.1, 0.5]))
def test_tops_are_each_blobs_channel_bounds(seed, n, ratio, prior_max):
    """Coloured blobs (some channels measured), values that clip in one channel only: every blob channel's prior
    top, min(prior max, its channel bound), as :func:`channel_bound` gives it blob by blob."""
    img, _ = highlight_frame(seed, 50, 70, n, 3.0)
    rng = np.random.default_rng(seed)
    img[rng.random(img.shape[:2]) < 0.05, rng.integers(3)] = 1.0
    found = find_blobs(img, CLIP_LEVEL)
    tops = prior.prior_tops(found, (CLIP_LEVEL, prior_max, ratio))
    assert tops.shape == (len(found.boxes), 3)
    for i, (win, clipped_ch) in enumerate(_blob_windows(img, found)):
        for c in range(3):
            if not clipped_ch[..., c].any():
                assert tops[i, c] == -math.inf
                continue
            assert tops[i, c] == min(prior_max, plain_channel_bound(img[win], clipped_ch, c, ratio))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 60), w=st.integers(1, 60), n=st.integers(1, 12))
def test_found_blobs_are_the_plain_ones(seed, h, w, n):
    """The blobs of numpy's nonzero pixels, whether their channels are clipped alike, and each value's slot
    (blob * 3 + channel) and index in the frame, against OpenCV's labelling of the whole frame."""
    img, _ = highlight_frame(seed, h, w, n, 3.0)
    found = find_blobs(img, CLIP_LEVEL)
    clipped = (img >= CLIP_LEVEL).any(axis=2)
    count, labels = cv2.connectedComponents(clipped.astype(np.uint8), connectivity=8)
    assert len(found.boxes) == count - 1
    frame_index = np.arange(img.size).reshape(img.shape)
    for b in range(1, count):
        ys, xs = np.nonzero(labels == b)
        a, e = found.starts[b - 1], found.starts[b]
        np.testing.assert_array_equal(found.ys[a:e], ys)
        np.testing.assert_array_equal(found.xs[a:e], xs)
        flags = img[ys, xs] >= CLIP_LEVEL
        pairs = ((0, 1), (0, 2), (1, 2))
        assert found.alike[b - 1] == [bool(np.array_equal(flags[:, p], flags[:, q])) for p, q in pairs]
        np.testing.assert_array_equal(found.slot[3 * a:3 * e], np.tile(3 * (b - 1) + np.arange(3), e - a))
        np.testing.assert_array_equal(found.dest[3 * a:3 * e], frame_index[ys, xs].ravel())


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), d=st.sampled_from([1.5, 4.0, 12.0, 31.0, 45.0]))
def test_samples_of_channels_clipped_alike_are_each_ones(seed, d):
    """Footprints whose blurred interior and edge are the same arrays (channels clipped alike, blurred once) next
    to footprints of their own: each one's samples and weights as it gives them alone."""
    rng = np.random.default_rng(seed)
    layers, keeps, alone = [], [], []
    for _ in range(int(rng.integers(1, 4))):
        h, w = (int(v) for v in rng.integers(8, 70, 2))
        block = rng.random((h, w, 3)).astype(np.float32)
        m = np.zeros((h, w), bool)
        y, x = int(rng.integers(0, h - 2)), int(rng.integers(0, w - 2))
        m[y:y + int(rng.integers(1, h - y)), x:x + int(rng.integers(1, w - x))] = True
        masks = [m, m, m.copy() if rng.random() < 0.5 else np.roll(m, 1, axis=1)]
        cover = {}
        for c, mc in enumerate(masks):
            edge, keep = plain_edge(mc), float(rng.uniform(0.9, 1.0))
            layers.append(footprints.footprint_layers(block[..., c], mc, edge, d, cover))
            keeps.append(keep)
            alone.append(plain_footprint(block[..., c], mc, edge, keep, d))
    assert any(a[1] is b[1] for a, b in zip(layers, layers[1:]))  # (some share their blurs)
    base, k, weight, counts = footprints.footprint_samples(layers, keeps)
    assert counts.tolist() == [a[0].size for a in alone]
    for got, want in zip((base, k, weight), zip(*alone)):
        np.testing.assert_array_equal(got, np.concatenate(want))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 14), layout=st.sampled_from(["in place", "copy", "F"]))
def test_levels_written_at_once_are_each_footprints(seed, n, layout):
    """Random levels for random blob channels: written in one go as footprint by footprint in its window (the
    interior to L, the edge to (L + keep) / 2, none below its value), into the input, a copy or a Fortran-ordered
    copy."""
    img, _ = highlight_frame(seed, 40, 60, n, 3.0)
    found = find_blobs(img, CLIP_LEVEL)
    rng = np.random.default_rng(seed)
    feet, chosen, interior, want = [], [], np.zeros(found.flags.shape, bool), img.copy()
    for i, (win, clipped_ch) in enumerate(_blob_windows(img, found)):
        a, b = found.starts[i], found.starts[i + 1]
        inner = footprints.interior_of(clipped_ch)
        interior[a:b] = inner[found.ys[a:b] - win[0].start, found.xs[a:b] - win[1].start]
        for c in range(3):
            if not clipped_ch[..., c].any() or rng.random() < 0.2:
                continue
            keep, level = found.keeps[i][c], float(rng.choice([found.keeps[i][c], rng.uniform(0.5, 20.0)]))
            feet.append((i, c, keep))
            chosen.append(level)
            m, edge = clipped_ch[..., c], plain_edge(clipped_ch[..., c])
            block = want[win]
            block[..., c][m] = np.maximum(block[..., c][m], np.where(edge[m], (level + keep) / 2, level))
    if not feet:
        return
    out = img if layout == "in place" else img.copy() if layout == "copy" else np.asfortranarray(img)
    prior.write_levels(out, found, feet, np.array(chosen), interior)
    np.testing.assert_array_equal(out, want)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 14), coc_max=st.sampled_from([3.0, 12.0, 40.0, 90.0]))
def test_prepared_codes_are_raised_as_blob_by_blob(seed, n, coc_max):
    """The stage as the pipeline runs it (8-bit codes prepared, then raised in place) against the method written
    blob by blob and channel by channel on the decoded colour."""
    img, coc = highlight_frame(seed, 70, 90, n, coc_max)
    codes = np.clip(np.rint(img ** (1 / 2.2) * 255), 0, 255).astype(np.uint8)
    prepared = highlights.prepare_highlights(codes)
    if prepared is None:
        return
    want = plain_prior(decode_to_linear(codes), coc, clip_level=prepared.clip_level)
    got = highlights.reconstruct_prepared(prepared, method="auto", coc_px=coc)
    np.testing.assert_array_equal(got, want)
    assert MAX_KERNEL_PX < 90.0  # (the widest blurs go through the shrunk window)
