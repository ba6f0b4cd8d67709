"""Tests of pcdof.synth.emitters: the emitters' light sampled where it lands.

Independent answers: plain distributed ray tracing of the same scene (render_thin_lens) and the
thin-lens contract (a defocused emitter of radiance L and pinhole energy E spreads E uniformly over
a disc of diameter c(z) = A fx |1/d_f - 1/z|).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from pcdof.errors import InputError
from pcdof.lens import ThinLens
from pcdof.synth import make_frame, render_thin_lens
from pcdof.synth.emitters import emitter_term, render_thin_lens_split, split_emitters
from pcdof.synth.rig import kinect_rig
from pcdof.synth.scene import Scene
from pcdof.synth.scenes import quad
from pcdof.synth.shading import Material

BG = 0.3


def _plane(z, half=5.0):
    return quad([(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)], facing=(0, 0, 0))


def _square(cx, cy, half, z):
    return quad([(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z),
                 (cx - half, cy + half, z)], facing=(0, 0, 0))


def _lens(fx, focus_m, z, coc_px):
    """The 50 mm thin lens focused at *focus_m* that blurs depth *z* by *coc_px*."""
    aperture_m = coc_px / (fx * abs(1 / focus_m - 1 / z))
    return ThinLens(50.0, 50e-3 / aperture_m, focus_m)


def _frame(objects, size=(48, 36), pixel_samples=2):
    rig = kinect_rig(size, size)
    scene = Scene(objects, ambient=1.0, diffuse=0.0)  # flat albedo BG is exactly radiance BG
    return make_frame(scene, rig, default_lens=ThinLens(50.0, 2.0, 1.0), pixel_samples=pixel_samples), rig


def _emitter_on_plane(radiance=50.0, z=2.0, half_px=1.0, size=(48, 36)):
    rig = kinect_rig(size, size)
    half = half_px * z / rig.color.fx
    objs = [(_plane(z), Material("flat", (BG, BG, BG)), False),
            (_square(0.0, 0.0, half, z - 0.001), Material("emissive", emission=(radiance,) * 3), False)]
    return _frame(objs, size)


class TestSplitEmitters:
    def test_darkens_only_emitters_and_keeps_geometry(self):
        sf, _ = _emitter_on_plane()
        dark, ids = split_emitters(sf.scene)
        assert ids == [1]
        assert dark.materials[1].emission == (0.0, 0.0, 0.0)
        assert dark.materials[0] == sf.scene.materials[0]
        assert len(dark.meshes) == len(sf.scene.meshes)


class TestEmitterTerm:
    def test_energy_is_conserved_and_spread_over_the_disc(self):
        """A defocused emitter's light: total = its pinhole energy; inside its bokeh = E / disc area."""
        sf, rig = _emitter_on_plane()
        fx = rig.color.fx
        lens = _lens(fx, 1.0, 2.0, 14.0)
        term = emitter_term(sf, lens, samples=256, seed=0)[..., 0]
        pin = emitter_term(sf, _lens(fx, 2.0 - 1e-6, 2.0, 1e-4), samples=64, seed=0)[..., 0]
        # the emitter's area in pixels, from the box-filtered colour image: BG + (50 - BG) x coverage
        area = float((sf.color_linear[..., 0] - BG).clip(min=0).sum()) / (50.0 - BG)
        assert pin.sum() == pytest.approx(50.0 * area, rel=0.02)
        assert term.sum() == pytest.approx(pin.sum(), rel=0.02)
        c = float(lens.coc_px(np.float32(2.0), fx))
        cy, cx = int(round(rig.color.cy)), int(round(rig.color.cx))
        centre = term[cy - 2:cy + 3, cx - 2:cx + 3].mean()
        assert centre == pytest.approx(pin.sum() / (math.pi * c * c / 4), rel=0.05)
        yy, xx = np.mgrid[:term.shape[0], :term.shape[1]]
        outside = np.hypot(yy - rig.color.cy, xx - rig.color.cx) > c / 2 + 2.5
        assert term[outside].max() == 0.0

    def test_matches_plain_ray_tracing(self):
        """Split ground truth = plain distributed ray tracing of the same scene (a moderate emitter,
        an occluder partly in front of it), within the plain render's noise."""
        rig = kinect_rig((40, 30), (40, 30))
        fx = rig.color.fx
        objs = [(_plane(2.0), Material("checker", (0.4, 0.4, 0.4), (0.1, 0.1, 0.1), scale_m=0.12), False),
                (_square(0.02, 0.0, 4 * 1.5 / fx, 1.5), Material("emissive", emission=(4.0, 3.0, 2.0)), False),
                (_square(-0.1, 0.0, 0.1, 0.8), Material("flat", (0.6, 0.2, 0.2)), False)]
        sf, _ = _frame(objs, size=(40, 30))
        lens = _lens(fx, 2.0, 1.5, 8.0)
        split = render_thin_lens_split(sf, lens, seed=1, target_psnr_db=40.0, emitter_samples=1024)
        plain = render_thin_lens(sf, lens, samples=4096, seed=2)
        mse = float(np.mean((split - plain) ** 2))
        assert -10 * math.log10(mse / 4.0 ** 2) > 45.0  # PSNR against the emitter peak (55 dB measured)
        assert split.sum() == pytest.approx(plain.sum(), rel=0.01)

    def test_occluder_in_front_hides_the_emitter(self):
        """An opaque plane between the lens and the whole emitter leaves no emitter light."""
        rig = kinect_rig((32, 24), (32, 24))
        objs = [(_plane(2.0), Material("flat", (BG,) * 3), False),
                (_square(0.0, 0.0, 0.01, 1.999), Material("emissive", emission=(50.0,) * 3), False),
                (_plane(0.5), Material("flat", (0.2,) * 3), False)]
        sf, _ = _frame(objs, size=(32, 24))
        term = emitter_term(sf, _lens(rig.color.fx, 1.0, 2.0, 10.0), samples=64)
        assert term.max() == 0.0

    def test_seed_changes_only_the_noise(self):
        sf, rig = _emitter_on_plane(size=(32, 24))
        lens = _lens(rig.color.fx, 1.0, 2.0, 8.0)
        a, b = emitter_term(sf, lens, samples=256, seed=0), emitter_term(sf, lens, samples=256, seed=1)
        assert not np.array_equal(a, b)
        assert a.sum() == pytest.approx(b.sum(), rel=0.01)

    def test_invalid_lens(self):
        sf, _ = _emitter_on_plane(size=(16, 12))
        with pytest.raises(InputError, match="circular aperture"):
            emitter_term(sf, replace(ThinLens(50.0, 2.0, 1.0), aperture_blades=6))
        with pytest.raises(InputError, match="lens"):
            emitter_term(sf, "f/2")
