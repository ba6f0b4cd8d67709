"""Blender's Defocus node as a benchmark peer (pcdof.bench.blender).

The settings are checked without Blender, against the node's own formula (Potmesil and Chakravarty 1981,
eq. 8, as Blender's compositor computes it); the node itself only where an interpreter with ``bpy`` is
configured (``PCDOF_BLENDER_PYTHON``, ``make blender``), against pcdof's exact renderer on a point source.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from pcdof.apertures import aperture_from_blades
from pcdof.bench import blender
from pcdof.errors import InputError
from pcdof.lens import ThinLens


def blender_coc_px(depth_m, *, width, sensor_width_mm, focal_length_mm, f_stop, focus_distance_m):
    """The diameter Blender's Defocus node gives a depth, in pixels (its radius, doubled)."""
    f = focal_length_mm / 1000.0
    v_object = f * depth_m / (depth_m - f)
    v_focus = f * focus_distance_m / (focus_distance_m - f)
    diameter_m = np.abs((v_object - v_focus) * (f / (f_stop * v_object)))
    return diameter_m * width / (sensor_width_mm / 1000.0)


class TestNodeSettings:
    @pytest.mark.parametrize("width, fx, focal_mm, f_number, focus", [
        (640, 525.0, 50.0, 1.4, 1.2), (256, 210.0, 85.0, 2.8, 3.0), (1920, 1500.0, 35.0, 8.0, 0.6),
    ])
    def test_the_nodes_coc_is_the_thin_lens(self, width, fx, focal_mm, f_number, focus):
        lens = ThinLens(focal_length_mm=focal_mm, f_number=f_number, focus_distance_m=focus)
        s = blender.node_settings(width=width, fx=fx, aperture_m=lens.aperture_m, focus_distance_m=focus)
        depth = np.geomspace(0.3, 50.0, 200)
        got = blender_coc_px(depth, width=width, focus_distance_m=focus, **s)
        np.testing.assert_allclose(got, lens.coc_px(depth, fx).astype(np.float64), rtol=1e-5, atol=1e-5)

    def test_the_camera_has_the_colour_cameras_focal_length(self):
        s = blender.node_settings(width=640, fx=525.0, aperture_m=0.02, focus_distance_m=2.0)
        assert s["focal_length_mm"] * 640 / s["sensor_width_mm"] == pytest.approx(525.0)

    @pytest.mark.parametrize("bad", [{"fx": 0.0}, {"width": -3}, {"aperture_m": float("nan")},
                                     {"focus_distance_m": "2"}])
    def test_rejects_bad_numbers(self, bad):
        args = {"width": 640, "fx": 525.0, "aperture_m": 0.02, "focus_distance_m": 2.0, **bad}
        with pytest.raises(InputError, match=next(iter(bad))):
            blender.node_settings(**args)

    def test_focus_inside_the_focal_length_is_refused(self):
        with pytest.raises(InputError, match="focus_distance_m must exceed"):
            blender.node_settings(width=640, fx=5250.0, aperture_m=0.02, focus_distance_m=0.2)


class TestBokeh:
    def test_disc_and_polygons(self):
        assert blender._bokeh(ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1))[0] == "CIRCLE"
        kind, angle = blender._bokeh(ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1, aperture_blades=6,
                                              aperture_rotation_deg=15.0))
        assert kind == "HEXAGON" and angle == pytest.approx(np.radians(15.0))

    def test_shapes_the_node_has_not_are_refused(self):
        with pytest.raises(blender.BlenderError, match="3 to 8 blades"):
            blender._bokeh(ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1, aperture_blades=9))
        with pytest.raises(blender.BlenderError, match="3 to 8 blades"):
            blender._bokeh(ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1,
                                    aperture_shape=aperture_from_blades(0, 0.0)))


