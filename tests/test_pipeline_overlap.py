"""The pipeline's schedule: the highlights stage's colour-only half runs on a worker thread while the fill runs, and
every result is the one of running the stages one after another."""

import threading

import numba
import numpy as np
import pytest

import pcdof.stages.highlights as highlights
import pcdof.pipeline as pipeline
import pcdof.runtime.threads as runtime_threads
import pcdof.stages.highlights.stage as highlights_stage
import pcdof.stages.render.stage as render_stage
from pcdof.camera import RGBDFrame
from pcdof.color import decode_to_linear, srgb_to_linear
from pcdof.errors import InputError
from pcdof.stages.highlights import (HIGHLIGHT_METHODS, ClippedColor, clipped_mask, prepare_highlights,
                              reconstruct_highlights, reconstruct_prepared)
from pcdof.lens import PaperLens, ThinLens
from pcdof.synth.rig import kinect_rig


def _clip_level(dtype):
    top = float(np.iinfo(dtype).max)
    return float(srgb_to_linear(np.float32((top - 0.5) / top)))


def _color(rng, h, w, dtype=np.uint8, blobs=6):
    """Random sRGB codes with *blobs* clipped discs and boxes: white, or clipped in one or two channels only."""
    top = np.iinfo(dtype).max
    img = (rng.uniform(0.0, 0.8, (h, w, 3)) * top).astype(dtype)
    yy, xx = np.mgrid[:h, :w]
    for _ in range(blobs):
        cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.5, 6.0)
        inside = ((yy - cy) ** 2 + (xx - cx) ** 2 <= r * r) if rng.random() < 0.7 else \
            ((abs(yy - cy) <= r) & (abs(xx - cx) <= r / 2))
        channels = ([0, 1, 2], [0], [1, 2], [2])[rng.choice(4, p=[0.55, 0.15, 0.15, 0.15])]
        for c in channels:
            img[..., c][inside] = top
    return img


def _frame(seed, dtype=np.uint8, size=(160, 120), blobs=6):
    """A Kinect-like frame (registration runs) of random steps of depth with holes, and a clipped colour."""
    rng = np.random.default_rng(seed)
    rig = kinect_rig(size, (128, 106))
    h, w = rig.depth.height, rig.depth.width
    depth = np.full((h, w), rng.uniform(2.0, 4.0), np.float32)
    for _ in range(3):
        y0, x0 = rng.integers(0, h - 10), rng.integers(0, w - 10)
        depth[y0:y0 + rng.integers(8, 40), x0:x0 + rng.integers(8, 40)] = rng.uniform(0.7, 1.8)
    depth[rng.random((h, w)) < 0.03] = 0.0
    return RGBDFrame(_color(rng, size[1], size[0], dtype, blobs), depth, rig)


LENS = ThinLens(50.0, 1.4, 1.2)


@pytest.fixture(autouse=True)
def every_thread():
    """These tests check what a frame does with a second thread: every thread numba may run (whatever count a test
    before left this thread with), and the load adaptation off."""
    from pcdof.runtime.threads import fixed_threads, max_threads

    with fixed_threads(max_threads()):
        yield


def _sequential(monkeypatch):
    monkeypatch.setattr(highlights_stage, "OVERLAP", False)


def _stage(result, name):
    return next(t for t in result.trace if t.name == name)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_the_clipped_codes_are_the_clipped_decoded_pixels(dtype):
    """Every code: at the top code exactly where the decoded value reaches the decoded clip level, so the mask
    counted on the codes is the one the blobs of the decoded colour are found from."""
    codes = np.arange(np.iinfo(dtype).max + 1, dtype=np.int64)
    img = np.zeros((codes.size, 3), dtype)
    for c in range(3):
        img[:, c] = np.roll(codes, 997 * c)
    img = img.reshape(-1, 1, 3)
    top = float(np.iinfo(dtype).max)
    np.testing.assert_array_equal(clipped_mask(img, top - 0.5), clipped_mask(decode_to_linear(img), _clip_level(dtype)))
    assert np.count_nonzero(clipped_mask(img, top - 0.5)) == 3


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("seed", range(4))
def test_prepared_reconstruction_is_the_reconstruction_of_the_decoded_colour(seed, dtype):
    rng = np.random.default_rng(seed)
    color = _color(rng, 60, 80, dtype, blobs=8)
    coc = rng.uniform(0.0, 12.0, (60, 80)).astype(np.float32)
    lin = decode_to_linear(color)
    for method in HIGHLIGHT_METHODS:
        prepared = prepare_highlights(color)
        assert isinstance(prepared, ClippedColor)
        assert prepared.clipped_pixels == np.count_nonzero(clipped_mask(lin, _clip_level(dtype)))
        want = reconstruct_highlights(lin, method=method, clip_level=_clip_level(dtype), coc_px=coc, gain=5.0)
        got = reconstruct_prepared(prepared, method=method, coc_px=coc, gain=5.0)
        np.testing.assert_array_equal(got, want)
        # the prior methods raise the decoded array itself (no copy); the others leave it as decoded
        assert (got is prepared.linear) == (method in ("auto", "prior", "prior-rim", "off"))
        if got is not prepared.linear:
            np.testing.assert_array_equal(prepared.linear, lin)
    assert method == "prior-rim" and not np.array_equal(want, lin)  # something was raised


