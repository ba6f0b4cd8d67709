"""Kernels compiled once and said so (pcdof.runtime.kernels), one kernel type per input dtype, and a light
render command (no heavy library imported, no kernel compiled when the cache is warm)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from click.testing import CliRunner

from pcdof.runtime import kernels
from pcdof.errors import InputError, PcdofError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "data", "sample")
HEAVY = ("open3d", "pyvista", "dask", "matplotlib", "trimesh")
#: Code that records in ``compiled`` every function numba compiles from scratch (a cache miss, not a load):
#: pcdof's kernels as "pcdof.<module>.<name>", and numba's own helpers that compile with them.
COUNT_COMPILES = ("from numba.core import dispatcher; compiled = []; "
                  "core = dispatcher._FunctionCompiler._compile_core; "
                  "dispatcher._FunctionCompiler._compile_core = lambda self, *a: compiled.append("
                  "self.py_func.__module__ + '.' + self.py_func.__qualname__) or core(self, *a)")


def _python(code: str, env: dict | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run *code* in a fresh interpreter (this one's), from a temporary working folder."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=timeout, cwd=ROOT)


class TestReadOnly:
    def test_view_not_copy(self):
        a = np.arange(6, dtype=np.float32).reshape(2, 3)
        v = kernels.read_only(a)
        assert not v.flags.writeable and np.shares_memory(a, v) and a.flags.writeable
        np.testing.assert_array_equal(v, a)
        with pytest.raises(ValueError):
            v[0, 0] = 1.0

    def test_fill_compiles_one_type_per_colour_path(self):
        """Writable, read-only, grey and every colour dtype share two kernel types (uint8, float64), all
        read-only; the results are the same whatever the caller's array flags."""
        from pcdof.stages.fill import fill_joint_bilateral
        from pcdof.stages.fill.combine import _combine_tasks

        rng = np.random.default_rng(3)
        depth = rng.uniform(1.0, 3.0, (12, 16)).astype(np.float32)
        depth[4:8, 5:9] = 0.0
        color = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
        frozen = color.copy()
        frozen.flags.writeable = False
        frozen_depth = depth.copy()
        frozen_depth.flags.writeable = False
        ref = fill_joint_bilateral(depth, color)
        np.testing.assert_array_equal(fill_joint_bilateral(frozen_depth, frozen), ref)
        for c in (color[:, :, 0], color.astype(np.uint16) * 257, color.astype(np.float32) / 255,
                  color.astype(np.float16) / 255, color.astype(np.float64) / 255):
            assert fill_joint_bilateral(depth, c).shape == depth.shape
        colour_types = {sig[3] for sig in _combine_tasks.signatures}  # (counter, n_tasks, depth, colour, ...)
        assert {t.dtype.name for t in colour_types} <= {"uint8", "float64"}
        assert all(not t.mutable and t.layout == "C" for t in colour_types)
        assert all(not sig[2].mutable for sig in _combine_tasks.signatures)  # the depth too

    def test_coc_and_tiles_take_read_only_inputs(self):
        from pcdof.lens import ThinLens, _signed_coc_tasks
        from pcdof.stages.render.tiles import classify_tiles, tile_ranges

        depth = np.linspace(0.5, 4.0, 64, dtype=np.float32).reshape(8, 8)
        frozen = depth.copy()
        frozen.flags.writeable = False
        lens = ThinLens(50.0, 2.0, 1.5)
        coc = lens.signed_coc_px(depth, 500.0)
        np.testing.assert_array_equal(lens.signed_coc_px(frozen, 500.0), coc)
        np.testing.assert_array_equal(lens.signed_coc_px(depth.astype(np.uint16), 500.0),
                                      lens.signed_coc_px(depth.astype(np.uint16).astype(np.float64), 500.0))
        depths = [sig[2] for sig in _signed_coc_tasks.signatures]  # (counter, n_tasks, depth, ...)
        assert depths and all(not t.mutable for t in depths)
        assert {t.dtype.name for t in depths} <= {"float32", "float64"}
        coc.flags.writeable = False
        classify_tiles(coc, tile_px=4)
        classify_tiles(np.array(coc), tile_px=4)
        assert len(tile_ranges.signatures) == 1 and not tile_ranges.signatures[0][0].mutable


