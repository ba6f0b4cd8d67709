"""Measured depth edges moved onto the colour edges before the fill (pcdof.stages.fill.edges): the fast kernel,
its plain specification (pcdof.stages.fill.reference.align_depth_edges), and the class of error it fixes."""

import numpy as np
import pytest

from pcdof.errors import InputError
from pcdof.stages.fill import align_depth_edges, fill_joint_bilateral
from pcdof.stages.fill import reference as ref


def square_scene(shift_px=1, size=(48, 64)):
    """A near red square (1 m) on a far grey wall (2 m) whose depth edge is *shift_px* px inside the colour edge:
    the square's first columns and rows carry the wall's depth (a depth edge off the colour edge)."""
    H, W = size
    color = np.full((H, W, 3), 200, np.uint8)
    color[12:36, 20:44] = (180, 30, 20)
    depth = np.full((H, W), 2.0, np.float32)
    depth[12 + shift_px:36, 20 + shift_px:44] = 1.0
    return depth, color


def test_pixels_of_the_foreground_that_carry_the_background_depth_move_to_the_foreground():
    depth, color = square_scene()
    out, moved = align_depth_edges(depth, color, with_count=True)
    square = np.zeros(depth.shape, bool)
    square[12:36, 20:44] = True
    assert np.count_nonzero(square & (depth > 1.5)) == 24 + 23  # the first row and column, before
    assert np.all(out[square] == 1.0)  # on the colour edge after
    assert np.all(out[~square] == 2.0)  # the wall keeps its depth
    assert moved == 47


def test_the_fill_renders_the_aligned_edge():
    """The fill stage's order: aligned, then filled; a hole beside the square is the wall's."""
    depth, color = square_scene()
    depth[20:28, 44:48] = 0.0  # a shadow beside the square
    filled = fill_joint_bilateral(align_depth_edges(depth, color), color)
    assert filled[12, 20] == 1.0 and filled[24, 20] == 1.0
    assert np.allclose(filled[20:28, 44:48], 2.0)


def test_background_pixels_with_the_foreground_depth_stay():
    """Only nearer surfaces take pixels: a fattened foreground (the wall's first pixels at the square's depth)
    is left as it is, since a mixed pixel on the edge renders right with the foreground."""
    depth, color = square_scene(shift_px=0)
    depth[11, 20:44] = 1.0  # the square one row too tall
    out = align_depth_edges(depth, color)
    assert np.array_equal(out, depth)


def test_thin_structures_keep_their_depth():
    """A rod two pixels wide has no pixel away from its edges: it keeps its measured depth."""
    color = np.full((32, 32, 3), 200, np.uint8)
    depth = np.full((32, 32), 2.0, np.float32)
    depth[:, 15:17] = 1.0  # a near rod whose colour is the wall's (no colour edge at all)
    out = align_depth_edges(depth, color)
    assert np.array_equal(out, depth)


def test_holes_stay_holes_and_bad_values_are_holes():
    depth, color = square_scene()
    depth[0:5, 0:5] = 0.0
    depth[40, 60] = np.nan
    out = align_depth_edges(depth, color)
    assert np.all(out[0:5, 0:5] == 0.0) and out[40, 60] == 0.0


@pytest.mark.parametrize("bad", [{"sigma_color": 0.0}, {"bias": 0.5}, {"band_steps": 0}, {"window_steps": 1.5}])
def test_bad_options_are_refused(bad):
    depth, color = square_scene()
    with pytest.raises(InputError):
        align_depth_edges(depth, color, **bad)


def _noisy_scene(seed):
    """Slanted surfaces, a near blob with a ragged, misregistered edge, texture, holes: every branch of the rule."""
    rng = np.random.default_rng(seed)
    H, W = 40, 56
    v, u = np.mgrid[0:H, 0:W]
    depth = (2.0 + 0.01 * u + 0.005 * v).astype(np.float32)
    blob = (u - 30) ** 2 + (v - 20) ** 2 < 12 ** 2
    color = np.where(blob[..., None], (150, 60, 40), (90, 120, 200)).astype(np.float64)
    color += rng.normal(0, 12, color.shape)
    color = np.clip(color, 0, 255).astype(np.uint8)
    shifted = np.roll(blob, rng.integers(-2, 3, 2), axis=(0, 1))
    depth[shifted] = (1.0 + 0.004 * u[shifted]).astype(np.float32)
    flying = rng.random(depth.shape) < 0.03
    depth[flying] = 1.5  # a third depth between the two
    depth[rng.random(depth.shape) < 0.05] = 0.0
    depth[:, :3] = 0.0
    return depth, color


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_matches_the_reference(seed):
    depth, color = _noisy_scene(seed)
    fast, moved = align_depth_edges(depth, color, with_count=True)
    slow = ref.align_depth_edges(depth, color / 255.0)
    assert moved > 10
    np.testing.assert_allclose(fast, slow, rtol=1e-6, atol=0)


def test_kernel_matches_the_reference_at_a_larger_step():
    """At 1280 px across a step is 2 px: the band, the window and its taps scale with it."""
    depth, color = _noisy_scene(3)
    depth = np.kron(depth, np.ones((2, 2), np.float32))
    color = np.kron(color, np.ones((2, 2, 1), np.uint8))
    pad = np.zeros((depth.shape[0], 1280 - depth.shape[1]), np.float32)
    depth = np.concatenate([depth, pad], 1)
    color = np.concatenate([color, np.zeros(pad.shape + (3,), np.uint8)], 1)
    fast = align_depth_edges(depth, color)
    slow = ref.align_depth_edges(depth, color / 255.0)
    np.testing.assert_allclose(fast, slow, rtol=1e-6, atol=0)


@pytest.mark.parametrize("reach", [1, 2, 3])
def test_band_is_its_definition(reach):
    """The band from OpenCV's window maxima and minima against the definition: a measured pixel with a measured
    pixel within *reach* (Chebyshev) whose depth differs by more than edge_ratio relative to the nearer, with
    depths exactly at the ratio (not a gap) and holes."""
    from pcdof.stages.fill.edges import band_of

    rng = np.random.default_rng(reach)
    H, W = 31, 43
    depth = rng.choice([1.0, 1.04, 1.05, 2.0, 2.08, 0.0], size=(H, W)).astype(np.float32)
    got = band_of(depth, reach, 0.04)
    want = np.zeros((H, W), bool)
    for y in range(H):
        for x in range(W):
            z = float(depth[y, x])
            if z <= 0:
                continue
            win = depth[max(0, y - reach):y + reach + 1, max(0, x - reach):x + reach + 1].astype(np.float64)
            w = win[win > 0]
            want[y, x] = bool((np.maximum(w, z) > 1.04 * np.minimum(w, z)).any())
    np.testing.assert_array_equal(got, want)
    assert got.any() and not got.all()


def test_fill_aligned_is_what_the_fill_stage_does():
    """fill_aligned: aligned then filled with the colour-guided fill (what the pipeline's fill stage and the
    register and cloud commands run); the other methods only fill."""
    from pcdof.stages.fill import fill_aligned, fill_depth

    depth, color = square_scene()
    depth[20:28, 44:48] = 0.0
    filled, moved = fill_aligned(depth, color)
    assert moved == 47
    np.testing.assert_array_equal(filled, fill_joint_bilateral(align_depth_edges(depth, color), color))
    filled, moved = fill_aligned(depth, color, method="telea")
    assert moved == 0
    np.testing.assert_array_equal(filled, fill_depth(depth, color, method="telea"))
    with pytest.raises(InputError, match="method"):
        fill_aligned(depth, color, method="nearest")
