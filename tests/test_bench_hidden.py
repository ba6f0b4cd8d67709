"""pcdof.bench.hidden: the renderer's linearity in colour, the true hidden layers, the over composite,
and the oracle against ray-traced ground truth on an analytic scene."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcdof.bench import hidden
from pcdof.errors import InputError, PcdofError
from pcdof.lens import ThinLens
from pcdof.pipeline import render_from_depth

FX = 60.0


def _render(color, depth, lens, quality="exact"):
    return render_from_depth(color, depth, lens, FX, linear=True, quality=quality, highlights="off")[0]


def _layered_depth(rng, h, w):
    """A wall with 1-4 fronto-parallel rectangles in front of it (sharp depth edges), metres."""
    depth = np.full((h, w), rng.uniform(2.0, 5.0), np.float32)
    for _ in range(int(rng.integers(1, 5))):
        y0, x0 = int(rng.integers(0, h - 4)), int(rng.integers(0, w - 4))
        depth[y0:y0 + int(rng.integers(3, h)), x0:x0 + int(rng.integers(3, w))] = rng.uniform(0.4, 2.0)
    return depth


class TestRendererIsLinearInColour:
    """The oracle's premise: for a fixed depth map, pcdof's physical render (exact, linear float
    colour, highlights off) is linear in colour. It holds to float32 rounding, not bit for bit:
    the scatter sums each channel's light in float32 in an order that does not follow the
    algebra, so render(a c1 + b c2) and a render(c1) + b render(c2) round differently. Over 60
    random cases the difference was at most 3.2e-7 of the image's peak (under 3 float32 steps);
    the tolerance is 2e-6."""

    @settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(seed=st.integers(0, 2**31 - 1), a=st.floats(0.0, 4.0), b=st.floats(0.0, 4.0))
    def test_superposition(self, seed, a, b):
        rng = np.random.default_rng(seed)
        h, w = 40, 56
        depth = _layered_depth(rng, h, w)
        lens = ThinLens(focal_length_mm=50.0, f_number=float(rng.uniform(1.2, 8.0)),
                        focus_distance_m=float(rng.uniform(0.5, 4.0)))
        c1 = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
        c2 = (rng.uniform(0, 1, (h, w, 3)) ** 4 * rng.choice([1.0, 50.0], (h, w, 1))).astype(np.float32)
        mixed = (np.float32(a) * c1 + np.float32(b) * c2).astype(np.float32)
        left = _render(mixed, depth, lens)
        right = np.float32(a) * _render(c1, depth, lens) + np.float32(b) * _render(c2, depth, lens)
        peak = max(float(np.abs(left).max()), 1e-3)
        assert np.abs(left - right).max() <= 2e-6 * peak

    def test_a_grey_mask_renders_as_each_channel_of_rgb(self):
        rng = np.random.default_rng(3)
        depth = _layered_depth(rng, 40, 56)
        lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=3.0)
        m = (rng.uniform(size=depth.shape) < 0.4).astype(np.float32)
        grey = _render(m, depth, lens)
        rgb = _render(np.repeat(m[..., None], 3, axis=2), depth, lens)
        for c in range(3):
            np.testing.assert_allclose(grey, rgb[..., c], atol=1e-6)


class TestCompositeOver:
    def test_one_layer_is_itself(self):
        f = np.random.default_rng(0).uniform(size=(5, 6, 3)).astype(np.float32)
        np.testing.assert_array_equal(hidden.composite_over([f], []), f)

    def test_three_layers_by_hand(self):
        rng = np.random.default_rng(1)
        f = [rng.uniform(size=(5, 6, 3)).astype(np.float32) for _ in range(3)]
        a = [rng.uniform(size=(5, 6)).astype(np.float32) for _ in range(2)]
        want = f[0] + (1 - a[0])[..., None] * (f[1] + (1 - a[1])[..., None] * f[2])
        np.testing.assert_allclose(hidden.composite_over(f, a), want, rtol=1e-6)
        # the last layer's opacity, when given, is not used
        np.testing.assert_array_equal(hidden.composite_over(f, a + [np.ones((5, 6))]), hidden.composite_over(f, a))

    def test_an_opaque_layer_hides_what_lies_behind(self):
        f = [np.full((2, 2, 3), v, np.float32) for v in (0.3, 7.0)]
        np.testing.assert_array_equal(hidden.composite_over(f, [np.ones((2, 2))]), f[0])
        np.testing.assert_array_equal(hidden.composite_over(f, [np.zeros((2, 2))]), f[0] + f[1])

    @pytest.mark.parametrize("lights, opacities", [([], []), ([np.zeros((2, 2, 3))] * 2, []),
                                                   ([np.zeros((2, 2, 3)), np.zeros((3, 2, 3))], [np.zeros((2, 2))]),
                                                   ([np.zeros((2, 2, 3))] * 2, [np.zeros((2, 3))]),
                                                   ([np.zeros((2, 2))] * 2, [np.zeros((2, 2))])])
    def test_invalid(self, lights, opacities):
        with pytest.raises(InputError, match="lights"):
            hidden.composite_over(lights, opacities)


# ------------------------------------------------------------------ an analytic scene: a square over a wall
WALL_Z, SQUARE_Z, HALF_M = 2.0, 0.6, 0.09


@pytest.fixture(scope="module")
def square_frame():
    """A fronto-parallel flat square 0.6 m from the camera over a striped wall at 2 m (64x48, 2x2 pixel filter)."""
    from pcdof.synth.frame import make_frame
    from pcdof.synth.rig import kinect_rig
    from pcdof.synth.scene import Scene
    from pcdof.synth.scenes import quad
    from pcdof.synth.shading import Material

    wall = quad([(-4, -3, WALL_Z), (4, -3, WALL_Z), (4, 3, WALL_Z), (-4, 3, WALL_Z)], facing=(0, 0, 0))
    h = HALF_M
    square = quad([(-h, -h, SQUARE_Z), (h, -h, SQUARE_Z), (h, h, SQUARE_Z), (-h, h, SQUARE_Z)], facing=(0, 0, 0))
    scene = Scene([(wall, Material("stripes", (0.9, 0.8, 0.2), (0.05, 0.1, 0.5), scale_m=0.08,
                                   direction=(1.0, 0.3, 0.0)), False),
                   (square, Material("flat", (0.7, 0.15, 0.1)), False)], light_dir=(0, 0, -1), ambient=0.3)
    lens = ThinLens(focal_length_mm=50.0, f_number=2.0, focus_distance_m=WALL_Z)
    return make_frame(scene, kinect_rig((64, 48), (64, 53)), default_lens=lens, pixel_samples=2)


GROUPS = [("square", [1]), ("wall", [0])]


class TestTraceLayers:
    def test_one_group_is_the_pinhole_frame(self, square_frame):
        sf = square_frame
        (layer,) = hidden.trace_layers(sf.scene, sf.rig.color, [("all", [0, 1])], pixel_samples=sf.pixel_samples)
        np.testing.assert_array_equal(layer.light, sf.color_linear)
        np.testing.assert_array_equal(layer.depth_m, sf.depth_color_m)
        assert np.all(layer.coverage == 1)

    def test_the_square_and_the_wall_behind_it(self, square_frame):
        from pcdof.synth.render import render_pinhole
        from pcdof.synth.scene import Scene

        sf = square_frame
        sq, wall = hidden.trace_layers(sf.scene, sf.rig.color, GROUPS, pixel_samples=sf.pixel_samples)
        intr = sf.rig.color
        # the square's image: |x - cx| < fx * HALF_M / SQUARE_Z, and the same in y
        ys, xs = np.mgrid[:intr.height, :intr.width]
        dx = np.abs(xs - intr.cx) - intr.fx * HALF_M / SQUARE_Z
        dy = np.abs(ys - intr.cy) - intr.fy * HALF_M / SQUARE_Z
        inside, outside = (dx < -0.5) & (dy < -0.5), (dx > 0.5) | (dy > 0.5)
        assert inside.sum() > 50 and np.all(sq.coverage[inside] == 1) and np.all(sq.coverage[outside] == 0)
        assert np.all(np.isin(sq.coverage, [0, 0.25, 0.5, 0.75, 1]))  # shares of 2 x 2 rays
        np.testing.assert_allclose(sq.depth_m[inside], SQUARE_Z, rtol=1e-5)
        np.testing.assert_allclose(sq.light[inside], sf.color_linear[inside], rtol=1e-6)
        # the wall's frame: the square removed, what the camera would see without it
        alone = Scene([(sf.scene.meshes[0], sf.scene.materials[0], False)], light_dir=sf.scene.light_dir,
                      ambient=sf.scene.ambient, diffuse=sf.scene.diffuse)
        color, depth = render_pinhole(alone, intr, pixel_samples=sf.pixel_samples)
        assert np.all(wall.coverage == 1)
        np.testing.assert_allclose(wall.light, color, rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(wall.depth_m, depth)
        # beside the square the wall is lit the same with or without it (the shading casts no shadows)
        np.testing.assert_allclose(sf.color_linear[outside], wall.light[outside], rtol=1e-6, atol=1e-7)

    def test_a_frame_that_does_not_enclose_the_camera(self, square_frame):
        sf = square_frame
        with pytest.raises(InputError, match="enclose the camera"):
            hidden.trace_layers(sf.scene, sf.rig.color, [("square", [1])])

    @pytest.mark.parametrize("groups", [[], [("a", [])], [("a", [0]), ("b", [0])], [("a", [2])], [("a", [-1])]])
    def test_invalid_groups(self, square_frame, groups):
        with pytest.raises(InputError, match="groups"):
            hidden.trace_layers(square_frame.scene, square_frame.rig.color, groups)

    @pytest.mark.parametrize("bad", [0, -2, 1.5, "2", True, None])
    def test_invalid_pixel_samples(self, square_frame, bad):
        with pytest.raises(PcdofError, match="pixel_samples"):
            hidden.trace_layers(square_frame.scene, square_frame.rig.color, GROUPS, pixel_samples=bad)


def _square_renders(sf, focus_z, **render_kw):
    """(frame, lens, oracle, plain render, ray-traced truth) of the square frame focused at *focus_z*, the
    farther surface blurring 12 px; *render_kw* go to both renders."""
    from pcdof.synth.render import render_ground_truth
    from pcdof.synth.wide import lens_for_blur

    lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, focus_z, 12.0)
    layers = hidden.trace_layers(sf.scene, sf.rig.color, GROUPS, pixel_samples=sf.pixel_samples)
    oracle = hidden.render_oracle(layers, lens, sf.rig.color.fx, **render_kw)
    whole = hidden.HiddenLayer("all", sf.color_linear, np.ones(sf.depth_color_m.shape, np.float32), sf.depth_color_m)
    plain = hidden.render_oracle([whole], lens, sf.rig.color.fx, **render_kw)
    truth = render_ground_truth(sf, lens, seed=1, target_psnr_db=45.0).image
    return sf, lens, oracle, plain, truth


class TestOracleOnTheSquare:
    """Focused on the wall, the square blurs over it: a real lens sees the wall behind the square's
    soft edge. The oracle, given that wall, must come closer to the ray-traced truth there than the
    plain render (which continues the wall from beside the square), and equal it far away."""

    @pytest.fixture(scope="class")
    @classmethod
    def renders(cls, square_frame):
        return _square_renders(square_frame, WALL_Z)  # the square blurs 12 px

    def _bands(self, sf, lens):
        intr = sf.rig.color
        coc = float(lens.coc_px(np.float32(SQUARE_Z), intr.fx))
        ys, xs = np.mgrid[:intr.height, :intr.width]
        d = np.maximum(np.abs(xs - intr.cx) - intr.fx * HALF_M / SQUARE_Z,
                       np.abs(ys - intr.cy) - intr.fy * HALF_M / SQUARE_Z)  # signed distance to the square, px
        return coc, np.abs(d) <= coc / 2, d > coc / 2 + 2

    def test_the_square_blurs_wide_enough(self, renders):
        sf, lens, *_ = renders
        coc, near, far = self._bands(sf, lens)
        assert 8 < coc < 20 and near.sum() > 300 and far.sum() > 300

    def test_closer_to_the_truth_at_the_silhouette(self, renders):
        sf, lens, oracle, plain, truth = renders
        _, near, _ = self._bands(sf, lens)
        err_oracle = np.mean((oracle - truth)[near] ** 2)
        err_plain = np.mean((plain - truth)[near] ** 2)
        assert err_oracle < 0.05 * err_plain, (err_oracle, err_plain)  # measured: 5.3e-5 against 6.4e-3

    def test_equal_far_from_it(self, renders):
        sf, lens, oracle, plain, truth = renders
        _, _, far = self._bands(sf, lens)
        np.testing.assert_allclose(oracle[far], plain[far], rtol=0, atol=1e-6)
        layers = hidden.trace_layers(sf.scene, sf.rig.color, GROUPS, pixel_samples=sf.pixel_samples)
        scattered = hidden.render_oracle(layers, lens, sf.rig.color.fx, convolve_uniform=False)
        np.testing.assert_allclose(scattered[far], plain[far], rtol=0, atol=1e-6)
        np.testing.assert_allclose(scattered, oracle, rtol=0, atol=1e-3)  # the convolution: within its bin

    def test_one_layer_is_the_plain_render(self, renders):
        sf, lens, _, plain, _ = renders
        want = render_from_depth(sf.color_linear, sf.depth_color_m, lens, sf.rig.color.fx, linear=True,
                                 quality="exact")[0]
        np.testing.assert_array_equal(plain, want)

    def test_invalid_layers(self, renders):
        sf, lens, *_ = renders
        for bad in ([], [np.zeros((48, 64, 3))]):
            with pytest.raises(InputError, match="layers"):
                hidden.render_oracle(bad, lens, sf.rig.color.fx)


class TestOracleFocusedOnTheSquare:
    """Focused on the square, the wall blurs behind it: the wall's light from behind the square's
    sharp edge spreads past it. Both renders scatter every tile (the convolution of uniform tiles
    depends on which tiles are uniform, so a wall with and without the square would differ far
    from it by up to 0.009)."""

    @pytest.fixture(scope="class")
    @classmethod
    def renders(cls, square_frame):
        return _square_renders(square_frame, SQUARE_Z, convolve_uniform=False)  # the wall blurs 12 px

    def test_closer_to_the_truth_at_the_edge_and_equal_far_from_it(self, renders):
        sf, lens, oracle, plain, truth = renders
        intr = sf.rig.color
        reach = float(lens.coc_px(np.float32(WALL_Z), intr.fx)) / 2
        assert 5 < reach < 8
        ys, xs = np.mgrid[:intr.height, :intr.width]
        d = np.maximum(np.abs(xs - intr.cx) - intr.fx * HALF_M / SQUARE_Z,
                       np.abs(ys - intr.cy) - intr.fy * HALF_M / SQUARE_Z)
        near, far = np.abs(d) <= reach, d > reach + 2
        err_oracle, err_plain = (np.mean((x - truth)[near] ** 2) for x in (oracle, plain))
        assert err_oracle < 0.95 * err_plain, (err_oracle, err_plain)  # measured: 3.7e-5 against 4.4e-5
        np.testing.assert_allclose(oracle[far], plain[far], rtol=0, atol=1e-6)


# ------------------------------------------------------------------ wide scenes
@pytest.fixture(scope="module")
def wide_frame():
    from pcdof.synth.wide import generate_wide

    return generate_wide("thin", seed=100, color_size=(64, 48), depth_size=(64, 53))


class TestDepthGroups:
    @pytest.mark.parametrize("kind", ["room", "thin", "night"])
    @pytest.mark.parametrize("seed", [0, 100, 101])
    def test_every_object_once_front_to_back(self, kind, seed):
        from pcdof.synth.wide import WIDE_SCENES

        spec = WIDE_SCENES[kind](np.random.default_rng([seed, 7]))
        groups = hidden.depth_groups(spec.object_groups, spec.scene)
        ids = sorted(i for _, g in groups for i in g)
        assert ids == list(range(len(spec.scene.meshes)))
        names = [n for n, _ in groups]
        assert names == [n for n in hidden.GROUP_NAMES if n in names]
        assert names[0] == "foreground" and names[-1] == "room" and "subject and glints" in names
        near = {n: min(float(spec.scene.meshes[i].bounds[0][2]) for i in g) for n, g in groups}
        assert near["foreground"] <= spec.focus_m["near"] + 1e-3  # the occluder starts there (a turned slab nearer)
        z_subject = near["subject and glints"]
        for n, g in groups:
            if n.startswith("thin"):
                for i in g:
                    z = float(spec.scene.meshes[i].bounds[0][2])
                    assert (z < z_subject) == (n == "thin in front of the subject")

    def test_invalid_labels(self, wide_frame):
        _, spec = wide_frame
        with pytest.raises(InputError, match="object_groups"):
            hidden.depth_groups(spec.object_groups[:-1], spec.scene)
        with pytest.raises(InputError, match="object_groups"):
            hidden.depth_groups(("wall",) * len(spec.scene.meshes), spec.scene)


class TestWideOracle:
    def test_one_group_is_the_error_budgets_plain_render(self, wide_frame):
        from pcdof.bench.wide import render_variant
        from pcdof.synth.wide import lens_for_blur

        sf, spec = wide_frame
        lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m["far"], 12.0)
        (whole,) = hidden.trace_layers(spec.scene, sf.rig.color, [("all", list(range(len(spec.scene.meshes))))],
                                       pixel_samples=sf.pixel_samples)
        got = hidden.render_oracle([whole], lens, sf.rig.color.fx, max_range_m=sf.rig.max_range_m)
        np.testing.assert_array_equal(got, render_variant("true depth+linear", sf, lens))

    def test_the_first_layer_sees_the_whole_frame(self, wide_frame):
        sf, spec = wide_frame
        layers = hidden.trace_layers(spec.scene, sf.rig.color, hidden.depth_groups(spec.object_groups, spec.scene),
                                     pixel_samples=sf.pixel_samples)
        np.testing.assert_array_equal(layers[0].depth_m, sf.depth_color_m)
        assert np.all(layers[-1].coverage == 1)  # nothing lies behind the room
        for la in layers:  # light within what the frame shows, coverage a share of 2 x 2 rays
            assert np.all(np.isin(la.coverage, [0, 0.25, 0.5, 0.75, 1]))
            assert np.all(la.light[la.coverage == 0] == 0) and np.all(la.light >= 0)
        # farther frames lie no nearer than the first (groups are removed, never added)
        for la in layers[1:]:
            assert np.all(la.depth_m >= layers[0].depth_m - 1e-6)


def test_cli_hidden_part(tmp_path):
    import json

    from click.testing import CliRunner

    from pcdof.cli import main

    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["bench", "--quick", "--only", "hidden", "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    rows = report["hidden"]
    methods = (hidden.PLAIN_BUDGET, hidden.PLAIN, hidden.ORACLE, hidden.ORACLE_MERGED)
    assert [r["method"] for r in rows] == list(methods) * 3
    assert all(10 < r["psnr"] < 80 for r in rows)
    for plain_budget, plain, oracle, merged in zip(*[iter(rows)] * 4):
        assert plain_budget["groups"] == plain["groups"] == 1 and oracle["groups"] >= 3
        assert 1 <= merged["groups"] <= oracle["groups"]
    summary = {s["label"]: s for s in report["hidden_cost"]}
    assert summary["all cases"]["cases"] == 3
    assert (out / "hidden.csv").read_text().count("\n") == len(rows) + 1
    assert "What the hidden background costs" in (out / "report.md").read_text()
    assert "wide" not in report and "dof" not in report  # only the part named


class TestMergeSimilarBlur:
    """Groups merge into the one in front when their blurs are closer to each other than to sharp."""

    @staticmethod
    def _layers(depths):
        return [hidden.HiddenLayer(f"g{i}", np.zeros((4, 4, 3), np.float32), np.ones((4, 4), np.float32),
                                   np.full((4, 4), z, np.float32)) for i, z in enumerate(depths)]

    def test_the_rule(self):
        lens = ThinLens(focal_length_mm=50.0, f_number=2.0, focus_distance_m=1.0)
        depths = (0.5, 1.0, 1.5, 1.6, 8.0, 9.0)
        coc = [float(lens.signed_coc_px(np.float32(z), FX)) for z in depths]
        groups = [(f"g{i}", [i]) for i in range(len(depths))]
        got = hidden.merge_similar_blur(groups, self._layers(depths), lens, FX)
        want, kp = [[groups[0][0], [0]]], coc[0]
        for i in range(1, len(depths)):  # the rule written out
            if abs(coc[i] - kp) < min(abs(coc[i]), abs(kp)):
                want[-1] = [want[-1][0] + f" + g{i}", want[-1][1] + [i]]
            else:
                want.append([f"g{i}", [i]])
            kp = coc[i]
        assert [(n, ids) for n, ids in got] == [(n, ids) for n, ids in want]
        # in focus never merges; 1.5 and 1.6 m blur alike and merge, and so do 8 and 9 m, but not 1.6 and 8 m
        assert got == [("g0", [0]), ("g1", [1]), ("g2 + g3", [2, 3]), ("g4 + g5", [4, 5])]

    def test_a_group_unseen_in_its_frame_stays_apart(self):
        lens = ThinLens(focal_length_mm=50.0, f_number=2.0, focus_distance_m=1.0)
        layers = self._layers((3.0, 3.1))
        layers[1] = hidden.HiddenLayer("g1", layers[1].light, np.zeros((4, 4), np.float32), layers[1].depth_m)
        assert len(hidden.merge_similar_blur([("g0", [0]), ("g1", [1])], layers, lens, FX)) == 2

    def test_invalid(self):
        lens = ThinLens(focal_length_mm=50.0, f_number=2.0, focus_distance_m=1.0)
        with pytest.raises(InputError, match="layers"):
            hidden.merge_similar_blur([("g0", [0]), ("g1", [1])], self._layers((1.0,)), lens, FX)
