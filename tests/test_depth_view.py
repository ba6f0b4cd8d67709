"""What the depth camera sees in the colour image (pcdof.depth_view) and `pcdof render --crop-to-depth-view`."""

import math
import os

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import invoke

from pcdof.bench.fill_rigs import outside_view
from pcdof.camera import Intrinsics, Rig
from pcdof.depth_view import (DepthViewBox, crop_result, depth_view_box, depth_view_mask, largest_box,
                              measured_range_m)
from pcdof.errors import InputError
from pcdof.geometry import pixel_rays, project_points, transform_points
from pcdof.synth.rigs import rig_case


def pinhole(width, height, hfov_deg, vfov_deg):
    fx = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    fy = 0.5 * height / math.tan(math.radians(vfov_deg) / 2)
    return Intrinsics(width, height, fx, fy, (width - 1) / 2, (height - 1) / 2)


def kinect_v2_like(baseline_m=0.0):
    """Colour 84 x 54 degrees over depth 71 x 60 (Kinect v2), the depth camera *baseline_m* to the side."""
    T = np.eye(4)
    T[0, 3] = baseline_m
    return Rig(pinhole(320, 180, 84.1, 53.8), pinhole(256, 212, 70.6, 60.0), T)


def test_a_registered_rig_sees_the_whole_frame():
    intr = pinhole(64, 48, 60.0, 46.8)
    rig = Rig.registered(intr)
    assert depth_view_mask(rig, 0.5, 8.0).all()
    assert depth_view_box(rig, 0.5, 8.0) == DepthViewBox(0, 0, 64, 48)


def test_a_wider_colour_camera_loses_the_side_strips_by_the_fields_of_view():
    """Same centre, no baseline: a colour column is seen when its ray's x/z is within the depth camera's
    half width (with the half-pixel edge), whatever the depth; every row is (the depth is taller)."""
    rig = kinect_v2_like()
    box = depth_view_box(rig, 0.5, 8.0)
    c, d = rig.color, rig.depth
    half_tan = (d.width / 2) / d.fx  # the depth image's edge at x/z = (W/2) / fx (pixel centre +- 0.5)
    x_left = c.cx - half_tan * c.fx  # colour columns at or right of this are seen
    assert box.y0 == 0 and box.y1 == c.height
    assert box.x0 == math.ceil(x_left) and box.x1 == c.width - math.ceil(x_left)
    assert 20 < box.x0 < 40  # about 9 % of the width on each side


def test_a_baseline_shifts_the_strips_and_the_box_holds_between_near_and_far():
    """With the depth camera 5 cm to the side, near objects shift the view: the box is seen from both ends of
    the range and (checked here) from depths between them."""
    rig = kinect_v2_like(baseline_m=0.05)
    near, far = 0.6, 6.0
    box = depth_view_box(rig, near, far)
    whole = depth_view_box(rig, far, far)
    assert box.width < whole.width  # the near end costs columns
    rays = pixel_rays(rig.color)[box.slices].reshape(-1, 2)
    T = np.linalg.inv(rig.T_color_from_depth)
    for z in np.geomspace(near, far, 7):
        uv = project_points(transform_points(T, np.column_stack([rays * z, np.full(len(rays), z)])), rig.depth)
        assert np.all((uv[:, 0] >= -0.5) & (uv[:, 0] <= rig.depth.width - 0.5))
        assert np.all((uv[:, 1] >= -0.5) & (uv[:, 1] <= rig.depth.height - 0.5))


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 1005])  # seed % 4: Kinect v2, Kinect v1, D435, wide over narrow
def test_no_pixel_of_the_box_is_outside_the_view_by_the_exact_depth(seed):
    """Independent check: the fill benchmark marks the colour pixels whose exact surface point falls outside
    the depth image; none of them lies in the box computed over the exact depth's range."""
    sf = rig_case(seed, color_width=128)
    z = sf.depth_color_m[sf.depth_color_m > 0]
    box = depth_view_box(sf.rig, float(z.min()), float(z.max()))
    assert box is not None
    assert not outside_view(sf)[box.slices].any()


