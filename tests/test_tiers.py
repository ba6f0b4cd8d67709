"""Reduced-resolution layers (the quality tiers): the upsampling, the blur they add, and the calibration part."""

import math

import cv2
import numpy as np
import pytest

import pcdof.stages.render as renderer
from pcdof.apertures import aperture_from_blades
from pcdof.bench import tiers
from pcdof.errors import InputError
from pcdof.plans import QUALITIES, plan_render


class TestUpsampleCells:
    @pytest.mark.parametrize("s", [1, 2, 4, 8, 16])
    def test_is_the_cell_spread_over_its_pixels_then_two_boxes(self, s):
        # independent: np.repeat, then OpenCV's separable filter with the two boxes' kernel (edges repeated)
        rng = np.random.default_rng(s)
        cells = rng.random((7, 9, 2)).astype(np.float32)
        full = np.repeat(np.repeat(cells, s, axis=0), s, axis=1)
        kernel = np.convolve(np.ones(s) / s, np.ones(s) / s)
        pad = len(kernel) // 2
        padded = np.pad(full, ((pad, pad), (pad, pad), (0, 0)), mode="edge")
        want = cv2.sepFilter2D(padded, -1, kernel, kernel)[pad:pad + 7 * s, pad:pad + 9 * s]
        np.testing.assert_allclose(renderer.upsample_cells(cells, s, 7 * s, 9 * s), want, atol=1e-6)

    @pytest.mark.parametrize("s", [2, 4, 8])
    def test_one_cell_spreads_positive_centred_and_as_wide_as_three_boxes(self, s):
        cells = np.zeros((9, 9, 1), np.float32)
        cells[4, 4] = 1.0
        k = renderer.upsample_cells(cells, s, 9 * s, 9 * s)[:, :, 0].astype(np.float64)
        assert np.all(k >= 0) and k.sum() == pytest.approx(s * s, rel=1e-6)
        x = np.arange(9 * s) - (4 * s + (s - 1) / 2)  # offsets from the cell's centre
        row = k.sum(axis=0) / k.sum()
        assert (row * x).sum() == pytest.approx(0.0, abs=1e-6)
        assert (row * x * x).sum() == pytest.approx(3 * (s * s - 1) / 12, rel=1e-6)
        assert np.count_nonzero(row > 1e-9) == 3 * s - 2

    def test_a_constant_grid_stays_constant_to_the_edges_and_is_cropped(self):
        out = renderer.upsample_cells(np.full((5, 6, 4), 0.25, np.float32), 4, 19, 22)
        assert out.shape == (19, 22, 4) and out.dtype == np.float32
        np.testing.assert_allclose(out, 0.25, atol=1e-7)

    @pytest.mark.parametrize("s, rows", [(2, 2), (2, 6), (4, 4), (4, 9), (8, 16), (16, 40), (16, 1000)])
    def test_strips_are_the_upsampled_layer_value_for_value(self, s, rows):
        from pcdof.stages.render.grids import upsampled_strips

        rng = np.random.default_rng(s * rows)
        cells = rng.random((23, 7, 4)).astype(np.float32)
        h = 23 * s - s // 2  # the last cell cropped
        want = renderer.upsample_cells(cells, s, h, 7 * s)
        got = np.full_like(want, np.nan)
        next_row = 0
        for y0, strip in upsampled_strips(cells, s, h, 7 * s, rows):
            assert y0 == next_row and strip.shape[1:] == want.shape[1:]
            got[y0:y0 + strip.shape[0]] = strip
            next_row = y0 + strip.shape[0]
        assert next_row == h
        np.testing.assert_array_equal(got, want)
        w = 7 * s - s // 2 - 1  # the last cell's columns cropped: the strips keep them, the first w are the layer's
        cropped = renderer.upsample_cells(cells, s, h, w)
        for y0, strip in upsampled_strips(cells, s, h, w, rows):
            assert strip.shape[1] == 7 * s and strip.flags.c_contiguous
            np.testing.assert_array_equal(strip[:, :w], cropped[y0:y0 + strip.shape[0]])
        with pytest.raises(InputError, match="upsampled_strips needs 0 < w <= ws s"):
            next(upsampled_strips(cells, s, h, 7 * s + 1, rows))

    @pytest.mark.parametrize("s, h, w", [(0, 4, 4), (3, 4, 4), (2.0, 4, 4), (2, 11, 4), (2, 4, 0)])
    def test_bad_sizes_are_refused(self, s, h, w):
        with pytest.raises(InputError, match="upsample_cells"):
            renderer.upsample_cells(np.zeros((5, 5, 1), np.float32), s, h, w)


