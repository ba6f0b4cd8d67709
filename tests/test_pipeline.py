"""The pipeline executor: stages skip the work a frame does not need, and say so in the trace."""


import numpy as np
import pytest

import pcdof.stages.render.physical as render_module
from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.errors import InputError, LensError
from pcdof.lens import PaperLens, ThinLens
from pcdof.pipeline import render, render_from_depth, run

INTR = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)


def frame_with(depth, *, rig=None, seed=0):
    rng = np.random.default_rng(seed)
    color = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    return RGBDFrame(color, depth.astype(np.float32), rig or Rig.registered(INTR))


def two_planes():
    depth = np.full((48, 64), 4.0, np.float32)
    depth[12:36, 20:44] = 1.0
    return depth


def stage(result, name):
    return next(t for t in result.trace if t.name == name)


class TestSkipping:
    def test_registered_rig_is_not_reprojected(self, monkeypatch):
        import pcdof.stages.register as register_module

        def forbidden(*a, **k):
            raise AssertionError("registration ran for a registered rig")

        monkeypatch.setattr(register_module, "register_depth", forbidden)
        res = run(frame_with(two_planes()), ThinLens(50, 2, 1.0))
        assert stage(res, "register").skipped
        np.testing.assert_array_equal(res.depth_registered_m, two_planes())

    def test_no_holes_no_fill(self, monkeypatch):
        import pcdof.stages.fill as fill_module

        monkeypatch.setattr(fill_module, "fill_depth", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
        res = run(frame_with(two_planes()), ThinLens(50, 2, 1.0))
        assert stage(res, "fill").skipped
        assert "hole" in stage(res, "fill").reason

    def test_holes_are_filled(self):
        depth = two_planes()
        depth[5:8, 5:8] = 0
        res = run(frame_with(depth), ThinLens(50, 2, 1.0))
        assert not stage(res, "fill").skipped
        assert np.all(res.depth_filled_m > 0)

    def test_sharp_frame_is_returned_bit_exact_without_blur(self, monkeypatch):
        def forbidden(*a, **k):
            raise AssertionError("blur ran although nothing is out of focus")

        monkeypatch.setattr(render_module, "render_layers_linear", forbidden)
        f = frame_with(two_planes())
        res = run(f, ThinLens(50, 5000, 1.0))
        assert stage(res, "render").skipped
        assert res.image is not f.color
        np.testing.assert_array_equal(res.image, f.color)

    @pytest.mark.parametrize("overlap", [True, False])
    def test_sharp_frame_with_clipped_lights_skips_the_highlights_estimate(self, monkeypatch, overlap):
        import pcdof.stages.highlights as highlights_module
        import pcdof.stages.highlights.stage as highlights_stage

        def forbidden(*a, **k):
            raise AssertionError("radiance estimated for a frame nothing of which is blurred")

        monkeypatch.setattr(highlights_module, "reconstruct_prepared", forbidden)
        monkeypatch.setattr(highlights_stage, "OVERLAP", overlap)
        f = frame_with(two_planes())
        f.color[20:24, 30:34] = 255  # a clipped light in the sharp subject
        res = run(f, ThinLens(50, 5000, 1.0))  # every CoC far below a pixel
        hl = stage(res, "highlights")
        assert hl.skipped and "nothing to blur" in hl.reason
        assert stage(res, "render").skipped
        np.testing.assert_array_equal(res.image, f.color)
        # stopped just enough to blur: the estimate runs
        monkeypatch.undo()
        res = run(f, ThinLens(50, 1.4, 1.0))
        assert not stage(res, "highlights").skipped

    def test_no_foreground_pass_when_nothing_is_in_front_of_focus(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))  # focus on the nearest surface
        detail = stage(res, "render").detail
        assert not detail["foreground_pass"]
        assert all(l["side"] == "back" for l in detail["layers"] if l["blurred"])
        assert "no foreground pass" in stage(res, "render").reason

    def test_only_the_blur_sizes_present_are_computed(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))
        layers = [l for l in stage(res, "render").detail["layers"] if l["blurred"]]
        c_wall = float(ThinLens(50, 1.4, 1.0).coc_px(np.array([[4.0]], np.float32), 60.0)[0, 0])
        assert len(layers) == 1  # one plane behind focus: one blur layer, whatever the range of sizes
        lo, hi = layers[0]["coc_px"]
        assert lo <= c_wall < hi

    def test_in_focus_pixels_are_copied_unchanged(self):
        f = frame_with(two_planes())
        res = run(f, ThinLens(50, 1.4, 1.0))
        # the in-focus subject's interior (further than the background's blur reach from the edge)
        np.testing.assert_array_equal(res.image[16:32, 24:40], f.color[16:32, 24:40])

    def test_explain_lists_every_stage(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))
        text = res.explain()
        for name in ("register", "fill", "coc", "render", "total"):
            assert name in text
        assert res.skipped.keys() >= {"register", "fill"}


class TestApi:
    def test_render_returns_input_dtype_and_shape(self):
        f = frame_with(two_planes())
        out = render(f, ThinLens(50, 1.4, 2.0))
        assert out.dtype == np.uint8 and out.shape == f.color.shape

    def test_focus_at_pixel_uses_depth_there(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 3.0), focus_at=(32, 24))
        assert res.lens.focus_distance_m == pytest.approx(1.0)
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 3.0), focus_at=(2, 2))
        assert res.lens.focus_distance_m == pytest.approx(4.0)

    def test_paper_method(self):
        f = frame_with(two_planes())
        res = run(f, PaperLens(1.0), method="paper")
        assert res.image.shape == f.color.shape and res.coc_px is None

    def test_render_from_depth_matches_run(self):
        f = frame_with(two_planes())
        lens = ThinLens(50, 1.4, 1.0)
        a = run(f, lens).image
        b, trace = render_from_depth(f.color, two_planes(), lens, INTR.fx)
        np.testing.assert_array_equal(a, b)

    def test_errors(self):
        f = frame_with(two_planes())
        with pytest.raises(InputError, match="frame"):
            run(f.color, ThinLens(50, 2, 1))
        with pytest.raises(InputError, match="method"):
            run(f, ThinLens(50, 2, 1), method="bokeh")
        with pytest.raises(LensError):
            run(f, PaperLens(1.0), method="physical")
        with pytest.raises(LensError):
            run(f, "f/2")
        with pytest.raises(InputError, match="focus"):
            run(f, ThinLens(50, 2, 1), focus_at=(500, 2))
