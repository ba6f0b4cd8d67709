"""The numba kernels of every stage: compiled once after install, and said so.

numba compiles each kernel the first time it runs and keeps the machine code in its on-disk
cache, so only the first run after an install (or an upgrade) pays for compiling. :func:`ensure_warm`
finds out, cheaply and before any work, whether that is about to happen for the stages a caller is
going to run (a stage with a module none of whose kernels is in the cache index) and then compiles
those stages, side by side in fresh interpreters, with an estimate and a line of progress per stage on
stderr, so a new user sees why the first frame takes long; when the cache is warm it prints nothing.
Stages are compiled only when asked for (lazily), so a call that runs one stage compiles that stage
only. ``pcdof warmup`` does the same ahead of time (e.g. at install), and writes the package's Python
bytecode too (:func:`byte_compile`).
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import os
import sys
import time

#: stage -> (modules whose ``warmup()`` compiles its kernels, modules whose cached kernels those compile)
STAGES = {
    "register": (("pcdof.stages.register",), ("pcdof.stages.register.project", "pcdof.stages.register.raster",
                                             "pcdof.distortion")),
    "fill": (("pcdof.stages.fill",), ("pcdof.stages.fill.index", "pcdof.stages.fill.boundary",
                                      "pcdof.stages.fill.combine", "pcdof.stages.fill.cleanup",
                                      "pcdof.stages.fill.inputs", "pcdof.stages.fill.edges")),
    "render": (("pcdof.stages.render", "pcdof.stages.render.tiles"),
               ("pcdof.stages.render.classify", "pcdof.stages.render.scatter", "pcdof.stages.render.composite",
                "pcdof.stages.render.extend", "pcdof.stages.render.uniform", "pcdof.stages.render.grids",
                "pcdof.stages.render.ownership", "pcdof.stages.render.tiles", "pcdof.stages.render.cells",
                "pcdof.stages.render.border", "pcdof.stages.render.mixed",
                "pcdof.lens", "pcdof.color")),
}

#: CPU seconds each stage's ``warmup()`` takes to compile with an empty cache, measured on the project's 2-core
#: machine with ``scripts/profile_compile.py`` (each stage in a fresh interpreter, its start and imports included;
#: other load on the cores adds 10-30 %, and the machine's faster hours measured down to 0.7 times these); only for
#: the estimate printed before compiling. With these, three stages on two cores estimate 35 s; a first render of a
#: 640x480 frame with an empty cache took 36.8 s wall, 65 s of CPU, the same hour.
COMPILE_CPU_S = {"register": 12.5, "fill": 21.0, "render": 28.5}

#: stages this process has checked (or compiled): each is checked once per process
_checked: set = set()


def read_only(array):
    """A read-only view of *array* (no copy): numba compiles a separate specialisation for read-only
    arrays, so a kernel's input arrays are passed read-only always, one type whatever the caller's flags.

    Parameters
    ----------
    array : ndarray

    Returns
    -------
    ndarray, the same data, not writeable
    """
    view = array.view()
    view.flags.writeable = False
    return view


def _cached_dispatchers(module_name: str) -> list | None:
    """The numba dispatchers defined in *module_name* that are cached on disk and compiled on their own
    (inlined helpers are compiled into their callers); None when numba's dispatchers no longer look as this
    probe expects (a numba release that renamed what it reads): the caller then treats the stage as warm and
    numba compiles what it must when it runs, as it always would."""
    module = importlib.import_module(module_name)
    try:
        from numba.core.registry import CPUDispatcher

        return [v for v in vars(module).values()
                if isinstance(v, CPUDispatcher) and v.__module__ == module_name
                and type(getattr(v, "_cache", None)).__name__ == "FunctionCache"
                and v.targetoptions.get("inline") != "always"]
    except Exception:  # noqa: BLE001  numba internals changed: never an error, at worst a silent compile
        return None


def _in_cache(dispatcher) -> bool:
    """Whether *dispatcher* has machine code in this process or in numba's cache index (for this source); True
    when the probe fails (see :func:`_cached_dispatchers`)."""
    try:
        return bool(dispatcher.overloads) or bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001  numba internals changed: assume warm, never block on the check
        return True


def check_stages(stages) -> list[str]:
    """*stages* as a list if every one is a key of :data:`STAGES`; else an InputError naming the unknown ones."""
    if isinstance(stages, str):
        stages = [stages]
    stages = list(stages)
    bad = [s for s in stages if s not in STAGES]
    if bad:
        from ..errors import InputError

        raise InputError(f"stages must be among {list(STAGES)}; got {bad}")
    return stages


def cold_stages(stages=tuple(STAGES)) -> list[str]:
    """The stages among *stages* that numba would have to compile, in pipeline order: those with a module
    none of whose kernels is in the on-disk cache (a new install or upgrade; numba keys its cache by each
    source file). A module with some kernels cached has been run before: kernels of rarer paths compile
    when first needed."""
    stages = check_stages(stages)
    return [stage for stage, (_, modules) in STAGES.items() if stage in stages and any(map(_cold, modules))]


def _cold(module_name: str) -> bool:
    """Whether none of *module_name*'s kernels is in numba's cache (False when that cannot be told)."""
    dispatchers = _cached_dispatchers(module_name)
    return dispatchers is not None and not any(_in_cache(d) for d in dispatchers)


def estimate_seconds(stages, workers: int | None = None, load: float | None = None) -> float:
    """Wall seconds to compile *stages* on *workers* cores (default: this machine's) while other work
    keeps *load* processes busy (default: the 1-minute load average), from :data:`COMPILE_CPU_S`.

    Stages run as :func:`_compile_apart` runs them: each in its own process, all at once (on one core, one
    after the other, as :func:`warmup` then compiles them); every busy process (these and the *load*) gets an
    equal share of the cores, at most one core.
    """
    stages = check_stages(stages)
    workers = max(1, workers or os.cpu_count() or 1)
    if load is None:
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # not on this platform
            load = 0.0
    left = [COMPILE_CPU_S[s] for s in stages]  # CPU seconds left per running process
    if workers == 1:
        left = [sum(left)] if left else []
    wall = 0.0
    while left:
        share = min(1.0, workers / (len(left) + max(0.0, float(load))))
        step = min(left)
        wall += step / share
        left = [cpu - step for cpu in left if cpu > step]
    return wall


#: the garbage collector's thresholds while numba compiles (generation 0 from 700 allocations): numba's compiler
#: makes millions of short-lived objects, and each of the collector's passes walks every object that survived;
#: compiling the fill took 9.3 s instead of 9.9 with these (pairs alternated), and 8% less again with the
#: modules' objects frozen out of the passes (:func:`warm_stage`'s *whole_process*)
_COMPILE_GC_THRESHOLDS = (50_000, 50, 1_000)


@contextlib.contextmanager
def _fewer_collections():
    """Run the block with the collector's thresholds at :data:`_COMPILE_GC_THRESHOLDS` (then as they were)."""
    before = gc.get_threshold()
    gc.set_threshold(*_COMPILE_GC_THRESHOLDS)
    try:
        yield
    finally:
        gc.set_threshold(*before)


def warm_stage(stage: str, whole_process: bool = False) -> float:
    """Run *stage*'s warm-up here; returns its seconds. *whole_process*: this process exists to compile (the
    modules' objects are frozen out of the collector's passes once imported: :func:`gc.freeze`)."""
    _checked.update(STAGES)  # the stage's own calls must not start another warm-up
    t0 = time.perf_counter()
    with _fewer_collections():
        modules = [importlib.import_module(module) for module in STAGES[stage][0]]
        if whole_process:
            gc.freeze()
        for module in modules:
            module.warmup()
    return time.perf_counter() - t0


def _compile_apart(stages, say, t0: float, then=None) -> dict:
    """Compile *stages* in fresh interpreters, one per stage, all at once, each writing numba's on-disk cache
    (numba compiles one function at a time per process, and the stages share no kernel). More processes than
    cores is what keeps every core busy to the end: stages of unequal length grouped into one process per core
    left one core idle for the last seconds (on 2 cores, the three stages took 20.5-21.2 s apart against
    22.2-23.2 s grouped, alternated). *say* gets a line as each stage ends (seconds since *t0*), and *then*
    (None, or a callable taking the stage's name) is called with it then, here, while the others compile.
    Returns seconds per stage that succeeded; a stage that failed or could not start there is left to this
    process."""
    import queue
    import subprocess
    import threading

    lines: queue.Queue = queue.Queue()  # (stage, seconds) as each ends; None as each process ends

    def read(proc):
        for line in proc.stdout:
            stage, _, seconds = line.partition(" ")
            if stage in STAGES:
                lines.put((stage, float(seconds)))
        proc.wait()
        lines.put(None)

    running = 0
    for stage in stages:
        code = ("from pcdof.runtime.kernels import warm_stage\n"
                f"print({stage!r}, warm_stage({stage!r}, whole_process=True), flush=True)")
        try:
            proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True)
        except OSError:  # no processes here: compile in this process
            break
        threading.Thread(target=read, args=(proc,), daemon=True).start()
        running += 1
    seconds = {}
    while running:
        item = lines.get()
        if item is None:
            running -= 1
            continue
        seconds[item[0]] = item[1]
        say(f"  [{len(seconds)}/{len(stages)}] {item[0]} compiled ({time.perf_counter() - t0:.0f} s)")
        if then is not None:
            then(item[0])
    return seconds


