"""Synthetic scenes and the ray-traced thin-lens ground truth, checked against analytic answers.

The thin-lens render is compared with an independent construction (the pinhole image convolved with
an anti-aliased aperture kernel built here by supersampling), the depths with plane formulas, and
the sensor model with the statistics it promises.
"""

import json
import math
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof.metrics import psnr
from pcdof.color import linear_to_srgb
from pcdof.errors import InputError
from pcdof.lens import ThinLens
from pcdof.synth import (
    SCENES,
    DepthSensorModel,
    Material,
    Scene,
    aperture_points,
    generate_scene,
    kinect_rig,
    make_frame,
    render_ground_truth,
    render_pinhole,
    render_thin_lens,
    write_scene,
)
from pcdof.synth.scenes import quad

TINY = dict(color_size=(64, 48), depth_size=(64, 53))


def shown(linear):
    """Linear radiance as it is shown: clipped to [0, 1], sRGB-encoded."""
    return linear_to_srgb(np.clip(linear, 0, 1))


def aperture_kernel(diameter, blades=0, rotation_rad=0.0, supersample=16):
    """Anti-aliased kernel for cv2.filter2D (a correlation) of a disc / regular polygon of the given
    diameter (pixels; circumscribed for polygons), sum 1. Edge pixels get their exact-ish coverage by
    supersampling. The thin lens sees a plane behind the focus plane through the aperture mirrored
    through its centre, so the correlation kernel is the aperture reflected (x, y -> -x, -y)."""
    r = diameter / 2
    n = int(math.ceil(r + 0.5))
    size = 2 * n + 1
    offs = (np.arange(size * supersample) + 0.5) / supersample - (n + 0.5)
    yy, xx = np.meshgrid(offs, offs, indexing="ij")
    xx, yy = -xx, -yy
    if blades == 0:
        inside = xx**2 + yy**2 <= r * r
    else:
        inside = np.ones(xx.shape, bool)
        for i in range(blades):
            a0 = rotation_rad + 2 * math.pi * i / blades
            a1 = a0 + 2 * math.pi / blades
            px, py = r * math.cos(a0), r * math.sin(a0)
            qx, qy = r * math.cos(a1), r * math.sin(a1)
            side = (qx - px) * (yy - py) - (qy - py) * (xx - px)
            centre = (qx - px) * (0 - py) - (qy - py) * (0 - px)
            inside &= side * centre >= 0
    k = inside.astype(np.float64).reshape(size, supersample, size, supersample).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


def plane_scene(z, material=None, **scene_kwargs):
    """One fronto-parallel plane at depth z that fills every view."""
    mat = material or Material("noise", (0.9, 0.8, 0.7), (0.05, 0.1, 0.2), scale_m=0.12, seed=3)
    e = 20.0
    return Scene([(quad([(-e, -e, z), (e, -e, z), (e, e, z), (-e, e, z)], facing=(0, 0, 0)), mat, False)],
                 **scene_kwargs)


@pytest.fixture(scope="module")
def portrait_tiny():
    return generate_scene("portrait", **TINY, seed=0)