class TestStages:
    def test_check_stages(self):
        assert kernels.check_stages("fill") == ["fill"]
        assert kernels.check_stages(("render", "register")) == ["render", "register"]
        with pytest.raises(InputError, match="stages must be among") as err:
            kernels.check_stages(["render", "paint"])
        assert isinstance(err.value, PcdofError) and "paint" in str(err.value)

    def test_estimate_runs_every_stage_at_once(self, monkeypatch):
        """Every stage in its own process, all at once; every busy process (these and the load) shares the
        cores equally, at most one core each; on one core the stages run one after the other."""
        cpu = {"register": 9.0, "fill": 14.0, "render": 20.0}  # the model, whatever the machine measured
        monkeypatch.setattr(kernels, "COMPILE_CPU_S", cpu)
        three = list(kernels.STAGES)
        a, b, c = sorted(cpu[s] for s in three)
        assert kernels.estimate_seconds([], workers=2, load=0) == 0.0
        assert kernels.estimate_seconds(["fill"], workers=8, load=0) == pytest.approx(cpu["fill"])
        assert kernels.estimate_seconds(["fill", "render"], workers=1, load=0) == pytest.approx(
            cpu["fill"] + cpu["render"])  # one core: all the work, one after the other
        assert kernels.estimate_seconds(three, workers=4, load=0) == pytest.approx(c)  # a core each
        # 2 cores: three processes at 2/3 of a core each until the shortest ends, then a core each
        assert kernels.estimate_seconds(three, workers=2, load=0) == pytest.approx(1.5 * a + (c - a))
        # one stage on one core beside 3 busy processes gets a quarter of it
        assert kernels.estimate_seconds(["render"], workers=1, load=3) == pytest.approx(4 * cpu["render"])
        # 2 cores, 2 busy processes besides: the first two stages get half a core each until the shorter ends
        assert kernels.estimate_seconds(["render", "fill"], workers=2, load=2) == pytest.approx(
            2 * min(b, c) + (max(b, c) - min(b, c)) / (2 / 3))
        loads = [kernels.estimate_seconds(three, workers=2, load=x) for x in (0.0, 0.5, 2.0, 6.0)]
        assert loads == sorted(loads) and loads[0] < loads[-1]

    def test_compile_apart_starts_a_process_per_stage(self, monkeypatch):
        """One process per stage, each printing its stage's line; every stage is reported once, with its seconds."""
        import subprocess

        started = []

        class Proc:
            def __init__(self, cmd, **kwargs):
                stage = cmd[-1].split("print(")[1].split(",")[0].strip("'\"")
                started.append(stage)
                self.stdout = iter([f"{stage} {1.5 + len(started)}\n"])

            def wait(self):
                return 0

        monkeypatch.setattr(subprocess, "Popen", Proc)
        monkeypatch.setattr(kernels.os, "cpu_count", lambda: 2)
        lines, then = [], []
        seconds = kernels._compile_apart(["register", "fill", "render"], lines.append, 0.0, then=then.append)
        assert started == ["register", "fill", "render"]
        assert seconds == {stage: 2.5 + i for i, stage in enumerate(started)}
        assert len(lines) == 3 and lines[-1].startswith("  [3/3] ")
        assert sorted(then) == sorted(started)  # each stage handed on as it ends, to be loaded here

    def test_warm_stages_are_checked_once_and_silently(self, monkeypatch):
        import io

        calls = []
        monkeypatch.setattr(kernels, "_checked", set())
        monkeypatch.setattr(kernels, "cold_stages", lambda stages=(): calls.append(list(stages)) or [])
        stream = io.StringIO()
        kernels.ensure_warm(stream, stages=["fill"])
        kernels.ensure_warm(stream, stages=["fill"])
        kernels.ensure_warm(stream)
        assert calls == [["fill"], ["register", "render"]] and stream.getvalue() == ""