def warmup(stages=tuple(STAGES), *, progress=None, processes: bool = False) -> dict:
    """Compile (or load from numba's cache) the kernels of *stages*; returns seconds per stage.

    Parameters
    ----------
    stages : iterable of keys of :data:`STAGES`
    progress : callable taking one line of text, or None; called as each stage starts and ends
    processes : bool, compile the stages that are not in numba's cache (:func:`cold_stages`) side by
        side in fresh interpreters first (numba compiles one function at a time per process), loading
        each here as it ends

    Returns
    -------
    dict, stage -> seconds (compiling and loading)
    """
    stages = check_stages(stages)
    say = progress or (lambda line: None)
    t0 = time.perf_counter()
    cold = cold_stages(stages) if processes and (os.cpu_count() or 1) > 1 else []
    loaded = {}  # stages compiled apart and loaded here as each ended (while the others still compiled)

    def load(stage):
        loaded[stage] = warm_stage(stage)

    apart = _compile_apart(cold, say, t0, then=load) if len(cold) > 1 else {}
    seconds = {}
    byte_compile()
    for i, stage in enumerate(stages, 1):
        if stage in loaded:
            seconds[stage] = apart[stage] + loaded[stage]
            continue
        if stage not in apart:
            say(f"  [{i}/{len(stages)}] {stage} ...")
        seconds[stage] = apart.get(stage, 0.0) + warm_stage(stage)
        if stage not in apart:
            say(f"  [{i}/{len(stages)}] {stage}: {seconds[stage]:.1f} s")
    return seconds


