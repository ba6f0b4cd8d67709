"""Focal-plane viewer: geometry against the pinhole/thin-lens formulas and OpenCV, scene driven off screen."""

import math
import os
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from conftest import invoke

from pcdof.camera import Intrinsics, Rig
from pcdof.errors import InputError, LensError
from pcdof.lens import ThinLens
from pcdof.viewer.ui import build_scene, scene_from_frame
from pcdof.viewer.scene import (
    COC_BAR_TITLE,
    PLANE_COLOR,
    MAX_WINDOW_SIDE,
    dof_slab,
    downscale_for_preview,
    focal_plane_corners,
    frustum_lines,
    image_corner_pixels,
    image_corner_rays,
    render_preview,
    strided_points,
)

pv = pytest.importorskip("pyvista")

W, H = 96, 64
PINHOLE = Intrinsics(W, H, 200.0, 190.0, 47.0, 30.5)
DISTORTED = Intrinsics(W, H, 200.0, 190.0, 49.0, 30.0, (-0.25, 0.08, 0.001, -0.0005, 0.0))
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)


def coc_by_hand(z, lens: ThinLens, fx: float) -> float:
    """Thin-lens circle of confusion, written out: (f / N) * fx * |1/d_f - 1/z| pixels."""
    aperture_m = lens.focal_length_mm / 1000.0 / lens.f_number
    return aperture_m * fx * abs(1.0 / lens.focus_distance_m - 1.0 / z)


def project_cv2(points, intr: Intrinsics) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K,
                              intr.dist_coeffs)
    return uv.reshape(-1, 2)


def two_plane_frame(near_m=1.0, far_m=3.0, seed=0):
    """Random texture; left half of the image at *near_m*, right half at *far_m*."""
    rng = np.random.default_rng(seed)
    color = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    depth = np.full((H, W), far_m, np.float32)
    depth[:, : W // 2] = near_m
    return color, depth


def scene(lens=None, **options):
    color, depth = two_plane_frame()
    options = {"off_screen": True, "stride": 1, "window_size": (600, 300), **options}
    return build_scene(color, depth, PINHOLE, lens or ThinLens(100, 1.4, 2.0), **options)


def halves_error(image, color):
    """Mean absolute difference from the sharp colour image, left half and right half (grey levels)."""
    diff = np.abs(image.astype(np.float64) - color.astype(np.float64)).mean(axis=2)
    return diff[:, : W // 2 - 4].mean(), diff[:, W // 2 + 4:].mean()


def fire_slider(slider, value, *, release=True):
    """Move a VTK slider the way a drag does: set the representation, fire its interaction event,
    then (with *release*) the end-of-interaction event a mouse release sends."""
    import vtk

    slider.GetRepresentation().SetValue(value)
    slider.InvokeEvent(vtk.vtkCommand.InteractionEvent)
    if release:
        slider.InvokeEvent(vtk.vtkCommand.EndInteractionEvent)


def press_key(interactor, key):
    """Fire the key-press event a keyboard would (the off-screen interactor is never enabled, so invoke it)."""
    interactor.SetKeySym(key)
    interactor.SetKeyCode(key)
    interactor.InvokeEvent("KeyPressEvent")


def display_xy(renderer, point):
    import vtk

    coord = vtk.vtkCoordinate()
    coord.SetCoordinateSystemToWorld()
    coord.SetValue(*map(float, point))
    return coord.GetComputedDisplayValue(renderer)


class TestFocalPlaneCorners:
    @pytest.mark.parametrize("intr", [PINHOLE, DISTORTED], ids=["pinhole", "distorted"])
    @pytest.mark.parametrize("d_f", [0.3, 1.7, 12.0])
    def test_corners_at_focus_depth_project_to_image_corners(self, intr, d_f):
        corners = focal_plane_corners(intr, d_f)
        assert corners.shape == (4, 3)
        np.testing.assert_allclose(corners[:, 2], d_f, rtol=0, atol=1e-12)
        np.testing.assert_allclose(project_cv2(corners, intr), image_corner_pixels(intr), atol=1e-6)

    def test_pinhole_corners_by_hand(self):
        d_f = 2.5
        expected = [[(u - PINHOLE.cx) / PINHOLE.fx * d_f, (v - PINHOLE.cy) / PINHOLE.fy * d_f, d_f]
                    for u, v in [(-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5)]]
        np.testing.assert_allclose(focal_plane_corners(PINHOLE, d_f), expected, rtol=1e-12)

    @pytest.mark.parametrize("intr", [PINHOLE, DISTORTED], ids=["pinhole", "distorted"])
    def test_corners_lie_on_frustum_edges(self, intr):
        points, segments = frustum_lines(intr, 7.0)
        np.testing.assert_array_equal(points[0], 0.0)
        corners = focal_plane_corners(intr, 1.3)
        for k in range(4):
            edge = segments[k]
            assert edge[0] == 0
            far = points[edge[1]]
            # collinear with the apex (origin) and between apex and far end
            np.testing.assert_allclose(np.cross(corners[k], far), 0.0, atol=1e-12)
            np.testing.assert_allclose(corners[k] / 1.3, far / 7.0, rtol=1e-12)

    def test_frustum_far_rectangle_closes(self):
        points, segments = frustum_lines(PINHOLE, 4.0)
        assert segments.shape == (8, 2)
        np.testing.assert_allclose(points[1:, 2], 4.0)
        rim = {tuple(sorted(s)) for s in segments[4:].tolist()}
        assert rim == {(1, 2), (2, 3), (3, 4), (1, 4)}

    @pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, "x"])
    def test_invalid_focus_distance(self, bad):
        with pytest.raises(LensError, match="focus_distance_m"):
            focal_plane_corners(PINHOLE, bad)

    def test_not_intrinsics(self):
        with pytest.raises(InputError, match="Intrinsics"):
            image_corner_rays({"fx": 1})


