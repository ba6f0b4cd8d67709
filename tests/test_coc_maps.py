"""ThinLens.coc_maps_px: the CoC stage's maps and statistics in one pass, the same values as computed one by one
(random depths with unknown, NaN and exactly-in-focus pixels; float32, float64 and integer depth)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st


@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from([(0,), (1,), (7, 5), (48, 64), (300, 257)]),
       dtype=st.sampled_from([np.float32, np.float64, np.uint16]))
@settings(max_examples=40, deadline=None)
def test_coc_maps_are_the_maps_computed_one_by_one(seed, shape, dtype):
    from pcdof.lens import ThinLens

    rng = np.random.default_rng(seed)
    z = rng.uniform(-0.5, 20.0, shape)
    special = rng.random(shape)
    z[special < 0.05] = 0.0
    z[(special >= 0.05) & (special < 0.08)] = np.nan if dtype != np.uint16 else 0.0
    z[(special >= 0.08) & (special < 0.1)] = 2.0  # exactly in focus
    z = (z * 1000).astype(dtype) if dtype == np.uint16 else z.astype(dtype)
    lens = ThinLens(focal_length_mm=float(rng.uniform(20, 200)), f_number=float(rng.uniform(1, 16)),
                    focus_distance_m=2.0)
    fx = float(rng.uniform(100, 3000))
    maps = lens.coc_maps_px(z, fx)
    signed = lens.signed_coc_px(z, fx)
    np.testing.assert_array_equal(maps.signed, signed)
    np.testing.assert_array_equal(maps.size, np.abs(signed))
    assert maps.size.dtype == maps.signed.dtype == np.float32 and maps.size.shape == z.shape
    assert maps.max_px == (float(np.abs(signed).max()) if signed.size else 0.0)
    assert maps.out_of_focus_share == (float(np.mean(np.abs(signed) >= 1.0)) if signed.size else 0.0)
