"""Compile every GPU kernel for a real device, on a machine without a GPU.

    pip install pcdof[gpu]            # numba-cuda with the CUDA 12 compiler wheels (NVVM, NVRTC)
    python scripts/gpu_compile_check.py --cc 9.0

The simulator tests (``tests/test_gpu_simulator.py``) run the kernels' Python source, which the CUDA compiler
may still refuse (a construct numba's CUDA target does not type). This script closes that gap without a GPU:

1. a child process runs the simulator tests with every kernel launch recorded (the kernel and the types of its
   arguments: array dtype, dimensions and layout, scalar types);
2. this process compiles each recorded kernel, with the device functions it calls, to PTX for compute
   capability ``--cc`` (:func:`numba.cuda.compile_ptx`), and prints what failed.

Device functions are compiled for the current device's compute capability, which needs a driver; here, without
one, the lookup is answered with ``--cc``. Exit status 0 when every signature compiled.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_RECORDER = r'''
import json, sys
import numpy as np
from numba.cuda.simulator import kernel as K
from numba.cuda.simulator.cudadrv.devicearray import FakeCUDAArray

seen = {}
launch = K.FakeCUDAKernel.__call__


def describe(a):
    a = a._ary if isinstance(a, FakeCUDAArray) else a
    if isinstance(a, np.ndarray):
        return ["array", a.dtype.name, a.ndim, "C" if a.flags.c_contiguous else "A"]
    if isinstance(a, (bool, np.bool_)):
        return ["scalar", "boolean"]
    if isinstance(a, (int, np.integer)):
        return ["scalar", "int64"]
    if isinstance(a, np.float32):
        return ["scalar", "float32"]
    if isinstance(a, (float, np.floating)):
        return ["scalar", "float64"]
    return ["other", type(a).__name__]


def recording(self, *args):
    if not self._device:
        seen[(self.fn.__module__, self.fn.__name__, json.dumps([describe(a) for a in args]))] = 1
    return launch(self, *args)


K.FakeCUDAKernel.__call__ = recording
import pytest
rc = pytest.main(["-q", "-p", "no:cacheprovider", "-k", "not no_gpu and not parent", sys.argv[2]])
with open(sys.argv[1], "w") as f:
    json.dump([[m, n, json.loads(s)] for (m, n, s) in seen], f)
sys.exit(int(rc))
'''


def record(path: str) -> list:
    """The kernels launched by the simulator tests, with their argument types (runs them in a child)."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1",
           "PYTHONPATH": os.pathsep.join([os.path.join(ROOT, "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", _RECORDER, path, os.path.join(ROOT, "tests", "test_gpu_simulator.py")],
                          env=env, cwd=ROOT)
    if proc.returncode != 0:
        raise SystemExit(f"the simulator tests failed (exit {proc.returncode}); fix them first")
    with open(path) as f:
        return json.load(f)


def compile_all(signatures: list, cc: tuple[int, int]) -> int:
    """Compile each (module, kernel, argument types) to PTX for *cc*; returns the number that failed."""
    try:  # numba-cuda's hook, which its .pth file runs at start-up when installed in site-packages
        import _numba_cuda_redirector  # noqa: F401
    except ImportError:
        pass
    from numba import cuda, types
    import numba.cuda.dispatcher as dispatcher

    class _Device:  # device functions ask the current device for its compute capability; none here
        compute_capability = cc

    dispatcher.get_current_device = lambda: _Device()

    def typed(d):
        if d[0] == "array":
            return types.Array(getattr(types, d[1]), d[2], d[3])
        return getattr(types, d[1])

    failed = 0
    for module, name, args in signatures:
        kernel = getattr(importlib.import_module(module), name)
        try:
            cuda.compile_ptx(kernel.py_func, tuple(typed(a) for a in args), cc=cc)
            print(f"ok      {module}.{name}{tuple(a[1] for a in args)}")
        except Exception as err:  # noqa: BLE001 - report every kernel
            failed += 1
            print(f"FAILED  {module}.{name}: {type(err).__name__}: {str(err)[:2000]}")
    return failed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cc", default="9.0", help="compute capability to compile for, e.g. 8.0 or 9.0")
    args = p.parse_args(argv)
    cc = tuple(int(x) for x in args.cc.split("."))
    sys.path.insert(0, os.path.join(ROOT, "src"))
    with tempfile.TemporaryDirectory() as tmp:
        signatures = record(os.path.join(tmp, "signatures.json"))
    failed = compile_all(signatures, cc)
    print(f"{len(signatures) - failed} of {len(signatures)} kernel signatures compiled for compute capability "
          f"{cc[0]}.{cc[1]}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
