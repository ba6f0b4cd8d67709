"""Depth and CoC previews: layout, colours against OpenCV's colour maps, scale bars, degenerate inputs."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pcdof.errors import InputError, PcdofError
from pcdof.previews import (
    BAR_BACKGROUND_RGB,
    UNKNOWN_RGB,
    bar_width_px,
    coc_preview,
    depth_preview,
    depth_range_m,
)

H, W = 241, 320  # odd height: the bar's middle row is exactly half way


def expected_rgb(unit, cmap):
    """OpenCV's colour map at *unit* (0..1), RGB: the reference the previews must match."""
    index = np.rint(np.asarray(unit, np.float64) * 255).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(index, cmap)[:, 0, ::-1]


def strip(preview, width):
    """(H, 3) colours down the middle of the bar's colour strip (right of *width* map columns)."""
    h = preview.shape[0]
    pad, strip_w = max(1, round(h / 80)), max(2, round(h / 24))
    return preview[:, width + pad + strip_w // 2]


def lightness(rgb):
    return cv2.cvtColor(np.ascontiguousarray(rgb, np.uint8)[None], cv2.COLOR_RGB2LAB)[0, :, 0].astype(int)


def ramp(near, far, h=H, w=W):
    """Depth that runs from *near* to *far* along the columns, evenly in 1/z."""
    inv = np.linspace(1 / near, 1 / far, w)
    return np.tile(1 / inv, (h, 1)).astype(np.float32)


class TestLayout:
    @pytest.mark.parametrize("shape", [(H, W), (480, 640), (1, 1), (3, 200), (200, 3), (2, 2), (17, 5)])
    def test_shape_and_dtype(self, shape):
        depth = np.full(shape, 2.0, np.float32)
        for out in (depth_preview(depth), coc_preview(depth)):
            assert out.shape == (shape[0], shape[1] + bar_width_px(shape[0]), 3)
            assert out.dtype == np.uint8

    def test_bar_grows_with_height_and_has_room_for_labels(self):
        widths = [bar_width_px(h) for h in (1, 3, 10, 100, 480, 1080, 4000)]
        assert widths == sorted(widths)
        assert bar_width_px(480) > 60  # strip + a label such as "2.25 m"

    def test_inputs_not_modified(self):
        depth = ramp(1.0, 4.0)
        depth[0, 0] = np.nan
        before = depth.copy()
        depth_preview(depth)
        coc_preview(depth)
        np.testing.assert_array_equal(depth, before)

    @pytest.mark.parametrize("bad", [0, -3, 1.5, True, "10"])
    def test_bar_width_refuses_bad_heights(self, bad):
        with pytest.raises(InputError, match="height"):
            bar_width_px(bad)


class TestDepthColours:
    def test_matches_opencv_viridis_on_inverse_depth(self):
        near, far = 1.0, 4.0
        out = depth_preview(ramp(near, far), near_m=near, far_m=far)
        unit = (1 / ramp(near, far)[0].astype(np.float64) - 1 / far) / (1 / near - 1 / far)
        diff = np.abs(out[0, :W].astype(int) - expected_rgb(unit, cv2.COLORMAP_VIRIDIS).astype(int))
        assert diff.max() <= 3  # float32 depth may round an index to its neighbour

    def test_bar_is_monotone_bright_at_near(self):
        out = depth_preview(ramp(0.5, 8.0))
        column = strip(out, W)
        light = lightness(column[::-1])  # bottom (far) to top (near)
        assert np.all(np.diff(light) >= 0)
        assert light[-1] - light[0] > 150
        assert len(np.unique(column, axis=0)) > 100  # a smooth map, not a few bands

    def test_near_and_far_ends_take_the_bars_end_colours(self):
        near, far = 0.8, 5.0
        depth = ramp(1.0, 3.0)
        depth[:, 0], depth[:, 1] = near, far
        depth[:, 2], depth[:, 3] = near / 2, far * 3  # outside the range: clamped to its ends
        out = depth_preview(depth, near_m=near, far_m=far)
        column = strip(out, W)
        for col in (0, 2):
            np.testing.assert_array_equal(out[:, col], np.broadcast_to(column[0], (H, 3)))
        for col in (1, 3):
            np.testing.assert_array_equal(out[:, col], np.broadcast_to(column[-1], (H, 3)))

    def test_a_quarter_way_in_inverse_depth_is_a_quarter_up_the_bar(self):
        near, far = 1.0, 3.0
        z = 1 / (1 / far + 0.25 * (1 / near - 1 / far))
        out = depth_preview(np.full((H, W), z), near_m=near, far_m=far)
        np.testing.assert_array_equal(out[0, 0], strip(out, W)[(H - 1) * 3 // 4])

    def test_range_from_percentiles_ignores_outliers(self):
        rng = np.random.default_rng(3)
        depth = rng.uniform(1.0, 3.0, (H, W))
        depth[::50, ::50] = 80.0  # a few flying pixels
        out = depth_preview(depth)
        reference = depth_preview(depth, near_m=float(np.percentile(depth, 2)), far_m=float(np.percentile(depth, 98)))
        np.testing.assert_array_equal(out, reference)
        far_colour = strip(out, W)[-1]
        assert (out[:, :W] == far_colour).all(axis=2).mean() < 0.05  # the scene is not squashed to one end

    def test_one_end_given(self):
        depth = ramp(1.0, 3.0)
        out = depth_preview(depth, near_m=0.5)
        assert np.all(np.diff(lightness(out[0, :W])) <= 0)  # still near bright, far dark
        np.testing.assert_array_equal(out[0, W - 1], strip(out, W)[-1])  # 3 m is the 98th percentile or less


class TestUnknown:
    def test_unknown_pixels_are_grey(self):
        depth = ramp(1.0, 4.0)
        bad = [0.0, np.nan, -1.0, np.inf, -np.inf]
        for i, value in enumerate(bad):
            depth[i, :] = value
        out = depth_preview(depth)
        assert (out[: len(bad), :W] == UNKNOWN_RGB).all()
        assert not (out[len(bad):, :W] == UNKNOWN_RGB).all(axis=2).any()

    @pytest.mark.parametrize("cmap", [cv2.COLORMAP_VIRIDIS, cv2.COLORMAP_INFERNO])
    def test_grey_is_far_from_every_map_colour(self, cmap):
        lut = expected_rgb(np.arange(256) / 255, cmap).astype(int)
        assert np.abs(lut - np.array(UNKNOWN_RGB)).max(axis=1).min() >= 40

    def test_all_unknown(self):
        out = depth_preview(np.zeros((30, 40), np.float32))
        assert (out[:, :40] == UNKNOWN_RGB).all()
        assert len(np.unique(strip(out, 40), axis=0)) > 10  # the bar's colours are still drawn

    def test_all_unknown_with_a_range_is_labelled(self):
        out = depth_preview(np.full((200, 50), np.nan), near_m=1.0, far_m=3.0)
        assert label_ink(out, 50) > 0

    def test_nan_coc_is_grey(self):
        coc = np.ones((20, 30))
        coc[5, 7] = np.nan
        out = coc_preview(coc)
        assert (out[5, 7] == UNKNOWN_RGB).all()
        assert (out[0, 0] != UNKNOWN_RGB).any()


class TestConstantAndTiny:
    def test_constant_depth_is_one_mid_colour(self):
        out = depth_preview(np.full((H, W), 2.5, np.float32))
        colours = np.unique(out[:, :W].reshape(-1, 3), axis=0)
        assert len(colours) == 1
        mid = expected_rgb([0.5], cv2.COLORMAP_VIRIDIS)[0].astype(int)
        assert np.abs(colours[0].astype(int) - mid).max() <= 12
        assert label_ink(out, W) > 0

    @pytest.mark.parametrize("shape", [(1, 1), (3, 200), (2, 1), (5, 5)])
    def test_tiny_images_have_no_labels_but_a_bar(self, shape):
        depth = np.linspace(1, 3, shape[0] * shape[1]).reshape(shape)
        for out in (depth_preview(depth), coc_preview(depth)):
            assert label_ink(out, shape[1]) == 0
            assert not (out[:, shape[1]:] == BAR_BACKGROUND_RGB).all()

    @pytest.mark.parametrize("height", [12, 20, 40, 100])
    def test_small_images_keep_labels_inside(self, height):
        out = depth_preview(ramp(1.0, 3.0, h=height, w=8))
        assert out.shape[1] == 8 + bar_width_px(height)
        assert label_ink(out, 8) > 0


def label_ink(preview, width):
    """Non-background pixels right of the colour strip and its tick marks (where labels are written)."""
    h = preview.shape[0]
    pad, strip_w = max(1, round(h / 80)), max(2, round(h / 24))
    area = preview[:, width + 3 * pad + strip_w:]
    return int((area != BAR_BACKGROUND_RGB).any(axis=2).sum())


class TestLabels:
    def test_depth_labels_exist(self):
        assert label_ink(depth_preview(ramp(0.5, 8.0)), W) > 100

    def test_coc_labels_exist(self):
        assert label_ink(coc_preview(np.linspace(0, 12, H * W).reshape(H, W)), W) > 100

    def test_wide_range_labels(self):
        assert label_ink(depth_preview(ramp(0.01, 900.0)), W) > 100


class TestCocColours:
    def test_matches_opencv_inferno_linear_in_pixels(self):
        coc = np.tile(np.linspace(0, 9.0, W), (H, 1))
        out = coc_preview(coc)
        diff = np.abs(out[0, :W].astype(int) - expected_rgb(coc[0] / 9.0, cv2.COLORMAP_INFERNO).astype(int))
        assert diff.max() == 0

    def test_zero_at_the_bottom_and_max_at_the_top(self):
        coc = np.tile(np.linspace(0, 5.0, W), (H, 1))
        out = coc_preview(coc)
        column = strip(out, W)
        np.testing.assert_array_equal(out[0, 0], column[-1])
        np.testing.assert_array_equal(out[0, W - 1], column[0])
        assert np.all(np.diff(lightness(column[::-1])) >= 0)

    def test_signed_is_shown_as_magnitude(self):
        coc = np.tile(np.linspace(-6, 6, W), (H, 1))
        np.testing.assert_array_equal(coc_preview(coc), coc_preview(np.abs(coc)))

    def test_max_px_clamps(self):
        coc = np.tile(np.linspace(0, 20, W), (H, 1))
        out = coc_preview(coc, max_px=10.0)
        top = strip(out, W)[0]
        assert (out[:, W // 2:W] == top).all()

    def test_all_in_focus(self):
        out = coc_preview(np.zeros((H, W), np.float32))
        assert (out[:, :W] == expected_rgb([0.0], cv2.COLORMAP_INFERNO)[0]).all()
        assert label_ink(out, W) > 0


class TestValidation:
    @pytest.mark.parametrize("func,name", [(depth_preview, "depth_m"), (coc_preview, "coc_px")])
    @pytest.mark.parametrize("bad", [[[1.0, 2.0]], np.zeros((2, 3, 3)), np.zeros((0, 4)), np.zeros(5),
                                     np.ones((3, 3), bool), np.ones((3, 3), complex), np.array([["a"]])])
    def test_bad_maps(self, func, name, bad):
        with pytest.raises(InputError, match=name) as info:
            func(bad)
        assert "\n" not in str(info.value)
        assert isinstance(info.value, PcdofError)

    @pytest.mark.parametrize("key", ["near_m", "far_m"])
    @pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, True, "2"])
    def test_bad_range(self, key, bad):
        with pytest.raises(InputError, match=key):
            depth_preview(np.ones((4, 4)), **{key: bad})

    @pytest.mark.parametrize("near,far", [(2.0, 2.0), (3.0, 1.0)])
    def test_near_not_below_far(self, near, far):
        with pytest.raises(InputError, match="near_m must be < far_m"):
            depth_preview(np.ones((4, 4)), near_m=near, far_m=far)

    @pytest.mark.parametrize("bad", [0.0, -2.0, np.nan, False])
    def test_bad_max_px(self, bad):
        with pytest.raises(InputError, match="max_px"):
            coc_preview(np.ones((4, 4)), max_px=bad)


finite_or_not = st.one_of(st.floats(0.01, 500.0), st.just(0.0), st.just(np.nan), st.floats(-5, 0))


@settings(max_examples=60, deadline=None)
@given(depth=hnp.arrays(st.sampled_from([np.float32, np.float64]), hnp.array_shapes(min_dims=2, max_dims=2,
                                                                                      max_side=60),
                        elements=finite_or_not),
       near=st.one_of(st.none(), st.floats(0.05, 5.0)), span=st.one_of(st.none(), st.floats(1.01, 50.0)))
def test_property_never_raises_and_size_holds(depth, near, span):
    far = None if span is None else (near or 1.0) * span
    out = depth_preview(depth, near_m=near, far_m=far)
    h, w = depth.shape
    assert out.shape == (h, w + bar_width_px(h), 3) and out.dtype == np.uint8
    unknown = ~(np.isfinite(depth) & (depth > 0))
    assert (out[:, :w][unknown] == UNKNOWN_RGB).all()
    coc = coc_preview(np.where(unknown, np.nan, depth))
    assert coc.shape == out.shape and coc.dtype == np.uint8


def test_tick_marks_sit_at_their_depth():
    """With near 1 m and far 4 m, the 2 m tick is a third of the way down the bar (1/z is linear on it)."""
    out = depth_preview(ramp(1.0, 4.0), near_m=1.0, far_m=4.0)
    pad, strip_w = max(1, round(H / 80)), max(2, round(H / 24))
    marks = out[:, W + pad + strip_w:W + 3 * pad + strip_w]
    rows = np.flatnonzero((marks == 0).all(axis=2).any(axis=1))
    for depth in (2.0, 3.0):
        expected = (1 - (1 / depth - 1 / 4) / (1 - 1 / 4)) * (H - 1)
        assert np.min(np.abs(rows - expected)) <= 0.5
    assert rows[0] == 0  # 1 m at the top


class TestDepthRange:
    def test_is_the_range_the_preview_maps(self):
        rng = np.random.default_rng(5)
        depth = rng.uniform(0.7, 6.0, (H, W))
        depth[rng.random((H, W)) < 0.2] = 0.0
        near, far = depth_range_m(depth)
        known = depth[depth > 0]
        assert (near, far) == pytest.approx((np.percentile(known, 2), np.percentile(known, 98)))
        np.testing.assert_array_equal(depth_preview(depth), depth_preview(depth, near_m=near, far_m=far))

    def test_degenerate(self):
        assert depth_range_m(np.zeros((3, 3))) is None
        assert depth_range_m(np.zeros((3, 3)), far_m=2.0) == pytest.approx((2.0 / 1.1, 2.0))
        near, far = depth_range_m(np.full((3, 3), 2.0))
        assert near < 2.0 < far
        with pytest.raises(InputError, match="near_m must be < far_m"):
            depth_range_m(np.ones((3, 3)), near_m=2.0, far_m=1.0)
