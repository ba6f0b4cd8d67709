"""CLI checks made before any work: contradictory or out-of-range flags, outputs that cannot hold the
result, and all-or-nothing outputs (render --save-maps, view --screenshot + --html)."""

import os

import click
import numpy as np
import pytest

from conftest import invoke

import pcdof.io
from pcdof.batch.focus import check_xy
from pcdof.cli import main
from pcdof.errors import EXIT_CODES, ImageWriteError, InputError, LensError
from pcdof.io import load_frame

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "data", "sample")
FRAME = [f"{SAMPLE}/color.png", f"{SAMPLE}/depth.png", "--calib", f"{SAMPLE}/calib.json"]


def assert_one_line_error(result, error_class, *words):
    assert result.exit_code == EXIT_CODES[error_class], result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), result.stderr
    for word in words:
        assert word in lines[0]


class TestRenderFlags:
    def test_focus_distance_and_focus_at_exclude_each_other(self, tmp_path):
        result = invoke("render", *FRAME, "-o", tmp_path / "x.png", "--focus-at", "10,10", "--focus-distance", 2)
        assert_one_line_error(result, InputError, "--focus-distance", "--focus-at")
        assert os.listdir(tmp_path) == []

    @pytest.mark.parametrize("flags, named", [
        (["--method", "paper", "--f-number", 0], "--f-number"),  # checked whichever method uses it
        (["--method", "paper", "--focal-length", -5], "--focal-length"),
        (["--weight-sigma", "nan"], "--weight-sigma"),
        (["--method", "paper", "--sigma", 0], "--sigma"),
        (["--method", "paper", "--weight", "eq1", "--eq1-aperture", "inf"], "--eq1-aperture"),
        (["--focus-distance", "-1"], "--focus-distance"),
    ])
    def test_lens_flags_are_named(self, tmp_path, flags, named):
        result = invoke("render", *FRAME, "-o", tmp_path / "x.png", *flags)
        assert_one_line_error(result, LensError, named)
        assert os.listdir(tmp_path) == []

    def test_output_formats_that_cannot_hold_the_render(self, tmp_path):
        frame = load_frame(*FRAME[:2], FRAME[3])
        inputs = tmp_path / "in"
        inputs.mkdir()
        np.save(inputs / "color16.npy", frame.color.astype(np.uint16) * 257)
        np.save(inputs / "color.npy", frame.color.astype(np.float32) / 255)
        out = tmp_path / "out"
        result = invoke("render", inputs / "color16.npy", *FRAME[1:], "--focus-distance", 1.49, "-o", out / "x.jpg")
        assert_one_line_error(result, InputError, "uint16", ".jpg", ".png")  # 16-bit colour: no 8-bit JPEG
        assert not out.exists()
        args = [inputs / "color.npy", FRAME[1], *FRAME[2:], "--linear", "--focus-distance", 1.49]
        result = invoke("render", *args, "-o", out / "x.npy")
        assert result.exit_code == 0, result.output
        image = np.load(out / "x.npy")
        assert image.dtype == np.float32 and image.shape == frame.color.shape
        result = invoke("render", *args, "-o", out / "x.png")  # float to PNG: encoded (tests/test_first_contact.py)
        assert result.exit_code == 0, result.output
        assert pcdof.io.read_color(out / "x.png").dtype == np.uint16


class TestAllOrNothingOutputs:
    def test_render_save_maps_failure_leaves_nothing(self, tmp_path):
        maps = tmp_path / "maps"
        (maps / "depth_filled.npy").mkdir(parents=True)  # the second map cannot be written
        result = invoke("render", *FRAME, "-o", tmp_path / "x.png", "--save-maps", maps, "--focus-distance", 1.49)
        assert result.exit_code != 0 and "Traceback" not in result.output
        assert sorted(os.listdir(tmp_path)) == ["maps"]
        assert os.listdir(maps) == ["depth_filled.npy"]  # the first map was removed again

    def test_render_save_maps_success(self, tmp_path):
        result = invoke("render", *FRAME, "-o", tmp_path / "x.png", "--save-maps", tmp_path / "maps",
                        "--focus-distance", 1.49)
        assert result.exit_code == 0, result.output
        assert sorted(os.listdir(tmp_path / "maps")) == ["coc_px.npy", "coc_px.png", "depth_filled.npy",
                                                         "depth_filled.png", "depth_filled_preview.png",
                                                         "depth_registered.npy", "depth_registered.png",
                                                         "depth_registered_preview.png", "trace.json"]
        from pcdof import io
        from pcdof.previews import bar_width_px

        preview = io.read_color(str(tmp_path / "maps" / "depth_filled_preview.png"))
        raw = io.read_depth(str(tmp_path / "maps" / "depth_filled.npy"))
        assert preview.shape == (raw.shape[0], raw.shape[1] + bar_width_px(raw.shape[0]), 3)
        assert preview.dtype == np.uint8 and preview.std() > 20  # a picture, not a black frame

    def test_view_html_failure_removes_the_screenshot(self, tmp_path):
        (tmp_path / "blocker").write_bytes(b"not a folder")
        shot = tmp_path / "view.png"
        result = invoke("view", *FRAME, "--screenshot", shot, "--html", tmp_path / "blocker" / "x.html",
                        "--window-size", "320x160")
        assert_one_line_error(result, ImageWriteError, "--html")
        assert not shot.exists()

    def test_view_html_into_a_new_folder(self, tmp_path):
        shot, page = tmp_path / "view.png", tmp_path / "new" / "deeper" / "view.html"
        result = invoke("view", *FRAME, "--screenshot", shot, "--html", page, "--window-size", "320x160")
        assert result.exit_code == 0, result.output
        assert shot.stat().st_size > 0 and page.read_text(encoding="utf-8").lstrip().lower().startswith("<!doctype")

    def test_view_focus_flags_exclude_each_other(self, tmp_path):
        result = invoke("view", *FRAME, "--screenshot", tmp_path / "v.png", "--focus-at", "5,5",
                        "--focus-distance", 1)
        assert_one_line_error(result, InputError, "--focus-distance", "--focus-at")


