"""Every frame command takes a source: the bundled RealSense .bag, a folder, a list file, or COLOR DEPTH --calib.

The same options reach the kernels whichever command parses them: a frame rendered by ``batch``
equals the frame ``render`` writes with the same flags, bit for bit.
"""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest

from conftest import invoke

from pcdof import io
from pcdof.errors import InputError, exit_code_for

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BAG = os.path.join(ROOT, "data", "real", "realsense_d435_bag", "single_depth_color_640x480.bag")
S = os.path.join(ROOT, "data", "sample")
PAIR = [f"{S}/color.png", f"{S}/depth.png", "--calib", f"{S}/calib.json"]


def ok(result):
    assert result.exit_code == 0, (result.exit_code, result.output)
    return result


@pytest.fixture
def folder(tmp_path):
    """A color/ + depth/ folder of three frames; frame k is the sample shifted by k pixels (distinct frames)."""
    root = tmp_path / "seq"
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    color, depth = (cv2.imread(f"{S}/{name}.png", cv2.IMREAD_UNCHANGED) for name in ("color", "depth"))
    for k in range(3):
        cv2.imwrite(str(root / "color" / f"{k:03d}.png"), np.roll(color, k, axis=1))
        cv2.imwrite(str(root / "depth" / f"{k:03d}.png"), np.roll(depth, k, axis=1))
    shutil.copy(f"{S}/calib.json", root / "calib.json")
    return root


class TestRecording:
    def test_render_register_cloud(self, tmp_path):
        out = tmp_path / "r.png"
        result = ok(invoke("render", BAG, "--frame", "0", "-o", out))
        assert result.stdout.startswith("pcdof render: focus ") and "depth at the image centre" in result.stdout
        assert "max blur" in result.stdout and str(out) in result.stdout
        assert io.read_color(str(out)).shape == (480, 640, 3)
        ok(invoke("register", BAG, "-o", tmp_path / "d.npy"))
        depth = np.load(tmp_path / "d.npy")
        assert depth.shape == (480, 640) and np.count_nonzero(depth) > 0.5 * depth.size
        result = ok(invoke("cloud", BAG, "--frame", "0", "--stride", "4", "-o", tmp_path / "c.ply"))
        assert "pcdof cloud: wrote " in result.stdout and (tmp_path / "c.ply").stat().st_size > 1000

    def test_the_recording_frame_is_the_sources_frame(self, tmp_path):
        """render INPUT renders what pcdof.pipeline.run gives for open_source(INPUT).frame(0)."""
        from pcdof import pipeline
        from pcdof.lens import ThinLens
        from pcdof.options import RenderOptions
        from pcdof.sources import open_source

        ok(invoke("render", BAG, "-o", tmp_path / "r.png", "--focus-distance", "1.2", "--f-number", "2.8"))
        with open_source(BAG) as src:
            frame = src.frame(0).rgbd()
        lens = ThinLens(focal_length_mm=50.0, f_number=2.8, focus_distance_m=1.2)
        expected = pipeline.run(frame, RenderOptions(lens=lens)).image
        np.testing.assert_array_equal(io.read_color(str(tmp_path / "r.png")), expected)

    def test_view_screenshot(self, tmp_path):
        pytest.importorskip("pyvista")
        shot = tmp_path / "v.png"
        result = ok(invoke("view", BAG, "--frame", "0", "--screenshot", shot, "--window-size", "400x200"))
        assert "pcdof view: focus " in result.stdout and str(shot) in result.stdout
        assert io.read_color(str(shot)).shape[:2] == (200, 400)

    def test_batch_with_video(self, tmp_path):
        pytest.importorskip("av")
        out, video = tmp_path / "out", tmp_path / "out.mp4"
        result = invoke("batch", BAG, "-o", out, "--video", video, "--workers", "1", "--no-progress")
        ok(result)
        assert "pcdof batch: focus " in result.stdout and "image centre" in result.stdout
        assert "focus point" not in result.stderr
        report = json.loads((out / "report.json").read_text())
        assert report["input"]["layout"] == "realsense-bag" and report["frames"][0]["frame"] == 0
        assert (out / "frame_000000.png").exists() and video.stat().st_size > 0

    def test_batch_gives_the_frame_render_gives(self, tmp_path):
        """The options object reaches the kernels: same flags, same pixels, through both commands."""
        flags = ["--quality", "exact", "--f-number", "1.4", "--focus-distance", "0.9", "--fill-method", "telea",
                 "--highlights", "4"]
        ok(invoke("render", BAG, "-o", tmp_path / "r.png", *flags))
        ok(invoke("batch", BAG, "-o", tmp_path / "b", "--workers", "1", "--no-progress", *flags))
        rendered = io.read_color(str(tmp_path / "r.png"))
        np.testing.assert_array_equal(io.read_color(str(tmp_path / "b" / "frame_000000.png")), rendered)
        balanced = tmp_path / "balanced.png"
        ok(invoke("render", BAG, "-o", balanced, *flags[2:]))
        assert not np.array_equal(io.read_color(str(balanced)), rendered)  # the quality flag did reach the kernels
        settings = json.loads((tmp_path / "b" / "report.json").read_text())["settings"]
        assert settings["quality"] == "exact" and settings["fill_method"] == "telea" and settings["linear"] is False
        assert settings["highlights"] == 4.0

    def test_frame_out_of_range_is_one_line(self, tmp_path):
        result = invoke("render", BAG, "--frame", "7", "-o", tmp_path / "r.png")
        assert result.exit_code == exit_code_for(InputError("")), result.output
        lines = result.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error: ") and "out of range" in lines[0], lines
        assert not os.listdir(tmp_path)

    def test_calib_overrides_the_recording(self, tmp_path):
        """--calib replaces the recording's calibration (here with sizes that do not match: refused, named)."""
        result = invoke("register", BAG, "--calib", f"{S}/calib.json", "-o", tmp_path / "d.npy")
        assert result.exit_code != 0 and "calib.json" in result.stderr and len(result.stderr.splitlines()) == 1