def _spread(r: float, s: int, y: int, x: int, n: int = 96) -> np.ndarray:
    """Coverage (n, n) float64 of one source of radius r px at (y, x), its layer computed at 1/s."""
    ap = renderer.aperture.RenderAperture(True, renderer.aperture.cached_aperture_table(aperture_from_blades(0, 0.0)))
    member = np.zeros((n, n), bool)
    member[y, x] = True
    buf, *_ = renderer.physical.scatter_layer(np.ones((n, n, 1), np.float32), np.full((n, n), r, np.float32), member, s,
                                              ap)
    return buf[:, :, -1].astype(np.float64)


def _moments(a: np.ndarray):
    ys, xs = np.indices(a.shape)
    m = a.sum()
    return m, (a * xs).sum() / m, (a * ys).sum() / m


class TestResampleVariance:
    @pytest.mark.parametrize("s, r", [(2, 5.0), (2, 12.0), (4, 10.0), (4, 24.0), (8, 20.0), (8, 32.0)])
    def test_a_reduced_layer_blurs_as_much_as_the_full_resolution_one(self, s, r):
        """The variance resample_variance_px2 takes off the disc: a source's spread, averaged over its
        position in the cell (the cell's s x s phases), has the full-resolution footprint's variance."""
        full = _spread(r, 1, 40, 40)
        m, cx, _ = _moments(full)
        want = (full * (np.indices(full.shape)[1] - cx) ** 2).sum() / m
        got, masses = [], []
        for py in range(s):
            for px in range(s):
                a = _spread(r, s, 40 + py, 40 + px)
                mass, _, _ = _moments(a)
                got.append((a * (np.indices(a.shape)[1] - (40 + px)) ** 2).sum() / mass)  # about the source
                masses.append(mass)
        assert np.mean(got) == pytest.approx(want, rel=0.02)
        np.testing.assert_allclose(masses, 1.0, rtol=1e-4)  # and carries exactly the source's light

    def test_the_correction_is_five_boxes_of_s_pixels(self):
        for s in (1, 2, 3, 8):
            assert renderer.resample_variance_px2(s) == pytest.approx(5 * (s * s - 1) / 12)


class TestThresholds:
    def test_tiers_are_ordered_and_reduce_nothing_below_twice_their_threshold(self):
        order = ["fast", "balanced", "high", "exact"]
        values = [QUALITIES[q] for q in order]
        assert values == sorted(values) and values[-1] == math.inf
        for q in order[:-1]:
            plan = plan_render(quality=q)
            m = QUALITIES[q]
            assert plan.scale(2 * m - 1e-3) == 1 and plan.scale(2 * m) == 2


def _result(deltas: dict, edge: dict | None = None) -> dict:
    """A run_tiers result with one case per list entry of *deltas* {threshold: [dB per case]}."""
    ladder = list(deltas)
    n = len(next(iter(deltas.values())))
    edge = edge or deltas
    cases = [{"scene": "room", "seed": i, "focus": "near", "blur_px": 8.0, "psnr_exact": 30.0,
              "psnr_edge_exact": 28.0, "delta": {m: deltas[m][i] for m in ladder},
              "delta_edge": {m: edge[m][i] for m in ladder}} for i in range(n)]
    return {"cases": cases, "curve": [], "ladder": ladder}