# ----------------------------------------------------------------------------- thin lens
class TestThinLens:
    def test_huge_f_number_equals_pinhole(self, portrait_tiny):
        sf = portrait_tiny
        pin_hole_lens = ThinLens(85.0, 1e6, sf.default_lens.focus_distance_m)
        img = render_thin_lens(sf, pin_hole_lens, samples=16)
        assert psnr(shown(img), shown(sf.color_linear)) > 45
        # and the scene's own lens does blur it (the comparison is not vacuous)
        blurred = render_thin_lens(sf, sf.default_lens, samples=64)
        assert psnr(shown(blurred), shown(sf.color_linear)) < 35

    @pytest.mark.parametrize("blades, rotation_deg", [(0, 0.0), (5, 10.0)])
    def test_fronto_parallel_plane_is_pinhole_image_convolved_with_aperture(self, blades, rotation_deg):
        z = 2.0
        rig = kinect_rig((112, 84), (32, 26))
        lens = ThinLens(50.0, 1.4, 0.5, aperture_blades=blades, aperture_rotation_deg=rotation_deg)
        sf = make_frame(plane_scene(z), rig, default_lens=lens, pixel_samples=1)  # point-sampled pixels
        c = float(lens.coc_px(np.float32([z]), rig.color.fx)[0])
        assert c == pytest.approx(lens.aperture_m * rig.color.fx * (1 / 0.5 - 1 / z), rel=1e-5)
        img = render_thin_lens(sf, lens, samples=256)
        m = int(math.ceil(c)) + 2  # away from the borders (the plane continues past them)
        crop = np.s_[m:-m, m:-m]
        rot = math.radians(rotation_deg) - math.pi / 2  # vertex 0 points up at rotation 0

        def conv(diameter, **kw):
            k = aperture_kernel(diameter, blades, rot, **kw)
            return cv2.filter2D(sf.color_linear, -1, k, borderType=cv2.BORDER_REFLECT)[crop]

        good = psnr(img[crop], conv(c))
        assert good > 45
        # a 10 % wrong blur size is clearly worse: the test resolves the CoC formula
        assert good > psnr(img[crop], conv(1.1 * c)) + 6

    def test_bokeh_of_a_point_light_is_the_aperture(self):
        # a small emitter behind the focus plane is seen through the aperture as it is; one in front of
        # it through the aperture mirrored through its centre. A triangle tells the two apart.
        rig = kinect_rig((128, 96), (32, 26))
        fx, cx, cy = rig.color.fx, rig.color.cx, rig.color.cy
        d_f = 0.8
        lens = ThinLens(100.0, 0.37, d_f, aperture_blades=3, aperture_rotation_deg=0.0)  # vertex 0 points up
        hot = Material("emissive", emission=(40.0, 40.0, 40.0))
        z_back, z_front = 2.4, 0.48  # equal |1/d_f - 1/z|: equal bokeh sizes
        from pcdof.synth.scenes import sphere

        base = plane_scene(3.0, Material("flat", (0.01, 0.01, 0.01)))
        objs = [(m, mat, s) for m, mat, s in zip(base.meshes, base.materials, base.smooth)]
        objs.append((sphere((-0.25 * z_back, 0.0, z_back), 0.02 * z_back), hot, True))
        objs.append((sphere((0.25 * z_front, 0.0, z_front), 0.02 * z_front), hot, True))
        sf = make_frame(Scene(objs), rig, default_lens=lens)
        img = render_thin_lens(sf, lens, samples=1024).mean(axis=2)
        c = float(lens.coc_px(np.float32([z_back]), fx)[0])
        assert c == pytest.approx(float(lens.coc_px(np.float32([z_front]), fx)[0]), rel=1e-4)
        for u, mirrored in ((-0.25, False), (0.25, True)):
            x0, y0 = cx + fx * u, cy
            half = int(c / 2 + 4)
            win = img[int(y0) - half: int(y0) + half + 2, int(x0) - half: int(x0) + half + 2]
            seen = win > 0.5 * np.median(win[win > 0.2 * win.max()])
            ys, xs = np.mgrid[: win.shape[0], : win.shape[1]]
            xs = xs + int(x0) - half - x0
            ys = ys + int(y0) - half - y0

            def triangle(sign):
                inside = np.ones(win.shape, bool)
                r = c / 2
                for i in range(3):
                    a0 = math.radians(-90.0) + 2 * math.pi * i / 3
                    a1 = a0 + 2 * math.pi / 3
                    px, py, qx, qy = r * math.cos(a0), r * math.sin(a0), r * math.cos(a1), r * math.sin(a1)
                    side = (qx - px) * (sign * ys - py) - (qy - py) * (sign * xs - px)
                    inside &= side * ((qx - px) * -py - (qy - py) * -px) >= 0
                return inside

            def iou(mask):
                return (mask & seen).sum() / (mask | seen).sum()

            right, wrong = (triangle(-1), triangle(1)) if mirrored else (triangle(1), triangle(-1))
            assert iou(right) > 0.8
            assert iou(wrong) < iou(right) - 0.2

    def test_sharp_checker_plane_matches_disc_convolution(self):
        # Hard texture edges: a pinhole image sampled at the pixel centres misplaces each edge by up to
        # half a pixel, so the reference is built at 3x resolution (pixel x of the image is pixel
        # 3x + 1 there, as the principal point is (W - 1) / 2), convolved, and sampled back.
        z = 2.0
        rig = kinect_rig((112, 84), (32, 26))
        fine = kinect_rig((336, 252), (32, 26))
        lens = ThinLens(50.0, 1.4, 0.5)
        scene = plane_scene(z, Material("checker", (0.9, 0.8, 0.7), (0.05, 0.1, 0.2), scale_m=0.15))
        sf = make_frame(scene, rig, default_lens=lens, pixel_samples=1)
        c = float(lens.coc_px(np.float32([z]), rig.color.fx)[0])
        img = render_thin_lens(sf, lens, samples=400)
        pin3, _ = render_pinhole(scene, fine.color)
        ref = cv2.filter2D(pin3, -1, aperture_kernel(3 * c), borderType=cv2.BORDER_REFLECT)[1::3, 1::3]
        m = int(math.ceil(c)) + 2
        assert psnr(img[m:-m, m:-m], ref[m:-m, m:-m]) > 38
        # the plain pixel-sampled pinhole image is a worse reference: the comparison resolves edges
        coarse = cv2.filter2D(sf.color_linear, -1, aperture_kernel(c), borderType=cv2.BORDER_REFLECT)
        assert psnr(img[m:-m, m:-m], ref[m:-m, m:-m]) > psnr(img[m:-m, m:-m], coarse[m:-m, m:-m]) + 3

    def test_box_filtered_pixels_blur_like_the_colour_image(self):
        # with the default box pixel filter the colour image averages 4 x 4 rays per pixel and the thin
        # lens integrates over the same points: the blurred plane is that image convolved with the disc
        z = 2.0
        rig = kinect_rig((112, 84), (32, 26))
        lens = ThinLens(50.0, 1.4, 0.5)
        scene = plane_scene(z, Material("checker", (0.9, 0.8, 0.7), (0.05, 0.1, 0.2), scale_m=0.15))
        sf = make_frame(scene, rig, default_lens=lens)
        assert sf.pixel_samples == 4
        c = float(lens.coc_px(np.float32([z]), rig.color.fx)[0])
        img = render_thin_lens(sf, lens, samples=400)
        ref = cv2.filter2D(sf.color_linear, -1, aperture_kernel(c), borderType=cv2.BORDER_REFLECT)
        m = int(math.ceil(c)) + 2
        assert psnr(img[m:-m, m:-m], ref[m:-m, m:-m]) > 38
        point = make_frame(scene, rig, default_lens=lens, pixel_samples=1)
        assert psnr(sf.color_linear, point.color_linear) < 35  # the filter matters on sharp edges

    def test_plane_in_focus_stays_sharp(self):
        rig = kinect_rig((48, 36), (32, 26))
        lens = ThinLens(50.0, 1.4, 2.0)
        sf = make_frame(plane_scene(2.0), rig, default_lens=lens)
        img = render_thin_lens(sf, lens, samples=64)
        np.testing.assert_allclose(img, sf.color_linear, atol=2e-4)

    def test_half_sample_renders_converge(self, portrait_tiny):
        gt = render_ground_truth(portrait_tiny, portrait_tiny.default_lens, samples=1024)
        assert gt.samples == 512
        assert gt.psnr_db > 45
        # fewer samples agree less: the PSNR measures sampling noise
        few = render_ground_truth(portrait_tiny, portrait_tiny.default_lens, samples=32)
        assert few.psnr_db < gt.psnr_db - 5

    def test_adaptive_ground_truth_reaches_target(self):
        sf = generate_scene("highlights", color_size=(96, 72), depth_size=(32, 26), seed=1)
        gt = render_ground_truth(sf, sf.default_lens, target_psnr_db=45.0)
        assert gt.psnr_db >= 45.0
        assert gt.image.shape == (72, 96, 3) and gt.image.dtype == np.float32
        assert gt.passes[-1] == (gt.samples, gt.psnr_db)
        # emitters of radiance > 1 survive in linear light: bokeh brighter than white somewhere
        assert sf.color_linear.max() > 4
        # samples go where the image is blurred, not to the in-focus subject
        coc = sf.default_lens.coc_px(sf.depth_color_m, sf.rig.color.fx)
        assert gt.counts[coc < 0.5].mean() < 0.5 * gt.counts[coc > 2].mean()

    def test_seed_and_chunking_independence(self, portrait_tiny, monkeypatch):
        import pcdof.synth.render as r

        lens = portrait_tiny.default_lens
        a = render_thin_lens(portrait_tiny, lens, samples=16, seed=3)
        monkeypatch.setattr(r, "RAYS_PER_CHUNK", 1000)
        b = render_thin_lens(portrait_tiny, lens, samples=16, seed=3)
        np.testing.assert_array_equal(a, b)
        c = render_thin_lens(portrait_tiny, lens, samples=16, seed=4)
        assert not np.array_equal(a, c)

    @pytest.mark.parametrize("bad", [dict(samples=0), dict(samples=2.5), dict(seed=-1)])
    def test_invalid_arguments(self, portrait_tiny, bad):
        with pytest.raises(InputError):
            render_thin_lens(portrait_tiny, portrait_tiny.default_lens, **bad)

    def test_lens_must_be_thin_lens(self, portrait_tiny):
        with pytest.raises(InputError, match="ThinLens"):
            render_thin_lens(portrait_tiny, "f/1.4", samples=4)


