"""pcdof.stages.highlights: clipped-highlight reconstruction."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.errors import InputError
from pcdof.stages.highlights import (CLIP_LEVEL, HIGHLIGHT_METHODS, clipped_mask, needs_reconstruction,
                                     reconstruct_highlights, rim_level)
from pcdof.stages.highlights.clipped import blob_components


def _box_filtered_disc(level, radius=3.3, bg=0.1, size=24, k=8):
    """A sharp disc of radiance *level* on a flat background, box-filtered over k x k sub-pixels, clipped at 1."""
    sub = (np.arange(size * k) + 0.5) / k - size / 2
    x, y = np.meshgrid(sub, sub)
    hi = np.where(x ** 2 + y ** 2 <= radius ** 2, level, bg)
    img = hi.reshape(size, k, size, k).mean(axis=(1, 3))
    true = np.repeat(img[..., None], 3, axis=2).astype(np.float32)
    return np.minimum(true, 1.0), true


@pytest.mark.parametrize("method", list(HIGHLIGHT_METHODS))
def test_unclipped_input_is_returned_unchanged(method):
    img = np.random.default_rng(0).uniform(0, 0.9, (20, 30, 3)).astype(np.float32)
    out = reconstruct_highlights(img, method=method, coc_px=np.full((20, 30), 9.0))
    assert out.dtype == np.float32 and np.array_equal(out, img) and out is not img


@pytest.mark.parametrize("method", list(HIGHLIGHT_METHODS))
def test_input_is_not_modified_and_only_clipped_channels_change(method):
    clipped, _ = _box_filtered_disc(20.0)
    clipped[..., 2] *= 0.5  # a yellowish lamp: blue is measured everywhere
    before = clipped.copy()
    out = reconstruct_highlights(clipped, method=method, gain=6.0, coc_px=np.full(clipped.shape[:2], 7.0))
    assert np.array_equal(clipped, before)
    changed = out != clipped
    assert not np.any(changed & (clipped < CLIP_LEVEL))
    assert np.all(out >= clipped)
    assert method == "off" or changed.any()


def test_gain_raises_clipped_channels_only():
    """Red clipped everywhere, green in the core only: red gets the gain, green the gain times its share
    of the blob (its hue), blue (measured) stays."""
    img = np.zeros((9, 9, 3), np.float32)
    img[3:6, 3:6] = (1.0, 0.5, 0.25)
    img[4, 4, 1] = 1.0
    out = reconstruct_highlights(img, method="gain", gain=4.0)
    green_hue = (8 * 0.5 + 1.0) / 9
    assert np.allclose(out[4, 4], (4.0, 4.0 * green_hue, 0.25))
    assert np.allclose(out[3, 3], (4.0, 0.5, 0.25))
    assert np.array_equal(out[0, 0], img[0, 0])


def test_rim_estimate_grows_with_the_radiance_of_a_box_filtered_source():
    """Edge-pixel counts of an independent forward model (a box-filtered sharp disc) rise with its
    radiance and stay within a factor 2.2 below it (the estimator is biased low, see the module notes)."""
    from pcdof.stages.highlights.rim import raise_blobs

    estimates = []
    for level in (1.5, 2.5, 4.0):
        clipped, _ = _box_filtered_disc(level, radius=5.2, size=32)
        got = []
        raise_blobs(clipped, CLIP_LEVEL, lambda b, m, r: got.append(rim_level(b, m, r)) or 1.0)
        assert len(got) == 1 and got[0] is not None
        assert level / 2.2 <= got[0] <= level * 1.3
        estimates.append(got[0])
    assert estimates == sorted(estimates) and estimates[-1] > estimates[0]


def test_reconstruction_brings_the_blurred_energy_closer():
    """Blurred with a wide box, the reconstructed source is at least 20 % closer to the truth than the clipped one."""
    import cv2

    clipped, true = _box_filtered_disc(3.0, radius=5.2, size=32)
    out = reconstruct_highlights(clipped, method="rim")
    blur = lambda a: cv2.blur(a, (15, 15))  # noqa: E731
    assert np.abs(blur(out) - blur(true)).mean() < 0.8 * np.abs(blur(clipped) - blur(true)).mean()


def test_linear_input_needs_no_reconstruction():
    assert needs_reconstruction(np.zeros((2, 2, 3), np.uint8), linear=False)
    assert needs_reconstruction(np.zeros((2, 2, 3), np.uint16), linear=False)
    assert not needs_reconstruction(np.zeros((2, 2, 3), np.float32), linear=True)
    assert not needs_reconstruction(np.zeros((2, 2, 3), np.uint16), linear=True)


@pytest.mark.parametrize("kwargs, match", [
    ({"method": "nope"}, "method"), ({"gain": 0.5}, "gain"), ({"gain": float("nan")}, "gain"),
    ({"clip_level": 0.0}, "clip_level"), ({"method": "prior"}, "coc_px"),
    ({"method": "prior", "coc_px": np.zeros((4, 5))}, "coc_px"),
    ({"method": "prior", "coc_px": np.full((4, 4), np.nan)}, "coc_px"),
    ({"method": "prior", "coc_px": np.full((4, 4), "a")}, "coc_px"),
    ({"method": "prior", "coc_px": np.zeros((4, 4)), "prior_max": 0.5}, "prior_max"),
    ({"method": "auto", "coc_px": np.zeros((4, 4)), "prior_max": float("inf")}, "prior_max"),
    ({"method": "auto", "coc_px": np.zeros((4, 4)), "max_channel_ratio": 0.5}, "max_channel_ratio"),
    ({"method": "auto", "coc_px": np.zeros((4, 4)), "max_channel_ratio": float("nan")}, "max_channel_ratio"),
])
def test_bad_options_name_the_argument(kwargs, match):
    with pytest.raises(InputError, match=match):
        reconstruct_highlights(np.zeros((4, 4, 3), np.float32), **kwargs)


def test_bad_image_is_rejected():
    with pytest.raises(InputError, match="linear_rgb"):
        reconstruct_highlights(np.zeros((4, 4), np.float32))
    with pytest.raises(InputError, match="linear_rgb"):
        reconstruct_highlights(np.zeros((4, 4, 3), np.uint8))


# ------------------------------------------------------------------------------- clipped pixels and their blobs
PROPERTY = settings(deadline=None, derandomize=True, max_examples=40, database=None)


class TestClippedMask:
    @PROPERTY
    @given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 40),
           st.sampled_from(["float16", "float32", "float64"]), st.sampled_from([CLIP_LEVEL, 0.5, 1.0, 1e-3]))
    def test_matches_any_over_the_channels(self, seed, h, w, dtype, clip):
        """Against numpy, values on either side of the level in float64 and in the image's dtype too."""
        rng = np.random.default_rng(seed)
        near = [np.nextafter(np.dtype(t).type(clip), np.dtype(t).type(to)) for t in (dtype, "float64") for to in (0, 9)]
        values = np.array([0.0, -1.0, clip, *near, 2.0, np.inf, -np.inf, np.nan], np.float64)
        img = rng.choice(values, (h, w, 3)).astype(dtype)
        img = img if rng.random() < 0.5 else np.asfortranarray(img)
        got = clipped_mask(img, clip)
        assert got.shape == (h, w) and got.dtype == bool
        np.testing.assert_array_equal(got, (img >= clip).any(axis=2))

    @pytest.mark.parametrize("img, clip, match", [(np.zeros((4, 4)), CLIP_LEVEL, "linear_rgb"),
                                                  (np.zeros((4, 4, 4)), CLIP_LEVEL, "linear_rgb"),
                                                  (np.zeros((4, 4, 3)), 0.0, "clip_level"),
                                                  (np.zeros((4, 4, 3)), float("nan"), "clip_level")])
    def test_bad_input_is_rejected(self, img, clip, match):
        with pytest.raises(InputError, match=match):
            clipped_mask(img, clip)


class TestComponents:
    @PROPERTY
    @given(st.integers(0, 2**32 - 1), st.integers(1, 50), st.integers(1, 50), st.floats(0.0, 1.0))
    def test_boxes_and_pixels_match_opencvs_stats(self, seed, h, w, share):
        """Each blob's box and pixels against cv2.connectedComponentsWithStats (which labels the same way)."""
        rng = np.random.default_rng(seed)
        clipped = rng.random((h, w)) < share
        labels, boxes, pixels = blob_components(clipped)
        n, want_labels, stats, _ = cv2.connectedComponentsWithStats(clipped.astype(np.uint8), connectivity=8)
        np.testing.assert_array_equal(labels, want_labels)
        assert len(boxes) == len(pixels) == n - 1
        for b in range(1, n):
            x, y, bw, bh = stats[b, :4]
            assert boxes[b - 1].tolist() == [y, y + bh, x, x + bw]
            ys, xs = np.nonzero(want_labels == b)  # raster order
            np.testing.assert_array_equal(pixels[b - 1][0], ys)
            np.testing.assert_array_equal(pixels[b - 1][1], xs)
