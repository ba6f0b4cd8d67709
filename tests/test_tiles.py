"""Tile classification and the renderer's tile paths: copied in-focus tiles and convolved uniform tiles."""

import dataclasses
import math

import numpy as np
import pytest

import pcdof.stages.render as renderer
from pcdof.errors import InputError
from pcdof.plans import plan_render
from pcdof.stages.render.tiles import TILE_PX, TileMap, classify_tiles

from conftest import disc_kernel, texture

from pcdof.metrics import psnr

#: the exact quality's plan with the convolution of uniform tiles switched off
SCATTER_ONLY = dataclasses.replace(plan_render(quality="exact"), convolve_uniform=False)


class TestClassify:
    def test_ranges_per_tile(self):
        coc = np.zeros((40, 50), np.float32)
        coc[3, 4] = -7.0
        coc[20, 33] = 5.0
        tiles = classify_tiles(coc, tile_px=16)
        assert tiles.coc_min.shape == (3, 4)
        assert tiles.coc_min[0, 0] == -7.0 and tiles.coc_max[0, 0] == 0.0
        assert tiles.coc_max[1, 2] == 5.0 and tiles.coc_min[1, 2] == 0.0
        assert tiles.coc_min[2, 3] == 0.0 == tiles.coc_max[2, 3]

    def test_all_in_focus_is_all_copy(self):
        tiles = classify_tiles(np.full((64, 80), 0.4, np.float32))
        assert tiles.copy.all()
        assert tiles.summary() == {"tile_px": TILE_PX, "tiles": 20, "copy_tiles": 20}

    def test_front_blur_reaches_its_neighbours_background_does_not(self):
        coc = np.zeros((160, 160), np.float32)
        coc[80, 80] = -20.0  # radius 10: reaches 2 r + 2 = 22 px, two tiles of 16 around tile (5, 5)
        coc[10, 150] = 40.0  # behind focus: never spreads over the in-focus tiles next to it
        tiles = classify_tiles(coc, tile_px=16)
        reached = ~tiles.copy
        assert not tiles.copy[5, 5]
        assert reached[3:8, 3:8].all()
        reached[3:8, 3:8] = False
        reached[0, 9] = False  # the background tile itself is not in focus
        assert not reached.any()

    def test_nan_counts_as_in_focus(self):
        coc = np.full((32, 32), np.nan, np.float32)
        assert classify_tiles(coc).copy.all()

    def test_uniform_needs_one_layer_and_small_spread_within_reach(self):
        coc = np.full((96, 96), 12.0, np.float32)
        coc[:, 80:] = 12.5  # same layer [11, 16), spread 0.5 / 12.25 = 4 %
        tiles = classify_tiles(coc, tile_px=16)
        assert tiles.uniform(11, 16, 1, reach_px=8).all()
        assert not tiles.uniform(11, 16, -1, reach_px=8).any()  # the front side of the layer
        coc[:, 88:] = 20.0  # another layer: tiles within reach of it are not uniform
        tiles = classify_tiles(coc, tile_px=16)
        uniform = tiles.uniform(11, 16, 1, reach_px=8)
        assert uniform[:, :4].all() and not uniform[:, 4:].any()
        ramp = np.tile(np.linspace(11.0, 15.9, 96, dtype=np.float32), (96, 1))  # spread far over 10 %
        assert not classify_tiles(ramp).uniform(11, 16, 1, reach_px=8).any()

    def test_pixel_mask(self):
        tiles = classify_tiles(np.zeros((20, 35), np.float32), tile_px=8)
        sel = np.zeros_like(tiles.copy)
        sel[1, 4] = True
        mask = tiles.pixel_mask(sel)
        assert mask.shape == (20, 35)
        assert mask[8:16, 32:35].all() and mask.sum() == 8 * 3
        window = (slice(5, 19), slice(30, 35))
        np.testing.assert_array_equal(tiles.pixel_mask(sel, window), mask[window])

    @pytest.mark.parametrize("seed", range(4))
    def test_boxes_cover_the_pixel_mask(self, seed):
        rng = np.random.default_rng(seed)
        tiles = classify_tiles(np.zeros((rng.integers(1, 70), rng.integers(1, 90)), np.float32), tile_px=8)
        sel = rng.random(tiles.copy.shape) < 0.5
        covered = np.zeros(tiles.shape, int)
        for box in tiles.boxes(sel):
            covered[box] += 1
        np.testing.assert_array_equal(covered, tiles.pixel_mask(sel).astype(int))  # each pixel once
        assert len(tiles.boxes(sel)) <= sel.sum()

    @pytest.mark.parametrize("kwargs, name", [
        ({"signed_coc": np.zeros((4, 4, 2), np.float32)}, "signed_coc"),
        ({"signed_coc": np.zeros((4, 4), np.int32)}, "signed_coc"),
        ({"signed_coc": np.zeros((4, 4), np.float32), "tile_px": 0}, "tile_px"),
        ({"signed_coc": np.zeros((4, 4), np.float32), "tile_px": 2.5}, "tile_px"),
        ({"signed_coc": np.zeros((4, 4), np.float32), "sharp_px": -1.0}, "sharp_px"),
    ])
    def test_bad_input_names_the_argument(self, kwargs, name):
        with pytest.raises(InputError, match=name):
            classify_tiles(**kwargs)