class TestAperture:
    def test_disc_samples_are_uniform(self):
        rng = np.random.default_rng(0)
        lens = ThinLens(50.0, 2.0, 1.0)  # A = 25 mm
        p = aperture_points(rng.random((200_000, 2)), lens)
        r2 = (p**2).sum(axis=1)
        R = lens.aperture_m / 2
        assert r2.max() <= R * R * (1 + 1e-9)
        assert r2.mean() == pytest.approx(R * R / 2, rel=0.01)  # uniform disc: E[r^2] = R^2 / 2
        assert np.abs(p.mean(axis=0)).max() < 0.01 * R

    @pytest.mark.parametrize("blades", [3, 6, 9])
    def test_polygon_samples_are_uniform_and_inside(self, blades):
        rng = np.random.default_rng(1)
        rot = 0.3 - math.pi / 2  # vertex 0 points up at rotation 0
        lens = ThinLens(50.0, 2.0, 1.0, aperture_blades=blades, aperture_rotation_deg=math.degrees(0.3))
        R = lens.aperture_m / 2
        p = aperture_points(rng.random((200_000, 2)), lens) / R
        # inside every edge's half-plane (apothem cos(pi/k)), with vertex 0 at the rotation angle
        for i in range(blades):
            mid = rot + (2 * i + 1) * math.pi / blades
            assert (p @ np.array([math.cos(mid), math.sin(mid)])).max() <= math.cos(math.pi / blades) + 1e-9
        # area-uniform: E[r^2] of a regular k-gon of circumradius 1 is (1 + 2 cos^2(pi/k)) / 6
        expected = (1 + 2 * math.cos(math.pi / blades) ** 2) / 6
        assert (p**2).sum(axis=1).mean() == pytest.approx(expected, rel=0.01)


    def test_polygon_vertex_points_up_at_rotation_zero(self):
        # the convention of pcdof.stages.render: at rotation 0 a vertex points up (-y, image rows grow down)
        rng = np.random.default_rng(2)
        lens = ThinLens(50.0, 2.0, 1.0, aperture_blades=3)
        p = aperture_points(rng.random((100_000, 2)), lens) / (lens.aperture_m / 2)
        assert -p[:, 1].min() == pytest.approx(1.0, abs=0.02)  # the top vertex
        assert p[:, 1].max() == pytest.approx(0.5, abs=0.01)  # the bottom edge, at the apothem


