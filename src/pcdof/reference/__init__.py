"""Plain reference implementations of the pipeline's stages: the specification the fast paths are tested against.

One module per stage, each whole-frame numpy/Python code that states its rule directly (no numba,
no tiles, no reduced resolution, no threads). They are slow on purpose and meant for small frames:
``tests/test_reference.py`` compares every fast path of :mod:`pcdof.stages.register`, :mod:`pcdof.stages.fill`,
:mod:`pcdof.lens` and :mod:`pcdof.renderer` with them, each within its stated tolerance.

- :mod:`pcdof.stages.register.reference`: depth into the colour camera (per-triangle z-buffer; kept with its stage)
- :mod:`pcdof.stages.fill.reference`: directional hole filling, per hole pixel (kept with its stage)
- :mod:`pcdof.stages.coc.reference`: thin-lens signed circle of confusion; the seed paper's eq. 1 / eq. 2 weights
  (kept with its stage)
- :mod:`pcdof.reference.render`: physical renderer (exact per-source scatter, layered compositing) and the
  seed paper's method
"""
