"""pcdof.color.to_uint8: the one 8-bit conversion (video frames, viewer previews, PLY colours)."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.color import from_float, to_uint8
from pcdof.errors import InputError, PcdofError


def nearest(numerator: int, denominator: int) -> int:
    """round(numerator / denominator) to nearest in exact rational arithmetic (an independent reference)."""
    return int(round(Fraction(numerator, denominator)))


class TestUint8:
    def test_returned_as_is(self):
        image = np.arange(256, dtype=np.uint8).reshape(16, 16)
        out = to_uint8(image)
        assert out is image


class TestUint16:
    def test_every_value_against_exact_rounding(self):
        v = np.arange(65536, dtype=np.uint16)
        want = np.array([nearest(int(x) * 255, 65535) for x in v], dtype=np.uint8)
        np.testing.assert_array_equal(to_uint8(v), want)

    def test_rounding_edges(self):
        # v / 257 crosses k + 1/2 between 128 and 129 (128.5 = 0.5 * 257): 128 -> 0, 129 -> 1
        got = to_uint8(np.array([0, 128, 129, 385, 386, 65406, 65407, 65535], np.uint16))
        np.testing.assert_array_equal(got, [0, 0, 1, 1, 2, 254, 255, 255])

    def test_not_a_shift(self):
        # v >> 8 floors: 255 * 257 - 1 = 65534 would give 255 - 1 = 254 by a shift; rounding gives 255
        assert to_uint8(np.array([65534], np.uint16))[0] == 255
        assert to_uint8(np.array([383], np.uint16))[0] == 1  # 383 >> 8 = 1 too, 383 / 257 = 1.49

    def test_round_trip_of_every_8_bit_value(self):
        v8 = np.arange(256, dtype=np.uint8)
        np.testing.assert_array_equal(to_uint8(v8.astype(np.uint16) * np.uint16(257)), v8)


class TestFloat:
    @pytest.mark.parametrize("dtype", [np.float32, np.float64])
    def test_rounding_and_clipping(self, dtype):
        x = np.array([-1.0, 0.0, 0.5 / 255 - 1e-6, 0.5 / 255 + 1e-6, 0.5, 1.0, 1.5, np.inf, -np.inf, np.nan],
                     dtype)
        np.testing.assert_array_equal(to_uint8(x), [0, 0, 0, 1, 128, 255, 255, 255, 0, 0])

    @settings(max_examples=200, deadline=None)
    @given(st.lists(st.integers(0, 10**6), min_size=1, max_size=50))
    def test_against_exact_rounding(self, millionths):
        x = np.array(millionths, dtype=np.float64) / 1e6
        want = [nearest(m * 255, 10**6) for m in millionths]
        got = to_uint8(x)
        # x is m / 1e6 rounded to float64; only an exact tie (m * 255 / 1e6 = k + 1/2) can round either way
        ties = np.array([(m * 255 * 2) % (2 * 10**6) == 10**6 for m in millionths])
        np.testing.assert_array_equal(got[~ties], np.array(want, np.uint8)[~ties])
        assert np.all(np.abs(got.astype(int) - np.array(want)) <= 1)

    def test_agrees_with_the_16_bit_encoding_within_one(self):
        x = np.random.default_rng(0).random(10_000)
        diff = to_uint8(from_float(x, np.uint16)).astype(int) - to_uint8(x).astype(int)
        assert np.abs(diff).max() <= 1


class TestOtherIntegers:
    def test_signed_negatives_are_zero(self):
        got = to_uint8(np.array([-32768, -1, 0, 16384, 32767], np.int16))
        np.testing.assert_array_equal(got, [0, 0, 0, nearest(16384 * 255, 32767), 255])

    def test_uint32_scales_by_its_maximum(self):
        top = 2**32 - 1
        v = np.array([0, top // 2, top], np.uint32)
        np.testing.assert_array_equal(to_uint8(v), [0, nearest(int(v[1]) * 255, top), 255])


class TestShapesAndErrors:
    @pytest.mark.parametrize("shape", [(5,), (4, 6), (4, 6, 3), (2, 3, 4, 1)])
    def test_shape_kept(self, shape):
        out = to_uint8(np.zeros(shape, np.uint16))
        assert out.shape == shape and out.dtype == np.uint8

    @pytest.mark.parametrize("image", [np.array([True, False]), np.array(["a"]), np.array([1 + 2j])])
    def test_unsupported_dtype(self, image):
        with pytest.raises(InputError, match="image dtype must be") as info:
            to_uint8(image)
        assert isinstance(info.value, PcdofError)
