"""A photographer's lens (an f-number in 35 mm terms, a blur as a share of the width), and a phone depth map's
registration (the depth camera is the photo's camera on a 5-10x coarser grid): its edges follow the photo."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof.camera import RGBDFrame
from pcdof.cli import main
from pcdof.errors import InputError, LensError
from pcdof.stages.fill import fill_depth
from pcdof.stages.register.guided import coarse_depth_scale, open_coarse_edges, open_depth_edges
from pcdof.lens import ThinLens
from pcdof.pipeline import prepare_depth
from pcdof.phone_lens import BlurShareLens, equivalent_lens, focal_35mm
from pcdof.stages.register import register_depth
from pcdof.sources.phone import intrinsics_from_35mm, phone_rig

CAM = intrinsics_from_35mm(4032, 3024, 26.0)


class TestEquivalentLens:
    def test_full_frame_thin_lens(self):
        """The blur, in pixels, of a full-frame camera at f/1.4 with the photo's angle of view (exact thin lens)."""
        lens = equivalent_lens(ThinLens(50.0, 1.8, 2.0), CAM, 1.4)
        f = focal_35mm(CAM)
        assert f == pytest.approx(26.0)
        pitch_mm = math.hypot(36, 24) / math.hypot(4032, 3024)  # the full-frame sensor, the photo's pixels
        z = np.array([0.5, 1.0, 4.0, 50.0])
        df_mm, z_mm, A = 2000.0, z * 1000, f / 1.4
        exact_px = A * np.abs(z_mm - df_mm) / z_mm * f / (df_mm - f) / pitch_mm
        got = np.abs(lens.signed_coc_px(z, CAM.fx))
        assert np.allclose(got, exact_px, rtol=0.015)  # pcdof drops f/(d_f - f) -> f/d_f: 1.3 % at 2 m

    def test_refuses_bad_values(self):
        for bad in (0, -1.4, float("nan"), True):
            with pytest.raises(LensError):
                equivalent_lens(ThinLens(50.0, 1.8, 2.0), CAM, bad)


class TestBlurShare:
    def test_far_background_disc_is_the_share_after_refocus(self):
        lens = BlurShareLens.for_camera(ThinLens(50.0, 1.8, 1.0), CAM, 0.03)
        for focus in (0.4, 2.0, 7.5):
            moved = dataclasses.replace(lens, focus_distance_m=focus)  # how the pipeline resolves the focus
            far = abs(float(moved.signed_coc_px(np.array([1e9]), CAM.fx)[0]))
            assert far == pytest.approx(0.03 * CAM.width, rel=1e-5)

    def test_needs_no_metric_scale(self):
        z = np.array([0.3, 0.6, 2.0, 9.0])
        a = BlurShareLens.for_camera(ThinLens(26.0, 1.0, 0.5), CAM, 0.02)
        b = dataclasses.replace(a, focus_distance_m=0.5 * 37.0)
        assert np.allclose(a.signed_coc_px(z, CAM.fx), b.signed_coc_px(z * 37.0, CAM.fx), rtol=1e-5)

    @pytest.mark.parametrize("share", [0.0, -0.1, 1.5, float("inf")])
    def test_refuses_bad_share(self, share):
        with pytest.raises(LensError):
            BlurShareLens.for_camera(ThinLens(26.0, 1.0, 0.5), CAM, share)


class TestCliFlags:
    @pytest.mark.parametrize("flags,code", [(["--blur", "0"], 5), (["--blur", "150"], 5),
                                            (["--equivalent-f-number", "-2"], 5),
                                            (["--blur", "2", "--equivalent-f-number", "2"], 6),
                                            (["--blur", "2", "--method", "paper"], 6)])
    def test_refused_before_reading(self, tmp_path, flags, code):
        result = CliRunner().invoke(main, ["render", "missing.heic", "-o", str(tmp_path / "o.png"), *flags],
                                    prog_name="pcdof")
        assert result.exit_code == code, result.output
        assert len(result.output.strip().splitlines()) == 1 and result.output.startswith("pcdof: error: ")


def ellipse_scene(H=300, W=400, k=5):
    """A photo with a sharp-edged ellipse (edges off any grid) and its depth at 1/k resolution, block majority."""
    yy, xx = np.mgrid[0:H, 0:W]
    inside = ((xx - 203.0) ** 2 / 90 ** 2 + (yy - 148.0) ** 2 / 70 ** 2) <= 1.0
    color = np.where(inside[..., None], np.array([220, 180, 60], np.uint8), np.array([30, 60, 120], np.uint8))
    rng = np.random.default_rng(0)
    color = np.clip(color.astype(int) + rng.integers(-4, 5, color.shape), 0, 255).astype(np.uint8)
    blocks = inside.reshape(H // k, k, W // k, k).mean(axis=(1, 3)) >= 0.5
    depth_low = np.where(blocks, 1.0, 3.0).astype(np.float32)
    rig = phone_rig(intrinsics_from_35mm(W, H, 26.0), depth_low.shape, max_range_m=4.0)
    return RGBDFrame(color, depth_low, rig), inside


@pytest.mark.parametrize("k", [5, 10])
def test_registered_depth_edges_follow_the_photo(k):
    """The depth at 1/k resolution; after the render's registration + fill the depth edge lies on the colour
    edge within 1 px, where the depth grid alone misses it by up to half a depth pixel."""
    frame, inside = ellipse_scene(k=k)
    _registered, filled, trace = prepare_depth(frame, ThinLens(focal_length_mm=26.0, f_number=2.0,
                                                               focus_distance_m=1.0))
    assert "left to the colour-guided fill" in trace[0].reason and trace[0].detail["edges"]["radius_px"] == k
    edge = cv2.Canny(inside.astype(np.uint8) * 255, 100, 200) > 0
    dist = cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, 5)
    wrong = (filled < 2.0) != inside
    assert dist[wrong].max(initial=0) <= 1.0 and wrong.sum() < 60
    # registration alone (the mesh and its footprints) keeps the depth grid's steps
    grid = (fill_depth(register_depth(frame), frame.color) < 2.0) != inside
    assert dist[grid].max() >= 0.4 * k and grid.sum() > 5 * wrong.sum()


def test_other_rigs_are_left_alone():
    frame, _ = ellipse_scene()
    same = phone_rig(frame.rig.color, (300, 400), max_range_m=4.0)  # depth as fine as colour
    assert coarse_depth_scale(same) is None and coarse_depth_scale(frame.rig) == pytest.approx(5.0)
    moved = dataclasses.replace(frame.rig, T_color_from_depth=np.array(
        [[1, 0, 0, 0.05], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]))
    assert coarse_depth_scale(moved) is None
    depth = np.full((50, 60), 2.0, np.float32)
    assert open_coarse_edges(depth, same)[1] is None and open_coarse_edges(depth, same)[0] is depth
    with pytest.raises(InputError):
        open_depth_edges(depth, radius_px=0)
