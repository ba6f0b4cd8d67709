"""Kernels compiled ahead of time, so that a process rendering one frame does not load numba's cache.

numba keeps each compiled kernel in its on-disk cache, but loading one is not free: the first load sets
up numba's typing and target registries, and each kernel's machine code is then unpacked and linked:
about 0.25 s for the 25 kernels a frame runs, half of a one-shot ``pcdof render``. numba's ahead-of-time
compiler (``numba.pycc``) builds the same kernels, with the signatures the stage warm-ups compile (and the
paths a stage leaves out of its warm-up to spare a first frame the compile: its ``warmup_ahead()``), into one
extension module, which loads in a millisecond.

Its functions run on one thread (it compiles ``prange`` loops as plain loops; kernels marked ``nogil``
still release the GIL) and give the same answer as numba's kernels up to floating-point reassociation
(kernels marked ``fastmath``). A process chooses them with :func:`activate`, which puts an
:class:`AheadKernel` in place of each numba dispatcher it covers; a call with argument types other than
the compiled ones goes on to numba's dispatcher, so nothing fails. Which processes do so is decided by
:func:`pcdof.plans.compiled_ahead` (one frame, up to a size where one thread still wins).

:func:`build` makes the module (``pcdof warmup`` runs it where a C compiler is found; about 25 s). It is
named by a fingerprint of the kernels' sources and of the Python, numpy, numba and llvmlite versions,
so an edited or upgraded install is never served old code: :func:`activate` then finds nothing and
numba's kernels run, until the next warm-up builds it again.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import logging
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

logger = logging.getLogger(__name__)

#: modules whose kernels are compiled ahead of time: every stage's (see :data:`pcdof.kernels.STAGES`)
MODULES = ("pcdof.register", "pcdof.distortion", "pcdof.fill", "pcdof.stages.render.classify",
           "pcdof.stages.render.scatter", "pcdof.stages.render.composite", "pcdof.stages.render.extend",
           "pcdof.stages.render.uniform", "pcdof.stages.render.grids", "pcdof.stages.render.ownership",
           "pcdof.stages.render.tiles", "pcdof.lens", "pcdof.color")

_PACKAGE = Path(__file__).resolve().parent
_PREFIX = "pcdof_ahead_"

#: (module, name, dispatcher) of every kernel :func:`activate` replaced, to put back
_replaced: list = []


class AheadKernel:
    """A kernel compiled ahead of time, called like the numba dispatcher it stands in for.

    *variants*: (argtypes, function) pairs, the numba type names of the arguments each compiled *function* takes
    (one per signature the warm-ups compiled); *dispatcher*: numba's. A call with other argument types (another
    dtype, a non-contiguous or writeable array where a read-only contiguous one was compiled) goes to
    *dispatcher*.
    """

    __slots__ = ("variants", "dispatcher", "_known")

    def __init__(self, variants, dispatcher):
        self.variants = [(tuple(argtypes), function) for argtypes, function in variants]
        self.dispatcher = dispatcher
        self._known = {}  # argument types (numba types) -> the function compiled for them, as calls find them

    @property
    def py_func(self):
        return self.dispatcher.py_func

    def __call__(self, *args):
        from numba import typeof
        from numba.core.typing.typeof import Purpose

        types = tuple(typeof(a, Purpose.argument) for a in args)
        function = self._known.get(types)
        if function is None:
            names = tuple(map(str, types))
            function = next((f for argtypes, f in self.variants if argtypes == names), None)
            if function is None:
                logger.debug("%s: arguments %s, compiled ahead for %s; numba's kernel runs it",
                             self.dispatcher.py_func.__qualname__, list(names), [list(a) for a, _ in self.variants])
                return self.dispatcher(*args)
            self._known[types] = function
        return function(*args)

    def __repr__(self) -> str:
        return f"AheadKernel({self.dispatcher.py_func.__module__}.{self.dispatcher.py_func.__qualname__})"


def fingerprint() -> str:
    """A hex digest of what the compiled module depends on: the source of every pcdof module defining
    numba kernels, and the Python, numpy, numba and llvmlite versions and the machine's architecture."""
    import llvmlite
    import numba
    import numpy

    digest = hashlib.sha256()
    for part in (sys.version, platform.machine(), numpy.__version__, numba.__version__, llvmlite.__version__):
        digest.update(part.encode() + b"\0")
    for path in sorted(_PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if b"@njit" in text:  # the modules that define kernels (this one only names them)
            digest.update(path.relative_to(_PACKAGE).as_posix().encode() + b"\0" + text + b"\0")
    return digest.hexdigest()


def cache_dir() -> Path:
    """Where the module is kept: ``$PCDOF_CACHE_DIR``; else ``$NUMBA_CACHE_DIR/pcdof`` (beside numba's cache);
    else the package's ``__pycache__`` where it is writable (as numba's default); else ``~/.cache/pcdof``."""
    if os.environ.get("PCDOF_CACHE_DIR"):
        return Path(os.environ["PCDOF_CACHE_DIR"])
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "pcdof"
    local = _PACKAGE / "__pycache__"
    if os.access(local if local.is_dir() else _PACKAGE, os.W_OK):
        return local
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pcdof"


def _paths(digest: str) -> tuple[Path, Path]:
    """The module's file and its manifest (JSON) for fingerprint *digest*."""
    name = _PREFIX + digest[:20]
    folder = cache_dir()
    return folder / (name + importlib.machinery.EXTENSION_SUFFIXES[0]), folder / (name + ".json")


def _names(code) -> set:
    """The global names *code* and the code nested in it read."""
    names = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            names |= _names(const)
    return names


def _entry_kernels(modules=MODULES) -> list:
    """(module, name, dispatcher) of every cached numba kernel of *modules* that Python code calls and that is
    still numba's in this process (other kernels' callees are compiled into their callers)."""
    from .kernels import _cached_dispatchers

    found = [(m, d.py_func.__name__, d) for m in modules for d in _cached_dispatchers(m)]
    every = [d for _, _, d in found] + [v.dispatcher for m in modules for v in
                                        vars(importlib.import_module(m)).values() if isinstance(v, AheadKernel)]
    called = {id(v) for d in every for n in _names(d.py_func.__code__) if (v := d.py_func.__globals__.get(n)) is not None}
    return [(m, name, d) for m, name, d in found if id(d) not in called]


@contextlib.contextmanager
def _each_with_its_options(dispatchers: dict):
    """numba.pycc compiles every export with one set of flags; this compiles each with its kernel's own options
    (fastmath, error model, nogil, boundscheck), less ``parallel`` (pycc has no threading layer)."""
    import numba.pycc.compiler as pycc_compiler
    from numba.core.compiler import Flags

    plain = pycc_compiler.compile_extra

    def compile_extra(typingctx, targetctx, func, args, return_type, flags, locals, library):
        dispatcher = dispatchers[func]
        own = Flags()
        options = {k: v for k, v in dispatcher.targetoptions.items() if k != "parallel"}
        dispatcher.targetdescr.options.parse_as_flags(own, options)
        own.no_compile, own.nrt = flags.no_compile, flags.nrt
        own.no_cpython_wrapper, own.no_cfunc_wrapper = flags.no_cpython_wrapper, flags.no_cfunc_wrapper
        return plain(typingctx, targetctx, func, args, return_type, own, locals=locals, library=library)

    pycc_compiler.compile_extra = compile_extra
    try:
        yield
    finally:
        pycc_compiler.compile_extra = plain


def build(progress=None) -> Path | None:
    """Compile every stage's kernels ahead of time into the module :func:`activate` loads.

    The stages' warm-ups run first (numba compiles or loads each kernel, with the signature a frame uses).
    *progress*: callable taking one line of text, or None. Returns the module's path, or None where it
    cannot be built here (no C compiler, or numba without ``pycc``), saying why on *progress*. Written
    atomically; older builds in the folder are removed.
    """
    say = progress or (lambda line: None)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pycc's pending-deprecation notice
            from numba.pycc import CC
    except ImportError as err:
        say(f"  kernels ahead of time: not built (this numba has no pycc: {err})")
        return None
    from .kernels import STAGES, warmup

    warmup()
    for module in {m for warm, _ in STAGES.values() for m in warm}:  # paths too slow to compile at a first frame
        getattr(importlib.import_module(module), "warmup_ahead", lambda: None)()
    digest = fingerprint()
    target, manifest = _paths(digest)
    entries = [(m, name, d, sig) for m, name, d in _entry_kernels() for sig in d.nopython_signatures]
    t0 = time.perf_counter()
    say(f"  kernels ahead of time: compiling {len(entries)} ...")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        folder = tempfile.TemporaryDirectory(dir=target.parent, prefix=".build-")
    except OSError as err:
        say(f"  kernels ahead of time: not built (cannot write {target.parent}: {err.strerror or err})")
        return None
    with folder as tmp:
        cc = CC(target.name.split(".")[0])
        cc.output_dir, cc.output_file, cc.verbose = tmp, target.name, False
        exports = []
        for i, (module, name, dispatcher, signature) in enumerate(entries):
            cc.export(f"k{i}", signature)(dispatcher.py_func)
            exports.append({"module": module, "name": name, "export": f"k{i}",
                            "argtypes": [str(t) for t in signature.args]})
        try:
            with _each_with_its_options({d.py_func: d for _, _, d, _ in entries}), open(os.devnull, "w") as quiet, \
                    contextlib.redirect_stdout(quiet):
                cc.compile()
        except Exception as err:  # no C compiler or linker, or a toolchain numba cannot drive
            say(f"  kernels ahead of time: not built ({type(err).__name__}: {' '.join(str(err).split())[:200]})")
            return None
        built = Path(tmp) / target.name
        note = Path(tmp) / manifest.name
        note.write_text(json.dumps({"fingerprint": digest, "exports": exports}, indent=1))
        for old in target.parent.glob(_PREFIX + "*"):
            if old.name not in (target.name, manifest.name):
                with contextlib.suppress(OSError):
                    old.unlink()
        os.replace(built, target)
        os.replace(note, manifest)  # last: a module without its manifest is never used
    say(f"  kernels ahead of time: {len(entries)} compiled in {time.perf_counter() - t0:.0f} s")
    return target


def available() -> bool:
    """Whether a module built for this install's kernels and versions is in :func:`cache_dir`."""
    target, manifest = _paths(fingerprint())
    return target.is_file() and manifest.is_file()


def active() -> bool:
    """Whether :func:`activate` has put kernels compiled ahead of time in place in this process."""
    return bool(_replaced)


def covers(module: str) -> bool:
    """Whether every kernel of *module* that Python code calls is compiled ahead of time in this process
    (then numba need not compile or load that module's kernels)."""
    return module in {m for m, _, _ in _replaced} and not _entry_kernels((module,))


def activate() -> bool:
    """Put the kernels compiled ahead of time in place of numba's, for the rest of this process (or until
    :func:`deactivate`). Returns whether they are in place: False where no module matches this install."""
    if _replaced:
        return True
    target, manifest = _paths(fingerprint())
    if not (target.is_file() and manifest.is_file()):
        return False
    try:
        exports = json.loads(manifest.read_text())["exports"]
        spec = importlib.util.spec_from_file_location(target.name.split(".")[0], target)
        library = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(library)
    except (OSError, ImportError, ValueError, KeyError) as err:  # unreadable or damaged: numba's kernels run
        logger.warning("kernels compiled ahead of time not used (%s: %s); run 'pcdof warmup' to build them again",
                       type(err).__name__, err)
        return False
    variants: dict = {}  # (module, name) -> [(argtypes, function)]
    for item in exports:
        variants.setdefault((item["module"], item["name"]), []).append((item["argtypes"],
                                                                         getattr(library, item["export"])))
    for (module_name, name), found in variants.items():
        module = importlib.import_module(module_name)
        dispatcher = getattr(module, name, None)
        if dispatcher is None or isinstance(dispatcher, AheadKernel):
            continue
        setattr(module, name, AheadKernel(found, dispatcher))
        _replaced.append((module_name, name, dispatcher))
    return bool(_replaced)


def deactivate() -> None:
    """Put numba's kernels back where :func:`activate` replaced them."""
    while _replaced:
        module, name, dispatcher = _replaced.pop()
        setattr(importlib.import_module(module), name, dispatcher)
