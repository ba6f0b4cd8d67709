"""What a new user meets in the first minutes: typo hints, swapped inputs, screen formats for float renders,
the files ``--save-maps`` promises, help texts that name the real flags, and README examples that stay in out/."""

import os
import re
import shlex
import subprocess
import sys
import warnings

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof import io
from pcdof.cli import SUBCOMMANDS, main
from pcdof.color import encode_for_display
from pcdof.errors import InputError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "data", "sample")
TUM = os.path.join(ROOT, "data", "real", "tum_rgbd_open3d")
CALIB = ["--calib", f"{SAMPLE}/calib.json"]
LENS = ["--focus-distance", "1.49", "--focal-length", "85", "--f-number", "1.8"]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def srgb_encode(linear: np.ndarray, top: int) -> np.ndarray:
    """IEC 61966-2-1's encoding written out in float64, clipped to [0, 1], rounded to codes 0..top."""
    x = np.clip(linear.astype(np.float64), 0.0, 1.0)
    enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(enc * top).astype(np.int64)


# ---------------------------------------------------------------------------------------------------------
class TestSubcommandTypos:
    @pytest.mark.parametrize("typo, meant", [("rendr", "render"), ("viw", "view"), ("registr", "register"),
                                             ("bech", "bench"), ("exprot", "export")])
    def test_a_close_name_is_suggested(self, typo, meant):
        result = invoke(typo)
        assert result.exit_code == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), result.stderr
        assert f"No such command '{typo}'" in lines[0] and f"Did you mean '{meant}'?" in lines[0]

    def test_nothing_close_gets_no_guess(self):
        result = invoke("frobnicate")
        assert result.exit_code == 2 and "No such command 'frobnicate'" in result.stderr
        assert "Did you mean" not in result.stderr

    def test_real_subcommands_and_options_are_untouched(self):
        assert invoke("render", "-h").exit_code == 0
        assert invoke("--version").exit_code == 0
        assert set(SUBCOMMANDS) >= {"render", "view", "batch"}

    def test_the_console_script_says_the_same(self):
        done = subprocess.run([sys.executable, "-m", "pcdof", "rendr"], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": os.path.join(ROOT, "src")}, timeout=120)
        assert done.returncode == 2
        assert "Did you mean 'render'?" in done.stderr and "Traceback" not in done.stderr


# ---------------------------------------------------------------------------------------------------------
class TestDepthInTheColourSlot:
    def test_sixteen_bit_grey_colour_warns(self, tmp_path):
        raw = np.random.default_rng(0).integers(500, 4000, (12, 16), dtype=np.uint16)
        cv2.imwrite(str(tmp_path / "d.png"), raw)
        with pytest.warns(UserWarning, match="single-channel 16-bit.*COLOR DEPTH"):
            img = io.read_color(tmp_path / "d.png")
        np.testing.assert_array_equal(img, np.repeat(raw[:, :, None], 3, axis=2))  # still read as it was

    @pytest.mark.parametrize("kind", ["grey8", "rgb16"])
    def test_ordinary_colour_files_do_not_warn(self, tmp_path, kind):
        rng = np.random.default_rng(1)
        img = (rng.integers(0, 256, (12, 16), dtype=np.uint8) if kind == "grey8"
               else rng.integers(0, 65536, (12, 16, 3), dtype=np.uint16))
        cv2.imwrite(str(tmp_path / "c.png"), img)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            io.read_color(tmp_path / "c.png")

    def test_the_command_line_says_so_in_one_line(self, tmp_path):
        # the TUM frame's depth is registered to its colour, so the swapped file has the colour's size
        result = invoke("render", f"{TUM}/depth.png", f"{TUM}/depth.png", "--calib", f"{TUM}/calib.json",
                        "-o", tmp_path / "x.png", "--focus-distance", "2")
        warning = [line for line in result.stderr.splitlines() if "single-channel 16-bit" in line]
        assert len(warning) == 1 and warning[0].startswith("pcdof: warning: colour file ")
        assert "depth.png" in warning[0]

    def test_swapped_files_are_one_error_not_a_warning_and_an_error(self, tmp_path):
        result = invoke("render", f"{TUM}/depth.png", f"{TUM}/color.png", "--calib", f"{TUM}/calib.json",
                        "-o", tmp_path / "x.png")
        assert result.exit_code == 3
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error: depth file ") and "colour image" in lines[0]


# ---------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def linear_colour(tmp_path_factory):
    """The sample's colour as float32 linear light, a corner raised above white (a light)."""
    folder = tmp_path_factory.mktemp("linear")
    srgb = cv2.imread(f"{SAMPLE}/color.png")[:, :, ::-1].astype(np.float64) / 255
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4).astype(np.float32)
    linear[:20, :20] *= 6.0
    np.save(folder / "linear.npy", linear)
    return folder / "linear.npy"