class TestDofSlab:
    @pytest.mark.parametrize("focal_mm,n,d_f,limit", [(50, 1.8, 1.2, 1.0), (85, 1.4, 2.5, 2.0), (35, 8, 0.8, 0.5)])
    def test_limits_are_where_coc_equals_the_limit(self, focal_mm, n, d_f, limit):
        lens = ThinLens(focal_mm, n, d_f)
        slab = dof_slab(PINHOLE, lens, coc_limit_px=limit, z_max_m=50.0)
        assert slab.near_m < d_f < slab.far_m
        assert coc_by_hand(slab.near_m, lens, PINHOLE.fx) == pytest.approx(limit, rel=1e-9)
        assert coc_by_hand(slab.far_m, lens, PINHOLE.fx) == pytest.approx(limit, rel=1e-9)
        # strictly inside is sharper than the limit, outside blurrier
        assert coc_by_hand(0.5 * (slab.near_m + d_f), lens, PINHOLE.fx) < limit
        assert coc_by_hand(0.5 * (slab.far_m + d_f), lens, PINHOLE.fx) < limit
        assert coc_by_hand(0.95 * slab.near_m, lens, PINHOLE.fx) > limit
        assert coc_by_hand(1.05 * slab.far_m, lens, PINHOLE.fx) > limit

    def test_faces_at_the_limits_on_the_frustum(self):
        lens = ThinLens(50, 2.0, 1.5)
        slab = dof_slab(DISTORTED, lens, coc_limit_px=1.0, z_max_m=30.0)
        np.testing.assert_allclose(slab.near_corners[:, 2], slab.near_m)
        np.testing.assert_allclose(slab.far_corners[:, 2], slab.far_m)
        assert not slab.far_clipped
        pixels = image_corner_pixels(DISTORTED)
        np.testing.assert_allclose(project_cv2(slab.near_corners, DISTORTED), pixels, atol=1e-6)
        np.testing.assert_allclose(project_cv2(slab.far_corners, DISTORTED), pixels, atol=1e-6)
        assert slab.corners.shape == (8, 3)

    def test_past_hyperfocal_far_is_infinite_and_clipped(self):
        lens = ThinLens(20, 11, 1.0)
        fx = PINHOLE.fx
        hyperfocal = lens.aperture_m * fx / 1.0  # 1/d_f <= c / (A fx)
        lens = lens.with_focus(1.5 * hyperfocal)
        slab = dof_slab(PINHOLE, lens, coc_limit_px=1.0, z_max_m=4.0 * hyperfocal)
        assert math.isinf(slab.far_m) and slab.far_clipped
        np.testing.assert_allclose(slab.far_corners[:, 2], 4.0 * hyperfocal)
        assert coc_by_hand(slab.near_m, lens, fx) == pytest.approx(1.0, rel=1e-9)
        # at infinity the blur tends to A fx / d_f, which is below the limit
        assert lens.aperture_m * fx / lens.focus_distance_m < 1.0

    def test_clip_never_cuts_the_focal_plane(self):
        lens = ThinLens(20, 11, 3.0)
        slab = dof_slab(PINHOLE, lens, coc_limit_px=1.0, z_max_m=1.0)
        assert slab.z_clip_m == 3.0
        assert slab.far_corners[0, 2] >= lens.focus_distance_m

    def test_invalid(self):
        with pytest.raises(LensError, match="coc_limit_px"):
            dof_slab(PINHOLE, ThinLens(50, 2, 1), coc_limit_px=0, z_max_m=3)
        with pytest.raises(InputError, match="z_max_m"):
            dof_slab(PINHOLE, ThinLens(50, 2, 1), z_max_m=-3)
        with pytest.raises(LensError, match="ThinLens"):
            dof_slab(PINHOLE, "f/2", z_max_m=3)