def test_nothing_clipped_is_not_decoded():
    color = np.full((8, 9, 3), 254, np.uint8)
    assert prepare_highlights(color) is None and prepare_highlights(color[..., 0]) is None
    with pytest.raises(InputError):
        prepare_highlights(color.astype(np.float32))
    with pytest.raises(InputError, match="prepared"):
        reconstruct_prepared(decode_to_linear(color))


@pytest.mark.parametrize("seed,dtype,options", [
    (0, np.uint8, {}), (1, np.uint8, {}), (2, np.uint8, {"highlights": "gain"}), (3, np.uint8, {"highlights": "rim"}),
    (4, np.uint8, {"highlights": "prior-rim"}), (5, np.uint16, {}), (6, np.uint8, {"quality": "exact"}),
    (7, np.uint8, {"highlights": 3.0}),
])
def test_overlapped_and_sequential_pipelines_give_the_same_bits(monkeypatch, seed, dtype, options):
    if numba.get_num_threads() < 2:
        pytest.skip("one thread: the pipeline runs every stage on it")
    frame = _frame(seed, dtype)
    got = pipeline.run(frame, LENS, **options)
    assert "ms more ran beside the fill" in got.explain()
    detail = _stage(got, "highlights").detail
    assert {"prepared_ms", "overlapped_ms", "waited_ms"} <= set(detail)
    assert 0.0 <= detail["overlapped_ms"] <= detail["prepared_ms"]
    assert _stage(got, "highlights").seconds * 1e3 >= detail["waited_ms"]
    _sequential(monkeypatch)
    want = pipeline.run(frame, LENS, **options)
    assert "overlapped_ms" not in _stage(want, "highlights").detail
    assert [(t.name, t.skipped, t.reason) for t in got.trace] == [(t.name, t.skipped, t.reason) for t in want.trace]
    assert not _stage(got, "highlights").skipped and not _stage(got, "register").skipped
    for a, b in ((got.image, want.image), (got.depth_filled_m, want.depth_filled_m), (got.coc_px, want.coc_px)):
        np.testing.assert_array_equal(a, b)
    assert got.image.dtype == dtype


def _counting_threads(monkeypatch, pool="colour"):
    """The work handed to the worker thread *pool* (the colour side's, or the render's "layers"), as a list that
    grows."""
    started = []
    real = runtime_threads.worker_pool

    class Counted:
        def __init__(self, name, workers):
            self.pool = real(name, workers)
            self.name = name

        def submit(self, fn):
            if self.name == pool:
                started.append(fn)
            return self.pool.submit(fn)

    monkeypatch.setattr(runtime_threads, "worker_pool", Counted)
    return started


@pytest.mark.parametrize("change,options", [
    ("none", {"highlights": "off"}), ("none", {"method": "paper"}), ("linear", {"linear": True}),
    ("unclipped", {}), ("grey", {}), ("one thread", {}),
])
def test_frames_that_do_not_need_the_colour_side_use_no_thread(monkeypatch, change, options):
    frame = _frame(0)
    color = {"linear": decode_to_linear(frame.color), "unclipped": frame.color // 2,
             "grey": frame.color[..., 1]}.get(change, frame.color)
    frame = RGBDFrame(color, frame.depth_m, frame.rig)
    lens = PaperLens(focus_distance_m=1.2) if options.get("method") == "paper" else LENS
    started = _counting_threads(monkeypatch)
    threads = numba.get_num_threads()
    numba.set_num_threads(1 if change == "one thread" else threads)
    try:
        result = pipeline.run(frame, lens, **options)
    finally:
        numba.set_num_threads(threads)
    assert started == []
    assert _stage(result, "highlights").skipped == (change != "one thread")
    pipeline.run(_frame(1), LENS)
    assert len(started) == (threads > 1)  # the counter sees a frame that needs it