class TestBatchFlags:
    @pytest.mark.parametrize("flags, named", [
        (["--focus-beta", "nan"], "--focus-beta"),
        (["--focus-window", -3], "--focus-window"),
        (["--focus-min-cutoff", 0], "--focus-min-cutoff"),
        (["--max-time-difference", -5], "--max-time-difference"),
        (["--fps", "inf"], "--fps"),
    ])
    def test_flags_are_checked_before_work(self, tmp_path, flags, named):
        result = invoke("batch", SAMPLE, "-o", tmp_path / "out", *flags)
        assert_one_line_error(result, InputError, named)
        assert not (tmp_path / "out").exists()

    def test_lens_flag(self, tmp_path):
        result = invoke("batch", SAMPLE, "-o", tmp_path / "out", "--f-number", 0)
        assert_one_line_error(result, LensError, "--f-number")

    def test_focus_pixel_bounds_follow_pixel_centres(self):
        rig = load_frame(*FRAME[:2], FRAME[3]).rig
        w, h = rig.color.width, rig.color.height
        assert check_xy((-0.5, -0.5), rig) == (-0.5, -0.5)  # pixel 0 spans [-0.5, 0.5)
        assert check_xy((w - 0.6, h - 0.6), rig)
        for xy in ((w - 0.5, 0), (0, h - 0.5), (-0.51, 0)):
            with pytest.raises(InputError, match="outside"):
                check_xy(xy, rig)


def test_input_paths_are_checked_by_pcdof_readers_not_click():
    """An unreadable input is pcdof's ImageReadError (exit 3, one line), not click's usage error: no
    click.Path option or argument checks readability itself."""
    def commands(group):  # the group loads its commands lazily
        ctx = click.Context(group)
        for name in group.list_commands(ctx):
            cmd = group.get_command(ctx, name)
            yield from commands(cmd) if isinstance(cmd, click.Group) else [cmd]

    paths = [(cmd.name, p.name, p.type) for cmd in commands(main) for p in cmd.params
             if isinstance(p.type, click.Path)]
    assert len(paths) >= 10  # every command's inputs and outputs are covered
    assert [(cmd, name) for cmd, name, kind in paths if kind.readable] == []


class TestFollowUps:
    """Arguments checked once and up front, where a late check would be caught per frame or ignored."""

    def test_focus_track_radius_is_checked_once(self):
        from pcdof.batch.runner import measure_focus_track

        rig = load_frame(*FRAME[:2], FRAME[3]).rig
        with pytest.raises(InputError, match="radius_px"):
            measure_focus_track(None, rig, (5, 5), radius_px=-1)  # before any frame is read

    def test_render_image_method_must_be_a_name(self):
        from pcdof.lens import ThinLens
        from pcdof.stages.render import render_image

        color = np.zeros((8, 8, 3), np.uint8)
        with pytest.raises(InputError, match="method must be one of"):
            render_image(color, np.ones((8, 8), np.float32), ThinLens(50, 2, 1), fx=100.0, method=["physical"])

    @pytest.mark.parametrize("ratio", [10 ** 400, "0.1", True, -1, float("nan")])
    def test_reproject_depth_ratio(self, ratio):
        from pcdof.stages.register import reproject_depth

        frame = load_frame(*FRAME[:2], FRAME[3])
        with pytest.raises(InputError, match="max_depth_ratio"):
            reproject_depth(frame.depth_m, frame.rig, max_depth_ratio=ratio)

    @pytest.mark.parametrize("blades", [65, 10 ** 9])
    def test_aperture_blades_are_capped(self, blades):
        from pcdof.lens import MAX_APERTURE_BLADES, ThinLens

        assert ThinLens(50, 2, 1, MAX_APERTURE_BLADES).aperture_blades == MAX_APERTURE_BLADES
        with pytest.raises(LensError, match="aperture_blades"):
            ThinLens(50, 2, 1, blades)

    def test_focus_pixel_bounds_agree_with_batch(self):
        from pcdof.lens import focus_depth_at

        z = np.arange(1, 13, dtype=np.float32).reshape(3, 4)
        assert focus_depth_at(z, -0.5, -0.5, radius_px=0) == 1.0
        assert focus_depth_at(z, 3.49, 2.49, radius_px=0) == 12.0
        for x, y in ((3.5, 0), (0, 2.5), (-0.51, 0)):
            with pytest.raises(InputError, match="outside"):
                focus_depth_at(z, x, y)
