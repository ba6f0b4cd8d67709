"""One error convention for every subcommand: usage errors on one line, exit 2; -v/-vv/-q anywhere."""

from __future__ import annotations

import os

import click
import pytest
from click.testing import CliRunner

from conftest import invoke

from pcdof.cli import SUBCOMMANDS
from pcdof.cli._report import format_decision, report_decision
from pcdof.errors import InputError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
S = os.path.join(ROOT, "data", "sample")
FRAME = [f"{S}/color.png", f"{S}/depth.png", "--calib", f"{S}/calib.json"]


def assert_one_line_usage_error(result, *needles):
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("pcdof: error: "), lines[0]
    assert "Usage:" not in result.output and "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


# an invalid value for a choice of every subcommand that has one (the out path is never written)
INVALID_CHOICES = [
    pytest.param(["render", *FRAME, "-o", "{tmp}/x.png", "--method", "nope"], "--method", id="render-method"),
    pytest.param(["render", *FRAME, "-o", "{tmp}/x.png", "--quality", "nope"], "--quality", id="render-quality"),
    pytest.param(["render", *FRAME, "-o", "{tmp}/x.png", "--fill-method", "nope"], "--fill-method",
                 id="render-fill-method"),
    pytest.param(["render", *FRAME, "-o", "{tmp}/x.png", "--weight", "nope"], "--weight", id="render-weight"),
    pytest.param(["register", *FRAME, "-o", "{tmp}/x.png", "--fill-method", "nope"], "--fill-method",
                 id="register-fill-method"),
    pytest.param(["cloud", *FRAME, "-o", "{tmp}/x.ply", "--fill-method", "nope"], "--fill-method",
                 id="cloud-fill-method"),
    pytest.param(["view", *FRAME, "--screenshot", "{tmp}/x.png", "--color-by", "nope"], "--color-by",
                 id="view-color-by"),
    pytest.param(["view", *FRAME, "--screenshot", "{tmp}/x.png", "--fill-method", "nope"], "--fill-method",
                 id="view-fill-method"),
    pytest.param(["batch", S, "-o", "{tmp}/o", "--method", "nope"], "--method", id="batch-method"),
    pytest.param(["batch", S, "-o", "{tmp}/o", "--easing", "nope"], "--easing", id="batch-easing"),
    pytest.param(["batch", S, "-o", "{tmp}/o", "--fill-method", "nope"], "--fill-method", id="batch-fill-method"),
    pytest.param(["bench", "-o", "{tmp}/b", "--only", "nope"], "--only", id="bench-only"),
    pytest.param(["bench", "-o", "{tmp}/b", "--scenes", "nope"], "--scenes", id="bench-scenes"),
    pytest.param(["synth", "nope", "-o", "{tmp}/s"], "NAME", id="synth-name"),
]


class TestUsageErrors:
    @pytest.mark.parametrize("args, flag", INVALID_CHOICES)
    def test_invalid_choice(self, tmp_path, args, flag):
        result = invoke([a.replace("{tmp}", str(tmp_path)) for a in args])
        assert_one_line_usage_error(result, flag, "nope")
        assert os.listdir(tmp_path) == []

    @pytest.mark.parametrize("command", list(SUBCOMMANDS))
    def test_unknown_option(self, command):
        result = invoke([command, "--no-such-option"])
        assert_one_line_usage_error(result, "--no-such-option", f"pcdof {command} -h")

    # every subcommand but those that need no argument
    @pytest.mark.parametrize("command", [c for c in SUBCOMMANDS if c not in ("demo", "bench", "warmup")])
    def test_missing_argument_or_option(self, command):
        result = invoke([command])
        assert_one_line_usage_error(result, "Missing")

    def test_bad_value_type(self, tmp_path):
        result = invoke(["render", *FRAME, "-o", tmp_path / "x.png", "--f-number", "fast"])
        assert_one_line_usage_error(result, "--f-number", "fast")

    def test_unknown_command_and_group_option(self):
        assert_one_line_usage_error(invoke(["nope"]), "nope", "pcdof -h")
        assert_one_line_usage_error(invoke(["--nope", "render"]), "--nope")

    def test_pcdof_errors_keep_their_own_codes(self, tmp_path):
        result = invoke(["render", *FRAME[:2], "--calib", tmp_path / "nope.json", "-o", tmp_path / "x.png"])
        assert result.exit_code == 3  # ImageReadError
        assert result.stderr.splitlines() == [result.stderr.strip()]
        assert result.stderr.startswith("pcdof: error: ")

    def test_help_still_works(self):
        result = invoke(["render", "-h"])
        assert result.exit_code == 0 and "--verbose" in result.output and "--quiet" in result.output


class TestVerbosityAnywhere:
    @pytest.mark.parametrize("where", ["before", "after"])
    def test_vv_shows_the_traceback(self, tmp_path, where):
        args = ["render", *FRAME[:2], "--calib", tmp_path / "nope.json", "-o", tmp_path / "x.png"]
        args = ["-vv", *args] if where == "before" else [*args, "-vv"]
        result = invoke(args)
        assert "No such option" not in result.output
        # -vv lets the error through with its traceback instead of the one-line message
        assert result.exit_code != 0 and result.exception is not None
        assert "calibration file not found" in str(result.exception)

    def test_v_counts_add_up(self, tmp_path):
        args = ["-v", "render", *FRAME[:2], "--calib", tmp_path / "nope.json", "-o", tmp_path / "x.png", "-v"]
        assert invoke(args).exception is not None and "calibration file not found" in str(invoke(args).exception)

    def test_single_v_keeps_the_one_line_error(self, tmp_path):
        result = invoke(["render", *FRAME[:2], "--calib", tmp_path / "nope.json", "-o", tmp_path / "x.png", "-v"])
        assert result.exit_code == 3 and result.stderr.startswith("pcdof: error: ")

    @pytest.mark.parametrize("command", list(SUBCOMMANDS))
    def test_every_subcommand_takes_v_and_q(self, command):
        for flag in ("-v", "-vv", "-q", "--quiet", "--verbose"):
            result = invoke([command, flag, "-h"])
            assert result.exit_code == 0, (command, flag, result.output)


class TestReport:
    def test_format(self):
        line = format_decision("render", output="out/x.png", focus_distance_m=1.4861,
                               focus_source="depth at pixel (160, 120)", max_blur_px=12.345, details="85 mm f/1.8")
        assert line == ("pcdof render: focus 1.49 m (depth at pixel (160, 120)), max blur 12.3 px, 85 mm f/1.8 "
                        "-> out/x.png")
        assert format_decision("register", output="r.png") == "pcdof register: done -> r.png"

    @pytest.mark.parametrize("bad", [{"focus_distance_m": float("nan")}, {"max_blur_px": -1.0},
                                     {"max_blur_px": "3"}])
    def test_bad_values(self, bad):
        with pytest.raises(InputError):
            format_decision("render", **bad)

    @pytest.mark.parametrize("args, printed", [([], True), (["-q"], False), (["--quiet"], False)])
    def test_quiet_silences_the_line(self, args, printed):
        @click.command()
        def probe():
            report_decision("probe", output="o.png", max_blur_px=2.0)

        from pcdof.cli import _with_verbosity

        group = click.Group(commands={"probe": _with_verbosity(probe)})
        before = CliRunner().invoke(group, ["probe", *args])
        assert before.exit_code == 0
        assert ("pcdof probe: max blur 2.0 px -> o.png" in before.stdout) == printed