@pytest.mark.parametrize("module,name", [("pcdof.stages.highlights", "prepare_highlights"),
                                         ("pcdof.stages.render.physical", "classify_frame")])
def test_a_failure_on_the_worker_is_raised_in_the_callers_thread(monkeypatch, module, name):
    """The highlights stage's colour side and the render's layers run on workers: what fails there is raised here."""
    import importlib

    if numba.get_num_threads() < 2:
        pytest.skip("one thread: no worker")

    class Broken(RuntimeError):
        pass

    where = []

    def broken(*args, **kwargs):
        where.append(threading.current_thread())
        raise Broken(f"{name} failed")

    monkeypatch.setattr(importlib.import_module(module), name, broken)
    with pytest.raises(Broken, match=f"{name} failed"):
        pipeline.run(_frame(0), LENS)
    assert where and where[0] is not threading.current_thread()


def test_the_fill_kernels_release_the_gil():
    """The fill runs while the worker does: its kernels must not hold the GIL (numba's nogil)."""
    from pcdof.runtime.kernels import STAGES, _cached_dispatchers

    kernels = [k for module in STAGES["fill"][1] for k in _cached_dispatchers(module)]
    assert {k.__name__ for k in kernels} >= {"index_depth", "_sweep_tasks", "_fit_tasks", "_combine_tasks",
                                             "_despeckle_tasks", "_median_tasks", "_align_tasks", "_band_from_range"}
    assert all(k.targetoptions.get("nogil") for k in kernels), [k.__name__ for k in kernels]


# -------------------------------------------------------------- the render's layers classified beside the highlights
@pytest.mark.parametrize("seed,options", [(0, {}), (3, {"quality": "exact"}), (5, {"highlights": "off"}),
                                          (6, {"quality": "fast"})])
def test_layers_classified_beside_the_highlights_give_the_same_bits(monkeypatch, seed, options):
    if numba.get_num_threads() < 2:
        pytest.skip("one thread: the pipeline runs every stage on it")
    frame = _frame(seed)
    started = _counting_threads(monkeypatch, "layers")
    got = pipeline.run(frame, LENS, **options)
    assert len(started) == 1
    detail = _stage(got, "render").detail
    assert {"classify_ms", "classify_overlapped_ms", "classify_waited_ms"} <= set(detail)
    assert 0.0 <= detail["classify_overlapped_ms"] <= detail["classify_ms"]
    assert "(its layers) ran beside the highlights stage" in got.explain()
    monkeypatch.setattr(render_stage, "OVERLAP", False)
    want = pipeline.run(frame, LENS, **options)
    assert len(started) == 1 and "classify_ms" not in _stage(want, "render").detail
    for a, b in ((got.image, want.image), (got.coc_px, want.coc_px)):
        np.testing.assert_array_equal(a, b)
    # a focus change (the depth given) classifies beside the highlights stage too
    lens = ThinLens(50.0, 1.2, 2.5)
    x, trace = pipeline.render_from_depth(frame.color, got.depth_filled_m, lens, frame.rig.color.fx, **options)
    monkeypatch.setattr(render_stage, "OVERLAP", True)
    y, trace_y = pipeline.render_from_depth(frame.color, got.depth_filled_m, lens, frame.rig.color.fx, **options)
    assert "classify_ms" in trace_y[-1].detail and "classify_ms" not in trace[-1].detail
    np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("change,options", [("paper", {"method": "paper"}), ("sharp", {}), ("one thread", {}),
                                            ("large", {})])
def test_frames_the_physical_render_does_not_blur_classify_nothing_beside(monkeypatch, change, options):
    import pcdof.plans as plans

    frame = _frame(0)
    if change == "large":  # as if the frame were larger than the plan classifies beside the highlights
        monkeypatch.setattr(plans, "CLASSIFY_BESIDE_MAX_PX", frame.color.shape[0] * frame.color.shape[1] - 1)
    lens = (PaperLens(focus_distance_m=1.2) if change == "paper" else
            ThinLens(50.0, 5000.0, 1.2) if change == "sharp" else LENS)
    started = _counting_threads(monkeypatch, "layers")
    threads = numba.get_num_threads()
    numba.set_num_threads(1 if change == "one thread" else threads)
    try:
        pipeline.run(frame, lens, **options)
    finally:
        numba.set_num_threads(threads)
    assert started == []
