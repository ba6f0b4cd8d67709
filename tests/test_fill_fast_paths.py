"""The fill's fast paths against the plain formulations they replace, bit for bit, on random inputs.

* the colour vote: the farthest surface's support summed only until it reaches what any nearer surface can
  score, the nearer surfaces' bounds computed once, the winner's depth interpolated once (against the vote
  that samples every surface it cannot rule out, and interpolates each one it scores);
* the candidates' sort: ranks counted (against an insertion sort);
* the index: one pass, the known range on the bits (against numpy);
* the speckle pass: neighbours sorted only at a speckle (against sorting every hole's);
* the depth's conversion for the kernels (against :func:`pcdof.camera.as_depth_m` and a copy).
"""

from __future__ import annotations


import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit

from pcdof.camera import as_depth_m
from pcdof.runtime.kernels import read_only
from pcdof.runtime.threads import numba_threads
from pcdof.stages.fill import (BORDER, BORDER_RULES, DEFAULT_BACKGROUND_BIAS, DEFAULT_BORDER, DEFAULT_EDGE_RATIO,
                               DEFAULT_SIGMA_COLOR, LOST, SURFACE)
from pcdof.stages.fill.boundary import fit_boundary, sweep
from pcdof.stages.fill.cleanup import despeckle
from pcdof.stages.fill.combine import combine
from pcdof.stages.fill.index import index_depth
from pcdof.stages.fill.inputs import color_for_kernel, prepare
from pcdof.stages.fill.rules import DIRS, FIT_RADIUS_STEPS, HALF, HOLE, Boundary, Holes, kernel_rules
from pcdof.stages.fill.surfaces import border_inv, collect_candidates, sort_far_to_near, support_bound
from pcdof.stages.fill.surfaces import color_sim  # the similarity itself is unchanged

# ---------------------------------------------------------------------------------------------
# the plain formulations


@njit
def _plain_idw(iv, r, past, order, start, end):
    """IDW on 1/z of candidates order[start:end]; on their past values when every one has one."""
    all_past = True
    for i in range(start, end):
        if past[order[i]] < 0.0:
            all_past = False
    sw = 0.0
    swi = 0.0
    for i in range(start, end):
        j = order[i]
        sw += 1.0 / r[j]
        swi += (past[j] if all_past else iv[j]) / r[j]
    return swi / sw


@njit
def _plain_choose_surface(depth, color, bnd, dirs, rules, py, px, m, iv, r, kq, qs, z, order, bias, past):
    for j in range(m):  # insertion sort, far to near
        zq = 1.0 / iv[j]
        i = j
        while i > 0 and z[i - 1] < zq:
            z[i] = z[i - 1]
            order[i] = order[i - 1]
            i -= 1
        z[i] = zq
        order[i] = j
    c0 = float(color[py, px, 0]) if rules.use_color else 0.0
    c1 = float(color[py, px, 1]) if rules.use_color else 0.0
    c2 = float(color[py, px, 2]) if rules.use_color else 0.0
    best_score = -1.0
    best_inv = 0.0
    start = 0
    while start < m:
        end = start + 1
        while end < m and z[end - 1] - z[end] <= rules.edge_ratio * z[end - 1]:
            end += 1
        if rules.use_color and start > 0 and \
                support_bound(r, order, start, end, rules.support_px) / bias <= best_score:
            start = end
            continue
        score = 0.0
        for i in range(start, end):
            j = order[i]
            if rules.use_color:
                k = kq[j]
                ux = rules.step if dirs[k, 0] > 0 else (-rules.step if dirs[k, 0] < 0 else 0)
                uy = rules.step if dirs[k, 1] > 0 else (-rules.step if dirs[k, 1] < 0 else 0)
                sim = color_sim(color, depth, c0, c1, c2, bnd.y[qs[j]], bnd.x[qs[j]], uy, ux,
                                rules.n_samples, rules.inv_two_sigma2)
                score += sim / (r[j] + rules.support_px)
        if start > 0:
            score /= bias
        if score > best_score:
            best_score = score
            best_inv = _plain_idw(iv, r, past, order, start, end)
        if not rules.use_color:
            break
        start = end
    return best_inv


