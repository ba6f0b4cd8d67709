"""pcdof.stages.highlights, the ``prior`` method (``auto``): the level of least expected output error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.lens import ThinLens
from pcdof.pipeline import run
from pcdof.stages.highlights import (CLIP_LEVEL, HIGHLIGHT_METHODS, disc_kernel, expected_best_level,
                                     prior_levels, reconstruct_highlights, rim_likelihood)
from pcdof.stages.highlights.loss import chosen_levels, display

PROPERTY = settings(deadline=None, derandomize=True, max_examples=25, database=None,
                    suppress_health_check=[HealthCheck.too_slow])


def _srgb(v):
    """sRGB encoding of linear light clipped at 1, written out independently of pcdof."""
    v = min(max(v, 0.0), 1.0)
    return 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055


def _brute_loss(base, k, weight, levels, probs, cand):
    return sum(p * sum(w * (_srgb(b + cand * kk) - _srgb(b + t * kk)) ** 2 for b, kk, w in zip(base, k, weight))
               for t, p in zip(levels, probs))


def _disc_source(level, radius, *, bg=0.1, size=48, k=16, offset=(0.31, 0.17)):
    """A sharp disc of radiance *level*, box-filtered over k x k sub-pixels: (clipped, true) (size, size, 3)."""
    sub = (np.arange(size * k) + 0.5) / k - size / 2
    x, y = np.meshgrid(sub - offset[0], sub - offset[1])
    true = np.where(x ** 2 + y ** 2 <= radius ** 2, level, bg).reshape(size, k, size, k).mean(axis=(1, 3))
    true = np.repeat(true[..., None], 3, axis=2).astype(np.float32)
    return np.minimum(true, 1.0), true


class TestExpectedBestLevel:
    @PROPERTY
    @given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.integers(1, 6))
    def test_matches_a_brute_force_search(self, seed, n, t):
        rng = np.random.default_rng(seed)
        base, k = rng.uniform(0, 0.8, n), rng.uniform(0, 1, n) ** 3
        weight, levels = rng.integers(1, 4, n).astype(float), np.sort(rng.uniform(1.0, 50.0, t))
        probs = rng.uniform(0.1, 1, t)
        got = expected_best_level(base, k, weight, levels, 1.0, probs)
        probs = probs / probs.sum()
        losses = [_brute_loss(base, k, weight, levels, probs, c) for c in (1.0, *levels)]
        assert got in (1.0, *levels)
        assert _brute_loss(base, k, weight, levels, probs, got) <= min(losses) + 1e-6

    @PROPERTY
    @given(st.integers(0, 2**32 - 1), st.integers(1, 9), st.sampled_from([1, 7, 64, 1 << 15]))
    def test_batches_choose_what_each_footprint_alone_chooses(self, seed, j, max_samples):
        """Footprints solved together, in batches of any size, against the table of every candidate against every
        truth (the expanded square, candidate by candidate): the same choice, or one as good within 1e-9."""
        rng = np.random.default_rng(seed)
        problems, t = [], int(rng.integers(1, 33))
        for i in range(j):
            n, t = int(rng.integers(0, 40)), t if i % 4 else int(rng.integers(1, 33))  # level grids of 1 or 2 sizes
            base, k = rng.uniform(0, 1.2, n) * (rng.random(n) < 0.8), rng.uniform(0, 1, n) ** 3
            levels = np.sort(rng.uniform(1.0, 30.0, t))
            probs = rng.uniform(0.1, 1, t) if rng.random() < 0.5 else np.ones(t)
            problems.append((base, k, rng.integers(1, 5, n).astype(float), np.concatenate(([1.0], levels)),
                             probs / probs.sum()))
        got = chosen_levels(problems, max_samples=max_samples)
        for (base, k, weight, cands, probs), level in zip(problems, got):
            shown = display(base[None, :] + cands[:, None] * k[None, :])
            table = np.array([[np.sum(weight * (a - b) ** 2) for b in shown[1:]] for a in shown]) @ probs
            assert level in cands
            assert table[list(cands).index(level)] <= table.min() + 1e-7 * max(weight.sum(), 1.0) + 1e-9
            assert level == cands[np.argmax(table <= table.min() + 1e-7 * max(weight.sum(), 1.0))] \
                or abs(table[list(cands).index(level)] - table.min() - 1e-7 * max(weight.sum(), 1.0)) < 1e-9

    def test_a_known_radiance_is_chosen(self):
        """With the truth known (one level), the choice is the truth wherever the output depends on it."""
        base, k = np.array([0.1, 0.05, 0.2]), np.array([0.3, 0.1, 0.02])
        for level in (1.5, 7.0, 40.0):
            assert expected_best_level(base, k, np.ones(3), np.array([level]), 1.0) == level

    def test_a_saturated_output_is_not_raised(self):
        """Where every plausible radiance shows white, raising changes nothing: the blob keeps its value."""
        assert expected_best_level(np.array([0.5]), np.array([1.0]), np.ones(1), prior_levels(CLIP_LEVEL, 64), 1.0) \
            == 1.0

    def test_level_rises_as_the_light_is_spread_thinner(self):
        """One output pixel receiving a share k of the blob: the less it receives, the higher the level."""
        levels = prior_levels(CLIP_LEVEL, 64.0)
        for bg in (0.0, 0.02, 0.5):
            chosen = [expected_best_level(np.array([bg]), np.array([k]), np.ones(1), levels, 1.0)
                      for k in np.geomspace(1e-3, 1.0, 60)]
            assert all(a >= b for a, b in zip(chosen, chosen[1:])), (bg, chosen)
            assert chosen[0] > 4 * chosen[-1]


class TestReconstructPrior:
    def test_point_source_level_grows_with_blur(self):
        """A clipped point light: its light is spread over its CoC disc, so the level does not fall as the CoC grows
        (from not raised at all in focus; up to one step of the prior's 32-point grid)."""
        img = np.full((130, 130, 3), 0.05, np.float32)
        img[65, 65] = 1.0
        got = [float(reconstruct_highlights(img, method="prior", prior_max=64.0,
                                            coc_px=np.full((130, 130), d))[65, 65, 0])
               for d in (0.0, 0.9, 1.5, 3.0, 7.0, 15.0, 31.0, 63.0)]
        grid_step = 64.0 ** (1 / 32)
        assert got[0] == got[1] == 1.0
        assert all(a <= b * grid_step for a, b in zip(got, got[1:])) and got[-1] > 1.5 * got[2], got

    @pytest.mark.parametrize("d", [40.0, 90.0, 200.0])
    def test_wide_blur_on_a_shrunk_window_matches_the_full_one(self, d, monkeypatch):
        """A blur wider than MAX_KERNEL_PX is weighed on a shrunk window: the same levels within one step of the
        prior's grid as the full-resolution footprint."""
        from pcdof.stages.highlights import footprints

        rng = np.random.default_rng(int(d))
        img = rng.uniform(0.0, 0.3, (120, 150, 3)).astype(np.float32)
        for y, x, r in ((30, 40, 1), (80, 100, 4), (60, 20, 0)):
            img[y - r: y + r + 1, x - r: x + r + 1, : 1 + r % 3] = 1.0
        coc = np.full(img.shape[:2], d)
        small = reconstruct_highlights(img, method="prior", coc_px=coc, prior_max=64.0, max_channel_ratio=np.inf)
        monkeypatch.setattr(footprints, "MAX_KERNEL_PX", 1e9)
        full = reconstruct_highlights(img, method="prior", coc_px=coc, prior_max=64.0, max_channel_ratio=np.inf)
        raised = full > 1.0
        assert raised.any() and np.array_equal(raised, small > 1.0)
        ratio = small[raised] / full[raised]
        assert np.all(np.abs(np.log(ratio)) <= np.log(64.0) / 32 + 1e-6), ratio

    def test_in_focus_blobs_are_not_raised(self):
        clipped, _ = _disc_source(20.0, 5.0)
        out = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], 0.6))
        assert np.array_equal(out, clipped)

    @pytest.mark.parametrize("level", [3.0, 12.0, 40.0])
    def test_blurred_light_closer_to_the_truth(self, level):
        """A clipped disc of known radiance blurred by its CoC disc (cv2.filter2D): the reconstructed source
        shows at least 30 % less displayed error than the clipped one."""
        clipped, true = _disc_source(level, 4.2)
        d = 15.0
        kern = disc_kernel(d)

        def shown(a):
            return display(cv2.filter2D(a, -1, kern, borderType=cv2.BORDER_REPLICATE))

        out = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], d))
        err = lambda a: float(np.mean((shown(a) - shown(true)) ** 2))  # noqa: E731
        assert err(out) < 0.7 * err(clipped), (err(out), err(clipped))

    @pytest.mark.parametrize("coc", [1e12, np.inf])
    def test_enormous_blur_is_clamped_like_the_renderers(self, coc):
        from pcdof.lens import MAX_COC_PX

        clipped, _ = _disc_source(30.0, 3.0)
        out = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], coc))
        same = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], MAX_COC_PX))
        np.testing.assert_array_equal(out, same)
        assert np.all(np.isfinite(out)) and out.max() > 1.5

    def test_unclipped_channels_are_measurements(self):
        """A red lamp: only its red channel clipped, green and blue stay exactly as measured."""
        clipped, _ = _disc_source(30.0, 3.0)
        clipped[..., 1:] *= 0.4
        out = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], 20.0),
                                     max_channel_ratio=np.inf)
        np.testing.assert_array_equal(out[..., 1:], clipped[..., 1:])
        assert out[24, 24, 0] > 2.0

    @pytest.mark.parametrize("ratio", [1.5, 3.0, 4.0])
    def test_measured_channels_bound_the_clipped_one(self, ratio):
        """Red clipped, green and blue measured at 0.4 and 0.3: red is at most ratio x 0.4 (the light's colour
        saturation bound), and is raised up to that bound when the blur spreads it thinly."""
        clipped, _ = _disc_source(30.0, 3.0, bg=0.02)
        clipped[..., 1] *= 0.4
        clipped[..., 2] *= 0.3
        red = clipped[..., 0] >= CLIP_LEVEL
        out = reconstruct_highlights(clipped, method="prior", coc_px=np.full(clipped.shape[:2], 30.0),
                                     max_channel_ratio=ratio)
        top = ratio * float(np.median(clipped[..., 1][red]))
        assert out[..., 0][red].max() <= max(top, 1.0) + 1e-6  # (a bound below the clipped value raises nothing)
        assert out[24, 24, 0] > 1.0 if top > 1.05 else out[24, 24, 0] == clipped[24, 24, 0]

    def test_rim_likelihood_follows_the_radiance(self):
        """The edge of a box-filtered disc: the most likely level rises with the true radiance and lies within a
        factor 2.5 of it."""
        levels = prior_levels(CLIP_LEVEL, 256.0, 64)
        best = []
        for level in (1.6, 3.0, 6.0, 12.0):
            clipped, _ = _disc_source(level, 8.6)
            mask = clipped[..., 0] >= CLIP_LEVEL
            like = rim_likelihood(clipped[..., 0], mask, mask, levels, CLIP_LEVEL)
            best.append(float(levels[np.argmax(like)]))
            assert level / 2.5 <= best[-1] <= level * 2.5, (level, best[-1])
        assert best == sorted(best) and best[-1] > 3 * best[0]


