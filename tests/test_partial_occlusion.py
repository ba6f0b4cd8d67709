"""Partial occlusion: a layer continued behind a blurred foreground is continued by what is seen beside it.

A small bright layer (a lamp or glint between a blurred foreground and a sharp background) must not be
copied over the whole width the foreground hides: the light it adds would come from nothing. A slanted
surface, cut into many thin layers, must be continued as deep as one layer of it would be.
"""

from __future__ import annotations

import threading
from unittest import mock

import cv2
import hypothesis.strategies as st
import numba
import numpy as np
import pytest
from hypothesis import given, settings

import pcdof.stages.render as renderer
from pcdof.plans import plan_render
from pcdof.stages.render import reference as ref
from pcdof.stages.render import render_layers_linear


def _scene(radiance):
    h, w = 48, 64
    lin = np.full((h, w, 3), 0.3, np.float32)
    coc = np.zeros((h, w), np.float32)  # background in focus
    coc[:, :30] = -24.0  # blurred foreground on the left
    lin[:, :30] = (0.6, 0.2, 0.2)
    coc[22:25, 30:33] = -4.0  # a 3 x 3 lamp between them, touching the foreground's edge
    lin[22:25, 30:33] = radiance
    return lin, coc


@pytest.mark.parametrize("radiance", [1.0, 50.0])
@pytest.mark.parametrize("renderer", ["fast", "reference"])
def test_small_layer_is_not_copied_behind_a_blurred_foreground(renderer, radiance):
    lin, coc = _scene(radiance)
    if renderer == "fast":
        out = render_layers_linear(lin, coc, quality="exact")[0]
    else:
        out = ref.render_layers_linear(lin, coc).astype(np.float32)
    # every source spreads its own light and nearer layers only take some away: no light from nothing
    assert float(out.sum()) <= 1.01 * float(lin.sum())


def _plane_behind_foreground(slanted):
    """A bright plane over the top half (its CoC from 2.9 px down to 0.6 px over 20 rows when *slanted*: layer
    edges every 2 to 5 rows; else 2.5 px, one layer) and a dark foreground blurred by 16 px below it."""
    h, w = 40, 48
    lin = np.full((h, w, 3), 0.9, np.float32)
    coc = np.repeat((2.9 - 0.12 * np.arange(h, dtype=np.float32) if slanted else np.full(h, 2.5, np.float32))
                    [:, None], w, axis=1)
    lin[20:] = 0.05
    coc[20:] = -16.0
    return lin, coc


@pytest.mark.parametrize("renderer", ["fast", "reference"])
def test_slanted_surface_is_continued_as_deep_as_one_layer_behind_a_blurred_foreground(renderer):
    """Each thin layer of the slanted plane used to be continued behind the foreground only as deep as the
    layer is wide (the next layer of the same plane counted as the end of it): three rows in, the plane's
    light stopped and the foreground's soft edge had a hard step (0.19 -> 0.05 at row 24). The surface
    ends at a depth jump, not at a layer edge: the render matches the plane as one layer."""
    def render(lin, coc):
        if renderer == "fast":
            return render_layers_linear(lin, coc, quality="exact")[0]
        return ref.render_layers_linear(lin, coc).astype(np.float32)
    slanted, flat = render(*_plane_behind_foreground(True)), render(*_plane_behind_foreground(False))
    # the foreground's first rows, away from the frame's sides: its soft edge lets the plane behind it through
    inside = (slice(20, 28), slice(8, 40))
    assert float(flat[24:26, 8:40, 0].min()) > 0.07  # the plane's light reaches there
    np.testing.assert_allclose(slanted[inside], flat[inside], atol=0.01)