@njit
def _plain_combine(depth, color, holes, bnd, dirs, rules, out, r_near, kind):
    K = holes.cand.shape[0]
    iv = np.empty(K)
    r = np.empty(K)
    kq = np.empty(K, dtype=np.int64)
    qs = np.empty(K, dtype=np.int64)
    z = np.empty(K)
    order = np.empty(K, dtype=np.int64)
    past = np.empty(K)
    for h in range(holes.y.shape[0]):
        py = holes.y[h]
        px = holes.x[h]
        r_near[h] = 0.0
        inv, r_border = border_inv(holes, bnd, h, rules)
        outside = inv >= 0.0
        if outside and rules.border == 0:  # "candidates": from the candidates, with the border's bias
            inv = -1.0
        if inv >= 0.0:
            kind[h] = BORDER if inv > 0.0 else LOST
            if rules.border_median:
                r_near[h] = r_border
        else:
            m = collect_candidates(holes, bnd, h, rules, iv, r, kq, qs, past, outside)
            if m == 0:
                kind[h] = LOST
                continue
            r_near[h] = r[:m].min()
            iv_min = iv[:m].min()
            iv_max = iv[:m].max()
            if 1.0 / iv_min - 1.0 / iv_max <= rules.edge_ratio / iv_min:
                inv = _plain_idw(iv, r, past, np.arange(m), 0, m)
                kind[h] = SURFACE
            else:
                inv = _plain_choose_surface(depth, color, bnd, dirs, rules, py, px, m, iv, r, kq, qs,
                                            z, order, rules.border_bias if outside else rules.bias, past)
                kind[h] = SURFACE
            if outside:
                kind[h] = BORDER
        if kind[h] != LOST:
            out[py, px] = np.float32(min(max(1.0 / inv, rules.border_zmin if outside else rules.zmin), rules.zmax))


def _insertion_sort(iv):
    z, order = [], []
    for j, v in enumerate(iv):
        zq = 1.0 / v
        i = len(z)
        while i > 0 and z[i - 1] < zq:
            i -= 1
        z.insert(i, zq)
        order.insert(i, j)
    return np.array(z), np.array(order)