class TestStridedPoints:
    def test_back_projection_by_hand(self):
        color, depth = two_plane_frame()
        depth[5, 7] = 0.0  # unknown: no point
        points, colors = strided_points(color, depth, PINHOLE, stride=3)
        vv, uu = np.mgrid[0:H:3, 0:W:3]
        keep = depth[vv, uu] > 0
        u, v = uu[keep], vv[keep]
        z = depth[v, u].astype(np.float64)
        expected = np.stack([(u - PINHOLE.cx) / PINHOLE.fx * z, (v - PINHOLE.cy) / PINHOLE.fy * z, z], axis=1)
        np.testing.assert_allclose(points, expected, rtol=1e-6)
        np.testing.assert_array_equal(colors, color[v, u])

    def test_invalid_stride(self):
        color, depth = two_plane_frame()
        with pytest.raises(InputError, match="stride"):
            strided_points(color, depth, PINHOLE, stride=0)


class TestScene:
    def test_initial_geometry(self):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            np.testing.assert_allclose(viewer.plane_mesh.points, focal_plane_corners(PINHOLE, 2.0))
            np.testing.assert_allclose(viewer.slab_mesh.points, viewer.slab.corners)
            assert viewer.z_max_m == pytest.approx(3.0)
            frustum = viewer.frustum_mesh.points
            np.testing.assert_allclose(frustum[1:, 2], 3.0)
            assert len(viewer.points) == W * H
        finally:
            viewer.close()

    def test_focus_slider_moves_plane_and_sharp_region(self):
        color, _ = two_plane_frame()
        viewer = scene(ThinLens(100, 1.4, 1.0))
        try:
            near_err, far_err = halves_error(viewer.preview_image, color)
            assert near_err < 1.0 < 10.0 < far_err  # focused on the left (1 m) half
            before = viewer.preview_image.copy()
            fire_slider(viewer.focus_slider, 3.0, release=False)  # dragging: the geometry follows at once
            assert viewer.lens.focus_distance_m == pytest.approx(3.0)
            np.testing.assert_allclose(viewer.plane_mesh.points[:, 2], 3.0)
            np.testing.assert_allclose(viewer.plane_mesh.points, focal_plane_corners(PINHOLE, 3.0))
            near, far = ThinLens(100, 1.4, 3.0).dof_limits_m(PINHOLE.fx, 1.0)
            np.testing.assert_allclose(viewer.slab_mesh.points[:4, 2], near)
            assert far > 3.0  # past the scene's deepest point (3 m): the far face is clipped there
            np.testing.assert_allclose(viewer.slab_mesh.points[4:, 2], 3.0)
            np.testing.assert_array_equal(viewer.preview_image, before)  # ... the preview waits for release
            fire_slider(viewer.focus_slider, 3.0)
            assert not np.array_equal(viewer.preview_image, before)
            near_err, far_err = halves_error(viewer.preview_image, color)
            assert far_err < 1.0 < 10.0 < near_err  # the sharp region moved to the right (3 m) half
            # the displayed texture follows the preview
            shown = viewer.preview_mesh.cell_data["rgb"].reshape(H, W, 3)[::-1]
            np.testing.assert_array_equal(shown, viewer.preview_image)
        finally:
            viewer.close()

    def test_f_number_slider_resizes_slab(self):
        viewer = scene(ThinLens(50, 2.0, 1.5))
        try:
            near0, far0 = viewer.slab.near_m, viewer.slab.far_m
            fire_slider(viewer.f_number_slider, 8.0)
            assert viewer.lens.f_number == pytest.approx(8.0)
            lens = ThinLens(50, 8.0, 1.5)
            assert coc_by_hand(viewer.slab.near_m, lens, PINHOLE.fx) == pytest.approx(1.0, rel=1e-9)
            assert viewer.slab.near_m < near0 and viewer.slab.far_m > far0
            np.testing.assert_allclose(viewer.slab_mesh.points[:4, 2], viewer.slab.near_m)
        finally:
            viewer.close()

    def test_pick_point_sets_focus_to_its_depth(self):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            viewer.pick_point([0.05, -0.02, 2.7])
            assert viewer.lens.focus_distance_m == pytest.approx(2.7)
            assert viewer.focus_slider.GetRepresentation().GetValue() == pytest.approx(2.7)
            with pytest.raises(InputError, match="z > 0"):
                viewer.pick_point([0.0, 0.0, -1.0])
        finally:
            viewer.close()

    def test_right_click_picks_a_cloud_point(self):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            viewer.screenshot()
            # a point of the left (1 m) plane, then one of the right (3 m) plane
            for target in (viewer.points[viewer.points[:, 2] < 2][100], viewer.points[viewer.points[:, 2] > 2][100]):
                x, y = display_xy(viewer.plotter.renderers[0], target)
                viewer.plotter.iren._mouse_right_button_click(x, y)
                assert viewer.lens.focus_distance_m == pytest.approx(target[2], rel=1e-6)
        finally:
            viewer.close()

    def test_p_key_picks_under_the_cursor(self):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            viewer.screenshot()
            target = viewer.points[viewer.points[:, 2] > 2][300]
            x, y = display_xy(viewer.plotter.renderers[0], target)
            viewer.plotter.iren.interactor.SetEventPosition(x, y)
            press_key(viewer.plotter.iren.interactor, "p")
            assert viewer.lens.focus_distance_m == pytest.approx(target[2], rel=1e-6)
        finally:
            viewer.close()

    def test_coc_colours_toggle(self):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            assert viewer.rgb_actor.GetVisibility() and not viewer.coc_actor.GetVisibility()
            bar = viewer.plotter.scalar_bars[COC_BAR_TITLE]
            assert "px" in COC_BAR_TITLE and not bar.GetVisibility()
            viewer.toggle_coc_colors(True)
            assert viewer.coc_actor.GetVisibility() and not viewer.rgb_actor.GetVisibility() and bar.GetVisibility()
            z = viewer.points[:, 2]
            expected = [coc_by_hand(zi, viewer.lens, PINHOLE.fx) for zi in z[:: 97]]
            np.testing.assert_allclose(viewer.cloud_mesh.point_data["coc_px"][:: 97], expected, rtol=1e-5)
            assert viewer.coc_checkbox.GetRepresentation().GetState() == 1
            press_key(viewer.plotter.iren.interactor, "c")  # the key flips it back
            assert not viewer.coc_colors and viewer.rgb_actor.GetVisibility()
            viewer.set_focus(1.0)  # CoC colours follow the focus
            np.testing.assert_allclose(viewer.cloud_mesh.point_data["coc_px"][z < 2], 0.0, atol=1e-6)
        finally:
            viewer.close()

    def test_screenshot_shows_plane(self, tmp_path):
        viewer = scene(ThinLens(100, 1.4, 2.0))
        try:
            image = viewer.screenshot(str(tmp_path / "shot.png"))
            on_disk = cv2.imread(str(tmp_path / "shot.png"))[:, :, ::-1]
            np.testing.assert_array_equal(on_disk, image)
            with_plane = plane_pixels(image)
            for name in ("focal_plane", "focal_plane_outline"):
                viewer.plotter.actors[name].SetVisibility(False)
            without_plane = plane_pixels(viewer.screenshot())
            assert with_plane > 50 and without_plane < with_plane / 10
        finally:
            viewer.close()

    def test_invalid_inputs(self):
        color, depth = two_plane_frame()
        with pytest.raises(InputError, match="depth_filled_m must be"):
            build_scene(color, depth[:, :-1], PINHOLE, ThinLens(50, 2, 1), off_screen=True)
        with pytest.raises(InputError, match="no known depth"):
            build_scene(color, np.zeros_like(depth), PINHOLE, ThinLens(50, 2, 1), off_screen=True)
        with pytest.raises(LensError, match="ThinLens"):
            build_scene(color, depth, PINHOLE, None, off_screen=True)
        with pytest.raises(LensError, match="coc_limit_px"):
            build_scene(color, depth, PINHOLE, ThinLens(50, 2, 1), coc_limit_px=-1, off_screen=True)
        with pytest.raises(InputError, match="color_by"):
            build_scene(color, depth, PINHOLE, ThinLens(50, 2, 1), color_by="depth", off_screen=True)
        viewer = scene()
        try:
            with pytest.raises(LensError, match="f_number"):
                viewer.set_f_number(0)
        finally:
            viewer.close()

    @pytest.mark.parametrize("size", [(16400, 800), (800, 16385), (20000, 20000), (16384, 8192), (0, 0), (63, 100)])
    def test_window_size_the_renderer_cannot_draw_is_refused(self, size):
        # beyond 16384 per side the off-screen renderer returned an all-black image
        color, depth = two_plane_frame()
        with pytest.raises(InputError, match="window_size"):
            build_scene(color, depth, PINHOLE, ThinLens(50, 2, 1), off_screen=True, window_size=size)

    def test_largest_window_side_renders(self):
        viewer = scene(window_size=(MAX_WINDOW_SIDE, 64))
        try:
            image = viewer.screenshot()
            assert image.shape == (64, MAX_WINDOW_SIDE, 3) and image.max() == 255 and image.std() > 5
        finally:
            viewer.close()

    def test_empty_render_is_an_error_and_writes_nothing(self, tmp_path, monkeypatch):
        viewer = scene()
        try:
            monkeypatch.setattr(viewer.plotter, "screenshot", lambda *a, **k: np.zeros((300, 600, 3), np.uint8))
            with pytest.raises(InputError, match="window_size"):
                viewer.screenshot(str(tmp_path / "black.png"))
            assert not list(tmp_path.iterdir())
        finally:
            viewer.close()

    def test_stride_that_keeps_no_known_pixel_is_refused(self):
        color, depth = two_plane_frame()
        depth[0, 0] = 0  # a stride of 100 keeps pixel (0, 0) only
        with pytest.raises(InputError, match="stride 100 keeps no pixel with known depth"):
            build_scene(color, depth, PINHOLE, ThinLens(100, 1.4, 2.0), off_screen=True, stride=100)
        with pytest.raises(InputError, match="stride"):
            build_scene(color, depth, PINHOLE, ThinLens(100, 1.4, 2.0), off_screen=True, stride=0)
        viewer = scene(stride=100, window_size=(200, 100))  # (0, 0) known: one point, no error
        try:
            assert len(viewer.points) == 1
        finally:
            viewer.close()

    def test_scene_from_frame_checks_fill_method_first(self):
        from pcdof.camera import RGBDFrame

        color, depth = two_plane_frame()  # hole-free: the fill stage would never look at the method
        frame = RGBDFrame(color, depth, Rig.registered(PINHOLE))
        with pytest.raises(InputError, match="fill_method"):
            scene_from_frame(frame, ThinLens(100, 1.4, 2.0), fill_method="bogus", off_screen=True)