# ----------------------------------------------------------------------------- geometry
class TestGroundTruthDepth:
    def test_slanted_plane_depth_matches_formula(self):
        sf = generate_scene("slanted_plane", color_size=(80, 60), depth_size=(64, 53), seed=2)
        p = sf.metadata["plane"]
        c = sf.rig.color
        u, v = np.meshgrid((np.arange(c.width) - c.cx) / c.fx, (np.arange(c.height) - c.cy) / c.fy)
        z = p["z0_m"] / (1 - p["b"] * u - p["a"] * v)
        np.testing.assert_allclose(sf.depth_color_m, z, rtol=1e-4)
        # the depth camera's exact depth: the same plane seen from the depth camera's pose
        d = sf.rig.depth
        R, t = sf.rig.T_color_from_depth[:3, :3], sf.rig.T_color_from_depth[:3, 3]
        ud, vd = np.meshgrid((np.arange(d.width) - d.cx) / d.fx, (np.arange(d.height) - d.cy) / d.fy)
        rays = np.stack([ud, vd, np.ones_like(ud)], -1) @ R.T  # depth-camera rays in the colour frame
        n = np.array([-p["b"], -p["a"], 1.0])  # plane: n . x = z0
        zd = (p["z0_m"] - n @ t) / (rays @ n)
        np.testing.assert_allclose(sf.depth_clean_m, zd, rtol=1e-4)

    def test_rig_is_kinect_like(self):
        rig = kinect_rig((640, 480), (512, 424))
        assert 0.025 <= rig.baseline_m <= 0.052 + 0.002
        angle = math.degrees(math.acos((np.trace(rig.T_color_from_depth[:3, :3]) - 1) / 2))
        assert 0 < angle < 1
        assert not rig.color.has_distortion
        hfov = 2 * math.degrees(math.atan(rig.color.width / 2 / rig.color.fx))
        assert 60 <= hfov <= 70
        dh = 2 * math.degrees(math.atan(rig.depth.width / 2 / rig.depth.fx))
        dv = 2 * math.degrees(math.atan(rig.depth.height / 2 / rig.depth.fy))
        assert dh == pytest.approx(70, abs=1) and dv == pytest.approx(60, abs=1.5)
        # intrinsics scale with the colour size
        big = kinect_rig((1920, 1080))
        assert big.color.fx == pytest.approx(rig.color.fx * 3)


