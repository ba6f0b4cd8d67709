"""The machine's thread bounds (:mod:`pcdof.bench.machine`): its loops compute what they say, and the rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcdof.bench import machine
from pcdof.bench.speed import thread_counts
from pcdof.errors import InputError


@pytest.mark.parametrize("n_threads", [1, 2])
def test_the_streaming_loop_writes_its_formula_on_any_thread_count(n_threads):
    a = np.random.default_rng(1).random(3 * machine.STREAM_TASK + 17, dtype=np.float32)  # a partial last task
    b = np.full_like(a, np.nan)
    machine.stream(a, b, n_threads)
    np.testing.assert_array_equal(b, a * np.float32(1.5) + np.float32(1.0))


@pytest.mark.parametrize("n_threads", [1, 2])
def test_the_arithmetic_loop_is_its_recurrence(n_threads):
    out = machine.arithmetic(np.full(5, np.nan), 50, n_threads)
    for i in range(5):
        x = 0.0
        for j in range(50):
            x = x * 0.999999 + math.sin(j * 1e-3 + i)
        assert out[i] == pytest.approx(x, rel=1e-12)


def test_rows_one_per_count_and_speedups_over_the_fewest():
    rows = machine.thread_bounds(megabytes=2.0, steps=100, repeats=1)
    assert [r["threads"] for r in rows] == thread_counts()
    assert rows[0]["arithmetic_speedup"] == rows[0]["stream_speedup"] == 1.0
    for r in rows:
        assert r["arithmetic_ms"] > 0 and r["stream_ms"] > 0
        assert r["stream_speedup"] == pytest.approx(rows[0]["stream_ms"] / r["stream_ms"])


@pytest.mark.parametrize("kwargs, name", [
    ({"counts": [0]}, "counts"), ({"counts": []}, "counts"), ({"counts": "1,2"}, "counts"),
    ({"counts": [10_000]}, "counts"), ({"counts": [True]}, "counts"),
    ({"megabytes": 0}, "megabytes"), ({"megabytes": float("nan")}, "megabytes"), ({"megabytes": "1"}, "megabytes"),
    ({"steps": 0}, "steps"), ({"repeats": 0}, "repeats"), ({"repeats": 1.5}, "repeats"),
])
def test_bad_arguments_are_refused_naming_the_argument(kwargs, name):
    with pytest.raises(InputError, match=f"^{name} must"):
        machine.thread_bounds(**kwargs)