class TestFloatRendersForScreens:
    def render(self, colour, out, *extra):
        result = invoke("render", colour, f"{SAMPLE}/depth.png", *CALIB, *LENS, "-o", out, *extra)
        assert result.exit_code == 0, result.output
        return result

    def test_linear_png_is_the_srgb_encoding_of_the_linear_render(self, linear_colour, tmp_path):
        self.render(linear_colour, tmp_path / "lin.tif", "--linear")
        result = self.render(linear_colour, tmp_path / "lin.png", "--linear")
        float_render = io.read_color(tmp_path / "lin.tif")
        png = io.read_color(tmp_path / "lin.png")
        assert png.dtype == np.uint16 and png.shape == float_render.shape
        diff = np.abs(png.astype(np.int64) - srgb_encode(float_render, 65535))
        assert diff.max() <= 2  # float32 against float64 arithmetic, 16-bit codes
        assert (png[:20, :20] == 65535).any()  # the light above white clipped
        assert "linear light encoded to sRGB, 16-bit" in result.stdout and "clipped" in result.stdout

    def test_linear_jpeg_is_eight_bit_srgb(self, linear_colour, tmp_path):
        self.render(linear_colour, tmp_path / "lin.tif", "--linear")
        result = self.render(linear_colour, tmp_path / "lin.jpg", "--linear")
        jpeg = io.read_color(tmp_path / "lin.jpg")
        expected = srgb_encode(io.read_color(tmp_path / "lin.tif"), 255)
        assert jpeg.dtype == np.uint8 and np.abs(jpeg - expected).mean() < 2.0  # JPEG is lossy
        assert "linear light encoded to sRGB, 8-bit" in result.stdout

    def test_float_srgb_png_is_quantised_not_encoded_twice(self, tmp_path):
        srgb = (cv2.imread(f"{SAMPLE}/color.png")[:, :, ::-1] / 255).astype(np.float32)
        np.save(tmp_path / "srgb.npy", srgb)
        self.render(tmp_path / "srgb.npy", tmp_path / "s.tif")
        result = self.render(tmp_path / "srgb.npy", tmp_path / "s.png")
        expected = np.rint(np.clip(io.read_color(tmp_path / "s.tif").astype(np.float64), 0, 1) * 65535)
        assert np.abs(io.read_color(tmp_path / "s.png") - expected).max() <= 1
        assert "float sRGB quantised, 16-bit" in result.stdout

    def test_encode_for_display_counts_clipped_pixels(self):
        image = np.zeros((2, 5, 3), np.float32)
        image[0, 0, 1] = 3.0    # above white in one channel
        image[1, 4] = -0.5      # below black
        encoded, clipped = encode_for_display(image, np.uint8, linear=True)
        assert clipped == pytest.approx(2 / 10)
        assert encoded[0, 0].tolist() == [0, 255, 0] and encoded[1, 4].tolist() == [0, 0, 0]

    @pytest.mark.parametrize("bad", [np.zeros((4, 4, 3), np.uint8), np.full((4, 4), np.nan, np.float32),
                                     np.zeros((0, 4, 3), np.float32)])
    def test_encode_for_display_refuses_what_it_cannot_encode(self, bad):
        with pytest.raises(InputError, match="image must"):
            encode_for_display(bad, np.uint16, linear=False)

    def test_encode_for_display_refuses_other_dtypes(self):
        with pytest.raises(InputError, match="dtype must be uint8 or uint16"):
            encode_for_display(np.zeros((2, 2), np.float32), np.float32, linear=True)


