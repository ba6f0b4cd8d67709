"""The pipeline executor: stages skip the work a frame does not need, and say so in the trace."""

import sys

import numpy as np
import pytest

import pcdof.stages.render.physical as render_module
from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.errors import InputError, LensError
from pcdof.lens import PaperLens, ThinLens
from pcdof.pipeline import render, render_from_depth, run

INTR = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)


def frame_with(depth, *, rig=None, seed=0):
    rng = np.random.default_rng(seed)
    color = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    return RGBDFrame(color, depth.astype(np.float32), rig or Rig.registered(INTR))


def two_planes():
    depth = np.full((48, 64), 4.0, np.float32)
    depth[12:36, 20:44] = 1.0
    return depth


def stage(result, name):
    return next(t for t in result.trace if t.name == name)


class TestSkipping:
    def test_registered_rig_is_not_reprojected(self, monkeypatch):
        import pcdof.register as register_module

        def forbidden(*a, **k):
            raise AssertionError("registration ran for a registered rig")

        monkeypatch.setattr(register_module, "register_depth", forbidden)
        res = run(frame_with(two_planes()), ThinLens(50, 2, 1.0))
        assert stage(res, "register").skipped
        np.testing.assert_array_equal(res.depth_registered_m, two_planes())

    def test_no_holes_no_fill(self, monkeypatch):
        import pcdof.fill as fill_module

        monkeypatch.setattr(fill_module, "fill_depth", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
        res = run(frame_with(two_planes()), ThinLens(50, 2, 1.0))
        assert stage(res, "fill").skipped
        assert "hole" in stage(res, "fill").reason

    def test_holes_are_filled(self):
        depth = two_planes()
        depth[5:8, 5:8] = 0
        res = run(frame_with(depth), ThinLens(50, 2, 1.0))
        assert not stage(res, "fill").skipped
        assert np.all(res.depth_filled_m > 0)

    def test_sharp_frame_is_returned_bit_exact_without_blur(self, monkeypatch):
        def forbidden(*a, **k):
            raise AssertionError("blur ran although nothing is out of focus")

        monkeypatch.setattr(render_module, "render_layers_linear", forbidden)
        f = frame_with(two_planes())
        res = run(f, ThinLens(50, 5000, 1.0))
        assert stage(res, "render").skipped
        assert res.image is not f.color
        np.testing.assert_array_equal(res.image, f.color)

    @pytest.mark.parametrize("overlap", [True, False])
    def test_sharp_frame_with_clipped_lights_skips_the_highlights_estimate(self, monkeypatch, overlap):
        import pcdof.highlights as highlights_module
        import pcdof.pipeline as pipeline_module

        def forbidden(*a, **k):
            raise AssertionError("radiance estimated for a frame nothing of which is blurred")

        monkeypatch.setattr(highlights_module, "reconstruct_prepared", forbidden)
        monkeypatch.setattr(pipeline_module, "_OVERLAP", overlap)
        f = frame_with(two_planes())
        f.color[20:24, 30:34] = 255  # a clipped light in the sharp subject
        res = run(f, ThinLens(50, 5000, 1.0))  # every CoC far below a pixel
        hl = stage(res, "highlights")
        assert hl.skipped and "nothing to blur" in hl.reason
        assert stage(res, "render").skipped
        np.testing.assert_array_equal(res.image, f.color)
        # stopped just enough to blur: the estimate runs
        monkeypatch.undo()
        res = run(f, ThinLens(50, 1.4, 1.0))
        assert not stage(res, "highlights").skipped

    def test_no_foreground_pass_when_nothing_is_in_front_of_focus(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))  # focus on the nearest surface
        detail = stage(res, "render").detail
        assert not detail["foreground_pass"]
        assert all(l["side"] == "back" for l in detail["layers"] if l["blurred"])
        assert "no foreground pass" in stage(res, "render").reason

    def test_only_the_blur_sizes_present_are_computed(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))
        layers = [l for l in stage(res, "render").detail["layers"] if l["blurred"]]
        c_wall = float(ThinLens(50, 1.4, 1.0).coc_px(np.array([[4.0]], np.float32), 60.0)[0, 0])
        assert len(layers) == 1  # one plane behind focus: one blur layer, whatever the range of sizes
        lo, hi = layers[0]["coc_px"]
        assert lo <= c_wall < hi

    def test_in_focus_pixels_are_copied_unchanged(self):
        f = frame_with(two_planes())
        res = run(f, ThinLens(50, 1.4, 1.0))
        # the in-focus subject's interior (further than the background's blur reach from the edge)
        np.testing.assert_array_equal(res.image[16:32, 24:40], f.color[16:32, 24:40])

    def test_explain_lists_every_stage(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 1.0))
        text = res.explain()
        for name in ("register", "fill", "coc", "render", "total"):
            assert name in text
        assert res.skipped.keys() >= {"register", "fill"}


