"""Aperture shapes: the registry, the disc and polygon, and a new shape added through the seam."""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass

import numpy as np
import pytest

import pcdof.stages.render as renderer
from pcdof.apertures import APERTURES, Aperture, Disc, Polygon, as_aperture
from pcdof.lens import aperture_for
from pcdof.errors import InputError, PcdofError
from pcdof.lens import ThinLens
from pcdof.stages.render import reference as ref_render
from pcdof.stages.render.tiles import TileMap

D = 0.6  # the cat's eye: the unit disc cut by the unit disc centred at (D, 0)


@dataclass(frozen=True)
class CatsEye(Aperture):
    """The lens-shaped overlap of two unit discs D apart (the vignetted bokeh near a frame's edge):
    row-convex, and off-centre on every row (its centroid is at x = D / 2)."""

    offset: float = D

    def span(self, v):
        s = np.sqrt(np.maximum(1.0 - np.asarray(v, np.float64) ** 2, 0.0))
        return self.offset - s, s

    @property
    def unit_area(self):
        h = 0.5 * self.offset  # two circular segments of height 1 - h
        return 2.0 * (math.acos(h) - h * math.sqrt(1.0 - h * h))


def _untiled(shape) -> TileMap:
    th, tw = -(-shape[0] // 16), -(-shape[1] // 16)
    inf = np.full((th, tw), np.inf, np.float32)
    return TileMap(shape, 16, -inf, inf, np.zeros((th, tw), bool))


@pytest.fixture
def cats_eye(monkeypatch):
    monkeypatch.setitem(APERTURES, "cats-eye", CatsEye)
    return APERTURES["cats-eye"]()


class TestRegistry:
    def test_lens_selects_disc_or_polygon(self):
        assert aperture_for(ThinLens(50.0, 2.0, 1.0)) == Disc()
        shape = aperture_for(ThinLens(50.0, 2.0, 1.0, aperture_blades=6, aperture_rotation_deg=15.0))
        assert shape == Polygon(6, math.radians(15.0) - math.pi / 2)  # a vertex points up at rotation 0
        assert set(APERTURES) >= {"disc", "polygon"}

    def test_invalid(self):
        with pytest.raises(InputError, match="blades"):
            Polygon(2)
        with pytest.raises(InputError, match="ThinLens"):
            aperture_for("disc")
        with pytest.raises(PcdofError, match="aperture"):
            as_aperture(1)
        with pytest.raises(InputError, match="aperture"):
            renderer.render_layers_linear(np.zeros((4, 4, 3), np.float32), np.zeros((4, 4), np.float32),
                                          aperture="disc")

    @pytest.mark.parametrize("shape", [Disc(), Polygon(3), Polygon(7, 0.4), Polygon(64)])
    def test_exact_bands_match_the_default_integration_of_the_span(self, shape):
        # the disc's closed form and the polygon's clipping against Aperture.band's quadrature of span
        for lo, hi in [(-1.0, 1.0), (-0.3, 0.2), (0.55, 0.95)]:
            exact = shape.band(2.5, 2.5 * lo, 2.5 * hi)
            generic = Aperture.band(shape, 2.5, 2.5 * lo, 2.5 * hi)
            assert generic[0] == pytest.approx(exact[0], rel=1e-6)  # area, px^2
            assert generic[1] == pytest.approx(exact[1], abs=1e-6)  # centroid x, px
        assert shape.band(1.0, -1.0, 1.0)[0] == pytest.approx(shape.unit_area, rel=1e-12)

    @pytest.mark.parametrize("shape", [Disc(), Polygon(5, 0.3)])
    def test_samples_are_area_uniform_on_the_shape(self, shape):
        p = shape.sample(np.random.default_rng(0).random((40_000, 2)))
        lo, hi = shape.span(p[:, 1])
        assert np.all((p[:, 0] >= lo - 1e-9) & (p[:, 0] <= hi + 1e-9))  # inside
        rows = np.histogram(p[:, 1], bins=8, range=(-1, 1))[0] / len(p)
        edges = np.linspace(-1, 1, 9)
        want = [shape.band(1.0, a, b)[0] / shape.unit_area for a, b in zip(edges[:-1], edges[1:])]
        np.testing.assert_allclose(rows, want, atol=0.01)


class TestNewShape:
    """A shape registered in the test reaches the fast renderer and the reference with no other change."""

    def test_table_carries_the_area_and_first_moment(self, cats_eye):
        table = renderer.aperture_table(cats_eye)
        area = table[0, -1] - table[0, 0]
        assert area == pytest.approx(cats_eye.unit_area, rel=1e-6)
        assert (table[1, -1] - table[1, 0]) / area == pytest.approx(0.5 * D, rel=1e-5)  # centroid x

    @pytest.mark.parametrize("r", [1.7, 3.3, 9.6])
    def test_fast_point_source_is_the_reference_footprint(self, cats_eye, r):
        table = renderer.aperture_table(cats_eye)
        fast = renderer.uniform.footprint_kernel(r, cats_eye.symmetric, table)  # one source through the scatter
        ref = ref_render.footprint(r, cats_eye) / (cats_eye.unit_area * r * r)
        assert fast.shape == ref.shape
        np.testing.assert_allclose(fast, ref, atol=2e-5, rtol=0)
        # energy: both carry exactly one source's weight
        assert fast.sum(dtype=np.float64) == pytest.approx(1.0, abs=1e-5)
        assert ref.sum() == pytest.approx(1.0, rel=1e-7)
        # and the footprint is off-centre as the shape is (a disc's centred footprint would fail here);
        # pixel centres move the first moment of each row's interval by at most 1/8 px
        R = ref.shape[0] // 2
        x = np.arange(-R, R + 1)
        assert (fast.sum(axis=0) * x).sum() == pytest.approx(0.5 * D * r, abs=0.125)

    def test_whole_render_matches_the_reference(self, cats_eye):
        rng = np.random.default_rng(3)
        h, w = 36, 40
        lin = rng.random((h, w, 3)).astype(np.float32)
        yy, xx = np.mgrid[0:h, 0:w]
        coc = np.where(xx < w // 2, -9.0, np.where(yy < h // 2, 0.2, 14.0)).astype(np.float32)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out, _ = renderer.render_layers_linear(lin, coc, aperture=cats_eye, quality="exact",
                                                   tiles=_untiled((h, w)), extend_behind=False)
        ref = ref_render.render_layers_linear(lin, coc, aperture=cats_eye, extend_behind_layers=False)
        np.testing.assert_allclose(out, ref, atol=2e-4, rtol=0)
        disc = ref_render.render_layers_linear(lin, coc, extend_behind_layers=False)
        assert np.abs(disc - ref).max() > 0.01  # the shape matters: a disc render is far from it


class TestShapeOnTheLens:
    """A registered shape reaches every renderer through the lens: ThinLens(aperture_shape=...)."""

    def test_pipeline_renders_the_lens_shape(self, cats_eye):
        from pcdof.camera import Intrinsics, RGBDFrame, Rig
        from pcdof.errors import LensError
        from pcdof.lens import ThinLens
        from pcdof.pipeline import run

        lens = ThinLens(focal_length_mm=400, f_number=1.4, focus_distance_m=1.0, aperture_shape=cats_eye)
        assert aperture_for(lens) is cats_eye
        rng = np.random.default_rng(5)
        color = np.zeros((40, 48, 3), np.uint8)
        color[20, 24] = 200  # one bright point on a dark wall behind the focus
        color += rng.integers(0, 3, color.shape, dtype=np.uint8)
        frame = RGBDFrame(color, np.full((40, 48), 3.0, np.float32), Rig.registered(Intrinsics(48, 40, 50.0, 50.0, 23.5, 19.5)))
        shaped = run(frame, lens, quality="exact").image.astype(float)
        disc = run(frame, dataclasses.replace(lens, aperture_shape=None), quality="exact").image.astype(float)
        assert np.abs(shaped - disc).max() > 5  # the bokeh of the point has the lens's shape
        x = np.arange(48)
        # the bokeh's centroid moves by the shape's: 0.3 r (r = 4.8 px here), the disc's stays at the point
        centre = lambda img: (img.sum(axis=(0, 2)) * x).sum() / img.sum()  # noqa: E731
        above = lambda img: np.maximum(img - 3.0, 0.0)  # noqa: E731 - the point's light, not the wall's noise
        assert centre(above(shaped)) - centre(above(disc)) > 0.7
        with pytest.raises(LensError, match="aperture_shape or aperture_blades"):
            ThinLens(focal_length_mm=100, f_number=1.4, focus_distance_m=1.0, aperture_blades=6,
                     aperture_shape=cats_eye)
        with pytest.raises(LensError, match="aperture_shape must be"):
            ThinLens(focal_length_mm=100, f_number=1.4, focus_distance_m=1.0, aperture_shape="cats-eye")