def brute_force_largest(mask):
    h, w = mask.shape
    best = 0
    for y0 in range(h):
        for y1 in range(y0 + 1, h + 1):
            for x0 in range(w):
                for x1 in range(x0 + 1, w + 1):
                    if (y1 - y0) * (x1 - x0) > best and mask[y0:y1, x0:x1].all():
                        best = (y1 - y0) * (x1 - x0)
    return best


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_largest_box_of_a_convex_region_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(3, 12)), int(rng.integers(3, 12))
    mask = np.zeros((h, w), np.uint8)
    points = np.column_stack([rng.integers(-2, w + 2, 5), rng.integers(-2, h + 2, 5)]).astype(np.int32)
    cv2.fillConvexPoly(mask, cv2.convexHull(points), 1)
    mask = mask.astype(bool)
    box = largest_box(mask)
    if not mask.any():
        assert box is None
        return
    assert mask[box.slices].all()
    assert box.width * box.height == brute_force_largest(mask)


def test_inputs_are_checked():
    rig = kinect_v2_like()
    with pytest.raises(InputError, match="near_m"):
        depth_view_mask(rig, 2.0, 1.0)
    with pytest.raises(InputError, match="near_m"):
        depth_view_mask(rig, float("nan"), 1.0)
    with pytest.raises(InputError, match="rig"):
        depth_view_mask("calib.json", 1.0, 2.0)
    with pytest.raises(InputError, match="mask"):
        largest_box(np.ones(5, bool))
    assert measured_range_m(np.zeros((4, 4))) is None
    assert measured_range_m(np.array([[0.0, 1.5], [np.nan, 3.0]])) == (1.5, 3.0)


def test_crop_result_cuts_every_map_alike():
    from pcdof.pipeline import RenderResult

    image = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    depth = np.arange(48, dtype=np.float32).reshape(6, 8)
    result = RenderResult(image, depth, depth + 1, None, None, [])
    box = DepthViewBox(2, 1, 7, 5)
    out = crop_result(result, box)
    assert out.image.shape == (4, 5, 3) and np.array_equal(out.image, image[1:5, 2:7])
    assert np.array_equal(out.depth_filled_m, depth[1:5, 2:7] + 1) and out.coc_px is None
    with pytest.raises(InputError, match="box"):
        crop_result(result, DepthViewBox(0, 0, 9, 6))


def test_render_crop_to_depth_view(tmp_path):
    """A Kinect-v2-like frame: the render and its maps are cut alike, and the command says where."""
    from pcdof import io
    from pcdof.synth import write_scene

    sf = rig_case(0, color_width=160)  # seed 0: the kinect-v2 rig
    assert sf.metadata["rig"] == "kinect-v2"
    folder = tmp_path / "in"
    write_scene(sf, folder, ground_truth=False, linear=False)
    frame = [folder / "color.png", folder / "depth.png", "--calib", folder / "calib.json"]
    result = invoke("render", *frame, "-o", tmp_path / "x.png", "--crop-to-depth-view",
                    "--save-maps", tmp_path / "maps")
    assert result.exit_code == 0, result.output
    assert "cropped to the depth camera's view" in result.output
    image = io.read_color(tmp_path / "x.png")
    registered = np.load(tmp_path / "maps" / "depth_registered.npy")
    assert image.shape[:2] == registered.shape == np.load(tmp_path / "maps" / "depth_filled.npy").shape
    h, w = sf.color.shape[:2]
    assert image.shape[0] <= h and image.shape[1] < w
    full = invoke("render", *frame, "-o", tmp_path / "full.png", "--save-maps", tmp_path / "full_maps")
    assert full.exit_code == 0, full.output
    assert "cropped" not in full.output
    full_registered = np.load(tmp_path / "full_maps" / "depth_registered.npy")
    box = depth_view_box(sf.rig, *measured_range_m(full_registered))
    assert np.array_equal(registered, full_registered[box.slices])
    assert os.path.exists(tmp_path / "maps" / "trace.json")


def test_crop_refuses_a_rig_whose_depth_camera_sees_none_of_the_colour_image():
    from pcdof.cli.render import cropped_to_depth_view
    from pcdof.pipeline import RenderResult

    rig = kinect_v2_like()
    T = np.diag([-1.0, 1.0, -1.0, 1.0])  # the depth camera turned to face backwards
    away = Rig(rig.color, rig.depth, T)
    assert not depth_view_mask(away, 0.5, 5.0).any()
    h, w = rig.color.height, rig.color.width
    result = RenderResult(np.zeros((h, w, 3), np.uint8), np.full((h, w), 2.0, np.float32),
                          np.full((h, w), 2.0, np.float32), None, None, [])
    with pytest.raises(InputError, match="--crop-to-depth-view"):
        cropped_to_depth_view(result, away)
    kept, note = cropped_to_depth_view(result, Rig.registered(rig.color))
    assert kept is result and "nothing cropped" in note