def _owned_whole(layer, li, box, bbox, hidden, reach_px, cell_px=1, threads=1, across=None):
    """The ownership rule stated plainly: both transforms on the box widened by twice the reach (every
    pixel that can compete for it), answered for every pixel of the box; the surface ends where *across*
    says (every farther layer's pixel when None)."""
    h, w = layer.shape
    pad = 2 * int(np.ceil(reach_px)) + 2
    y0, x0 = max(0, box[0].start - pad), max(0, box[1].start - pad)
    big = layer[y0:min(h, box[0].stop + pad), x0:min(w, box[1].stop + pad)]
    behind = big >= li
    dist, labels = cv2.distanceTransformWithLabels((~behind).astype(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    nearest = np.flatnonzero(behind.ravel())[labels.ravel() - 1]
    farther = big > li
    if across is not None:
        farther &= across[y0:y0 + big.shape[0], x0:x0 + big.shape[1]] >= li
    width = (cv2.distanceTransform((~farther).astype(np.uint8), cv2.DIST_L2, 5).ravel()[nearest] if farther.any()
             else np.full(nearest.shape, np.inf, np.float32))
    own = ((big.ravel()[nearest] == li) & (dist.ravel() <= np.maximum(width, 1.0))).reshape(big.shape)
    return hidden & own[box[0].start - y0:box[0].stop - y0, box[1].start - x0:box[1].stop - x0]


def _random_frame(seed):
    """Random colour and a piecewise-constant signed CoC of random blocks, bars and specks (many layers,
    many edges, ties between equally near layer pixels)."""
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(24, 160, 2))
    lin = rng.random((h, w, 3), dtype=np.float32)
    k = int(rng.integers(2, 10))
    coc = cv2.resize(rng.uniform(-40, 40, (k, k)).astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    for _ in range(int(rng.integers(0, 6))):
        y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
        coc[y:y + int(rng.integers(1, 6)), x:x + int(rng.integers(1, 40))] = rng.uniform(-60, 60)
    if rng.random() < 0.4:
        coc[rng.random((h, w)) < 0.1] = 0.0
    return lin, coc


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), quality=st.sampled_from(["exact", "balanced", "fast"]))
def test_ownership_on_its_window_renders_as_on_the_whole_box(seed, quality):
    """The renderer decides ownership only where the extension can use it, on the smallest windows that
    decide it: the render is bit for bit the one of the rule answered everywhere on the widened box."""
    lin, coc = _random_frame(seed)
    out, info = render_layers_linear(lin, coc, quality=quality)
    with mock.patch.object(renderer.ownership, "owners_of_hidden", _owned_whole):
        whole, whole_info = render_layers_linear(lin, coc, quality=quality)
    np.testing.assert_array_equal(out, whole)
    assert info["layers"] == whole_info["layers"]


def test_ownership_with_no_candidate_near_the_hidden_pixels_owns_nothing():
    """Hidden pixels whose window holds no pixel of this or a farther layer: nothing owned, no error."""
    layer = np.zeros((200, 200), np.int32)
    layer[0, 0] = layer[199, 199] = 1  # the layer's bounding box is the whole frame
    layer[100, 5] = 2  # a farther layer within twice the reach of the hidden pixels, not within the reach
    hidden = np.zeros_like(layer, bool)
    hidden[95:105, 20:30] = True
    box = (slice(0, 200), slice(0, 200))
    out = renderer.ownership.owned_mask(layer, 1, box, (0, 199, 0, 199), hidden, 8.0)
    assert out.shape == hidden.shape and not out.any()


def test_ownership_with_no_farther_layer_owns_every_hidden_pixel_in_reach():
    """Only this layer behind: it is every hidden pixel's nearest candidate, so all within reach are owned."""
    layer = np.zeros((60, 80), np.int32)
    layer[:, 50:] = 1
    hidden = layer == 0
    box = (slice(0, 60), slice(0, 80))
    out = renderer.ownership.owned_mask(layer, 1, box, (0, 59, 50, 79), hidden, 10.0)
    assert out[:, 40:50].all()  # every hidden pixel within the reach (10 px) of the layer
    assert (out <= hidden).all() and _owned_whole(layer, 1, box, None, hidden, 10.0)[:, 40:50].all()


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cell_px=st.sampled_from([1, 2, 4]), threads=st.integers(2, 5))
def test_ownership_on_threads_is_the_serial_answer(seed, cell_px, threads):
    """The hidden pixels cut into strips, each decided on its own windows and thread: the serial answer, bit for bit."""
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(20, 120, 2))
    k = int(rng.integers(2, 12))
    layer = cv2.resize(rng.integers(0, 5, (k, k)).astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    layer = layer.astype(np.int32)
    li = int(rng.integers(1, 4))
    ys, xs = np.nonzero(layer == li)
    if ys.size == 0:
        return
    hidden = np.zeros((h, w), bool)  # in a random rectangle: the windows end inside the frame
    y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
    hidden[y0:y0 + int(rng.integers(1, h)), x0:x0 + int(rng.integers(1, w))] = True
    hidden &= (layer < li) & (rng.random((h, w)) < 0.8)
    box = (slice(0, h), slice(0, w))
    bbox = (ys.min(), ys.max(), xs.min(), xs.max())
    reach = float(rng.uniform(1, 20))
    serial = renderer.ownership.owned_mask(layer, li, box, bbox, hidden, reach, cell_px)
    threaded = renderer.ownership.owned_mask(layer, li, box, bbox, hidden, reach, cell_px, threads=threads)
    np.testing.assert_array_equal(serial, threaded)


def test_ownership_sees_a_farther_layer_beyond_the_hidden_pixels_reach():
    """A hidden pixel 15 px from a one-pixel layer, which a farther layer meets 11 px beyond: the layer
    reaches 11 px beside the occluder, not 15, so the pixel is not owned. The farther layer lies 26 px
    from the hidden pixel, outside the window of its candidates (20 + 3 px): the second transform must
    look farther."""
    layer = np.zeros((100, 100), np.int32)
    layer[50, 25] = 1
    layer[50, 36] = 2
    hidden = np.zeros_like(layer, bool)
    hidden[50, 10] = True
    box = (slice(0, 100), slice(0, 100))
    out = renderer.ownership.owned_mask(layer, 1, box, (50, 50, 25, 25), hidden, 20.0)
    assert not out.any() and not _owned_whole(layer, 1, box, None, hidden, 20.0).any()
    layer[50, 36] = 0  # with no farther layer the pixel is owned
    assert renderer.ownership.owned_mask(layer, 1, box, (50, 50, 25, 25), hidden, 20.0)[50, 10]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), quality=st.sampled_from(["exact", "balanced"]))
