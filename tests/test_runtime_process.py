"""Process tuning: ``import pcdof`` changes nothing in the host process; the ``pcdof`` command (and a program
that asks, through :func:`pcdof.runtime.process.tune_process`) gets its OpenMP spin, numba threading layer,
malloc and stderr-capture settings, each only where the user made no choice."""

import ctypes
import json
import os
import subprocess
import sys

import pytest

from pcdof.runtime.process import numba_cache_fallback

pytestmark = pytest.mark.subprocess


def _python(code: str, env: dict | None = None, drop=()) -> str:
    base = {k: v for k, v in os.environ.items() if k not in drop}
    out = subprocess.run([sys.executable, "-c", code], env={**base, **(env or {})}, capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()


class TestImportChangesNothing:
    def test_environment_modules_and_descriptors_untouched(self):
        code = ("import os, sys, json\n"
                "before = dict(os.environ); fd2 = os.fstat(2).st_ino\n"
                "import pcdof\n"
                "print(json.dumps({'env': dict(os.environ) == before, 'numba': 'numba' in sys.modules,\n"
                "                  'cv2': 'cv2' in sys.modules, 'fd2': os.fstat(2).st_ino == fd2}))")
        assert json.loads(_python(code)) == {"env": True, "numba": False, "cv2": False, "fd2": True}

    def test_using_the_api_does_not_tune_either(self):
        # the libraries pcdof uses are loaded first (OpenCV's own import sets LD_LIBRARY_PATH): what changes
        # after that is pcdof's doing
        code = ("import os, json, numpy as np, cv2, numba\nbefore = dict(os.environ)\n"
                "import pcdof\nfrom pcdof.io import capture\n"
                "pcdof.ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1)"
                ".signed_coc_px(np.ones((4, 4), np.float32), 100.0)\n"
                "from pcdof.runtime.process import tuning\n"
                "changed = sorted(k for k in set(os.environ) | set(before) if os.environ.get(k) != before.get(k))\n"
                "print(json.dumps([changed, capture.enabled(), tuning()]))")
        assert json.loads(_python(code)) == [[], False, {}]


class TestOpenMPSpin:
    @pytest.mark.parametrize("env, expected", [({}, "10000"), ({"GOMP_SPINCOUNT": "5"}, "5"),
                                               ({"OMP_WAIT_POLICY": "ACTIVE"}, "unset")])
    def test_spin_count(self, env, expected):
        code = ("import os\nfrom pcdof.runtime.process import tune_process\ntune_process()\n"
                "print(os.environ.get('GOMP_SPINCOUNT', 'unset'))")
        assert _python(code, env, drop=("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")) == expected

    def test_the_command_is_tuned(self):
        code = ("import os, sys\nsys.argv = ['pcdof', '--help']\nfrom pcdof.cli import console_main\n"
                "try:\n    console_main()\nexcept SystemExit:\n    pass\n"
                "sys.stdout = sys.__stdout__\nprint('SPIN', os.environ.get('GOMP_SPINCOUNT', 'unset'))")
        assert _python(code, drop=("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")).splitlines()[-1] == "SPIN 10000"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc only")
class TestMalloc:
    CODE = ("import ctypes, resource, numpy as np\nfrom pcdof.runtime.process import tune_process\n"
            "tuned = 'malloc' in tune_process()\n"
            "def faults():\n"
            "    r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
            "    for _ in range(4):\n"
            "        a = np.empty(8 << 20); a[::512] = 1; del a\n"  # 64 MB, one write per 4 KiB page
            "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0\n"
            "faults()\n"
            "print(tuned, faults())")

    @pytest.mark.parametrize("env, tuned", [({}, True), ({"PCDOF_DEFAULT_MALLOC": "1"}, False),
                                            ({"MALLOC_TRIM_THRESHOLD_": "131072"}, False)])
    def test_freed_memory_is_reused(self, env, tuned):
        if not hasattr(ctypes.CDLL(None), "gnu_get_libc_version"):
            pytest.skip("not glibc")
        flag, faults = _python(self.CODE, env, drop=("PCDOF_DEFAULT_MALLOC", "MALLOC_TRIM_THRESHOLD_",
                                                     "MALLOC_MMAP_THRESHOLD_")).split()
        assert flag == str(tuned)
        # kept, the array's pages are reused; unmapped, they are faulted in again: 4 x 64 MB, at least 4 x 32
        # faults even where the kernel backs them with 2 MB pages
        assert (int(faults) < 50) if tuned else (int(faults) > 100)


    ARENA_CODE = ("import resource, threading, numpy as np\nfrom pcdof.runtime.process import tune_process\n"
                  "shared = tune_process().get('malloc_arenas') == 1\n"
                  "def work():\n"
                  "    a = np.empty(6 << 20); a[::512] = 1; del a\n"  # 48 MB, written and freed by another thread
                  "t = threading.Thread(target=work); t.start(); t.join()\n"
                  "r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
                  "b = np.empty(6 << 20); b[::512] = 1\n"
                  "print(shared, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0)")

    @pytest.mark.parametrize("env, shared", [({}, True), ({"MALLOC_ARENA_MAX": "8"}, False),
                                             ({"PCDOF_DEFAULT_MALLOC": "1"}, False)])
    def test_memory_a_thread_frees_is_reused_by_another(self, env, shared):
        if not hasattr(ctypes.CDLL(None), "gnu_get_libc_version"):
            pytest.skip("not glibc")
        flag, faults = _python(self.ARENA_CODE, env, drop=("PCDOF_DEFAULT_MALLOC", "MALLOC_ARENA_MAX",
                                                           "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")).split()
        assert flag == str(shared)
        if flag == "True":  # one arena: the main thread's array takes the block the other thread freed
            assert int(faults) < 12
        elif "MALLOC_ARENA_MAX" in env:  # the block stays in the other thread's arena: 48 MB of fresh pages
            assert int(faults) >= 24  # (at least 24 where the kernel backs them with 2 MB pages)


class TestThreadingLayer:
    def test_openmp_without_tbb_warning_after_open3d(self):
        code = ("import warnings; warnings.simplefilter('always')\n"
                "from pcdof.runtime.process import tune_process; tune_process()\n"
                "import open3d, pcdof, numpy as np\n"
                "pcdof.ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1)"
                ".signed_coc_px(np.ones((4, 4), np.float32), 100.0)\n"  # starts numba's threading layer
                "import numba; print(numba.threading_layer())")
        base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
        out = subprocess.run([sys.executable, "-c", code], env=base, capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "omp"
        assert "TBB" not in out.stderr, out.stderr

    def test_user_choice_is_kept(self):
        code = ("from pcdof.runtime.process import tune_process; tune_process()\n"
                "import numba; print(numba.config.THREADING_LAYER_PRIORITY)")
        assert _python(code, {"NUMBA_THREADING_LAYER_PRIORITY": "workqueue omp tbb"}) == "['workqueue', 'omp', 'tbb']"


class TestNumbaCacheFallback:
    def test_fallback_only_when_no_candidate_is_writable(self, tmp_path):
        blocker = tmp_path / "file"
        blocker.write_bytes(b"")
        unwritable = [str(blocker / "a"), str(blocker / "b")]  # under a regular file: never a folder
        fallback = str(tmp_path / "cache")
        assert numba_cache_fallback(unwritable, fallback) == fallback
        assert os.path.isdir(fallback)
        assert numba_cache_fallback([*unwritable, str(tmp_path / "ok")], fallback) is None
        assert numba_cache_fallback(unwritable, str(blocker / "c")) is None  # nothing writable at all


def test_a_library_users_synthetic_scene_starts_numbas_loops_without_a_warning():
    """A program that imports pcdof as a library (no tuning) and makes a synthetic scene (Open3D, with its older TBB,
    loaded before numba's parallel loops start) gets no NumbaWarning about TBB: the loops start through
    :func:`pcdof.runtime.threads.start_parallel_loops`, on the layer numba takes anyway."""
    code = ("import warnings\n"
            "from numba.core.errors import NumbaWarning\n"
            "warnings.simplefilter('error', NumbaWarning)\n"
            "import numba\n"
            "from pcdof.synth import generate_scene\n"
            "generate_scene('portrait', color_size=(48, 32), depth_size=(48, 32), seed=0)\n"
            "print(numba.threading_layer())\n")
    layer = _python(code, drop=("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"))
    assert layer in ("omp", "tbb", "workqueue")