def byte_compile() -> bool:
    """Write the bytecode (``.pyc``) of pcdof's modules where it is missing or stale.

    Python writes it on import unless told not to (``PYTHONDONTWRITEBYTECODE``, which many container
    images set); then every process compiles each module it imports from source again: about 0.09 s of
    a one-shot ``pcdof render``. Returns False where some could not be written (a read-only install),
    which costs only that time.
    """
    import compileall

    return bool(compileall.compile_dir(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), quiet=2))


def ensure_warm(stream=None, *, stages=None) -> None:
    """Before running *stages* (default: every stage), compile those of them that are not in numba's
    cache, saying so on *stream* (default stderr): an estimate first, then a line as each stage is done.
    Each stage is checked once per process; silent and cheap (about a millisecond per stage) when the
    cache is warm."""
    todo = [s for s in (STAGES if stages is None else check_stages(stages)) if s not in _checked]
    if not todo:
        return
    _checked.update(todo)
    cold = cold_stages(todo)
    if not cold:
        return
    stream = sys.stderr if stream is None else stream

    def say(line):
        print(line, file=stream, flush=True)

    say(f"pcdof: compiling kernels, once after install: {', '.join(cold)} "
        f"(about {estimate_seconds(cold):.0f} s on {os.cpu_count() or 1} cores)")
    t0 = time.perf_counter()
    warmup(cold, progress=say, processes=True)
    say(f"pcdof: kernels compiled and cached in {time.perf_counter() - t0:.0f} s")
