"""Test-session settings."""

import os

# The pipeline lowers its thread count while other processes keep cores busy (pcdof.runtime.threads.threads_for_load).
# Results do not depend on it (tests/test_threads_under_load.py checks that and the adaptation itself), but some
# tests check what a frame does on two threads (the colour side's worker), and a test run shares its machine:
# keep every run on the thread count numba was given.
os.environ.setdefault("PCDOF_ADAPT_THREADS", "0")

# The pcdof command sets numba's threading-layer order (pcdof.runtime.process.tune_process); a test session
# imports pcdof as a library, which tunes nothing: give numba the same order here, so Open3D's older bundled TBB
# does not make numba warn in every test that loads both.
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")