# ---------------------------------------------------------------------------------------------------------
class TestWhatTheHelpAndMapsPromise:
    def test_save_maps_writes_the_registered_depth_as_npy(self, tmp_path):
        result = invoke("render", f"{SAMPLE}/color.png", f"{SAMPLE}/depth.png", *CALIB, *LENS,
                        "-o", tmp_path / "x.png", "--save-maps", tmp_path / "maps")
        assert result.exit_code == 0, result.output
        registered = io.read_depth(tmp_path / "maps" / "depth_registered.npy")
        as_png = io.read_depth(tmp_path / "maps" / "depth_registered.png", 0.001)
        filled = io.read_depth(tmp_path / "maps" / "depth_filled.npy")
        assert registered.dtype == np.float32 and registered.shape == filled.shape
        np.testing.assert_allclose(registered, as_png, atol=0.0005 + 1e-6)  # the PNG holds whole millimetres
        assert (registered == 0).any() and not (filled == 0).any()  # registered keeps its holes; filled has none

    @pytest.mark.parametrize("command", ["render", "register", "cloud", "export", "synth", "bench"])
    def test_help_names_the_output_flag(self, command):
        text = invoke(command, "--help").output
        description = text.split("Options:")[0]
        assert "OUTPUT" not in description and "-o" in description

    def test_view_without_a_display_suggests_every_way_that_needs_none(self, monkeypatch, tmp_path):
        monkeypatch.delenv("DISPLAY", raising=False)
        monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
        monkeypatch.setattr("sys.platform", "linux")
        result = invoke("view", f"{SAMPLE}/color.png", f"{SAMPLE}/depth.png", *CALIB)
        assert result.exit_code == 6
        for way in ("--screenshot", "--html", "--serve"):
            assert way in result.stderr


# ---------------------------------------------------------------------------------------------------------
class TestLongStepsShowProgress:
    def test_synth_says_what_it_is_doing_before_it_does_it(self, tmp_path):
        result = invoke("synth", "portrait", "-o", tmp_path / "s", "--size", "32x24", "--depth-size", "32x24",
                        "--no-gt")
        assert result.exit_code == 0, result.output
        lines = result.stderr.splitlines()
        assert lines[0].startswith("pcdof synth: building the portrait scene (32x24 colour")
        assert any(line.startswith("  scene built in ") for line in lines)
        assert lines[-1].startswith("  done in ")
        quiet = invoke("synth", "portrait", "-o", tmp_path / "q", "--size", "32x24", "--depth-size", "32x24",
                       "--no-gt", "-q")
        assert quiet.exit_code == 0 and "building" not in quiet.stderr

    def test_the_make_steps_say_what_they_do_and_how_long_they_take(self):
        makefile = open(os.path.join(ROOT, "Makefile"), encoding="utf-8").read()
        assert "pip install -q" not in makefile  # pip's progress is shown
        assert "half a minute" not in makefile   # the one estimate is pcdof warmup's
        for step in ("installing pcdof", "compiling", "Chromium", "running the test suite"):
            assert step in makefile, step


# ---------------------------------------------------------------------------------------------------------
OUTPUT_FLAGS = ("-o", "--output", "--save-maps", "--video", "--screenshot", "--html", "--output-dir")


def readme_commands() -> list[list[str]]:
    """Every ``pcdof ...`` command line in README.md's shell blocks (continuation lines joined)."""
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    commands = []
    for block in re.findall(r"```(?:sh|bash|shell)\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("pcdof "):
                commands.append(shlex.split(line))
    return commands


def test_readme_examples_write_only_under_out():
    commands = readme_commands()
    assert len(commands) >= 5
    for words in commands:
        for flag, value in zip(words, words[1:]):
            if flag in OUTPUT_FLAGS:
                assert value.startswith("out/"), f"{' '.join(words)}: {flag} {value} is not under out/"