# ----------------------------------------------------------------------------------- through the pipeline
def _frame(rng, h, w, dtype):
    top = np.iinfo(dtype).max
    color = rng.integers(0, top // 2, (h, w, 3)).astype(dtype)
    for _ in range(int(rng.integers(1, 5))):  # blobs clipped in one to three channels
        y, x, r = int(rng.integers(0, h)), int(rng.integers(0, w)), int(rng.integers(0, 4))
        ch = rng.random(3) < 0.6
        ch[int(rng.integers(3))] = True
        color[max(y - r, 0): y + r + 1, max(x - r, 0): x + r + 1, ch] = top
    depth = np.where(rng.random((h, w)) < 0.5, rng.uniform(0.4, 1.0), rng.uniform(2.0, 6.0)).astype(np.float32)
    depth = cv2.blur(depth, (5, 5))
    fx = float(w)
    return RGBDFrame(color, depth, Rig.registered(Intrinsics(w, h, fx, fx, (w - 1) / 2, (h - 1) / 2)))


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.integers(8, 48), st.integers(8, 48), st.sampled_from(["uint8", "uint16"]),
       st.floats(0.7, 4.0), st.floats(0.3, 5.0), st.sampled_from(sorted(HIGHLIGHT_METHODS)))
def test_render_stays_within_the_inputs_range(seed, h, w, dtype, f_number, focus_m, method):
    """Every output pixel lies within the input's per-channel [min, max] (1 code of rounding): only clipped
    channels are raised, and the render is encoded with clipping at the encoding's top again."""
    rng = np.random.default_rng(seed)
    frame = _frame(rng, h, w, np.dtype(dtype))
    out = run(frame, ThinLens(50.0, f_number, focus_m), highlights=method).image
    inp = frame.color.reshape(-1, 3).astype(np.int64)
    o = out.reshape(-1, 3).astype(np.int64)
    assert np.all(o >= inp.min(0) - 1) and np.all(o <= inp.max(0) + 1)