def test_ownership_found_a_layer_ahead_renders_as_found_in_turn(seed, quality):
    """With two threads each layer's continued pixels are found on a helper thread while the layer before it
    renders (a mask taken one layer early, cut when used): the render is bit for bit the one-thread render, which
    finds them in turn."""
    _render_ahead_and_in_turn(*_random_frame(seed), quality)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_ownership_ahead_runs_on_the_helper_thread():
    """The lamp and the background behind a blurred foreground are each continued from a mask found ahead."""
    assert _render_ahead_and_in_turn(*_scene(1.0), "exact") == 2


def _render_ahead_and_in_turn(lin, coc, quality):
    """Render with one thread and with two; assert they agree bit for bit and that every layer's continued pixels
    found with two threads were found on the helper. Returns how many were."""
    serial, _ = render_layers_linear(lin, coc, quality=quality, plan=plan_render(quality=quality, threads=1))
    threads = []
    find = renderer.ownership.OwnershipAhead._find

    def spy(self, li, hidden, n):
        threads.append(threading.current_thread() is not threading.main_thread())
        return find(self, li, hidden, n)

    with mock.patch.object(renderer.ownership.OwnershipAhead, "_find", spy):
        ahead, _ = render_layers_linear(lin, coc, quality=quality, plan=plan_render(quality=quality, threads=2))
    np.testing.assert_array_equal(ahead, serial)
    assert all(threads)
    return len(threads)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_a_render_that_fails_drops_what_was_found_ahead():
    """A layer that fails stops the render with its error, and the next layer's job found ahead is dropped
    (cancelled, or finished and not kept), so nothing of the failed render is left pending."""
    lin, coc = _scene(1.0)
    made = []
    real = renderer.ownership.OwnershipAhead

    class Recorded(real):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    def fail(*a, **k):
        raise RuntimeError("layer failed")

    with mock.patch.object(renderer.physical, "OwnershipAhead", Recorded), \
            mock.patch.object(renderer.physical, "_blur_layer", fail):
        with pytest.raises(RuntimeError, match="layer failed"):
            render_layers_linear(lin, coc, quality="exact", plan=plan_render(quality="exact", threads=2))
    assert len(made) == 1 and made[0]._pending == {}


def test_ownership_ahead_falls_back_to_in_turn_when_no_thread_can_start():
    """At interpreter exit a pool takes no new work (RuntimeError): the layers find their pixels in turn, and the
    render is the same."""
    lin, coc = _scene(1.0)
    want, _ = render_layers_linear(lin, coc, quality="exact", plan=plan_render(quality="exact", threads=1))

    class Closed:
        def submit(self, *a, **k):
            raise RuntimeError("cannot schedule new futures after interpreter shutdown")

    with mock.patch.object(renderer.ownership, "task_pool", lambda *a, **k: Closed()):
        got, _ = render_layers_linear(lin, coc, quality="exact", plan=plan_render(quality="exact", threads=2))
    np.testing.assert_array_equal(got, want)
