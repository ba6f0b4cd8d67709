"""The optional GPU backend (:mod:`pcdof.gpu`): every kernel against the plain reference of its stage, run in
numba's CUDA simulator, and the device choice without a GPU.

The simulator must be switched on before numba is imported, so the kernel tests run in a child process
(:func:`test_parent_kernels_in_the_simulator` runs this module again under ``NUMBA_ENABLE_CUDASIM=1``); in the parent
they are skipped with that reason. The simulator runs each CUDA thread as a Python thread, so the frames are small
(at most 32 x 24): the rules are the same at every size, and each frame is built to take every branch
(holes of every kind, layers in front, in focus and behind, continued behind a blurred foreground).

Tolerances (each kernel computes the reference's arithmetic, in another order or precision):

- CoC: relative 1e-6 (float64 per pixel, stored as float32, like the reference's float32 cast);
- registration: relative depth 1e-5 where both have depth (1/z kept as float32 in the z-buffer: 6e-8), equal
  coverage; by design (see :mod:`pcdof.gpu.register`) overlapping footprints within the discontinuity ratio may
  keep the nearer instead of the first: at most 2 % of covered pixels may differ, each by less than the ratio;
- fill: relative 1e-5 (the plane's normal equations by Cramer's rule instead of LU, in float64, results stored
  as float32), at most one pixel beyond it (a decision exactly at a tie may go either way with another rounding);
- render: absolute 1e-5 in linear light (values <= 1) for the exact scatter, the tolerance of the CPU renderer's
  exact path (the same 4096-entry aperture table, float32 accumulation);
- mixed pixels at in-focus edges: 1e-6 against the CPU's (the same float64 arithmetic, stored as float32);
- colour: decoding bit-identical (the host's own table); encoding within one code (a GPU's power function may
  differ from numpy's in the last bit);
- the whole pipeline against the references chained: PSNR >= 50 dB (the issue's bar for the GPU against the CPU).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

SIM = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") == "1"
sim_only = pytest.mark.skipif(not SIM, reason="runs in the child process of test_parent_kernels_in_the_simulator "
                                              "(NUMBA_ENABLE_CUDASIM=1 must be set before numba is imported)")
parent_only = pytest.mark.skipif(SIM, reason="the parent process's test")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REL_COC = 1e-6
REL_REGISTER = 1e-5
MAX_FOOTPRINT_SHARE = 0.02
REL_FILL = 1e-5
ATOL_RENDER = 1e-5
MIN_PIPELINE_PSNR_DB = 50.0


def _psnr(a, b) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


# ------------------------------------------------------------------------------------------ parent process
@parent_only
def test_parent_kernels_in_the_simulator():
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1",
           "PYTHONPATH": os.pathsep.join([os.path.join(ROOT, "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                           "-k", "not no_gpu and not parent", os.path.abspath(__file__)],
                          env=env, cwd=ROOT, capture_output=True, text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-6000:]
    summary = [line for line in out.splitlines() if " passed" in line]
    assert summary and "skipped" not in summary[-1] and "deselected" in summary[-1], out[-2000:]


def _real_gpu() -> bool:
    from pcdof.gpu.device import available

    return available()[0]


@parent_only
def test_no_gpu_device_gpu_fails_in_one_line(tmp_path):
    if _real_gpu():
        pytest.skip("a usable GPU is present")
    data = os.path.join(ROOT, "data", "real", "tum_rgbd_open3d")
    out = tmp_path / "out.png"
    proc = subprocess.run([sys.executable, "-c", "from pcdof.cli import console_main; console_main()", "render",
                           os.path.join(data, "color.png"), os.path.join(data, "depth.png"), "--calib",
                           os.path.join(data, "calib.json"), "-o", str(out), "--device", "gpu"],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")})
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 8, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: no usable GPU was found: "), proc.stderr
    assert "pip install pcdof[gpu]" in lines[0] and "--device cpu" in lines[0]
    assert not out.exists()


@parent_only
def test_no_gpu_pipeline_device_choice():
    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.errors import DeviceError, InputError
    from pcdof.gpu.device import resolve_device
    from pcdof.lens import ThinLens
    from pcdof.options import RenderOptions
    from pcdof.pipeline import run

    if _real_gpu():
        pytest.skip("a usable GPU is present")
    lens = ThinLens(50.0, 1.8, 1.0)
    assert RenderOptions(lens, device="gpu").device == "gpu"
    with pytest.raises(InputError, match="device must be one of"):
        RenderOptions(lens, device="cuda")
    assert resolve_device("cpu") == "cpu" and resolve_device("auto") == "cpu"
    with pytest.raises(DeviceError, match="no usable GPU was found"):
        resolve_device("gpu")
    intr = Intrinsics(8, 6, 8.0, 8.0, 4.0, 3.0)
    frame = RGBDFrame(np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), Rig.registered(intr))
    with pytest.raises(DeviceError, match=r"pip install pcdof\[gpu\]"):
        run(frame, lens, device="gpu")


# ------------------------------------------------------------------------------------------ simulator (child)
def _frame(distorted=False):
    """A small two-camera frame built in closed form (no ray tracer): a slanted background 4-5 m away and a box
    at 1 m in front of it, seen by a 24 x 20 depth camera 25 mm beside and slightly rotated from a 32 x 24 colour
    camera; the colour is a gradient with the box in another colour. Returns (RGBDFrame, ThinLens) with a
    lens whose circle of confusion reaches a few pixels in front of and behind its focus."""
    import cv2

    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.lens import ThinLens

    ddist = (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103) if distorted else ()
    cdist = (0.2080, -0.5861, 0.0007, 0.0010, 0.4986) if distorted else ()
    depth_cam = Intrinsics(24, 20, 22.0, 22.1, 11.8, 9.7, ddist)
    color_cam = Intrinsics(32, 24, 30.0, 29.9, 15.7, 11.6, cdist)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.004, -0.006, 0.002]))[0]
    T[:3, 3] = [-0.025, 0.001, 0.002]
    v, u = np.mgrid[0:20, 0:24].astype(np.float32)
    depth = (4.0 + 0.04 * u + 0.01 * v).astype(np.float32)
    depth[6:13, 8:15] = 1.0
    depth[3, 3] = 0.0  # a sensor hole
    yy, xx = np.mgrid[0:24, 0:32]
    color = np.stack([xx * 7, yy * 9, 200 - xx * 3], axis=-1).astype(np.uint8)
    color[8:16, 9:19] = (230, 40, 40)
    frame = RGBDFrame(color, depth, Rig(color_cam, depth_cam, T))
    return frame, ThinLens(200.0, 1.4, 2.0)


@sim_only
def test_coc_matches_reference():
    from pcdof.gpu.coc import coc_maps
    from pcdof.lens import ThinLens
    from pcdof.stages.coc.reference import signed_coc_px

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 8.0, (12, 16)).astype(np.float32)
    depth[0, :4] = [0.0, np.nan, np.inf, -1.0]
    depth[1, 0] = 1.5  # exactly in focus
    lens = ThinLens(50.0, 1.4, 1.5)
    signed, size, stats = coc_maps(depth, lens, 40.0)
    ref = signed_coc_px(depth, lens, 40.0)
    got = signed.copy_to_host()
    np.testing.assert_allclose(got, ref, rtol=REL_COC, atol=1e-12)
    np.testing.assert_array_equal(size.copy_to_host(), np.abs(got))
    largest, n_out = stats.copy_to_host()
    assert largest == np.abs(got).max() and n_out == np.count_nonzero(np.abs(got) >= 1.0)
    assert got[0, 0] == got[0, 1] == got[0, 3] == 0.0 and got[1, 0] == 0.0


@sim_only
def test_clamped_window_widens_with_edges_and_cuts_back():
    from pcdof.gpu.launch import to_device
    from pcdof.gpu.render import clamped_window

    rgb = np.arange(5 * 6 * 3, dtype=np.float32).reshape(5, 6, 3)
    wide = clamped_window(to_device(rgb), -2, -2, (9, 10))
    np.testing.assert_array_equal(wide.copy_to_host(), np.pad(rgb, ((2, 2), (2, 2), (0, 0)), mode="edge"))
    np.testing.assert_array_equal(clamped_window(wide, 2, 2, (5, 6)).copy_to_host(), rgb)
    grey = rgb[..., 0].copy()
    np.testing.assert_array_equal(clamped_window(to_device(grey), -1, -1, (7, 8)).copy_to_host(),
                                  np.pad(grey, 1, mode="edge"))


@sim_only
def test_continued_border_matches_the_cpus():
    from pcdof.gpu.launch import to_device
    from pcdof.gpu.render import continued_border
    from pcdof.stages.render.border import continue_border

    rgb = np.random.default_rng(1).random((6, 7, 3)).astype(np.float32)
    for pad in (0, 1, 4):
        np.testing.assert_allclose(continued_border(to_device(rgb), pad).copy_to_host(), continue_border(rgb, pad),
                                   rtol=1e-6, atol=1e-6)
    bright = rgb * 3
    np.testing.assert_allclose(continued_border(to_device(bright), 3, 1.0).copy_to_host(),
                               continue_border(bright, 3, most=1.0), rtol=1e-6, atol=1e-6)


@sim_only
def test_mixed_edges_match_the_cpus():
    from pcdof.gpu.launch import to_device
    from pcdof.gpu.render import mix_edges as mix_on_device
    from pcdof.stages.render.mixed import mix_edges

    rng = np.random.default_rng(3)
    h, w, b = 10, 14, 2
    z = np.where(rng.random((h, w)) < 0.3, 1.0, 3.0).astype(np.float32)
    coc = np.where(z < 2, 0.3, 6.0).astype(np.float32)
    lin = rng.random((h + 2 * b, w + 2 * b, 3)).astype(np.float32)
    inner = lin[b:b + h, b:b + w]
    for y in range(h):  # each row's pixels mixes of their neighbours
        for x in range(1, w - 1):
            inner[y, x] = 0.6 * inner[y, x + 1] + 0.4 * inner[y, x - 1] if (x + y) % 3 == 0 else inner[y, x]
    out = rng.random((h, w, 3)).astype(np.float32)
    want = out.copy()
    assert mix_edges(want, lin, z, coc, b) > 0
    got = to_device(out.copy())
    mix_on_device(got, to_device(lin), z, coc, b)
    np.testing.assert_allclose(got.copy_to_host(), want, rtol=1e-6, atol=1e-6)


@sim_only
@pytest.mark.parametrize("distorted", [False, True])
def test_register_matches_reference(distorted):
    from pcdof.gpu.register import register_depth
    from pcdof.stages.register.reference import reproject_depth
    from pcdof.stages.register import default_depth_ratio

    frame, _ = _frame(distorted)
    rig = frame.rig
    depth = frame.depth_m.copy()
    depth[2:4, 16:20] = 0.0  # a hole: its border pixels are drawn as footprints
    got = register_depth(depth, rig).copy_to_host()
    ref = reproject_depth(depth, rig)
    covered = ref > 0
    assert covered.sum() > 0.5 * covered.size
    np.testing.assert_array_equal(got > 0, covered)
    rel = np.abs(got[covered] - ref[covered]) / ref[covered]
    ratio = default_depth_ratio(rig.depth)
    assert rel.max() < ratio
    assert np.count_nonzero(rel > REL_REGISTER) <= MAX_FOOTPRINT_SHARE * covered.sum()


def _holes(depth, rng):
    depth = depth.copy()
    depth[rng.random(depth.shape) < 0.12] = 0.0  # sensor holes inside
    depth[:2, :] = 0.0  # border rows: a hole with known pixels only on one side of its column
    depth[:, :2] = 0.0  # and columns: the corner (0..1, 0..1) has none on its row or column: lost
    depth[9:14, 15:20] = 0.0  # a larger hole: some of it far from its candidates
    return depth


@sim_only
def test_fill_matches_reference():
    from pcdof.color import to_float
    from pcdof.gpu.fill import fill_depth
    from pcdof.stages.fill.reference import fill_directional

    frame, _ = _frame()
    rng = np.random.default_rng(3)
    depth = _holes(frame.depth_m, rng)
    color = to_float(frame.color[:20, :24])
    for use_color in (True, False):
        got = fill_depth(depth, color, use_color=use_color).copy_to_host()
        # the default rule outside the depth camera's view ("candidates"), corners blended
        ref = fill_directional(depth, color.astype(np.float64) if use_color else None, use_color=use_color)
        assert np.all(got > 0)
        rel = np.abs(got - ref) / ref
        assert np.count_nonzero(rel > REL_FILL) <= 1, (use_color, rel.max())
        np.testing.assert_array_equal(got[depth > 0], depth[depth > 0])  # known pixels unchanged


@sim_only
def test_fill_outside_the_view_continues_past_the_measured_range_as_the_reference():
    """A slanted wall whose nearest part is cut off at the left and top: outside the view its planes run nearer
    than any measured depth, down to BORDER_NEARER times nearer, on the device as in the reference."""
    from pcdof.gpu.fill import fill_depth
    from pcdof.stages.fill.reference import fill_directional
    from pcdof.stages.fill.rules import BORDER_NEARER

    h, w = 14, 18
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = (1.0 / (0.2 + 0.012 * xx + 0.008 * yy)).astype(np.float32)  # nearest at the bottom right
    truth = truth[::-1, ::-1].copy()  # nearest at the top left
    depth = truth.copy()
    depth[:, :3] = 0.0
    depth[:2, :] = 0.0
    color = np.full((h, w, 3), 0.5, np.float32)
    got = fill_depth(depth, color).copy_to_host()
    ref = fill_directional(depth, color.astype(np.float64))
    zmin = float(depth[depth > 0].min())
    assert ref.min() < zmin and ref.min() >= zmin / BORDER_NEARER * (1 - 1e-6)  # the rule is exercised
    np.testing.assert_allclose(got, ref, rtol=REL_FILL)


def _layers(h, w, rng):
    lin = (rng.random((h, w, 3)) * 0.4 + np.linspace(0.0, 0.5, w)[None, :, None]).astype(np.float32)
    coc = np.full((h, w), 0.4, np.float32)  # in focus
    coc[:, : w // 3] = -4.0  # in front, blurred: the layers behind continue under its soft edge
    coc[2:6, w // 2: w - 2] = 2.5  # behind
    coc[h - 4:, w // 2:] = 6.0  # farther behind
    return lin, coc


@sim_only
@pytest.mark.parametrize("blades", [0, 6])
def test_render_matches_reference(blades):
    from pcdof.apertures import aperture_from_blades
    from pcdof.gpu.render import render_layers_linear
    from pcdof.stages.render.reference import render_layers_linear as reference

    rng = np.random.default_rng(blades)
    lin, coc = _layers(12, 16, rng)
    aperture = aperture_from_blades(blades, 15.0)
    out, layers = render_layers_linear(lin, coc, aperture)
    ref = reference(lin, coc, aperture=aperture)
    np.testing.assert_allclose(out.copy_to_host(), ref, rtol=0, atol=ATOL_RENDER)
    assert [l["side"] for l in layers] == ["front", "focus", "back", "back"]
    assert [l["extended"] for l in layers] == [False, True, True, True]  # every layer behind the blurred front
    flat = reference(lin, coc, aperture=aperture, extend_behind_layers=False)
    assert np.abs(flat - ref).max() > 100 * ATOL_RENDER  # the continuation behind the front matters here


@sim_only
def test_colour_codes():
    from pcdof.color import decode_to_linear, encode_from_linear, to_float
    from pcdof.gpu.color import decode, encode

    codes = np.arange(256, dtype=np.uint8).reshape(16, 16, 1)
    lin = decode(codes, linear=False)
    np.testing.assert_array_equal(lin.copy_to_host(), decode_to_linear(codes))
    np.testing.assert_array_equal(decode(codes, linear=True).copy_to_host(), to_float(codes))
    np.testing.assert_array_equal(encode(lin, np.uint8, linear=False).copy_to_host(), codes)  # round trip
    rng = np.random.default_rng(1)
    values = rng.uniform(-0.1, 1.3, (8, 8, 3)).astype(np.float32)
    from pcdof.gpu.launch import to_device

    for dtype in (np.uint8, np.uint16):
        got = encode(to_device(values), dtype, linear=False).copy_to_host().astype(np.int64)
        assert np.abs(got - encode_from_linear(values, dtype).astype(np.int64)).max() <= 1
    got = encode(to_device(values), np.float32, linear=False).copy_to_host()
    np.testing.assert_allclose(got, encode_from_linear(values, np.float32), rtol=1e-6, atol=1e-7)


@sim_only
def test_a_phone_rigs_depth_edges_are_opened_as_on_the_cpu():
    # the depth map in the photo's own camera on a 4x coarser grid (a phone): the register stage clears a band
    # around its depth edges for the colour-guided fill, on the GPU as on the CPU
    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.gpu.api import run
    from pcdof.lens import ThinLens
    from pcdof.options import RenderOptions
    from pcdof.stages.register import open_coarse_edges, register_depth
    from pcdof.stages.register.guided import coarse_depth_scale

    s = 4
    depth_cam = Intrinsics(8, 6, 7.0, 7.0, 3.5, 2.5)
    color_cam = Intrinsics(8 * s, 6 * s, 7.0 * s, 7.0 * s, (3.5 + 0.5) * s - 0.5, (2.5 + 0.5) * s - 0.5)
    rig = Rig(color_cam, depth_cam)
    assert coarse_depth_scale(rig) == pytest.approx(s)
    depth = np.full((6, 8), 3.0, np.float32)
    depth[2:4, 3:6] = 1.0
    yy, xx = np.mgrid[0:6 * s, 0:8 * s]
    color = np.stack([xx * 5, yy * 7, 120 + 0 * xx], axis=-1).astype(np.uint8)
    frame = RGBDFrame(color, depth, rig)
    result = run(frame, RenderOptions(ThinLens(50.0, 1.4, 2.0), highlights="off"))
    want, edges = open_coarse_edges(register_depth(frame), rig)
    assert edges["opened"] > 0
    got = result.depth_registered_m
    np.testing.assert_array_equal(got > 0, want > 0)
    np.testing.assert_allclose(got[want > 0], want[want > 0], rtol=REL_REGISTER)
    register = next(t for t in result.trace if t.name == "register")
    assert register.detail["edges"]["opened"] == edges["opened"]


@sim_only
def test_pipeline_on_the_gpu_matches_the_references_chained():
    from pcdof.color import to_float
    from pcdof.gpu.api import run
    from pcdof.options import RenderOptions
    from pcdof.pipeline import RenderResult
    from pcdof.stages.coc.reference import signed_coc_px
    from pcdof.stages.fill.reference import fill_directional
    from pcdof.stages.register.reference import reproject_depth
    from pcdof.stages.render.reference import render_physical

    frame, lens = _frame()
    result = run(frame, RenderOptions(lens, highlights="off"))
    assert isinstance(result, RenderResult)
    names = [t.name for t in result.trace]
    assert names == ["upload", "register", "fill", "coc", "highlights", "render", "download"], names
    assert all(t.detail.get("device") in ("gpu", "cpu") for t in result.trace)
    reg = reproject_depth(frame.depth_m, frame.rig)
    np.testing.assert_array_equal(result.depth_registered_m > 0, reg > 0)
    assert np.abs(result.depth_registered_m - reg).max() < 1e-3  # metres: the 1 mm
    filled = fill_directional(result.depth_registered_m, to_float(frame.color).astype(np.float64))
    np.testing.assert_allclose(result.depth_filled_m, filled, rtol=REL_FILL)
    np.testing.assert_allclose(result.coc_px, np.abs(signed_coc_px(result.depth_filled_m, lens, frame.rig.color.fx)),
                               rtol=REL_COC, atol=1e-12)
    assert result.coc_px.max() > 2.0  # something is blurred
    image = render_physical(frame.color, result.depth_filled_m, lens, fx=frame.rig.color.fx)
    assert result.image.dtype == np.uint8 and result.image.shape == frame.color.shape
    assert _psnr(result.image / 255.0, image) >= MIN_PIPELINE_PSNR_DB


@parent_only
def test_parent_frames_streamed_in_order():
    from pcdof.gpu.stream import map_overlapped

    out = list(map_overlapped(lambda i: i * i, range(7), in_flight=2))
    assert out == [i * i for i in range(7)]

    def fail(i):
        if i == 3:
            raise ValueError("frame 3")
        return i

    it = map_overlapped(fail, range(5))
    assert [next(it) for _ in range(3)] == [0, 1, 2]
    with pytest.raises(ValueError, match="frame 3"):
        next(it)


@sim_only
def test_streamed_frames_match_one_at_a_time():
    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.gpu.api import run
    from pcdof.gpu.stream import render_frames
    from pcdof.lens import ThinLens
    from pcdof.options import RenderOptions

    rig = Rig.registered(Intrinsics(12, 8, 40.0, 40.0, 5.5, 3.5))  # no registration: fill, CoC and render only
    depth = np.full((8, 12), 3.0, np.float32)
    depth[2:6, 3:7] = 1.0
    depth[0, 0] = depth[5, 9] = 0.0
    rng = np.random.default_rng(5)
    frames = [RGBDFrame(rng.integers(0, 250, (8, 12, 3), dtype=np.uint8), depth, rig) for _ in range(2)]
    options = RenderOptions(ThinLens(200.0, 1.4, 1.0), highlights="off")
    streamed = list(render_frames(frames, options))
    assert len(streamed) == 2
    for frame, got in zip(frames, streamed):
        alone = run(frame, options)
        assert [t.name for t in got.trace if t.name == "register" and t.skipped] == ["register"]
        np.testing.assert_array_equal(got.depth_filled_m, alone.depth_filled_m)
        assert np.abs(got.image.astype(int) - alone.image.astype(int)).max() <= 1  # float32 atomics: any order
        assert np.abs(got.image.astype(int) - frame.color.astype(int)).max() > 10  # the frame was blurred


@sim_only
def test_highlights_and_paper_paths():
    from pcdof.lens import aperture_for
    from pcdof.camera import Intrinsics, RGBDFrame, Rig
    from pcdof.color import encode_from_linear
    from pcdof.gpu.api import run
    from pcdof.stages.highlights import prepare_highlights, reconstruct_prepared
    from pcdof.lens import PaperLens, ThinLens
    from pcdof.options import RenderOptions
    from pcdof.stages.coc.reference import signed_coc_px
    from pcdof.stages.render.reference import render_layers_linear
    from pcdof.stages.render import render_image

    rig = Rig.registered(Intrinsics(12, 8, 40.0, 40.0, 5.5, 3.5))
    depth = np.full((8, 12), 3.0, np.float32)
    depth[:, :4] = 1.0  # in focus
    color = np.full((8, 12, 3), 90, np.uint8)
    color[3:5, 7:9] = (255, 255, 200)  # a clipped blob behind the focus
    frame = RGBDFrame(color, depth, rig)
    lens = ThinLens(200.0, 1.4, 1.0)
    result = run(frame, RenderOptions(lens, highlights="auto"))
    rec = {t.name: t for t in result.trace}["highlights"]
    assert not rec.skipped and rec.detail["device"] == "cpu", rec
    lin = reconstruct_prepared(prepare_highlights(color), method="auto", coc_px=result.coc_px)
    assert lin.max() > 1.0  # the blob was raised above white
    coc = signed_coc_px(result.depth_filled_m, lens, rig.color.fx)
    ref = render_layers_linear(lin, coc, aperture=aperture_for(lens))
    expected = encode_from_linear(ref.astype(np.float32), np.uint8)
    assert _psnr(result.image / 255.0, expected / 255.0) >= MIN_PIPELINE_PSNR_DB
    paper = PaperLens(focus_distance_m=1.0)
    result = run(frame, RenderOptions(paper, method="paper"))
    expected, _ = render_image(color, result.depth_filled_m, paper, fx=rig.color.fx, method="paper",
                               max_range_m=rig.max_range_m)
    np.testing.assert_array_equal(result.image, expected)
    assert {t.name: t for t in result.trace}["render"].detail["device"] == "cpu"