class TestApi:
    def test_render_returns_input_dtype_and_shape(self):
        f = frame_with(two_planes())
        out = render(f, ThinLens(50, 1.4, 2.0))
        assert out.dtype == np.uint8 and out.shape == f.color.shape

    def test_focus_at_pixel_uses_depth_there(self):
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 3.0), focus_at=(32, 24))
        assert res.lens.focus_distance_m == pytest.approx(1.0)
        res = run(frame_with(two_planes()), ThinLens(50, 1.4, 3.0), focus_at=(2, 2))
        assert res.lens.focus_distance_m == pytest.approx(4.0)

    def test_paper_method(self):
        f = frame_with(two_planes())
        res = run(f, PaperLens(1.0), method="paper")
        assert res.image.shape == f.color.shape and res.coc_px is None

    def test_render_from_depth_matches_run(self):
        f = frame_with(two_planes())
        lens = ThinLens(50, 1.4, 1.0)
        a = run(f, lens).image
        b, trace = render_from_depth(f.color, two_planes(), lens, INTR.fx)
        np.testing.assert_array_equal(a, b)

    def test_errors(self):
        f = frame_with(two_planes())
        with pytest.raises(InputError, match="frame"):
            run(f.color, ThinLens(50, 2, 1))
        with pytest.raises(InputError, match="method"):
            run(f, ThinLens(50, 2, 1), method="bokeh")
        with pytest.raises(LensError):
            run(f, PaperLens(1.0), method="physical")
        with pytest.raises(LensError):
            run(f, "f/2")
        with pytest.raises(InputError, match="focus"):
            run(f, ThinLens(50, 2, 1), focus_at=(500, 2))


class TestOpenMPSpin:
    """Importing pcdof shortens OpenMP's spin-wait, unless the user chose a spin or wait policy."""

    @pytest.mark.parametrize("env, expected", [
        ({}, "10000"),
        ({"GOMP_SPINCOUNT": "5"}, "5"),
        ({"OMP_WAIT_POLICY": "ACTIVE"}, "unset"),
    ])
    def test_spin_count(self, env, expected):
        import os
        import subprocess
        import sys

        base = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
        code = "import os, pcdof; print(os.environ.get('GOMP_SPINCOUNT', 'unset'))"
        out = subprocess.run([sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True,
                             check=True)
        assert out.stdout.strip() == expected


class TestMalloc:
    """Importing pcdof lets glibc keep freed large blocks (no page faults on the next frame's arrays), unless the
    user tuned glibc's malloc or asked for its defaults."""

    CODE = ("import ctypes, resource, numpy as np, pcdof\n"
            "def faults():\n"
            "    r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
            "    for _ in range(4):\n"
            "        a = np.empty(8 << 20); a[::512] = 1; del a\n"  # 64 MB, one write per 4 KiB page
            "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0\n"
            "faults()\n"
            "print(pcdof.MALLOC_TUNED, faults())")

    @pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc only")
    @pytest.mark.parametrize("env, tuned", [({}, True), ({"PCDOF_DEFAULT_MALLOC": "1"}, False),
                                            ({"MALLOC_TRIM_THRESHOLD_": "131072"}, False)])
    def test_freed_memory_is_reused(self, env, tuned):
        import ctypes
        import os
        import subprocess

        if not hasattr(ctypes.CDLL(None), "gnu_get_libc_version"):
            pytest.skip("not glibc")
        base = {k: v for k, v in os.environ.items()
                if k not in ("PCDOF_DEFAULT_MALLOC", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")}
        out = subprocess.run([sys.executable, "-c", self.CODE], env={**base, **env}, capture_output=True, text=True,
                             check=True)
        flag, faults = out.stdout.split()
        assert flag == str(tuned)
        # kept, the array's pages are reused; unmapped, they are faulted in again: 4 x 64 MB, at least 4 x 32
        # faults even where the kernel backs them with 2 MB pages
        assert (int(faults) < 50) if tuned else (int(faults) > 100)


class TestThreadingLayer:
    """numba's parallel kernels run on OpenMP even when Open3D's bundled TBB is loaded first, silently."""

    def test_openmp_without_tbb_warning_after_open3d(self):
        import os
        import subprocess
        import sys

        base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
        code = ("import warnings; warnings.simplefilter('always')\n"
                "import open3d, pcdof, numpy as np\n"
                "from pcdof.lens import ThinLens\n"
                "ThinLens(50, 2, 1).signed_coc_px(np.ones((4, 4), np.float32), 100.0)\n"  # a parallel kernel
                "import numba; print(numba.threading_layer())")
        out = subprocess.run([sys.executable, "-c", code], env=base, capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "omp"
        assert "TBB" not in out.stderr, out.stderr

    def test_user_choice_is_kept(self):
        import os
        import subprocess
        import sys

        code = "import pcdof, numba; print(numba.config.THREADING_LAYER_PRIORITY)"
        env = {**os.environ, "NUMBA_THREADING_LAYER_PRIORITY": "workqueue omp tbb"}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "['workqueue', 'omp', 'tbb']"