class TestColdCache:
    def test_first_use_says_what_it_compiles(self, tmp_path):
        """With an empty cache every stage is cold; the first call names the stages it compiles and an
        estimate, then one line per stage and the total (the compile itself replaced here by a stand-in)."""
        proc = _python("""
            import sys
            from pcdof.runtime import kernels
            print(kernels.cold_stages())
            kernels.warmup = lambda stages, progress, processes: [progress(f"  [{i}/{len(stages)}] {s}: 0.0 s")
                                                                  for i, s in enumerate(stages, 1)]
            kernels.ensure_warm(sys.stdout, stages=["fill", "render"])
            kernels.ensure_warm(sys.stdout, stages=["fill"])  # checked once per process
        """, {"NUMBA_CACHE_DIR": str(tmp_path)})
        assert proc.returncode == 0, proc.stderr
        lines = proc.stdout.splitlines()
        assert lines[0] == "['register', 'fill', 'render']"
        assert lines[1].startswith("pcdof: compiling kernels, once after install: fill, render (about ")
        assert lines[2:4] == ["  [1/2] fill: 0.0 s", "  [2/2] render: 0.0 s"]
        assert lines[4].startswith("pcdof: kernels compiled and cached in ") and len(lines) == 5

    @pytest.mark.slow
    def test_fill_compiles_once_with_progress(self, tmp_path):
        """A real compile of one stage into an empty cache at the caller's boundary: progress on stderr, then a
        warm cache, silent."""
        code = """
            import numpy as np
            from pcdof.runtime import kernels
            from pcdof.stages.fill import fill_depth
            kernels.ensure_warm(stages=["fill"])
            d = np.array([[1.0, 0.0, 2.0]], np.float32)
            print(fill_depth(d, np.zeros((1, 3, 3), np.uint8)).tolist())
            print(kernels.cold_stages(["fill"]))
        """
        env = {"NUMBA_CACHE_DIR": str(tmp_path)}
        first = _python(code, env)
        assert first.returncode == 0, first.stderr
        assert first.stdout.splitlines() == ["[[1.0, 2.0, 2.0]]", "[]"]
        assert "compiling kernels, once after install: fill" in first.stderr
        assert "[1/1] fill" in first.stderr and "kernels compiled and cached in" in first.stderr
        second = _python(code, env)
        assert second.returncode == 0 and second.stdout == first.stdout and "compiling" not in second.stderr


class TestWarmupCommand:
    def test_reports_progress_and_total(self):
        from pcdof.cli import main

        # through the group, as a user runs it (click caches a command's help option on first use: invoking the
        # bare command here would leave it without the group's -h for later tests)
        result = CliRunner().invoke(main, ["warmup", "--stages", "fill"])
        assert result.exit_code == 0, result.output
        assert "[1/1] fill" in result.output and "ready in " in result.output and "fill " in result.output

    def test_unknown_stage_is_one_line(self):
        from pcdof.cli import main

        result = CliRunner().invoke(main, ["warmup", "--stages", "fill,paint"])
        assert result.exit_code != 0 and "stages must be among" in result.output