def _plain_despeckle(out, hole_y, hole_x, edge_ratio):
    h_, w_ = out.shape
    new = {}
    for y, x in zip(hole_y, hole_x):
        v = float(out[y, x])
        nb = [float(out[y + dy, x + dx]) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
              if (dy or dx) and 0 <= y + dy < h_ and 0 <= x + dx < w_]
        if nb and not any(max(u, v) <= (1.0 + edge_ratio) * min(u, v) for u in nb):
            new[y, x] = sorted(nb)[(len(nb) - 1) // 2]
    res = out.copy()
    for (y, x), v in new.items():
        res[y, x] = v
    return res


# ---------------------------------------------------------------------------------------------
# random inputs


def _frame(rng, h, w, levels, hole_frac, grey, colours=None, noise=40):
    """A depth map of a few noisy layers (slanted), blocks and speckles of holes, and colour that partly
    follows the layers (so that colour votes go both ways): *colours* distinct ones (default: one a layer),
    plus noise up to *noise*; with one colour and no noise every similarity is 1 and every surface scores
    its bound."""
    yy, xx = np.mgrid[0:h, 0:w]
    layer = np.zeros((h, w), np.int64)
    for lv in range(1, levels):
        cy, cx = rng.integers(0, h), rng.integers(0, w)
        ry, rx = rng.integers(2, max(3, h // 2)), rng.integers(2, max(3, w // 2))
        layer[(np.abs(yy - cy) < ry) & (np.abs(xx - cx) < rx)] = lv
    base = rng.uniform(0.5, 6.0, levels)
    depth = (base[layer] * (1 + rng.uniform(-0.004, 0.004) * xx + rng.uniform(-0.004, 0.004) * yy)
             * (1 + rng.normal(0, 0.003, (h, w)))).astype(np.float32)
    depth[rng.random((h, w)) < hole_frac] = 0
    for _ in range(rng.integers(0, 4)):
        y0, x0 = rng.integers(0, h), rng.integers(0, w)
        depth[y0: y0 + rng.integers(1, 10), x0: x0 + rng.integers(1, 14)] = 0
    palette = rng.integers(0, 256, (levels, 3))
    if colours is not None:
        palette = palette[rng.integers(0, min(colours, levels), levels)]
    color = palette[layer] + rng.integers(-noise, noise + 1, (h, w, 3))
    if grey:
        color[...] = color[..., :1]
    color = np.clip(color, 0, 255).astype(np.uint8)
    if not (depth > 0).any():
        depth[0, 0] = 1.0
    return depth, color


def _kernel_inputs(depth, color, *, edge_ratio, sigma_color, bias, use_color, sixteen_bit, border=DEFAULT_BORDER):
    depth, color, _, _, _ = prepare(depth, color, need_color=True)
    guide, unit = color_for_kernel(color.astype(np.uint16) * 257 if sixteen_bit else color)
    depth, guide = read_only(depth), read_only(guide)
    code, hole_y, hole_x, b_y, b_x, row_start, zmin, zmax = index_depth(depth)
    rules = kernel_rules(depth.shape, use_color=use_color, unit=unit, edge_ratio=edge_ratio, sigma_color=sigma_color,
                         background_bias=bias, zmin=zmin, zmax=zmax, border=border)
    holes = Holes(hole_y, hole_x, sweep(code, hole_x, row_start, DIRS, HALF))
    bnd = Boundary(b_y, b_x, np.empty((b_y.size, 3)))
    fit_boundary(depth, b_y, b_x, FIT_RADIUS_STEPS * rules.step, rules.step, edge_ratio, bnd.plane)
    return depth, guide, holes, bnd, rules


def _run_combine(fn, depth, guide, holes, bnd, rules):
    out = depth.copy()
    r_near = np.full(holes.y.size, np.nan)
    kind = np.full(holes.y.size, -1, np.int8)
    fn(depth, guide, holes, bnd, DIRS, rules, out, r_near, kind)
    return out, r_near, kind


# ---------------------------------------------------------------------------------------------
# tests


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 48), w=st.integers(1, 64), levels=st.integers(1, 5),
       hole_frac=st.floats(0.0, 0.7), edge_ratio=st.sampled_from([0.01, 0.04, 0.2]),
       sigma_color=st.sampled_from([0.01, 0.04, 0.3, 3.0]), bias=st.sampled_from([1.0, 1.5, 6.0, 40.0]),
       use_color=st.booleans(), grey=st.booleans(), colours=st.sampled_from([None, 1, 2]),
       noise=st.sampled_from([0, 3, 40]), sixteen_bit=st.booleans(), parallel=st.booleans(),
       border=st.sampled_from(BORDER_RULES))
def test_combine_matches_the_plain_vote(seed, h, w, levels, hole_frac, edge_ratio, sigma_color, bias, use_color, grey,
                                        colours, noise, sixteen_bit, parallel, border):
    depth, color = _frame(np.random.default_rng(seed), h, w, levels, hole_frac, grey, colours, noise)
    if (depth > 0).all() and depth.size > 1:
        depth[h // 2, w // 2] = 0
    args = _kernel_inputs(depth, color, edge_ratio=edge_ratio, sigma_color=sigma_color, bias=bias,
                          use_color=use_color, sixteen_bit=sixteen_bit, border=border)
    with numba_threads(numba.get_num_threads() if parallel else 1):
        fast = _run_combine(combine, *args)
    plain = _run_combine(_plain_combine, *args)
    for a, b in zip(fast, plain):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def test_combine_matches_the_plain_vote_on_a_synthetic_frame():
    """A registered synthetic frame: disocclusions beside near objects, where the colour vote runs most."""
    from pcdof.stages.register import register_depth
    from pcdof.synth import generate_scene

    sf = generate_scene("portrait", color_size=(320, 240), depth_size=(256, 212), seed=3)
    args = _kernel_inputs(register_depth(sf.frame), sf.frame.color, edge_ratio=DEFAULT_EDGE_RATIO,
                          sigma_color=DEFAULT_SIGMA_COLOR, bias=DEFAULT_BACKGROUND_BIAS, use_color=True,
                          sixteen_bit=False)
    fast, plain = _run_combine(combine, *args), _run_combine(_plain_combine, *args)
    assert np.count_nonzero(fast[2] == SURFACE) > 1000
    for a, b in zip(fast, plain):
        assert np.array_equal(a, b)


@settings(max_examples=300, deadline=None)
@given(m=st.integers(1, 16), seed=st.integers(0, 2**32 - 1), distinct=st.integers(1, 16))
def test_rank_sort_matches_insertion_sort(m, seed, distinct):
    rng = np.random.default_rng(seed)
    values = rng.uniform(0.1, 3.0, distinct)
    iv = values[rng.integers(0, distinct, m)]  # ties: equal depths keep their order
    zu, z, order = np.empty(16), np.full(16, np.nan), np.full(16, -1)
    sort_far_to_near(iv, m, zu, z, order)
    want_z, want_order = _insertion_sort(iv)
    assert np.array_equal(z[:m], want_z) and np.array_equal(order[:m], want_order)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 30), w=st.integers(1, 30), hole_frac=st.floats(0.0, 1.0))