class TestRendererTiles:
    def scene(self):
        """Left: in focus; middle: a blurred foreground strip; right: a far, uniformly blurred background."""
        h, w = 96, 192
        lin = texture(h, w, seed=3)
        coc = np.zeros((h, w), np.float32)
        coc[:, 64:80] = -9.0
        coc[:, 128:] = 12.0
        return lin, coc

    def test_copy_tiles_are_the_input_and_match_the_unskipped_path(self):
        lin, coc = self.scene()
        tiles = classify_tiles(coc)
        assert tiles.copy.any() and not tiles.copy.all()
        out, info = renderer.render_layers_linear(lin, coc, tiles=tiles)
        assert info["tiles"]["copy_tiles"] == int(tiles.copy.sum())
        mask = tiles.pixel_mask(tiles.copy)
        np.testing.assert_array_equal(out[mask], lin[mask])
        no_copy = TileMap(tiles.shape, tiles.tile_px, tiles.coc_min, tiles.coc_max, np.zeros_like(tiles.copy))
        reference, _ = renderer.render_layers_linear(lin, coc, tiles=no_copy)
        np.testing.assert_array_equal(out, reference)
        # the same by the plan: copy tiles switched off
        plan = dataclasses.replace(plan_render(), copy_tiles=False)
        np.testing.assert_array_equal(renderer.render_layers_linear(lin, coc, plan=plan)[0], reference)

    def test_tile_size_changes_only_the_convolved_region(self):
        lin, coc = self.scene()
        results = []
        for tile_px in (8, 16, 32):
            for copy in (True, False):
                plan = dataclasses.replace(SCATTER_ONLY, tile_px=tile_px, copy_tiles=copy)
                out, info = renderer.render_layers_linear(lin, coc, plan=plan)
                assert info["tiles"]["tile_px"] == tile_px and info["plan"]["tile_px"] == tile_px
                results.append(out)
        for out in results[1:]:  # without the convolution, tiles only skip work: bit-identical
            np.testing.assert_array_equal(out, results[0])

    @pytest.mark.parametrize("dtype", [np.uint16, np.float16])
    def test_copy_tiles_come_out_bit_exact(self, dtype):
        rng = np.random.default_rng(4)
        color = rng.integers(0, 65536, (64, 96, 3), dtype=np.uint16)
        if dtype == np.float16:
            color = (color / 65535.0).astype(np.float16)
        depth = np.full((64, 96), 2.0, np.float32)
        depth[:, 70:] = 9.0  # far background, behind focus: blurred, never spreads over the subject
        from pcdof.lens import ThinLens

        out, info = renderer.render_image(color, depth, ThinLens(50, 1.4, 2.0), fx=500.0)
        assert info["tiles"]["copy_tiles"] >= 4
        np.testing.assert_array_equal(out[:, :48], color[:, :48])
        assert not np.array_equal(out[:, 80:], color[:, 80:])

    def test_uniform_tiles_are_convolved_and_agree_with_the_scatter(self):
        lin, coc = self.scene()
        out, info = renderer.render_layers_linear(lin, coc, quality="exact")
        back = [l for l in info["layers"] if l.get("side") == "back"]
        assert back[0]["uniform_tiles"] > 0 and back[0]["kernels"] >= 1
        # only the sources near the layer's edge (within a footprint of a non-uniform pixel) are scattered
        assert 0 < back[0]["sources_scattered"] < back[0]["pixels"] / 2
        scattered, info_s = renderer.render_layers_linear(lin, coc, plan=SCATTER_ONLY)
        assert all(l.get("uniform_tiles", 0) == 0 for l in info_s["layers"])
        # a radius bin is 4 % wide: the convolution uses the bin's centre, the scatter the exact radius
        assert psnr(out, scattered) > 50
        # away from the layer's edge the result is the disc convolution of the texture
        import cv2

        expected = cv2.filter2D(lin, -1, disc_kernel(12.0), borderType=cv2.BORDER_REFLECT)
        assert psnr(out[:, 150:180], expected[:, 150:180]) > 40

    def test_uniform_path_at_a_bin_centre_equals_the_scatter(self):
        step = math.log1p(renderer.UNIFORM_BIN)
        r = math.exp(30 * step)  # 3.24 px: exactly a bin centre, so one kernel of the exact radius
        lin = texture(80, 96, seed=5)
        coc = np.full((80, 96), 2 * r, np.float32)
        out, info = renderer.render_layers_linear(lin, coc, quality="exact")
        layer = info["layers"][0]
        assert layer["uniform_tiles"] == 30 and layer["kernels"] == 1
        # the whole frame is one uniform region: nothing is left for the scatter
        assert layer["sources_scattered"] == 0
        scattered, info_s = renderer.render_layers_linear(lin, coc, plan=SCATTER_ONLY)
        assert info_s["layers"][0]["sources_scattered"] == 80 * 96
        np.testing.assert_allclose(out, scattered, atol=2e-6)

    def test_small_blur_layers_keep_the_scatter(self):
        lin = texture(64, 64, seed=6)
        coc = np.full((64, 64), 2.5, np.float32)  # radius 1.25 px: the scatter is cheaper than a convolution
        _, info = renderer.render_layers_linear(lin, coc, quality="exact")
        assert info["layers"][0]["uniform_tiles"] == 0 and info["layers"][0]["kernels"] == 0

    def test_bad_tiles_argument(self):
        lin, coc = self.scene()
        with pytest.raises(InputError, match="tiles"):
            renderer.render_layers_linear(lin, coc, tiles=classify_tiles(coc[:, :100]))