class TestRenderCommand:
    def test_imports_no_heavy_module_and_compiles_nothing_when_warm(self, tmp_path):
        """``pcdof render`` of the bundled sample: none of the 3D/plotting/cluster libraries is imported,
        and with the kernels cached (warmed first) no kernel is compiled, only loaded."""
        out = tmp_path / "out.png"
        warm = _python("from pcdof.runtime import kernels; kernels.warmup()")
        assert warm.returncode == 0, warm.stderr
        proc = _python(f"""
            import sys
            {COUNT_COMPILES}
            from pcdof.cli import main
            try:
                main(["-q", "render", {os.path.join(SAMPLE, "color.png")!r}, {os.path.join(SAMPLE, "depth.png")!r},
                      "--calib", {os.path.join(SAMPLE, "calib.json")!r}, "-o", {str(out)!r}])
            except SystemExit as exc:
                assert not exc.code, exc.code
            print(sorted(n for n in sys.modules if n.split(".")[0] in {HEAVY!r}))
            print([n for n in compiled if n.startswith("pcdof.")])
        """)
        assert proc.returncode == 0, proc.stderr
        heavy, compiled = proc.stdout.splitlines()[-2:]
        assert heavy == "[]" and compiled == "[]" and out.exists()


class TestWarmupCoversTheFrame:
    @pytest.mark.slow
    def test_nothing_compiles_after_warmup(self, tmp_path):
        """Into an empty cache: after ``warmup()`` a render of the bundled sample (colour 8-bit, uniform blur
        tiles, blurred foreground) compiles no kernel, it only loads them: the first frame after an install
        never pays for a kernel the warm-up left out."""
        env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
        warm = _python("from pcdof.runtime import kernels; kernels.warmup(processes=True)", env)
        assert warm.returncode == 0, warm.stderr
        proc = _python(f"""
            {COUNT_COMPILES}
            from pcdof.cli import main
            try:
                main(["-q", "render", {os.path.join(SAMPLE, "color.png")!r}, {os.path.join(SAMPLE, "depth.png")!r},
                      "--calib", {os.path.join(SAMPLE, "calib.json")!r}, "-o", {str(tmp_path / "out.png")!r}])
            except SystemExit as exc:
                assert not exc.code, exc.code
            print([n for n in compiled if n.startswith("pcdof.")])  # numba's own helpers compile with them
        """, env)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.splitlines()[-1] == "[]"


RENDER_KERNEL_MODULES = tuple(f"pcdof.stages.render.{m}" for m in
                              ("classify", "scatter", "composite", "extend", "uniform", "grids", "ownership"))


@pytest.mark.parametrize("warm_module,module_names", [
    ("pcdof.stages.render", RENDER_KERNEL_MODULES),
    ("pcdof.stages.register", ("pcdof.stages.register.project", "pcdof.stages.register.raster")),
    ("pcdof.stages.fill", kernels.STAGES["fill"][1])])
def test_stage_warmup_reaches_every_kernel_of_its_module(warm_module, module_names):
    """A stage's warm-up takes every path of its modules, so a first frame never compiles a kernel silently."""
    import importlib

    importlib.import_module(warm_module).warmup()
    dispatchers = [d for m in module_names for d in kernels._cached_dispatchers(m)]
    # a kernel called from another kernel loaded from the cache is not loaded itself (its code is in its
    # caller's): it counts as reached when a reached kernel calls it
    by_name = {d.__name__: d for d in dispatchers}
    reached = {d.__name__ for d in dispatchers if d.signatures}
    todo = list(reached)
    while todo:
        for name in by_name[todo.pop()].py_func.__code__.co_names:
            if name in by_name and name not in reached:
                reached.add(name)
                todo.append(name)
    missed = [d.__name__ for d in dispatchers if d.__name__ not in reached]
    assert missed == []


def test_the_renderer_kernels_run_as_tasks_that_release_the_gil():
    """The renderer's parallel kernels are task kernels run on the calling thread and a pool's helpers
    (:func:`pcdof.runtime.tasks.run_tasks`): each must release the GIL (numba's nogil) or the helpers would
    wait for it; none is a ``prange`` kernel (numba's parallel machinery costs about a second of compiling each)."""
    dispatchers = [d for m in kernels.STAGES["render"][1] for d in kernels._cached_dispatchers(m)]
    tasks = [d for d in dispatchers if d.__name__.endswith("_tasks")]
    assert {d.__name__ for d in tasks} >= {"_band_tasks", "_relabel_tasks", "_across_tasks", "_under_tasks",
                                          "_normalise_tasks", "_reduce_tasks", "_convolve_tasks", "_scatter_tasks",
                                          "_signed_coc_tasks", "_coc_maps_tasks", "_encode8_tasks"}
    assert all(d.targetoptions.get("nogil") for d in tasks), [d.__name__ for d in tasks]
    assert [d.__name__ for d in dispatchers if d.targetoptions.get("parallel")] == []


