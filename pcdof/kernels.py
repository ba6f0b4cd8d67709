"""The numba kernels of every stage: compiled once after install, and said so.

numba compiles each kernel the first time it runs and keeps the machine code in its on-disk
cache, so only the first run after an install (or an upgrade) pays for compiling, about half a
minute. :func:`ensure_warm` finds out, cheaply and before any work, whether that is about to
happen (a kernel with no entry in the cache index) and then compiles every stage with a line of
progress on stderr, so a new user sees why the first frame takes long; when the cache is warm it
prints nothing. ``pcdof warmup`` does the same ahead of time.
"""

from __future__ import annotations

import importlib
import os
import sys
import time

#: stage -> (module with its ``warmup()``, modules whose cached kernels it compiles)
STAGES = {
    "register": ("pcdof.register", ("pcdof.register",)),
    "fill": ("pcdof.fill", ("pcdof.fill",)),
    "render": ("pcdof.renderer", ("pcdof.renderer", "pcdof.tiles", "pcdof.lens", "pcdof.color")),
}

_checked = False


def _cached_dispatchers(module_name: str) -> list:
    """The numba dispatchers defined in *module_name* that are cached on disk and compiled on their own
    (inlined helpers are compiled into their callers)."""
    from numba.core.registry import CPUDispatcher

    module = importlib.import_module(module_name)
    return [v for v in vars(module).values()
            if isinstance(v, CPUDispatcher) and v.__module__ == module_name and v._cache.__class__.__name__
            == "FunctionCache" and v.targetoptions.get("inline") != "always"]


def _in_cache(dispatcher) -> bool:
    """Whether *dispatcher* has machine code in this process or in numba's cache index (for this source)."""
    if dispatcher.overloads:
        return True
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba internals changed: assume warm, never block on the check
        return True


def cold_stages() -> list[str]:
    """The stages numba would have to compile, in pipeline order: those with a module none of whose kernels
    is in the on-disk cache (a new install or upgrade; numba keys its cache by each source file). A module
    with some kernels cached has been run before: kernels of rarer paths compile when first needed."""
    return [stage for stage, (_, modules) in STAGES.items()
            if any(not any(_in_cache(d) for d in _cached_dispatchers(m)) for m in modules)]


def check_stages(stages) -> list[str]:
    """*stages* as a list if every one is a key of :data:`STAGES`; else an InputError naming the unknown ones."""
    stages = list(stages)
    bad = [s for s in stages if s not in STAGES]
    if bad:
        from .errors import InputError

        raise InputError(f"stages must be among {list(STAGES)}; got {bad}")
    return stages


def _warm_stage(stage: str) -> float:
    """Run *stage*'s warm-up here; returns its seconds."""
    global _checked
    _checked = True  # the stage's own calls must not start another warm-up
    t0 = time.perf_counter()
    importlib.import_module(STAGES[stage][0]).warmup()
    return time.perf_counter() - t0


def _compile_apart(stages, say) -> dict:
    """Compile *stages* side by side in fresh interpreters (numba compiles one function at a time per
    process, and the stages share no kernel), each writing numba's on-disk cache. Returns seconds per
    stage that succeeded; a stage that failed there is left to this process."""
    import subprocess

    procs = {}
    for stage in stages:
        code = f"from pcdof.kernels import _warm_stage; print(_warm_stage({stage!r}))"
        try:
            procs[stage] = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                                            stderr=subprocess.DEVNULL, text=True)
        except OSError:  # no processes here: compile in this process
            break
    seconds = {}
    for stage, proc in procs.items():
        out, _ = proc.communicate()
        if proc.returncode == 0:
            seconds[stage] = float(out.split()[-1])
            say(f"  [{len(seconds)}/{len(stages)}] {stage}: {seconds[stage]:.1f} s")
    return seconds


def warmup(stages=tuple(STAGES), *, progress=None, processes: bool = False) -> dict:
    """Compile (or load from numba's cache) the kernels of *stages*; returns seconds per stage.

    *progress*, if given, is called with one line of text as each stage starts and ends.
    *processes*: compile the stages that are not in numba's cache (:func:`cold_stages`) side by side
    in fresh interpreters first (numba compiles one function at a time per process), then load them here.
    """
    stages = check_stages(stages)
    say = progress or (lambda line: None)
    cold = [s for s in cold_stages() if s in stages] if processes and (os.cpu_count() or 1) > 1 else []
    apart = _compile_apart(cold, say) if len(cold) > 1 else {}
    seconds = {}
    for i, stage in enumerate(stages, 1):
        if stage not in apart:
            say(f"  [{i}/{len(stages)}] {stage} ...")
        seconds[stage] = apart.get(stage, 0.0) + _warm_stage(stage)
        if stage not in apart:
            say(f"  [{i}/{len(stages)}] {stage}: {seconds[stage]:.1f} s")
    return seconds


def ensure_warm(stream=None) -> None:
    """Once per process: when some kernel is not in numba's cache, compile every such stage now, saying so on
    *stream* (default stderr). Silent and cheap (a few milliseconds, once) when the cache is warm."""
    global _checked
    if _checked:
        return
    _checked = True
    cold = cold_stages()
    if not cold:
        return
    stream = sys.stderr if stream is None else stream

    def say(line):
        print(line, file=stream, flush=True)

    say(f"pcdof: compiling kernels, once after install (about 10-20 s per stage): {', '.join(cold)}")
    t0 = time.perf_counter()
    warmup(cold, progress=say, processes=True)
    say(f"pcdof: kernels compiled and cached in {time.perf_counter() - t0:.0f} s")
