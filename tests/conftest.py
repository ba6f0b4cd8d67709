"""Test-session settings."""

import os

# The pcdof command sets numba's threading-layer order (pcdof.runtime.process.tune_process); a test session
# imports pcdof as a library, which tunes nothing: give numba the same order here, so Open3D's older bundled TBB
# does not make numba warn in every test that loads both.
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")