def test_byte_compile_leaves_every_module_with_current_bytecode():
    """After byte_compile() no pcdof module is compiled from source on import, even where Python is told not
    to write bytecode: each one's .pyc exists and records its source's mtime and size (PEP 552 header)."""
    import importlib.util
    import pathlib
    import struct

    from pcdof.runtime.kernels import byte_compile

    assert byte_compile() is True
    root = pathlib.Path(kernels.__file__).parents[1]  # the package (kernels lives in pcdof.runtime)
    sources = sorted(root.rglob("*.py"))
    assert len(sources) > 30
    for src in sources:
        pyc = pathlib.Path(importlib.util.cache_from_source(str(src)))
        header = pyc.read_bytes()[:16]
        flags, mtime, size = struct.unpack("<3I", header[4:16])
        st = src.stat()
        assert header[:4] == importlib.util.MAGIC_NUMBER and flags == 0, src
        assert (mtime, size) == (int(st.st_mtime) & 0xFFFFFFFF, st.st_size & 0xFFFFFFFF), src


def test_compiling_relaxes_the_collector_and_puts_it_back(monkeypatch):
    import gc

    seen = []
    monkeypatch.setattr(kernels.importlib, "import_module",
                        lambda name: type("Stage", (), {"warmup": staticmethod(lambda: seen.append(gc.get_threshold()))}))
    before = gc.get_threshold()
    gc.unfreeze()
    kernels.warm_stage("fill")
    assert seen == [kernels._COMPILE_GC_THRESHOLDS]
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0  # a process that does more than compile keeps its collector as it was
    kernels.warm_stage("fill", whole_process=True)
    assert gc.get_freeze_count() > 0  # a process that only compiles leaves the modules out of the passes
    gc.unfreeze()
    assert gc.get_threshold() == before


def test_a_numba_that_renamed_its_internals_degrades_to_a_silent_compile(monkeypatch):
    """The cache probe reads numba internals; where they changed it answers "warm" (numba then compiles on first
    use, as it always can), never an error."""
    import numba.core.registry

    from pcdof.runtime import kernels as k

    monkeypatch.setattr(numba.core.registry, "CPUDispatcher", None)  # isinstance(..., None) raises TypeError
    assert k._cached_dispatchers("pcdof.lens") is None
    assert k.cold_stages(["render"]) == []

    class Renamed:  # a dispatcher without the attributes the probe reads
        overloads = {}

    assert k._in_cache(Renamed()) is True


def test_map_on_threads_keeps_the_order_and_shares_the_items_out():
    """Every item's result in the items' order, whatever the thread count; with two threads the helper takes every
    other item, with numba on one thread there (the items are the parallel work)."""
    import threading

    import numba

    from pcdof.runtime.tasks import map_on_threads
    from pcdof.runtime.threads import numba_threads

    seen = {}

    def square(i):
        seen[i] = (threading.get_ident(), numba.get_num_threads())
        return i * i

    items = list(range(11))
    for n in (1, 2, 3, 20):
        assert map_on_threads(square, items, n) == [i * i for i in items]
    assert map_on_threads(square, [], 4) == []
    with numba_threads(2) as n:
        seen.clear()
        map_on_threads(square, items, n)
    if n == 2:
        assert {seen[i][0] for i in items[0::2]} == {threading.get_ident()}
        assert threading.get_ident() not in {seen[i][0] for i in items[1::2]}
        assert {seen[i][1] for i in items} == {1}