class TestPreview:
    @pytest.mark.parametrize("shape", [(2000, 1), (1, 2000), (3, 1200), (480, 640)])
    def test_preview_matches_a_downscaled_full_size_render(self, shape):
        # the preview's blur must be the full-size blur times the scale along both axes, also for a
        # very narrow image whose short side cannot shrink below 1 pixel
        h, w = shape
        rng = np.random.default_rng(1)
        color = cv2.resize(rng.integers(0, 256, (max(1, h // 20), max(1, w // 20), 3), dtype=np.uint8), (w, h),
                           interpolation=cv2.INTER_NEAREST)
        depth = np.full((h, w), 3.0, np.float32)
        if h >= w:
            depth[: h // 2] = 1.0
        else:
            depth[:, : w // 2] = 1.0
        lens, fx = ThinLens(50, 2, 1.0), 500.0
        small_color, small_depth, small_fx = downscale_for_preview(color, depth, fx)
        scale = 400 / max(h, w)
        assert small_fx == pytest.approx(fx * scale)
        expected = cv2.resize(render_preview(color, depth, lens, fx), small_color.shape[1::-1],
                              interpolation=cv2.INTER_AREA)
        preview = render_preview(small_color, small_depth, lens, small_fx)
        assert np.abs(preview.astype(float) - expected.astype(float)).mean() < 3


def plane_pixels(image, tol=8):
    """Number of pixels within *tol* grey levels of the focal plane's colour."""
    return int(np.all(np.abs(image[:, :, :3].astype(int) - np.array(PLANE_COLOR)) <= tol, axis=2).sum())


@pytest.fixture
def frame_files(tmp_path):
    from pcdof import io

    color, depth = two_plane_frame()
    io.write_image(tmp_path / "color.png", color)
    io.write_depth(tmp_path / "depth.png", depth)
    io.write_json(tmp_path / "calib.json", Rig.registered(PINHOLE).to_dict())
    return [str(tmp_path / "color.png"), str(tmp_path / "depth.png"), "--calib", str(tmp_path / "calib.json")]


class TestCli:
    def test_screenshot(self, frame_files, tmp_path):
        out = tmp_path / "view.png"
        result = invoke(["view", *frame_files, "--focus-distance", "1.0", "--f-number", "1.4",
                          "--focal-length", "100", "--screenshot", str(out), "--window-size", "640x320"])
        assert result.exit_code == 0, result.output
        image = cv2.imread(str(out))[:, :, ::-1]
        assert image.shape == (320, 640, 3)
        assert image.std() > 20
        assert plane_pixels(image) > 50

    def test_html_written(self, frame_files, tmp_path):
        out = tmp_path / "view.html"
        result = invoke(["view", *frame_files, "--html", str(out), "--color-by", "coc"])
        assert result.exit_code == 0, result.output
        text = out.read_text(encoding="utf-8")
        assert text.lstrip().lower().startswith("<!doctype html") and len(text) > 10_000
        # titled with the input and the lens, the lens values in the page, the 3-D view filling the window
        assert "<title>pcdof \u2014 color.png \u2014 focus " in text and "VTK.js | Example" not in text
        assert "max blur" in text and "sharp (CoC &lt;= 1 px)" in text
        assert ".content { position: fixed; inset: 0; }" in text
        assert not [p for p in os.listdir(tmp_path) if p.startswith(".view.html")]  # no temporary left

    @pytest.mark.browser

    @pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium)")
    def test_html_renders_in_headless_chromium(self, frame_files, tmp_path):
        page = tmp_path / "view.html"
        shot = tmp_path / "page.png"
        assert invoke(["view", *frame_files, "--html", str(page)]).exit_code == 0
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
               "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
               "--window-size=800,600", "--virtual-time-budget=10000", f"file://{page}"]
        subprocess.run(cmd, check=False, capture_output=True, timeout=120)
        assert shot.exists(), "chromium wrote no screenshot"
        image = cv2.imread(str(shot))[:, :, ::-1]
        assert image.std() > 10, "the page rendered as a blank canvas"
        assert len(np.unique(image.reshape(-1, 3) // 16, axis=0)) > 20
        orange = (image[:, :, 0] > 200) & (image[:, :, 1] > 90) & (image[:, :, 1] < 190) & (image[:, :, 2] < 80)
        assert orange.sum() > 20, "the focal plane's outline is not on the page"

    def test_no_display_without_output_is_an_error(self, frame_files, monkeypatch):
        monkeypatch.delenv("DISPLAY", raising=False)
        monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
        monkeypatch.setattr("sys.platform", "linux")
        result = invoke(["view", *frame_files])
        assert result.exit_code == 6
        assert "--screenshot" in result.output

    def test_bad_output_suffix(self, frame_files, tmp_path):
        result = invoke(["view", *frame_files, "--html", str(tmp_path / "x.png")])
        assert result.exit_code == 6 and "--html" in result.output
        result = invoke(["view", *frame_files, "--screenshot", str(tmp_path / "x.html")])
        assert result.exit_code == 6 and "--screenshot" in result.output

    @pytest.mark.parametrize("size", ["16400x800", "20000x20000", "0x0"])
    def test_window_size_flag_is_checked_first(self, frame_files, tmp_path, size):
        out = tmp_path / "o.png"
        result = invoke(["view", *frame_files, "--window-size", size, "--screenshot", str(out)])
        assert result.exit_code == 6, result.output
        assert "--window-size" in result.output and "Traceback" not in result.output
        assert not out.exists()

    def test_fill_method_is_checked(self, frame_files, tmp_path):
        out = tmp_path / "o.png"
        result = invoke(["view", *frame_files, "--fill-method", "bogus", "--screenshot", str(out)])
        assert result.exit_code == 2 and "--fill-method" in result.output
        assert not out.exists()

    def test_focus_at_pixel(self, frame_files, tmp_path, monkeypatch):
        import pcdof.viewer.ui as viewer_module

        seen = {}
        original = viewer_module.build_scene

        def spy(*args, **kwargs):
            viewer = original(*args, **kwargs)
            seen["focus"] = viewer.lens.focus_distance_m
            return viewer

        monkeypatch.setattr(viewer_module, "build_scene", spy)
        out = tmp_path / "v.png"
        result = invoke(["view", *frame_files, "--focus-at", f"{W - 10},{H // 2}", "--screenshot", str(out)])
        assert result.exit_code == 0, result.output
        assert seen["focus"] == pytest.approx(3.0)  # the right half of the frame is at 3 m