class TestScenes:
    @pytest.mark.parametrize("name", list(SCENES))
    def test_every_scene_builds_closed_with_a_lens(self, name):
        sf = generate_scene(name, **TINY, seed=0)
        assert sf.color.shape == (48, 64, 3) and sf.color.dtype == np.uint8
        assert sf.color_linear.dtype == np.float32 and sf.depth_color_m.shape == (48, 64)
        assert sf.depth_m.shape == (53, 64) and sf.depth_clean_m.shape == (53, 64)
        assert (sf.depth_color_m > 0).all() and (sf.depth_clean_m > 0).all()  # every ray hits something
        assert isinstance(sf.default_lens, ThinLens)
        assert sf.depth_color_m.min() - 1e-3 < sf.default_lens.focus_distance_m < sf.depth_color_m.max()
        assert sf.frame.rig is sf.rig and sf.frame.depth_m.shape == (53, 64)
        # the sRGB image is the encoded linear image
        np.testing.assert_allclose(sf.color / 255.0, shown(sf.color_linear), atol=0.6 / 255 + 1e-6)

    def test_deterministic_for_a_seed(self):
        a = generate_scene("clutter", **TINY, seed=5)
        b = generate_scene("clutter", **TINY, seed=5)
        c = generate_scene("clutter", **TINY, seed=6)
        for field in ("color", "color_linear", "depth_m", "depth_clean_m", "depth_color_m"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        assert a.default_lens == b.default_lens
        assert not np.array_equal(a.color, c.color)

    def test_highlights_has_bright_emitters(self):
        sf = generate_scene("highlights", color_size=(160, 120), depth_size=(64, 53), seed=0)
        assert sf.color_linear.max() > 5

    @pytest.mark.parametrize("bad", [dict(name="nope"), dict(name="portrait", seed=-1),
                                     dict(name="portrait", color_size=(4, 4)),
                                     dict(name="portrait", depth_size="64by53")])
    def test_invalid_arguments(self, bad):
        with pytest.raises(InputError):
            generate_scene(**{**TINY, **bad})

    def test_seed_range(self):
        # the sensor's dropout noise takes the seed as a signed 64-bit integer: the largest one works
        # (on a dark glossy plane, where the dropout noise is evaluated), one more is refused up front
        glossy = Material("flat", (0.03, 0.03, 0.03), dark_glossy=True)
        rig = kinect_rig((16, 12), (64, 53))
        sf = make_frame(plane_scene(1.5, glossy), rig, default_lens=ThinLens(50, 2, 1), seed=2**63 - 1)
        assert sf.seed == 2**63 - 1 and 0 < (sf.depth_m == 0).mean() < 1
        for bad in (2**63, 2**64, -1):
            with pytest.raises(InputError, match="seed"):
                generate_scene("portrait", **TINY, seed=bad)
            with pytest.raises(InputError, match="seed"):
                make_frame(plane_scene(1.5), rig, default_lens=ThinLens(50, 2, 1), seed=bad)


# ----------------------------------------------------------------------------- sensor model
class TestSensor:
    def test_noise_std_and_millimetre_quantisation(self):
        z = 2.0
        rig = kinect_rig((32, 24), (128, 106))
        sf = make_frame(plane_scene(z), rig, default_lens=ThinLens(50, 2, 2), seed=1)
        valid = sf.depth_m > 0
        assert valid.mean() > 0.99  # a plane at 2 m facing the projector: no holes
        err = (sf.depth_m - sf.depth_clean_m)[valid]
        expected = math.sqrt((1.4e-3 * z * z) ** 2 + 1e-6 / 12)  # Gaussian noise + 1 mm quantisation
        assert err.std() == pytest.approx(expected, rel=0.05)
        assert abs(err.mean()) < 3 * expected / math.sqrt(err.size)
        mm = sf.depth_m[valid] * 1000
        np.testing.assert_allclose(mm, np.round(mm), atol=1e-3)
        # noise grows as z^2
        far = make_frame(plane_scene(3.5), rig, default_lens=ThinLens(50, 2, 2), seed=1)
        err_far = (far.depth_m - far.depth_clean_m)[far.depth_m > 0]
        assert err_far.std() / err.std() == pytest.approx((3.5 / 2.0) ** 2, rel=0.08)

    def test_range_cut_offs(self):
        rig = kinect_rig((32, 24), (64, 53), max_range_m=4.5)
        near = make_frame(plane_scene(0.3), rig, default_lens=ThinLens(50, 2, 1))
        far = make_frame(plane_scene(5.0), rig, default_lens=ThinLens(50, 2, 1))
        assert (near.depth_m == 0).all() and (far.depth_m == 0).all()
        assert (near.depth_clean_m > 0).all() and (far.depth_clean_m > 0).all()

    @pytest.mark.parametrize("side", [+1, -1])
    def test_projector_shadow_beside_near_object(self, side):
        sphere_scene = generate_scene("near_object", **TINY)  # for its metadata only
        centre = np.array(sphere_scene.metadata["object_center_m"])
        r = sphere_scene.metadata["object_radius_m"]
        sensor = DepthSensorModel(projector_offset_m=(side * 0.075, 0.0, 0.0))
        sf = generate_scene("near_object", color_size=(32, 24), depth_size=(128, 106), sensor=sensor)
        d = sf.rig.depth
        R, t = sf.rig.T_color_from_depth[:3, :3], sf.rig.T_color_from_depth[:3, 3]
        c_d = R.T @ (centre - t)  # ball centre in the depth camera
        row = int(round(d.fy * c_d[1] / c_d[2] + d.cy))
        col = int(round(d.fx * c_d[0] / c_d[2] + d.cx))
        half = int(d.fx * r / c_d[2])
        band = slice(row - half // 2, row + half // 2 + 1)
        background = sf.depth_clean_m[band] > 1.0
        holes = (sf.depth_m[band] == 0) & background
        left = holes[:, max(0, col - 3 * half): col].sum()
        right = holes[:, col: col + 3 * half].sum()
        # the projector at +x lights the ball from the right: its shadow falls to the left (and vice versa)
        shadow, lit = (left, right) if side > 0 else (right, left)
        assert shadow > 10 * half
        assert lit <= shadow / 10

    def test_dark_glossy_dropouts_are_blobs(self):
        glossy = Material("flat", (0.03, 0.03, 0.03), dark_glossy=True)
        rig = kinect_rig((32, 24), (128, 106))
        sf = make_frame(plane_scene(1.5, glossy), rig, default_lens=ThinLens(50, 2, 1), seed=2)
        lost = (sf.depth_m == 0).astype(np.uint8)
        assert 0.05 < lost.mean() < 0.8
        n, _, stats, _ = cv2.connectedComponentsWithStats(lost, connectivity=8)
        assert np.median(stats[1:, cv2.CC_STAT_AREA]) >= 10  # blobs, not salt-and-pepper
        matte = make_frame(plane_scene(1.5), rig, default_lens=ThinLens(50, 2, 1), seed=2)
        assert (matte.depth_m == 0).mean() < 0.01


# ----------------------------------------------------------------------------- files and CLI
class TestWrite:
    def test_write_scene_round_trips(self, portrait_tiny, tmp_path):
        from pcdof.io import read_calibration, read_color, read_depth

        lens = portrait_tiny.default_lens
        info = write_scene(portrait_tiny, tmp_path, lens=lens, gt_samples=32)
        names = {p.name for p in tmp_path.iterdir()}
        assert {"color.png", "color_linear.npy", "depth.png", "depth_clean.npy", "depth_color_gt.npy", "calib.json",
                "lens.json", "dof_gt.png", "dof_gt_linear.npy", "scene.json"} == names
        rig = read_calibration(tmp_path / "calib.json")
        assert rig.color.same_as(portrait_tiny.rig.color) and rig.depth.same_as(portrait_tiny.rig.depth)
        np.testing.assert_allclose(rig.T_color_from_depth, portrait_tiny.rig.T_color_from_depth)
        assert rig.max_range_m == portrait_tiny.rig.max_range_m
        calib = json.loads((tmp_path / "calib.json").read_text())
        assert set(portrait_tiny.rig.to_dict()) <= set(calib)
        np.testing.assert_allclose(read_depth(tmp_path / "depth.png", 0.001), portrait_tiny.depth_m, atol=1e-6)
        np.testing.assert_array_equal(read_color(tmp_path / "color.png"), portrait_tiny.color)
        np.testing.assert_array_equal(np.load(tmp_path / "depth_color_gt.npy"), portrait_tiny.depth_color_m)
        spec = json.loads((tmp_path / "lens.json").read_text())
        assert ThinLens(spec["focal_length_mm"], spec["f_number"], spec["focus_distance_m"],
                        spec["aperture_blades"]) == lens
        gt = np.load(tmp_path / "dof_gt_linear.npy")
        assert gt.shape == (48, 64, 3)
        assert info["ground_truth"]["samples_per_pixel"] == 32
        assert not list(tmp_path.glob("*.tmp"))

    def test_without_lens_no_ground_truth(self, portrait_tiny, tmp_path):
        write_scene(portrait_tiny, tmp_path, linear=False)
        names = {p.name for p in tmp_path.iterdir()}
        assert "dof_gt.png" not in names and "color_linear.npy" not in names and "lens.json" in names

    def test_rerun_removes_the_stale_files_of_an_earlier_run(self, portrait_tiny, tmp_path):
        from pcdof.synth.write import SCENE_FILES

        lens = portrait_tiny.default_lens
        write_scene(portrait_tiny, tmp_path, lens=lens, gt_samples=4)
        assert {p.name for p in tmp_path.iterdir()} == set(SCENE_FILES)
        (tmp_path / "notes.txt").write_text("mine")  # not pcdof's: kept
        (tmp_path / "sub").mkdir()
        info = write_scene(portrait_tiny, tmp_path, lens=lens, ground_truth=False, linear=False)
        names = {p.name for p in tmp_path.iterdir()}
        assert names == {os.path.basename(f) for f in info["files"]} | {"notes.txt", "sub"}
        assert not names & {"dof_gt.png", "dof_gt_linear.npy", "color_linear.npy"}
        assert "ground_truth" not in json.loads((tmp_path / "scene.json").read_text())

    def test_ground_truth_settings_checked_before_writing(self, portrait_tiny, tmp_path):
        with pytest.raises(InputError, match="gt_samples"):
            write_scene(portrait_tiny, tmp_path / "a", lens=portrait_tiny.default_lens, gt_samples=0)
        with pytest.raises(InputError, match="gt_seed"):
            write_scene(portrait_tiny, tmp_path / "a", lens=portrait_tiny.default_lens, gt_seed=-1)
        assert not (tmp_path / "a").exists()


class TestCli:
    def test_synth_command(self, tmp_path):
        from pcdof.cli import main

        out = tmp_path / "scene"
        res = CliRunner().invoke(main, ["synth", "near_object", "-o", str(out), "--size", "48x36",
                                        "--depth-size", "32x26", "--samples", "32", "--f-number", "4",
                                        "--seed", "2"])
        assert res.exit_code == 0, res.output
        spec = json.loads((out / "lens.json").read_text())
        assert spec["f_number"] == 4
        assert (out / "dof_gt.png").exists()
        scene = json.loads((out / "scene.json").read_text())
        assert scene["seed"] == 2 and scene["ground_truth"]["samples_per_pixel"] == 32

    @pytest.mark.parametrize("args, code", [(["nope"], 2), (["portrait", "--size", "10"], 6),
                                            (["portrait", "--f-number", "-1", "--no-gt"], 5)])
    def test_bad_arguments(self, tmp_path, args, code):
        from pcdof.cli import main

        res = CliRunner().invoke(main, ["synth", *args, "-o", str(tmp_path / "x")])
        assert res.exit_code == code, res.output

    @pytest.mark.parametrize("args, flag", [(["--seed", "18446744073709551616"], "--seed"),
                                            (["--seed", "9223372036854775808"], "--seed"),
                                            (["--seed", "-1"], "--seed"), (["--size", "0x0"], "--size"),
                                            (["--depth-size", "0x0"], "--depth-size"),
                                            (["--focus-distance", "0"], "--focus-distance")])
    def test_bad_flags_named_in_one_line(self, tmp_path, args, flag):
        from pcdof.cli import main

        res = CliRunner().invoke(main, ["synth", "portrait", "-o", str(tmp_path / "x"), "--size", "16x12", *args])
        assert res.exit_code in (5, 6), res.output
        assert res.output.startswith("pcdof: error: ") and res.output.count("\n") == 1 and flag in res.output
        assert not (tmp_path / "x").exists()

    def test_rerun_leaves_no_stale_files(self, tmp_path):
        from pcdof.cli import main

        out = tmp_path / "scene"
        common = ["synth", "portrait", "-o", str(out), "--size", "16x12", "--depth-size", "16x14"]
        assert CliRunner().invoke(main, [*common, "--samples", "4"]).exit_code == 0
        assert (out / "dof_gt.png").exists() and (out / "dof_gt_linear.npy").exists()
        res = CliRunner().invoke(main, [*common, "--no-gt", "--no-linear", "--f-number", "4"])
        assert res.exit_code == 0, res.output
        assert sorted(p.name for p in out.iterdir()) == ["calib.json", "color.png", "depth.png", "depth_clean.npy",
                                                         "depth_color_gt.npy", "lens.json", "scene.json"]
        assert json.loads((out / "lens.json").read_text())["f_number"] == 4


class TestBundledSample:
    """data/sample is what its README's command makes (the generator is deterministic)."""

    def test_sample_matches_its_generating_command(self):
        from pathlib import Path

        from pcdof.io import read_calibration, read_color, read_depth

        sample = Path(__file__).resolve().parent.parent / "data" / "sample"
        sf = generate_scene("portrait", color_size=(320, 240), depth_size=(256, 212), seed=0)
        color = read_color(sample / "color.png").astype(int)
        assert (np.abs(color - sf.color.astype(int)) <= 1).mean() > 0.999
        depth = read_depth(sample / "depth.png", 0.001)
        assert (np.abs(depth - sf.depth_m) <= 0.0015).mean() > 0.995
        np.testing.assert_allclose(np.load(sample / "depth_color_gt.npy"), sf.depth_color_m, rtol=1e-5)
        rig = read_calibration(sample / "calib.json")
        assert rig.color.same_as(sf.rig.color) and rig.depth.same_as(sf.rig.depth)
        spec = json.loads((sample / "lens.json").read_text())
        lens = ThinLens(spec["focal_length_mm"], spec["f_number"], spec["focus_distance_m"], spec["aperture_blades"])
        assert lens == sf.default_lens
        # the bundled ground truth agrees with a quick, noisier render of the same lens
        gt = read_color(sample / "dof_gt.png") / 255.0
        quick = shown(render_thin_lens(sf, lens, samples=32, seed=7))
        assert psnr(gt, quick) > 36
        assert psnr(gt, sf.color / 255.0) < 30  # and it is blurred


def test_synthetic_frame_pickles_and_renders_the_same():
    import pickle

    sf = generate_scene("fence", **TINY)
    back = pickle.loads(pickle.dumps(sf))  # e.g. sent to a worker process
    np.testing.assert_array_equal(render_thin_lens(sf, sf.default_lens, samples=8),
                                  render_thin_lens(back, back.default_lens, samples=8))


def test_write_scene_refuses_a_file_as_folder(portrait_tiny, tmp_path):
    from pcdof.errors import ImageWriteError

    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ImageWriteError, match="output folder"):
        write_scene(portrait_tiny, blocker)
    with pytest.raises(InputError, match="SyntheticFrame"):
        write_scene("frame", tmp_path)
