"""RenderOptions: one checked, frozen object from the boundary to the stages."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.errors import InputError, LensError, PcdofError
from pcdof.lens import PaperLens, ThinLens
from pcdof.options import RenderOptions, as_options
from pcdof.pipeline import run

INTR = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)


def frame(seed=0):
    rng = np.random.default_rng(seed)
    depth = np.full((48, 64), 3.0, np.float32)
    depth[10:30, 15:40] = rng.uniform(0.8, 1.2)
    depth[rng.random((48, 64)) < 0.05] = 0.0  # holes for the fill stage
    color = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    return RGBDFrame(color, depth, Rig.registered(INTR))


class TestConstruction:
    def test_defaults(self):
        o = RenderOptions(ThinLens(50, 2, 1.0))
        assert (o.method, o.quality, o.fill_method, o.linear, o.focus_at) == (
            "physical", "balanced", "joint-bilateral", False, None)

    @pytest.mark.parametrize("field, value", [
        ("method", "blur"), ("quality", "ultra"), ("fill_method", "magic"), ("linear", "yes"),
        ("focus_at", (1.0,)), ("focus_at", (np.nan, 2.0)), ("device", "tpu"), ("method", ["physical"]),
    ])
    def test_bad_values_name_the_field(self, field, value):
        with pytest.raises(PcdofError, match=field):
            RenderOptions(ThinLens(50, 2, 1.0), **{field: value})

    def test_lens_type_and_method_checked(self):
        with pytest.raises(LensError, match="lens"):
            RenderOptions("50mm")
        with pytest.raises(LensError, match="physical method needs a ThinLens"):
            RenderOptions(PaperLens(1.0))
        assert RenderOptions(PaperLens(1.0), method="paper").method == "paper"

    def test_frozen_and_replace_checks(self):
        o = RenderOptions(ThinLens(50, 2, 1.0))
        with pytest.raises(dataclasses.FrozenInstanceError):
            o.quality = "fast"
        assert o.replace(quality="fast").quality == "fast" and o.quality == "balanced"
        with pytest.raises(InputError, match="quality"):
            o.replace(quality="nope")

    def test_focus_at_normalised(self):
        o = RenderOptions(ThinLens(50, 2, 1.0), focus_at=[3, np.float32(4.5)])
        assert o.focus_at == (3.0, 4.5) and all(type(v) is float for v in o.focus_at)

    def test_to_dict_is_plain(self):
        import json

        d = RenderOptions(ThinLens(50, 2, 1.0, aperture_blades=6), focus_at=(1, 2)).to_dict()
        assert json.loads(json.dumps(d)) == d
        assert d["lens"]["type"] == "ThinLens" and d["lens"]["aperture_blades"] == 6


class TestAsOptions:
    def test_unknown_keyword_is_named(self):
        with pytest.raises(InputError, match="'qualty'"):
            as_options(ThinLens(50, 2, 1.0), qualty="fast")

    def test_overrides_apply_to_options(self):
        o = RenderOptions(ThinLens(50, 2, 1.0))
        assert as_options(o) is o
        assert as_options(o, method="paper").method == "paper"


class TestPipelineTakesOptions:
    @settings(max_examples=8, deadline=None)
    @given(seed=st.integers(0, 2**16), quality=st.sampled_from(["exact", "balanced", "fast"]),
           fill=st.sampled_from(["joint-bilateral", "telea", "nearest-background"]),
           method=st.sampled_from(["physical", "paper"]))
    def test_same_result_either_way(self, seed, quality, fill, method):
        f, lens = frame(seed), ThinLens(50, 1.4, 1.0)
        kw = dict(method=method, quality=quality, fill_method=fill, focus_at=(30, 20))
        a = run(f, lens, **kw)
        b = run(f, RenderOptions(lens, **kw))
        np.testing.assert_array_equal(a.image, b.image)
        assert a.lens == b.lens

    def test_focus_at_resolves_the_lens_by_keyword(self):
        res = run(frame(), RenderOptions(ThinLens(50, 2, 9.0, aperture_blades=5), focus_at=(20, 15)))
        assert res.lens.aperture_blades == 5 and abs(res.lens.focus_distance_m - 9.0) > 1
        res = run(frame(), RenderOptions(PaperLens(9.0, sigma=0.2), method="paper", focus_at=(20, 15)))
        assert res.lens.sigma == 0.2 and abs(res.lens.focus_distance_m - 9.0) > 1


def clipped_frame(seed=0, *, focus_m=1.0):
    """A dark wall at 3 m with a small clipped lamp on it, in 8-bit sRGB (the lamp's pixels at 255)."""
    rng = np.random.default_rng(seed)
    color = rng.integers(20, 60, (48, 64, 3), dtype=np.uint8)
    color[20:24, 30:34] = 255
    depth = np.full((48, 64), 3.0, np.float32)
    return RGBDFrame(color, depth, Rig.registered(INTR))


class TestHighlights:
    @pytest.mark.parametrize("value, expected", [("off", "off"), ("auto", "auto"), ("rim", "rim"), (8, 8.0),
                                                 ("16", 16.0), (np.float32(2.5), 2.5)])
    def test_values(self, value, expected):
        assert RenderOptions(ThinLens(50, 2, 1.0), highlights=value).highlights == expected

    @pytest.mark.parametrize("value", ["bright", 0.5, np.nan, True, None, 1e9])
    def test_bad_values(self, value):
        with pytest.raises(InputError, match="highlights"):
            RenderOptions(ThinLens(50, 2, 1.0), highlights=value)

    def test_auto_by_default_and_off_skips(self):
        f, lens = clipped_frame(), ThinLens(50, 1.4, 1.0)
        assert RenderOptions(lens).highlights == "auto"
        stage = next(t for t in run(f, lens).trace if t.name == "highlights")
        assert not stage.skipped and stage.detail["method"] == "auto"
        assert next(t for t in run(f, lens, highlights="off").trace if t.name == "highlights").reason == "off"

    def test_gain_brightens_the_bokeh_by_the_lamps_extra_energy(self):
        from pcdof.color import decode_to_linear

        f, lens = clipped_frame(), ThinLens(200, 1.0, 1.0)  # the lamp spread over an 8 px disc
        off = decode_to_linear(run(f, lens, highlights="off").image)
        on_res = run(f, lens, highlights=4.0)
        on = decode_to_linear(on_res.image)
        stage = next(t for t in on_res.trace if t.name == "highlights")
        assert not stage.skipped and stage.detail["clipped_pixels"] == 16
        # the lamp (16 px of linear 1) now carries 4x its light: about 48 more units spread into its disc,
        # the part that stays under the 8-bit clip is counted
        extra = float((on - off).sum() / 3)
        assert 20.0 < extra <= 48.5, extra
        assert on_res.image.dtype == np.uint8

    def test_skipped_when_nothing_is_clipped_or_input_is_linear(self):
        f, lens = frame(), ThinLens(50, 1.4, 1.0)
        f = RGBDFrame(np.minimum(f.color, 250).astype(np.uint8), f.depth_m, f.rig)
        a, b = run(f, lens), run(f, lens, highlights="auto")
        np.testing.assert_array_equal(a.image, b.image)
        assert next(t for t in b.trace if t.name == "highlights").reason == "nothing clipped"
        lin = RGBDFrame(f.color.astype(np.float32) / 255 * 3, f.depth_m, f.rig)
        res = run(lin, lens, linear=True, highlights="auto")
        assert next(t for t in res.trace if t.name == "highlights").reason == "linear input is not clipped"

    def test_in_focus_frame_is_returned_bit_exact(self):
        f = clipped_frame()
        res = run(f, ThinLens(50, 1.4, 3.0), highlights=8)  # the whole wall in focus
        np.testing.assert_array_equal(res.image, f.color)


def test_public_names():
    import pcdof
    import pcdof.sources

    assert pcdof.RenderOptions is RenderOptions
    assert pcdof.open_source is pcdof.sources.open_source and pcdof.SOURCES is pcdof.sources.SOURCES
    assert set(pcdof.__all__) <= set(dir(pcdof))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pcdof.nope


def test_highlights_clip_level_follows_the_encoding():
    """uint16 colour is clipped only at its own top code: 65528 is a measured value, not a clipped one."""
    f = clipped_frame()
    c16 = f.color.astype(np.uint16) * 257
    c16[20:24, 30:34] = 65528  # just below the top of 16 bits: not clipped
    res = run(RGBDFrame(c16, f.depth_m, f.rig), ThinLens(200, 1.0, 1.0), highlights=4.0)
    assert next(t for t in res.trace if t.name == "highlights").reason == "nothing clipped"
    c16[20:24, 30:34] = 65535
    res = run(RGBDFrame(c16, f.depth_m, f.rig), ThinLens(200, 1.0, 1.0), highlights=4.0)
    assert next(t for t in res.trace if t.name == "highlights").detail["clipped_pixels"] == 16