def test_index_matches_numpy(seed, h, w, hole_frac):
    rng = np.random.default_rng(seed)
    depth = rng.choice(np.array([1e-40, 0.3, 0.31, 2.0, 7.5, 3e38, np.inf], np.float32), (h, w))
    with np.errstate(over="ignore"):  # 3e38 may become inf: known, the largest
        depth *= rng.uniform(0.5, 1.5, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < hole_frac] = rng.choice(np.array([0.0, -0.0, -1.0, np.nan, -np.inf], np.float32))
    code, hole_y, hole_x, b_y, b_x, row_start, zmin, zmax = index_depth(depth)
    known = depth > 0
    assert np.array_equal(np.nonzero(~known), (hole_y, hole_x))
    assert np.array_equal(row_start, np.concatenate([[0], np.cumsum((~known).sum(axis=1))]))
    if known.any():
        assert (zmin, zmax) == (depth[known].min(), depth[known].max())
    else:
        assert (zmin, zmax) == (np.inf, -np.inf)
    assert np.array_equal(code == HOLE, ~known)
    assert np.array_equal(code[b_y, b_x], np.arange(b_y.size))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 20), w=st.integers(1, 20), n=st.integers(0, 400),
       edge_ratio=st.sampled_from([0.0001, 0.04, 0.5]))
def test_despeckle_matches_sorting_every_hole(seed, h, w, n, edge_ratio):
    rng = np.random.default_rng(seed)
    out = rng.choice(np.array([1.0, 1.01, 2.0, 3.5], np.float32), (h, w)) * rng.uniform(0.98, 1.02, (h, w))
    out = out.astype(np.float32)
    flat = np.unique(rng.integers(0, h * w, n))
    hole_y, hole_x = (flat // w).astype(np.int64), (flat % w).astype(np.int64)
    want = _plain_despeckle(out, hole_y, hole_x, edge_ratio)
    got = out.copy()
    despeckle(got, hole_y, hole_x, edge_ratio)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("layout", ["C", "F", "float64", "int"])
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 12), w=st.integers(1, 12))
def test_prepared_depth_matches_as_depth_m(layout, seed, h, w):
    rng = np.random.default_rng(seed)
    depth = rng.choice(np.array([0.0, -0.0, -2.0, 1e-42, 0.5, 4.0, np.inf, -np.inf, np.nan, 3e38]), (h, w))
    depth[0, 0] = 1.5  # at least one known pixel
    depth = {"C": depth.astype(np.float32), "F": np.asfortranarray(depth.astype(np.float32)), "float64": depth,
             "int": np.clip(np.nan_to_num(depth, posinf=9, neginf=-9), -9, 9).astype(np.int32)}[layout]
    want, _ = as_depth_m(depth)
    holes = int(want.size - np.count_nonzero(want > 0))
    got, _, n_holes, done, out = prepare(depth, None, need_color=False)
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32)) and n_holes == holes
    assert (done is got) == (holes == 0)
    if out is not None:
        assert out is not got and np.array_equal(out.view(np.uint32), want.view(np.uint32))
