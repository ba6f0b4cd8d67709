"""The fill's colour vote skips a nearer surface only when it cannot win: its score, every colour similarity 1
(:func:`pcdof.stages.fill.surfaces.support_bound`), is no more than the best so far. The bound holds bit for bit
(the score's terms are rounded alike and summed in the same order), so the fill is the one that samples every surface;
``tests/test_reference.py`` compares the whole fill with the per-pixel reference."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.stages.fill.surfaces import support_bound


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), m=st.integers(1, 16), support=st.floats(0.5, 80.0))
def test_no_score_exceeds_the_bound(seed, m, support):
    rng = np.random.default_rng(seed)
    r = rng.random(m) * 100 + 1e-3
    order = rng.permutation(m)
    start = int(rng.integers(0, m))
    end = int(rng.integers(start + 1, m + 1))
    sims = rng.random(m)
    sims[rng.random(m) < 0.3] = 1.0  # exact matches give the largest similarity
    score = 0.0
    for i in range(start, end):  # as pcdof.stages.fill.surfaces.choose_surface sums it
        score += sims[order[i]] / (r[order[i]] + support)
    bound = support_bound(r, order, start, end, support)
    assert score <= bound
    for bias in (1.0, 6.0, 36.0):
        assert score / bias <= bound / bias
