"""The uint8 sRGB encoder (a table indexed by a float32's top bits) against the float32 formula it replaces."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.color import _ENCODE_SHIFT, _code_thresholds, _encode8_tables, encode_from_linear, linear_to_srgb


def formula(x: np.ndarray) -> np.ndarray:
    """The plain definition: sRGB-encode in float32, scale to 255, round, clip."""
    with np.errstate(invalid="ignore", over="ignore"):
        code = np.rint(linear_to_srgb(np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0)) * 255)
    return np.clip(code, 0, 255).astype(np.uint8)


def encode(x) -> np.ndarray:
    return encode_from_linear(np.asarray(x, np.float32), np.uint8)


def neighbours(values: np.ndarray, ulps: int = 3) -> np.ndarray:
    """*values* (float32) and the floats up to *ulps* steps either side, positive ones only."""
    bits = values.astype(np.float32).view(np.int32).astype(np.int64)
    near = (bits[:, None] + np.arange(-ulps, ulps + 1)[None, :]).ravel()
    return near[(near >= 0) & (near < 0x7F800000)].astype(np.int32).view(np.float32)


def test_every_code_boundary_and_its_neighbours():
    thresholds = _code_thresholds()
    x = neighbours(thresholds)
    np.testing.assert_array_equal(encode(x), formula(x))
    # each threshold is the first float of its code: the float below it encodes one code lower
    assert np.array_equal(encode(thresholds), np.arange(1, 256, dtype=np.uint8))
    assert np.array_equal(encode(np.nextafter(thresholds, np.float32(0))), np.arange(0, 255, dtype=np.uint8))


def test_first_and_last_value_of_every_bucket():
    n = int(np.float32(1.0).view(np.uint32)) >> _ENCODE_SHIFT
    first = (np.arange(n + 1, dtype=np.uint32) << _ENCODE_SHIFT).view(np.float32)
    x = neighbours(first, ulps=2)
    np.testing.assert_array_equal(encode(x), formula(x))
    base, boundary = _encode8_tables()
    assert base.shape == boundary.shape == (n,)
    assert np.all(np.diff(base) >= 0) and base[0] == 0 and base[-1] <= 255


def test_special_values():
    x = np.array([0.0, -0.0, -1e-30, -1.0, np.nan, -np.nan, np.inf, -np.inf, 1.0, np.nextafter(1, 0), 1.5, 3e38,
                  1e-45, 1e-40, 1e-38], np.float32)
    assert encode(x).tolist() == [0, 0, 0, 0, 0, 0, 255, 0, 255, 255, 255, 255, 0, 0, 0]
    np.testing.assert_array_equal(encode(x[np.isfinite(x)]), formula(x[np.isfinite(x)]))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([(1,), (7, 5), (33, 17, 3)]))
def test_random_images_of_any_shape(seed, shape):
    rng = np.random.default_rng(seed)
    x = (rng.random(shape, dtype=np.float32) * 1.2 - 0.1) ** 1  # some below 0 and above 1
    got = encode(x)
    assert got.shape == x.shape and got.dtype == np.uint8
    np.testing.assert_array_equal(got, formula(x))


def test_every_float32_in_the_unit_interval():
    """All 1.07e9 float32 values from 0 to just above 1 against the formula (about ten seconds)."""
    top = int(np.float32(1.0).view(np.uint32)) + 16
    step = 1 << 24
    for lo in range(0, top, step):
        x = np.arange(lo, min(top, lo + step), dtype=np.uint32).view(np.float32)
        np.testing.assert_array_equal(encode(x), formula(x))