def test_linear_input_is_untouched():
    rng = np.random.default_rng(3)
    f = _frame(rng, 32, 40, np.dtype(np.uint8))
    lin = RGBDFrame(f.color.astype(np.float32) / 255 * 4, f.depth_m, f.rig)
    lens = ThinLens(50.0, 1.4, 0.5)
    a, b = run(lin, lens, linear=True, highlights="off"), run(lin, lens, linear=True, highlights="auto")
    np.testing.assert_array_equal(a.image, b.image)
    assert next(t for t in b.trace if t.name == "highlights").reason == "linear input is not clipped"


def test_auto_uses_the_renders_circle_of_confusion():
    """auto in the pipeline equals the reconstruction given the pipeline's own CoC, then rendered as linear light."""
    from pcdof.color import decode_to_linear, encode_from_linear
    from pcdof.pipeline import render_from_depth

    rng = np.random.default_rng(5)
    f = _frame(rng, 40, 48, np.dtype(np.uint8))
    lens = ThinLens(50.0, 1.0, 0.5)
    got = run(f, lens, highlights="auto").image
    coc = lens.coc_px(f.depth_m, f.rig.color.fx)
    lin = reconstruct_highlights(decode_to_linear(f.color), method="prior", coc_px=coc)
    want = render_from_depth(lin, f.depth_m, lens, f.rig.color.fx, linear=True)[0]
    np.testing.assert_array_equal(got, encode_from_linear(want, np.uint8))
