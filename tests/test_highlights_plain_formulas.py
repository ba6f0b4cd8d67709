"""The highlights stage's shortcuts give what the plain formulas give, bit for bit.

Integer codes are compared with OpenCV at the level rounded up; the display curve raises to a power only
between its linear segment and white; the prior's levels are kept per (clip level, top); the blurred clipped
pixels of one mask serve every channel clipped in the same pixels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.stages.highlights import CLIP_LEVEL, clipped_mask, footprints, loss, prior_levels


class TestClippedMaskOfCodes:
    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2 ** 32 - 1), h=st.integers(1, 30), w=st.integers(1, 30),
           dtype=st.sampled_from(["uint8", "uint16"]),
           level=st.sampled_from([0.25, 1.0, 17.5, 254.5, 255.0, 255.5, 300.0, 65534.5, 65535.0, 70000.0]))
    def test_matches_numpy(self, seed, h, w, dtype, level):
        rng = np.random.default_rng(seed)
        top = np.iinfo(dtype).max
        values = np.array([0, 1, 17, 18, 254, 255, 256, 65534, 65535], np.int64)
        img = rng.choice(values[values <= top], (h, w, 3)).astype(dtype)
        img = img if rng.random() < 0.5 else np.asfortranarray(img)
        got = clipped_mask(img, level)
        assert got.shape == (h, w) and got.dtype == bool
        np.testing.assert_array_equal(got, (img >= level).any(axis=2))


def _display_plainly(linear):
    v = np.clip(linear, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def test_display_is_the_clipped_srgb_curve():
    v = np.concatenate([np.linspace(-1.0, 3.0, 40001), [np.nan, np.inf, -np.inf, 0.0031308, 1.0,
                                                        np.nextafter(0.0031308, 1.0), np.nextafter(1.0, 0.0)]])
    np.testing.assert_array_equal(loss.display(np.stack([v, v[::-1]])), _display_plainly(np.stack([v, v[::-1]])))


def test_prior_levels_are_fresh_arrays_of_the_formula():
    a = prior_levels(CLIP_LEVEL, 16.0)
    lo, hi = math.log(CLIP_LEVEL), math.log(16.0)
    np.testing.assert_array_equal(a, np.exp(lo + (np.arange(32) + 0.5) / 32 * (hi - lo)))
    a[:] = 0.0  # the caller's copy: the kept levels are not touched
    assert prior_levels(CLIP_LEVEL, 16.0)[0] > CLIP_LEVEL


@pytest.mark.parametrize("d", [1.5, 6.0, 20.0, 31.9])
def test_shared_cover_gives_each_channel_its_own_footprint(d):
    rng = np.random.default_rng(int(d * 10))
    block = rng.random((40, 50, 3)).astype(np.float32)
    m = np.zeros((40, 50), bool)
    m[12:25, 15:33] = True
    edge = footprints.edge_of(m)
    cover = {}
    for c in range(3):  # the second and third channels reuse the first one's blurred mask
        shared = footprints.footprint(block[..., c], m, edge, 1.0, d, cover)
        alone = footprints.footprint(block[..., c], m, edge, 1.0, d)
        for a, b in zip(shared, alone):
            np.testing.assert_array_equal(a, b)
    assert len(cover) == 1
    other = m.copy()
    other[12, 15] = False  # another mask: blurred anew
    footprints.footprint(block[..., 0], other, footprints.edge_of(other), 1.0, d, cover)
    assert len(cover) == 2