class TestWorkerWithoutBlender:
    def frame(self):
        return np.zeros((8, 10, 3), np.float32), np.full((8, 10), 2.0, np.float32)

    def lens(self):
        return ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1)

    def test_no_interpreter_names_the_variable(self, monkeypatch):
        monkeypatch.delenv(blender.PYTHON_VARIABLE, raising=False)
        monkeypatch.setattr(blender.importlib.util, "find_spec", lambda name: None)
        assert blender.blender_python() is None and not blender.available()
        with pytest.raises(blender.BlenderError, match=blender.PYTHON_VARIABLE):
            blender.BlenderWorker().defocus(*self.frame(), self.lens(), fx=100.0)

    def test_a_path_that_is_no_interpreter(self, tmp_path):
        w = blender.BlenderWorker(python=str(tmp_path / "python"))
        with pytest.raises(blender.BlenderError, match="must name a Python interpreter"):
            w.defocus(*self.frame(), self.lens(), fx=100.0)

    @pytest.mark.skipif(blender.blender_python() == sys.executable, reason="this interpreter has bpy")
    def test_an_interpreter_without_bpy_says_so(self):
        w = blender.BlenderWorker(python=sys.executable)
        try:
            with pytest.raises(blender.BlenderError, match="import bpy failed"):
                w.defocus(*self.frame(), self.lens(), fx=100.0)
        finally:
            w.close()

    @pytest.mark.parametrize("lin, depth, match", [
        (np.zeros((8, 10), np.float32), np.ones((8, 10), np.float32), "lin must be"),
        (np.zeros((8, 10, 3), np.float32), np.ones((8, 9), np.float32), "depth_m must be"),
        (np.zeros((8, 10, 3), np.float32), np.zeros((8, 10), np.float32), "filled depth"),
    ])
    def test_bad_input_is_refused_before_any_process(self, lin, depth, match):
        w = blender.BlenderWorker(python="/nonexistent/python")
        with pytest.raises(InputError, match=match):
            w.defocus(lin, depth, self.lens(), fx=100.0)
        assert w._process is None


needs_blender = pytest.mark.skipif(not os.environ.get(blender.PYTHON_VARIABLE) and blender.blender_python() is None,
                                   reason=f"no interpreter with bpy ({blender.PYTHON_VARIABLE}; make blender)")


@pytest.fixture(scope="module")
def worker():
    w = blender.BlenderWorker()
    yield w
    w.close()


@needs_blender
class TestDefocusNode:

    @pytest.mark.parametrize("blades, rotation", [(0, 0.0), (6, 15.0)])
    def test_a_point_spreads_over_pcdofs_footprint(self, worker, blades, rotation):
        from pcdof.stages.render.physical import render_layers_linear

        h, w, fx = 120, 160, 150.0
        lin = np.zeros((h, w, 3), np.float32)
        lin[60, 80] = 100.0
        depth = np.full((h, w), 4.0, np.float32)
        lens = ThinLens(focal_length_mm=50, f_number=0.25, focus_distance_m=1.0, aperture_blades=blades,
                        aperture_rotation_deg=rotation)
        out, seconds = worker.defocus(lin, depth, lens, fx=fx)
        ref, _ = render_layers_linear(lin, lens.signed_coc_px(depth, fx), blades=blades, rotation_deg=rotation,
                                      quality="exact")
        assert out.shape == (h, w, 3) and out.dtype == np.float32 and seconds > 0
        np.testing.assert_allclose(out.sum(axis=(0, 1)), 100.0, rtol=1e-3)  # the node keeps the energy
        mine, theirs = ref[..., 0] > 0.5 * ref[..., 0].max(), out[..., 0] > 0.5 * out[..., 0].max()
        assert (mine & theirs).sum() / (mine | theirs).sum() > 0.95  # the same disc or hexagon, the same size

    def test_in_focus_stays_sharp(self, worker):
        rng = np.random.default_rng(0)
        lin = rng.random((40, 50, 3), dtype=np.float32)
        depth = np.full((40, 50), 1.0, np.float32)
        out, _ = worker.defocus(lin, depth, ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1.0), fx=100.0)
        np.testing.assert_allclose(out, lin, atol=1e-4)
