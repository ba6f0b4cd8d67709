"""The expected displayed error of a blurred clipped channel, and the levels that minimise it.

The blob's true radiance is unknown; over the prior's quadrature levels (:func:`prior_levels`) the level
chosen minimises the expected sum of squared differences of the display (linear light clipped at white,
sRGB-encoded: :func:`display`) from the truth (:func:`expected_best_level`), for many footprints at once
(:func:`levels_of`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: radiance levels of the prior's quadrature (log-spaced midpoints)
PRIOR_SAMPLES = 32


def disc_kernel(diameter_px: float, *, supersample: int = 4) -> np.ndarray:
    """A uniform disc of *diameter_px*, each cell weighted by its covered area (supersampled), sum 1.
    (n, n) float32, n odd; a single 1 below 1 px."""
    r = float(diameter_px) / 2
    n = 2 * int(math.ceil(r - 0.5)) + 1 if r > 0.5 else 1
    sub = (np.arange(n * supersample) + 0.5) / supersample - n / 2
    inside = sub[:, None] ** 2 + sub[None, :] ** 2 <= max(r, 0.5) ** 2
    k = inside.reshape(n, supersample, n, supersample).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


@functools.lru_cache(maxsize=256)
def cached_disc(diameter_px: float) -> np.ndarray:
    """:func:`disc_kernel`, read-only and kept: a blob's channels, and blobs at one depth, share their kernel."""
    k = disc_kernel(diameter_px)
    k.flags.writeable = False
    return k


#: what white shows (:func:`display` of 1), computed as it computes it
_WHITE = 1.055 * np.power(np.float64(1.0), 1 / 2.4) - 0.055


def display(linear):
    """What a pixel shows: linear light clipped at white, sRGB-encoded (the scale the loss is taken on)."""
    return _display_in_place(np.clip(linear, 0.0, 1.0))


def _display_in_place(v):
    """:func:`display` of *v* (float64 ndarray) already clipped to [0, 1], written over *v* (a temporary:
    fresh arrays of a blob batch's size cost more than the arithmetic). The values are the plain formula's: the
    curve's of every value (at 1 it gives :data:`_WHITE`, as white is defined), the linear segment put back (where
    some value lies on it)."""
    if v.min(initial=1.0) > 0.0031308:  # (none on the linear segment: most tables)
        np.power(v, 1 / 2.4, out=v)
        v *= 1.055
        v -= 0.055
        return v
    low = v <= 0.0031308
    linear = v[low] * 12.92
    np.power(v, 1 / 2.4, out=v)
    v *= 1.055
    v -= 0.055
    v[low] = linear
    return v


def prior_levels(clip_level: float, prior_max: float, n: int = PRIOR_SAMPLES) -> np.ndarray:
    """Quadrature of the log-uniform prior over [clip_level, prior_max]: *n* log-spaced midpoints (equal weight)."""
    return cached_prior_levels(float(clip_level), float(prior_max), int(n)).copy()


@functools.lru_cache(maxsize=256)
def cached_prior_levels(clip_level: float, prior_max: float, n: int) -> np.ndarray:
    """:func:`prior_levels`, read-only and kept: most blobs' channels share one prior."""
    lo, hi = math.log(clip_level), math.log(max(prior_max, clip_level))
    levels = np.exp(lo + (np.arange(n) + 0.5) / n * (hi - lo))
    levels.flags.writeable = False
    return levels


def expected_best_level(base, k, weight, levels, keep: float, level_weights=None) -> float:
    """The radiance that minimises the expected displayed error of one blurred channel.

    Parameters
    ----------
    base : (N,) float, the blurred light at N output pixels without the blob's clipped pixels
    k : (N,) float, the blob's clipped pixels blurred (its share of each output pixel)
    weight : (N,) float, pixels each sample stands for
    levels : (T,) float, possible true radiances (the prior's quadrature levels)
    keep : float, the level of not raising the blob (its clipped value)
    level_weights : (T,) float >= 0, their probabilities (None: equally likely)

    Returns
    -------
    float, the candidate (*keep* or one of *levels*) with the least expected sum of squared
    differences of :func:`display` from the truth; ties go to the lowest, so a blob whose output
    stays white (or unchanged) whatever its radiance is not raised.
    """
    base, k, weight = (np.asarray(a, np.float64).ravel() for a in (base, k, weight))
    levels = np.asarray(levels, np.float64).ravel()
    p = np.full(len(levels), 1.0 / len(levels)) if level_weights is None else level_weights / level_weights.sum()
    return chosen_levels([(base, k, weight, np.concatenate(([keep], levels)), np.asarray(p, np.float64))])[0]


