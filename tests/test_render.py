"""Renderer tests against analytic answers and an independent OpenCV disc convolution."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from conftest import disc_kernel, texture

from pcdof.color import decode_to_linear, linear_to_srgb, srgb_to_linear
from pcdof.errors import InputError, LensError
from pcdof.lens import PaperLens, ThinLens
from pcdof.metrics import psnr
from pcdof.plans import plan_render
from pcdof.stages.render import render_image, render_layers_linear

FX = 500.0


class TestPhysical:
    def test_huge_f_number_returns_input_exactly(self):
        rng = np.random.default_rng(1)
        color = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
        depth = rng.uniform(0.5, 5.0, (40, 50)).astype(np.float32)
        out, info = render_image(color, depth, ThinLens(50, 1e6, 1.0), fx=FX)
        assert info["skipped"]
        np.testing.assert_array_equal(out, color)

    @pytest.mark.parametrize("blades", [0, 5])
    def test_uniform_image_stays_uniform(self, blades):
        rng = np.random.default_rng(2)
        color = np.full((60, 70, 3), 173, np.uint8)
        depth = rng.uniform(0.4, 8.0, (60, 70)).astype(np.float32)
        out, _ = render_image(color, depth, ThinLens(50, 1.4, 1.0, aperture_blades=blades), fx=FX)
        assert np.abs(out.astype(int) - 173).max() <= 1

    def test_textured_plane_matches_disc_convolution(self):
        h, w = 96, 112
        lin = texture(h, w)
        lens = ThinLens(50, 2.0, 1.0)
        z = 2.0
        c = lens.aperture_m * FX * abs(1 / lens.focus_distance_m - 1 / z)
        assert 6 < c < 10
        out, _ = render_layers_linear(lin, np.full((h, w), c, np.float32))
        ref = cv2.filter2D(lin, -1, disc_kernel(c), borderType=cv2.BORDER_CONSTANT)
        m = int(c) + 2
        assert psnr(out[m:-m, m:-m], ref[m:-m, m:-m]) > 45

    def test_bright_pixel_becomes_disc_of_predicted_diameter_with_its_energy(self):
        h, w = 81, 81
        img = np.zeros((h, w, 3), np.float32)
        img[40, 40] = 50.0
        for c in (3.0, 7.5, 15.0, 30.0):
            out, _ = render_layers_linear(img, np.full((h, w), c, np.float32), quality="exact")
            assert out[..., 0].sum() == pytest.approx(50.0, rel=1e-4)
            lit = out[..., 0] > 1e-6
            ys, xs = np.nonzero(lit)
            width = xs.max() - xs.min() + 1
            assert abs(width - c) <= 1.5, (c, width)  # a disc of diameter c covers about c pixels
            assert abs(lit.sum() - math.pi * c * c / 4) <= 2 * math.pi * c / 2 + 2

    def test_polygon_aperture_makes_polygon(self):
        h, w = 81, 81
        img = np.zeros((h, w, 1), np.float32)
        img[40, 40] = 1.0
        c = 40.0
        hexagon, _ = render_layers_linear(img, np.full((h, w), c, np.float32), blades=6, quality="exact")
        disc, _ = render_layers_linear(img, np.full((h, w), c, np.float32), quality="exact")
        assert hexagon.sum() == pytest.approx(1.0, rel=1e-4)
        # a vertex points up at rotation 0: the hexagon reaches the full radius vertically but only
        # sqrt(3)/2 of it horizontally; the disc reaches the radius both ways
        rows = np.nonzero(hexagon[:, 40, 0] > 1e-7)[0]
        cols = np.nonzero(hexagon[40, :, 0] > 1e-7)[0]
        assert rows.max() - rows.min() + 1 == pytest.approx(c, abs=1.5)
        assert cols.max() - cols.min() + 1 == pytest.approx(c * math.sqrt(3) / 2, abs=1.5)
        # the hexagon has less area than its circumscribed disc
        assert (hexagon > 1e-7).sum() < (disc > 1e-7).sum()

    def _subject_scene(self):
        h, w = 80, 120
        lin = np.zeros((h, w, 3), np.float32)
        # high-contrast background: red/blue stripes far away
        lin[:, :, 0] = (np.arange(w) // 4 % 2)[None, :] * 1.0
        lin[:, :, 2] = 1.0 - lin[:, :, 0]
        depth = np.full((h, w), 6.0, np.float32)
        # a green subject at the focus distance
        lin[20:60, 40:80] = [0.0, 1.0, 0.0]
        depth[20:60, 40:80] = 1.0
        return lin, depth

    def test_sharp_subject_receives_no_background(self):
        lin, depth = self._subject_scene()
        lens = ThinLens(50, 1.4, 1.0)
        coc = lens.signed_coc_px(depth, FX)
        assert coc.max() > 10
        out, _ = render_layers_linear(lin, coc)
        subject = out[20:60, 40:80]
        np.testing.assert_allclose(subject, np.broadcast_to([0, 1, 0], subject.shape), atol=1e-5)
        # while the background right next to it is blurred (stripes averaged)
        assert 0.2 < out[40, 20, 0] < 0.8

    @pytest.mark.parametrize("reduce_min_coc_px", [math.inf, 4.0])  # full resolution; the foreground at 1/2
    def test_blurred_foreground_spreads_over_sharp_background(self, reduce_min_coc_px):
        h, w = 80, 120
        lin = np.zeros((h, w, 3), np.float32)
        lin[..., 2] = 1.0  # blue background, in focus at 3 m
        depth = np.full((h, w), 3.0, np.float32)
        lin[20:60, 40:80] = [1.0, 0.0, 0.0]  # red foreground at 0.6 m, strongly blurred
        depth[20:60, 40:80] = 0.6
        lens = ThinLens(50, 2.0, 3.0)
        coc = lens.signed_coc_px(depth, FX)
        c = float(-coc.min())
        assert c > 10
        plan = dataclasses.replace(plan_render(), reduce_min_coc_px=reduce_min_coc_px)
        out, info = render_layers_linear(lin, coc, plan=plan)
        # red light reaches outside the silhouette, up to about c/2, and fades with distance
        outside = out[40, 40 - int(c / 4), 0]
        assert outside > 0.1
        # a layer computed at 1/s resolution is upsampled from its cells: its edge may soften by s pixels
        s = max(layer["scale"] for layer in info["layers"])
        assert (s == 1) == (reduce_min_coc_px == math.inf)
        assert out[40, 40 - int(c / 2) - 2 - s * (s > 1), 0] < 1e-6
        # the background far from the foreground is untouched
        np.testing.assert_allclose(out[5, 5], [0, 0, 1], atol=1e-6)
        # soft edge: red fades monotonically across the silhouette
        profile = out[40, 40 - int(c / 2): 40 + int(c / 2), 0]
        assert np.all(np.diff(profile) >= -1e-5)

    # (4.0, 41): 41.8 dB with the B-spline upsampling (44.4 bilinear); no tier reduces from 4 px any more
    @pytest.mark.parametrize("reduce_min_coc_px, min_psnr_db", [(8.0, 50), (4.0, 41), (2.0, 33)])
    def test_reduced_resolution_layers_approximate_the_exact_scatter(self, reduce_min_coc_px, min_psnr_db):
        h, w = 120, 140
        lin = cv2.GaussianBlur(texture(h, w, seed=5), (0, 0), 2)  # natural images are not white noise
        coc = np.full((h, w), 40.0, np.float32)
        exact, _ = render_layers_linear(lin, coc, quality="exact")
        plan = dataclasses.replace(plan_render(), reduce_min_coc_px=reduce_min_coc_px)
        fast, info = render_layers_linear(lin, coc, plan=plan)
        assert info["layers"][0]["scale"] > 1  # the reduced path really ran
        m = 25
        assert psnr(fast[m:-m, m:-m], exact[m:-m, m:-m]) > min_psnr_db
        # a single bright pixel keeps its energy at reduced resolution too
        img = np.zeros((h, w, 1), np.float32)
        img[60, 70] = 1.0
        out, _ = render_layers_linear(img, coc, plan=plan)
        assert out.sum() == pytest.approx(1.0, rel=1e-3)

    def test_light_is_conserved_on_a_plane(self):
        lin = texture(64, 64) * 3
        lin[:12], lin[-12:], lin[:, :12], lin[:, -12:] = 0, 0, 0, 0
        out, _ = render_layers_linear(lin, np.full((64, 64), 12.0, np.float32))
        assert out.sum() == pytest.approx(lin.sum(), rel=1e-4)

    @pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
    def test_dtype_and_shape_preserved(self, dtype):
        rng = np.random.default_rng(3)
        base = rng.random((30, 40, 3))
        color = (base * np.iinfo(dtype).max).astype(dtype) if np.dtype(dtype).kind == "u" else base.astype(dtype)
        depth = rng.uniform(0.5, 4, (30, 40)).astype(np.float32)
        for method in ("physical", "paper"):
            out, _ = render_image(color, depth, ThinLens(50, 1.4, 1.0), fx=FX, method=method)
            assert out.dtype == color.dtype and out.shape == color.shape

    def test_grey_image(self):
        color = np.tile(np.arange(40, dtype=np.uint8)[None, :] * 6, (30, 1))
        depth = np.full((30, 40), 3.0, np.float32)
        out, _ = render_image(color, depth, ThinLens(50, 1.4, 1.0), fx=FX)
        assert out.shape == color.shape and out.dtype == np.uint8

    def test_rejects_bad_input(self):
        color = np.zeros((10, 10, 3), np.uint8)
        with pytest.raises(InputError, match="depth_m"):
            render_image(color, np.ones((9, 10)), ThinLens(50, 2, 1), fx=FX)
        with pytest.raises(InputError, match="method"):
            render_image(color, np.ones((10, 10)), ThinLens(50, 2, 1), fx=FX, method="magic")
        with pytest.raises(LensError, match="ThinLens"):
            render_image(color, np.ones((10, 10)), PaperLens(1.0), fx=FX, method="physical")


@pytest.mark.parametrize("quality", ["exact", "balanced"])
@pytest.mark.parametrize("blades", [0, 3])
def test_flat_colour_stays_flat_under_a_huge_blur(quality, blades):
    """A render is a weighted mean of the input: a flat colour stays that colour to float32's rounding, however
    many sources overlap. Summed in float32, the equal terms of a flat colour rounded alike: a 84x123 frame
    blurred by 256 px came out 7.6e-5 too dark at ``exact`` (the scatter's runs) and 6e-6 at ``balanced`` (the
    cell means)."""
    value = 922.3816406
    color = np.full((123, 84, 3), value, np.float64)
    depth = np.full((123, 84), 0.5, np.float32)
    depth[:, :40] = 0.9
    lens = ThinLens(focal_length_mm=18.8, f_number=0.0053, focus_distance_m=168.0, aperture_blades=blades)
    with pytest.warns(UserWarning, match="clamped"):  # (a CoC of 370-660 px, rendered at the 256 px limit)
        out, _ = render_image(color, depth, lens, fx=93.0, linear=True, quality=quality)
    assert np.abs(out / value - 1).max() < 1e-6


def test_layers_classified_by_the_caller_render_as_the_renderer_classifies_them():
    from pcdof.stages.render.physical import classify_frame

    rng = np.random.default_rng(7)
    b = 9
    lin = rng.random((40 + 2 * b, 52 + 2 * b, 3)).astype(np.float32)
    coc = rng.choice([-14.0, -3.0, 0.2, 2.5, 7.0, 19.0], size=(40, 52)).astype(np.float32)
    plan = plan_render(quality="balanced")
    want, info = render_layers_linear(lin, coc, plan=plan, coc_border_px=b)
    layers = classify_frame(coc, b, plan)
    got, info_got = render_layers_linear(lin, coc, plan=plan, coc_border_px=b, layers=layers)
    np.testing.assert_array_equal(got, want)
    assert info_got["layers"] == info["layers"]
    with pytest.raises(InputError, match="layers must be the FrameLayers"):
        render_layers_linear(lin, coc, plan=plan, coc_border_px=b, layers=classify_frame(coc, b - 1, plan))
    with pytest.raises(InputError, match="layers must be the FrameLayers"):
        render_layers_linear(lin, coc, plan=plan, coc_border_px=b, layers="layers")


class TestPaper:
    def test_uniform_image_unchanged_without_luminosity_constant(self):
        color = np.full((50, 60, 3), 200, np.uint8)
        depth = np.random.default_rng(0).uniform(0.5, 8, (50, 60)).astype(np.float32)
        out, _ = render_image(color, depth, PaperLens(1.5, blur_sigma_px=6), fx=FX, method="paper")
        assert np.abs(out.astype(int) - 200).max() == 0

    def test_blend_follows_eq2_and_eq3(self):
        rng = np.random.default_rng(4)
        color = rng.random((40, 40, 3)).astype(np.float32)
        depth = np.linspace(0.5, 4.5, 40 * 40, dtype=np.float32).reshape(40, 40)
        lens = PaperLens(1.51, sigma=0.3, blur_sigma_px=4)
        out, _ = render_image(color, depth, lens, fx=FX, method="paper", max_range_m=4.5)
        blurred = cv2.GaussianBlur(color, (25, 25), 4, borderType=cv2.BORDER_REFLECT)
        d, df = depth / 4.5, 1.51 / 4.5
        alpha = 1 - np.exp(-((d - df) ** 2) / (2 * 0.3**2))
        ref = blurred * alpha[..., None] + color * (1 - alpha[..., None])
        np.testing.assert_allclose(out, ref, atol=1e-5)


def test_srgb_round_trip():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-6)
    lut = decode_to_linear(np.arange(256, dtype=np.uint8))
    np.testing.assert_allclose(lut, srgb_to_linear(np.arange(256) / 255), atol=1e-7)


class TestPartialOcclusion:
    def _bar_scene(self, focus):
        h, w = 60, 90
        lin = np.zeros((h, w, 3), np.float32)
        lin[..., 2] = 1.0  # blue wall at 3 m
        depth = np.full((h, w), 3.0, np.float32)
        lin[:, 44:47] = [1.0, 0.0, 0.0]  # a thin red bar (3 px) at 0.8 m
        depth[:, 44:47] = 0.8
        lens = ThinLens(50, 2.0, focus)
        return lin, lens.signed_coc_px(depth, FX)

    def test_thin_blurred_bar_turns_translucent_over_sharp_background(self):
        lin, coc = self._bar_scene(3.0)
        c = float(-coc.min())
        assert c > 10
        out, _ = render_layers_linear(lin, coc)
        # a real lens sees around a thin out-of-focus bar: at its centre only about
        # (bar width) / (CoC) of the aperture is blocked, so the wall shows through
        centre = out[30, 45]
        assert centre[2] > 0.5, centre
        assert 0.5 * 3 / c < centre[0] < 2.0 * 3 / c * 1.3, (centre, c)
        np.testing.assert_allclose(centre.sum(), 1.0, atol=1e-4)  # no light lost or gained

    def test_without_extension_the_bar_stays_opaque(self):
        # the ablation: what the extension behind edges buys
        lin, coc = self._bar_scene(3.0)
        out, _ = render_layers_linear(lin, coc, extend_behind=False)
        assert out[30, 45, 0] > 0.9
