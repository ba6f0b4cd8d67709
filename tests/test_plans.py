"""pcdof.plans: each stage's schedule chosen in one place, recorded, and overridable by parameter."""

import dataclasses
import math

import numba
import numpy as np
import pytest

import pcdof.stages.render as renderer
from pcdof.errors import InputError
from pcdof.lens import PaperLens, ThinLens
from pcdof.plans import QUALITIES, RegisterPlan, RenderPlan, as_dict, plan_register, plan_render

from conftest import texture


def scene(h=72, w=120):
    """In focus on the left, a blurred foreground bar, a far background blurred enough for reduced layers."""
    lin = texture(h, w, seed=11)
    coc = np.zeros((h, w), np.float32)
    coc[:, 40:52] = -7.0
    coc[:, 80:] = 26.0
    return lin, coc


class TestPlanRender:
    def test_quality_sets_the_reduction_threshold(self):
        for quality, threshold in QUALITIES.items():
            plan = plan_render(quality=quality)
            assert plan.reduce_min_coc_px == threshold
            assert plan.threads == numba.get_num_threads()
        assert plan_render(quality="exact").scale(200.0) == 1
        m = QUALITIES["balanced"]  # a layer from CoC 2 m px runs at 1/2, from 4 m at 1/4, ...
        assert [plan_render(quality="balanced").scale(c) for c in (m, 2 * m, 4 * m, 8 * m)] == [1, 2, 4, 8]

    def test_plan_is_recorded_in_the_info(self):
        lin, coc = scene()
        _, info = renderer.render_layers_linear(lin, coc, quality="fast")
        assert info["plan"] == as_dict(plan_render(quality="fast"))
        assert info["plan"]["plan"] == "RenderPlan"
        color = (np.clip(lin, 0, 1) * 255).astype(np.uint8)
        depth = np.full(coc.shape, 2.0, np.float32)
        depth[:, 80:] = 20.0
        _, info = renderer.render_image(color, depth, ThinLens(50, 1.4, 2.0), fx=500.0)
        assert info["plan"]["reduce_min_coc_px"] == QUALITIES["balanced"]

    def test_an_explicit_plan_wins_over_the_quality(self):
        lin, coc = scene()
        exact, _ = renderer.render_layers_linear(lin, coc, quality="exact")
        plan = dataclasses.replace(plan_render(quality="fast"), reduce_min_coc_px=math.inf)
        out, info = renderer.render_layers_linear(lin, coc, quality="fast", plan=plan)
        assert all(l["scale"] == 1 for l in info["layers"])
        np.testing.assert_array_equal(out, exact)
        _, info = renderer.render_layers_linear(lin, coc, quality="fast")
        assert max(l["scale"] for l in info["layers"]) > 1

    def test_threads_change_nothing_and_are_restored(self):
        lin, coc = scene()
        before = numba.get_num_threads()
        ref, _ = renderer.render_layers_linear(lin, coc)
        for threads in range(1, numba.config.NUMBA_NUM_THREADS + 1):
            out, info = renderer.render_layers_linear(lin, coc, plan=plan_render(threads=threads))
            assert info["plan"]["threads"] == threads
            np.testing.assert_array_equal(out, ref)
            assert numba.get_num_threads() == before

    @pytest.mark.parametrize("change, match", [
        ({"threads": 0}, "RenderPlan.threads"), ({"tile_px": 0}, "RenderPlan.tile_px"),
        ({"copy_tiles": 1}, "RenderPlan.copy_tiles"), ({"reduce_min_coc_px": 0.0}, "reduce_min_coc_px"),
        ({"reduce_min_coc_px": float("nan")}, "reduce_min_coc_px"), ({"uniform_min_radius_px": -1}, "uniform_min"),
        ({"convolve_uniform": "yes"}, "convolve_uniform"),
    ])
    def test_bad_plans_are_refused(self, change, match):
        lin, coc = scene(24, 24)
        with pytest.raises(InputError, match=match):
            renderer.render_layers_linear(lin, coc, plan=dataclasses.replace(plan_render(), **change))

    def test_wrong_plan_kind_and_paper_method(self):
        lin, coc = scene(24, 24)
        with pytest.raises(InputError, match="plan must be a RenderPlan"):
            renderer.render_layers_linear(lin, coc, plan=RegisterPlan(1, 1, 1))
        color = np.zeros((24, 24, 3), np.uint8)
        depth = np.full((24, 24), 2.0, np.float32)
        with pytest.raises(InputError, match="paper method"):
            renderer.render_image(color, depth, PaperLens(2.0), fx=500.0, method="paper", plan=plan_render())
        with pytest.raises(InputError, match="quality"):
            plan_render(quality="best")


class TestPlanRegister:
    def test_a_few_tasks_per_thread(self):
        plan = plan_register(424, 1080, threads=2)
        assert plan == RegisterPlan(threads=2, chunks=8, bands=8, block_kernel=True)
        assert plan_register(10, 20, threads=2) == RegisterPlan(threads=2, chunks=1, bands=1)
        assert as_dict(plan)["plan"] == "RegisterPlan"

    def test_render_plan_defaults_are_the_module_constants(self):
        plan = RenderPlan(threads=1)
        assert plan.tile_px == renderer.classify_tiles(np.zeros((4, 4), np.float32)).tile_px
        assert plan.uniform_min_radius_px == renderer.UNIFORM_MIN_RADIUS_PX


class TestKernels:
    def test_warm_cache_is_silent_and_warmup_reports_every_stage(self):
        import io

        from click.testing import CliRunner

        from pcdof.runtime import kernels
        from pcdof.cli.warmup import command

        seconds = kernels.warmup()
        assert set(seconds) == set(kernels.STAGES) and all(s >= 0 for s in seconds.values())
        assert kernels.cold_stages() == []
        stream = io.StringIO()
        kernels._checked.clear()
        kernels.ensure_warm(stream)
        assert stream.getvalue() == ""
        result = CliRunner().invoke(command, ["--stages", "render"])
        assert result.exit_code == 0, result.output
        assert "render" in result.output and "already compiled" in result.output

    def test_unknown_stage(self):
        from pcdof.runtime import kernels

        with pytest.raises(InputError, match="stages must be among"):
            kernels.warmup(["render", "paint"])


def test_layers_are_classified_beside_the_highlights_up_to_the_plans_size():
    from pcdof.plans import CLASSIFY_BESIDE_MAX_PX, classify_beside_highlights

    assert classify_beside_highlights(1920 * 1080, 2) and classify_beside_highlights(640 * 480, 16)
    assert not classify_beside_highlights(1920 * 1080, 1)  # no second thread
    assert not classify_beside_highlights(3840 * 2160, 2)  # memory first: in turn
    assert classify_beside_highlights(CLASSIFY_BESIDE_MAX_PX, 2) and not classify_beside_highlights(
        CLASSIFY_BESIDE_MAX_PX + 1, 2)
    assert not classify_beside_highlights(0, 2)