class TestBenchTiers:
    def test_choose_thresholds_takes_the_smallest_within_the_margin(self):
        res = _result({2.0: [-0.9, -0.2], 4.0: [-0.2, -0.01], 8.0: [-0.04, 0.0], 16.0: [0.0, 0.0]})
        got = tiers.choose_thresholds(res, {"fast": 0.5, "balanced": 0.1, "high": 0.01}, margin=0.5)
        assert got == {"fast": 4.0, "balanced": 8.0, "high": 16.0}

    def test_the_edge_band_counts_as_much_as_the_whole_frame(self):
        res = _result({4.0: [0.0], 8.0: [0.0]}, edge={4.0: [-0.3], 8.0: [-0.01]})
        assert tiers.choose_thresholds(res, {"balanced": 0.1}, margin=1.0) == {"balanced": 8.0}

    def test_no_threshold_within_tolerance_gives_inf(self):
        res = _result({4.0: [-1.0], 8.0: [-1.0]})
        assert tiers.choose_thresholds(res, {"balanced": 0.1}) == {"balanced": math.inf}

    def test_tables_list_every_threshold(self):
        res = _result({4.0: [-0.2, -0.01], 8.0: [-0.04, 0.0]})
        res["curve"] = [{"threshold": 4.0, "scale": 2, "cells": 4.0, "pixels": 10, "delta_db": -0.05}]
        table = tiers.loss_table(res)
        assert "| 4 | -0.200 |" in table and "| 8 | -0.040 |" in table and "1 of 2" in table
        assert "| 1/2 | -0.050 |" in tiers.curve_table(res)

    @pytest.mark.parametrize("ladder", [(), (0.0,), (math.nan,), (-1.0, 4.0)])
    def test_bad_ladder_is_refused(self, ladder):
        with pytest.raises(InputError, match="ladder"):
            tiers.run_tiers(kinds=["room"], seeds=[0], ladder=ladder, progress=False)

    def test_a_threshold_above_every_layer_is_exact_and_small_ones_cost(self, tmp_path):
        res = tiers.run_tiers(kinds=["room"], seeds=[0], blurs=(120.0,), size=(64, 48), depth_size=(64, 53),
                              ladder=(1.0, 1e6), cache_dir=str(tmp_path), progress=False)
        assert len(res["cases"]) == 3  # one per focus position
        for case in res["cases"]:
            assert case["delta"][1e6] == 0.0 and case["delta_edge"][1e6] == 0.0  # nothing reduced: bit for bit
        assert min(c["delta"][1.0] for c in res["cases"]) < 0.0  # everything at 1/2 or less is not free
        assert {p["threshold"] for p in res["curve"]} == {1.0} and all(p["scale"] >= 2 for p in res["curve"])


def test_cli_tiers_part(tmp_path):
    """`pcdof bench --only tiers` runs the calibration on the tuning seeds and reports the rule's thresholds."""
    import json

    from click.testing import CliRunner

    from pcdof.cli import main

    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["bench", "--quick", "--only", "tiers", "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    cases = report["tiers"]["result"]["cases"]
    assert len(cases) == 3 and {c["seed"] for c in cases} == {0}  # a tuning seed, never a reported one
    chosen = report["tiers"]["chosen"]
    assert set(chosen) == {"high", "balanced", "fast"}
    assert chosen["fast"] <= chosen["balanced"] <= chosen["high"]  # a looser tolerance never needs a larger threshold
    md = (out / "report.md").read_text()
    assert "Quality tiers: thresholds from the measured curve" in md and "wide" not in report


@pytest.mark.parametrize("blur", [15.0, 16.0, 17.0, 31.5, 32.0, 64.0])
def test_the_tiers_bench_gives_each_pixel_the_grid_its_layer_had(blur):
    """The bench's grid per pixel is the one the renderer's trace reports for the layer (layers cut at the
    frame's edges, which move off a blur the frame is full of: a wall 16 px out of focus is one layer)."""
    rng = np.random.default_rng(int(blur))
    coc = np.full((64, 96), blur, np.float32) * (1 + rng.uniform(-0.005, 0.005, (64, 96))).astype(np.float32)
    coc[:, :30] = -3.0
    m = QUALITIES["balanced"]
    lin = rng.random((64, 96, 3)).astype(np.float32)
    _, info = renderer.render_layers_linear(lin, coc, plan=plan_render(quality="balanced"))
    wall = [layer["scale"] for layer in info["layers"] if layer.get("side") == "back"]
    assert len(wall) == 1  # one layer, whatever the edges
    np.testing.assert_array_equal(tiers._layer_scale(coc, m)[:, 30:], wall[0])
    assert np.all(tiers._layer_scale(coc, m)[:, :30] == 1)
