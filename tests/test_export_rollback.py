"""Commands that write several files write all of them or none: ``export``, ``render --save-maps``.

* an output in the way (a folder where a file goes, a file where a folder goes) is found before any
  work, with the exit status of a write failure (7) whichever command and whichever file it is;
* a failure part-way (a write that fails late, Ctrl-C) removes what the command had written, and the
  folders it had created, and leaves what was there before;
* ``export --frames`` that selects no frame is an input error naming the range, before anything is written.
"""

from __future__ import annotations

import os
import subprocess

import pytest
from click.testing import CliRunner

from pcdof.cli import main
from pcdof.errors import EXIT_CODES, ImageWriteError, InputError

WRITE, INPUT = EXIT_CODES[ImageWriteError], EXIT_CODES[InputError]


def cli(*args):
    return CliRunner().invoke(main, [os.fspath(a) for a in args])


def one_line(result, code: int, *words: str) -> str:
    lines = result.stderr.splitlines()
    assert result.exit_code == code, (result.exit_code, result.stderr, result.exception)
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), result.stderr
    for word in words:
        assert word.lower() in lines[0].lower(), lines[0]
    return lines[0]


def tree(folder) -> list[str]:
    """Every path under *folder*, relative, folders marked with a slash."""
    out = []
    for root, dirs, files in os.walk(folder):
        rel = os.path.relpath(root, folder)
        out += [os.path.normpath(os.path.join(rel, d)) + "/" for d in dirs]
        out += [os.path.normpath(os.path.join(rel, f)) for f in files]
    return sorted(out)


# --------------------------------------------------------------------------- in the way: found before any work
@pytest.mark.parametrize("blocker", ["calib.json/", "depth/000000.png/", "color/000000.png/", "color", "depth"])
def test_export_finds_an_output_in_the_way_first(sample_bag, tmp_path, blocker):
    out = tmp_path / "out"
    target = out / blocker.rstrip("/")
    target.parent.mkdir(parents=True, exist_ok=True)
    target.mkdir() if blocker.endswith("/") else target.write_text("mine")
    before = tree(out)
    one_line(cli("export", sample_bag, "-o", out), WRITE, blocker.rstrip("/").split("/")[0])
    assert tree(out) == before  # not one frame written
    if not blocker.endswith("/"):
        assert target.read_text() == "mine"


@pytest.mark.parametrize("command", ["render", "export"])
def test_a_folder_in_place_of_an_output_file_is_the_same_failure_everywhere(sample_bag, small_frame, tmp_path, command):
    if command == "render":
        (tmp_path / "out.png").mkdir()
        result = cli("render", small_frame["color"], small_frame["depth"], "--calib", small_frame["calib"],
                     "-o", tmp_path / "out.png")
    else:
        (tmp_path / "out" / "depth" / "000000.png").mkdir(parents=True)
        result = cli("export", sample_bag, "-o", tmp_path / "out")
    one_line(result, WRITE, "is a folder")


@pytest.mark.parametrize("name", ["trace.json", "coc_px.png", "depth_registered.png"])
def test_save_maps_finds_a_map_in_the_way_first(small_frame, tmp_path, name):
    maps = tmp_path / "maps"
    (maps / name).mkdir(parents=True)
    result = cli("render", small_frame["color"], small_frame["depth"], "--calib", small_frame["calib"],
                 "-o", tmp_path / "out.png", "--save-maps", maps)
    one_line(result, WRITE, name)
    assert not (tmp_path / "out.png").exists() and tree(maps) == [name + "/"]


# --------------------------------------------------------------------------- a late failure: rolled back
class LateFailure(Exception):
    pass


@pytest.mark.parametrize("failure", [ImageWriteError("disk full"), KeyboardInterrupt(), LateFailure("bug")])
@pytest.mark.parametrize("existing", [False, True])
def test_export_rolls_back_a_late_failure(sample_bag, tmp_path, monkeypatch, failure, existing):
    import pcdof.io

    out = tmp_path / "out"
    if existing:  # a folder with the user's own files: kept as it was
        (out / "color").mkdir(parents=True)
        (out / "color" / "notes.txt").write_text("mine")
    before = tree(out) if existing else None

    def fail(*args, **kwargs):
        raise failure

    monkeypatch.setattr(pcdof.io, "write_json", fail)  # calib.json comes last, after every frame
    result = cli("export", sample_bag, "-o", out)
    assert result.exit_code != 0
    if existing:
        assert tree(out) == before and (out / "color" / "notes.txt").read_text() == "mine"
    else:
        assert not out.exists()


def test_save_maps_rolls_back_when_the_image_fails(small_frame, tmp_path, monkeypatch):
    import pcdof.io

    real = pcdof.io.write_image

    def fail_on_output(path, *args, **kwargs):
        if os.path.basename(path) == "out.png":
            raise ImageWriteError("disk full")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(pcdof.io, "write_image", fail_on_output)
    result = cli("render", small_frame["color"], small_frame["depth"], "--calib", small_frame["calib"],
                 "-o", tmp_path / "out.png", "--save-maps", tmp_path / "maps")
    one_line(result, WRITE, "disk full")
    assert not (tmp_path / "maps").exists() and not (tmp_path / "out.png").exists()


# --------------------------------------------------------------------------- an empty selection
@pytest.mark.parametrize("spec", ["1:0", "0:0", "5:2", "-1:0", "3:", "1::2"])
def test_export_frames_selecting_nothing_is_an_error(sample_bag, tmp_path, spec):
    out = tmp_path / "out"
    one_line(cli("export", sample_bag, "-o", out, "--frames", spec), INPUT, f"--frames {spec}", "no frame")
    assert not out.exists()


@pytest.mark.parametrize("spec,frames", [("0:1", 1), (":", 1), ("0", 1), ("-1", 1), ("0::5", 1)])
def test_export_frames_selecting_some_still_writes_them(sample_bag, tmp_path, spec, frames):
    out = tmp_path / "out"
    result = cli("export", sample_bag, "-o", out, "--frames", spec)
    assert result.exit_code == 0, result.stderr
    assert len(os.listdir(out / "color")) == frames and (out / "calib.json").is_file()


def test_export_in_a_subprocess_is_one_line_and_leaves_nothing(sample_bag, tmp_path, console_script):
    out = tmp_path / "out"
    (out / "calib.json").mkdir(parents=True)
    proc = subprocess.run(console_script + ["export", str(sample_bag), "-o", str(out)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == WRITE and proc.stderr.count("\n") == 1, proc.stderr
    assert tree(out) == ["calib.json/"]