class TestSequences:
    def test_folder_frame_is_the_pair(self, tmp_path, folder):
        for k in (0, 2, -1):
            ok(invoke("render", folder, "--frame", k, "-o", tmp_path / f"f{k}.png", "--focus-at", "60,40"))
        j = 2
        ok(invoke("render", folder / "color" / f"{j:03d}.png", folder / "depth" / f"{j:03d}.png", "--calib",
                  folder / "calib.json", "-o", tmp_path / "pair.png", "--focus-at", "60,40"))
        pair = io.read_color(str(tmp_path / "pair.png"))
        np.testing.assert_array_equal(io.read_color(str(tmp_path / "f2.png")), pair)
        np.testing.assert_array_equal(io.read_color(str(tmp_path / "f-1.png")), pair)
        assert not np.array_equal(io.read_color(str(tmp_path / "f0.png")), pair)

    def test_list_file(self, tmp_path, folder):
        listing = folder / "frames.txt"
        listing.write_text("".join(f"color/{k:03d}.png depth/{k:03d}.png\n" for k in range(3)))
        ok(invoke("render", listing, "--frame", "1", "-o", tmp_path / "l.png", "--focus-distance", "2"))
        ok(invoke("render", folder, "--frame", "1", "-o", tmp_path / "f.png", "--focus-distance", "2"))
        np.testing.assert_array_equal(io.read_color(str(tmp_path / "l.png")), io.read_color(str(tmp_path / "f.png")))

    def test_frame_out_of_range(self, tmp_path, folder):
        result = invoke("cloud", folder, "--frame", "3", "-o", tmp_path / "c.ply")
        assert result.exit_code == exit_code_for(InputError("")) and len(result.stderr.splitlines()) == 1
        assert "frame index 3 is out of range" in result.stderr

    def test_output_onto_a_frame_file_is_refused(self, folder):
        target = folder / "color" / "001.png"
        before = target.read_bytes()
        result = invoke("render", folder, "--frame", "1", "-o", target)
        assert result.exit_code == exit_code_for(InputError("")) and "refusing to overwrite" in result.stderr
        assert target.read_bytes() == before

    def test_frame_with_a_pair_is_refused(self, tmp_path):
        result = invoke("render", *PAIR, "--frame", "1", "-o", tmp_path / "r.png")
        assert result.exit_code == exit_code_for(InputError("")) and "--frame" in result.stderr

    def test_pair_needs_calib(self, tmp_path):
        result = invoke("render", f"{S}/color.png", f"{S}/depth.png", "-o", tmp_path / "r.png")
        assert result.exit_code == 2 and "--calib" in result.stderr


class TestReportLine:
    def test_quiet_silences_the_line(self, tmp_path):
        result = ok(invoke("render", *PAIR, "-o", tmp_path / "r.png", "-q"))
        assert result.stdout == ""
        result = ok(invoke("render", *PAIR, "-o", tmp_path / "r2.png", "--focus-distance", "1.5"))
        assert result.stdout.startswith("pcdof render: focus 1.50 m (--focus-distance), max blur ")

    def test_batch_names_the_missing_file_first(self, tmp_path, folder):
        missing = folder / "depth" / "001.png"
        missing.unlink()
        listing = folder / "frames.txt"
        listing.write_text("".join(f"color/{k:03d}.png depth/{k:03d}.png\n" for k in range(3)))
        result = invoke("batch", listing, "-o", tmp_path / "out", "--workers", "1", "--no-progress")
        assert result.exit_code == 10, result.output
        failed = [line for line in result.stderr.splitlines() if line.startswith("pcdof: frame 1:")]
        assert len(failed) == 1 and failed[0].startswith("pcdof: frame 1: ImageReadError: "), failed
        assert str(missing) in failed[0] and failed[0].index(str(missing)) < failed[0].index("(input ")
        assert "focus" not in result.stderr


class TestFloatColour:
    """Float colour without --linear is read as sRGB, and render says so (it usually holds linear light)."""

    def _frame(self, tmp_path):
        color = io.read_color(f"{S}/color.png").astype(np.float32) / 255
        np.save(tmp_path / "c.npy", color)
        return [tmp_path / "c.npy", f"{S}/depth.png", "--calib", f"{S}/calib.json"]

    def test_warns_without_linear(self, tmp_path):
        result = invoke("render", *self._frame(tmp_path), "-o", tmp_path / "r.exr")
        assert result.exit_code == 0, result.output
        assert "pcdof: warning: the colour image holds floats and is read as sRGB" in result.stderr
        assert "--linear" in result.stderr

    def test_quiet_with_linear(self, tmp_path):
        result = invoke("render", *self._frame(tmp_path), "--linear", "-o", tmp_path / "r.exr")
        assert result.exit_code == 0, result.output
        assert "warning" not in result.stderr