def best_levels(base, k, weight, starts, cands, probs) -> np.ndarray:
    """:func:`expected_best_level` of J footprints at once: *base*, *k*, *weight* (N,) float64 hold their
    samples one after another (footprint j: samples starts[j]:starts[j + 1], none empty); *cands* (J, 1 + T):
    keep, then the levels; *probs* (J, T), rows summing to 1. Returns (J,) float64, the chosen candidates."""
    counts = np.diff(starts)
    table = np.repeat(cands.T, counts, axis=1)  # (1 + T, N): row 0 keep, rows 1.. the truths
    table *= k
    table += base
    shown = _display_in_place(np.clip(table, 0.0, 1.0, out=table))
    # E_t sum_n w (s_c - s_t)^2 = a2_c - 2 sum_n w s_c E_t[s_t] + E_t[a2_t]: the square is linear in the
    # truths once expanded, so no table of every candidate against every truth (T times the work). einsum and
    # reduceat, not a BLAS product: one thread, and the same sums on every machine
    if (probs[1:] == probs[0]).all():  # (one prior for every footprint, ``prior``'s: its T weights, not N T)
        mean_shown = mean_over_truths(probs[0], shown[1:])
    else:
        mean_shown = np.einsum("tn,tn->n", np.repeat(probs.T, counts, axis=1), shown[1:])
    first = starts[:-1]
    if weight.min(initial=1.0) == 1.0 == weight.max(initial=1.0):  # (most batches: w s is s, bit for bit)
        cross = np.add.reduceat(shown * mean_shown, first, axis=1)
        a2 = np.add.reduceat(np.multiply(shown, shown, out=shown), first, axis=1)  # (1 + T, J)
    else:
        ws = shown * weight
        a2 = np.add.reduceat(np.multiply(ws, shown, out=shown), first, axis=1)
        cross = np.add.reduceat(np.multiply(ws, mean_shown, out=ws), first, axis=1)
    expected = a2 - 2 * cross + np.einsum("jt,tj->j", probs, a2[1:])
    # the first candidate within rounding of the least (the expanded square leaves ~1e-12 noise)
    near = expected <= expected.min(axis=0) + 1e-7 * np.maximum(np.add.reduceat(weight, first), 1.0)
    return cands[np.arange(len(cands)), np.argmax(near, axis=0)]


def mean_over_truths(probs, shown):
    """sum_t probs[t] shown[t, n]: (N,) float64 from *probs* (T,) and *shown* (T, N) float64, the sums of
    ``np.einsum("tn,tn->n", probs (T, N) repeated over n, shown)`` bit for bit: both accumulate over t in order,
    one multiply-add per truth and sample."""
    return np.einsum("t,tn->n", probs, shown)


def normalised(weights):
    """*weights* (T,) as probabilities (summing to 1)."""
    return weights / weights.sum()


@functools.lru_cache(maxsize=8)
def uniform_probabilities(n: int) -> np.ndarray:
    """n equal probabilities, as :func:`normalised` gives them (read-only, kept)."""
    p = normalised(np.ones(n))
    p.flags.writeable = False
    return p


def _batches(items, sizes, cap: int):
    """*items* in consecutive lists whose *sizes* add up to at most *cap* (or one item larger than that)."""
    batch, n = [], 0
    for item, size in zip(items, sizes):
        if batch and n + size > cap:
            yield batch
            batch, n = [], 0
        batch.append(item)
        n += size
    if batch:
        yield batch


def chosen_levels(problems, max_samples: int = 8192) -> list:
    """The chosen candidate of each (base, k, weight, candidates, probabilities) problem (:func:`levels_of`)."""
    chosen = [float(p[3][0]) for p in problems]
    for t in sorted({len(p[3]) for p in problems}):  # (one level grid size in a batch; every blob's is T)
        todo = [i for i, p in enumerate(problems) if len(p[3]) == t]
        base, k, weight = (np.concatenate([np.asarray(problems[i][j], np.float64) for i in todo]) for j in range(3))
        levels = levels_of(base, k, weight, np.array([problems[i][0].size for i in todo]),
                            np.array([problems[i][3] for i in todo]), np.array([problems[i][4] for i in todo]),
                            max_samples)
        for i, level in zip(todo, levels):
            chosen[i] = level
    return chosen


def levels_of(base, k, weight, counts, cands, probs, max_samples: int = 8192, threads: int | None = None) -> list:
    """The chosen candidate of J footprints whose samples (*base*, *k*, *weight* (N,) float64) lie one after
    another, *counts* (J,) of them each; *cands* (J, 1 + T), *probs* (J, T): :func:`best_levels` in batches of
    about *max_samples* samples, so its (1 + T, N) tables stay about 2 MB (4096 samples: about 10 % slower, 16384
    no faster). A footprint of no samples keeps its value (candidate 0). Returns a list of J floats.

    The batches are independent: with *threads* > 1 (None: numba's count for this thread) they are shared out
    among that many threads (:func:`pcdof.runtime.tasks.map_on_threads`; numpy's arithmetic releases the GIL),
    each batch's values the same: the 1920x1080 refocus's highlights stage on two threads 61 -> 54 ms."""
    chosen = cands[:, 0].tolist()
    ends = np.cumsum(counts).tolist()
    todo = np.flatnonzero(counts).tolist()
    batches = list(_batches(todo, [int(counts[i]) for i in todo], max_samples))

    def solve(batch):
        a, b = ends[batch[0]] - int(counts[batch[0]]), ends[batch[-1]]
        starts = np.concatenate(([0], np.cumsum(counts[batch])))
        return best_levels(base[a:b], k[a:b], weight[a:b], starts, cands[batch], probs[batch])

    from ...runtime.tasks import map_on_threads
    from ...runtime.threads import current_threads

    threads = current_threads() if threads is None else threads
    for batch, levels in zip(batches, map_on_threads(solve, batches, threads)):
        for i, level in zip(batch, levels.tolist()):
            chosen[i] = level
    return chosen
