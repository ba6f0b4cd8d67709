"""Never lose a user's file: the promises of pcdof's command line under hostile use.

Each class below guards one promise, most as a property over every way to reach the case:

* an output that names an input (same path, ``./`` spelling, symbolic link, hard link, linked folder)
  is refused before any work, by render, register, cloud and batch;
* one batch at a time owns an output folder (a second one is refused; a killed one never leaves it stuck);
* ``--resume`` keys on the inputs' content and the lens: a changed frame is rendered again, alone;
* readers refuse what is not a regular file (FIFO, device, folder) before opening it for decoding;
* every calibration is read through the one guarded reader (no crash on hostile YAML);
* paths with NUL bytes, newlines or bytes that are not UTF-8 give one-line errors and valid reports;
* out-of-range values (focus, depth scale, focal length, depth, smoothing) are refused with a clear
  error and no numpy warning; libpng's warnings never reach the terminal;
* batch workers die with their parent; Ctrl-C and SIGTERM leave no traceback, no temporary file and
  a report.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import stat
import struct
import subprocess
import sys
import time
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import pcdof_command, run_pcdof

from pcdof.camera import Intrinsics, Rig
from pcdof.errors import (EXIT_CODES, CalibrationError, ImageReadError, ImageWriteError, InputError, LensError,
                          OutputInUseError, PcdofError, is_out_of_memory, one_line)

pytestmark = pytest.mark.subprocess  # most tests here run pcdof in a child process

W, H = 24, 18
INPUT = EXIT_CODES[InputError]
WRITE = EXIT_CODES[ImageWriteError]
CALIB = EXIT_CODES[CalibrationError]
READ = EXIT_CODES[ImageReadError]
HYPO = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def one_error_line(proc, code: int, word: str = "") -> str:
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), proc.stderr
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert word.lower() in lines[0].lower(), lines[0]
    return lines[0]


def rig() -> Rig:
    return Rig.registered(Intrinsics(W, H, 200.0, 200.0, (W - 1) / 2, (H - 1) / 2), depth_scale=0.001)


def depth_mm(i: int) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return (800 + 40 * i + 60 * ((xx // 6 + yy // 6) % 2) + 10 * xx).astype(np.uint16)


def color8(i: int) -> np.ndarray:
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


def write_sequence(root: Path, n: int) -> Path:
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    for i in range(n):
        cv2.imwrite(str(root / "color" / f"{i:04d}.png"), color8(i))
        cv2.imwrite(str(root / "depth" / f"{i:04d}.png"), depth_mm(i))
    (root / "calib.json").write_text(json.dumps(rig().to_dict()))
    return root


@pytest.fixture()
def frame(tmp_path) -> Path:
    d = tmp_path / "in"
    d.mkdir()
    cv2.imwrite(str(d / "color.png"), color8(0))
    cv2.imwrite(str(d / "depth.png"), depth_mm(0))
    (d / "calib.json").write_text(json.dumps(rig().to_dict()))
    return d


# --------------------------------------------------------------------------- outputs never replace inputs
SPELLINGS = ("same", "dot", "symlink", "hardlink", "linked_folder", "dotdot")


def spell(path: Path, how: str, work: Path) -> Path:
    """Another name of the existing file *path*."""
    if how == "same":
        return path
    if how == "dot":
        return path.parent / "." / path.name
    if how == "dotdot":
        return path.parent / ".." / path.parent.name / path.name
    if how == "symlink":
        link = work / f"link_{path.name}"
        link.symlink_to(path)
        return link
    if how == "hardlink":
        link = work / f"hard_{path.name}"
        os.link(path, link)
        return link
    linked = work / "linked_folder"
    linked.symlink_to(path.parent, target_is_directory=True)
    return linked / path.name


class TestOutputsNeverReplaceInputs:
    @HYPO
    @given(target=st.sampled_from(["color.png", "depth.png", "calib.json"]), how=st.sampled_from(SPELLINGS),
           label=st.sampled_from(["-o", "--save-maps file", "--video"]))
    def test_any_spelling_of_an_input_is_refused(self, frame, tmp_path_factory, target, how, label):
        from pcdof.cli._common import check_output_paths

        work = tmp_path_factory.mktemp("w")
        out = spell(frame / target, how, work)
        inputs = {"COLOR": frame / "color.png", "DEPTH": frame / "depth.png", "--calib": frame / "calib.json"}
        with pytest.raises(InputError, match="refusing to overwrite the input"):
            check_output_paths(inputs, {label: out})
        check_output_paths(inputs, {label: work / "new.png"})  # a new file is fine

    @pytest.mark.parametrize("command,how,target", [("render", "same", "depth.png"), ("render", "hardlink", "color.png"),
                                                    ("register", "symlink", "depth.png"),
                                                    ("cloud", "linked_folder", "calib.json")])
    def test_command_line_refuses_before_work(self, frame, tmp_path, command, how, target):
        before = {p.name: p.read_bytes() for p in frame.iterdir()}
        out = spell(frame / target, how, tmp_path)
        proc = run_pcdof([command, frame / "color.png", frame / "depth.png", "--calib", frame / "calib.json", "-o", out])
        one_error_line(proc, INPUT, "refusing to overwrite")
        assert {p.name: p.read_bytes() for p in frame.iterdir()} == before

    def test_save_maps_naming_the_output_leaves_nothing(self, frame, tmp_path):
        x = tmp_path / "X.png"
        proc = run_pcdof(["render", frame / "color.png", frame / "depth.png", "--calib", frame / "calib.json", "-o", x,
                        "--save-maps", x])
        one_error_line(proc, INPUT, "same path")
        assert not x.exists()
        proc = run_pcdof(["render", frame / "color.png", frame / "depth.png", "--calib", frame / "calib.json",
                        "-o", tmp_path / "m" / "coc_px.png", "--save-maps", tmp_path / "m"])
        one_error_line(proc, INPUT, "same path")
        assert not (tmp_path / "m").exists()

    def test_batch_refuses_a_hard_link_of_an_input(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 2)
        out = tmp_path / "out"
        out.mkdir()
        os.link(seq / "depth" / "0001.png", out / "frame_000001.png")
        proc = run_pcdof(["batch", seq, "-o", out, "--workers", "1", "--no-progress", "--focus-distance", "1"])
        one_error_line(proc, INPUT, "refusing to overwrite")


# --------------------------------------------------------------------------- one batch per folder
def batch_args(seq: Path, out: Path, f_number: float, *extra) -> list:
    return ["batch", seq, "-o", out, "--workers", "1", "--no-progress", "--focus-distance", "1.0",
            "--f-number", str(f_number), *extra]


class TestOneBatchPerFolder:
    def test_a_held_folder_is_refused_before_any_work(self, tmp_path):
        from pcdof.batch.lock import LOCK_NAME, folder_lock

        seq = write_sequence(tmp_path / "seq", 2)
        out = tmp_path / "out"
        out.mkdir()
        with folder_lock(str(out)):
            proc = run_pcdof(batch_args(seq, out, 2.0))
            line = one_error_line(proc, WRITE, "in use by another pcdof batch")
            assert f"pid {os.getpid()}" in line and socket.gethostname() in line
            assert sorted(os.listdir(out)) == [LOCK_NAME]
        assert os.listdir(out) == []  # released and removed
        with folder_lock(str(out)), pytest.raises(OutputInUseError):
            from pcdof.batch.lock import _acquire

            _acquire(os.path.realpath(out))

    @pytest.mark.parametrize("when", ["taking", "giving back"])
    def test_sigterm_while_the_lock_is_taken_or_given_back_leaves_no_lock_file(self, tmp_path, monkeypatch, when):
        """The signal arrives as the lock file has just been created (or is about to be removed): it raises once
        that is done, and the file is gone (raised halfway, it left the file behind)."""
        import pcdof.batch.lock as lock
        from pcdof.batch.signals import Terminated, sigterm_interrupts

        out = tmp_path / "out"
        out.mkdir()
        if when == "taking":
            real = lock._acquire

            def acquire(folder):
                fd = real(folder)
                os.kill(os.getpid(), signal.SIGTERM)  # handled at the next line of Python: in the caller
                return fd

            monkeypatch.setattr(lock, "_acquire", acquire)
        else:
            real_unlink = os.unlink

            def unlink(path, *a, **k):
                os.kill(os.getpid(), signal.SIGTERM)
                return real_unlink(path, *a, **k)

            monkeypatch.setattr(lock.os, "unlink", unlink)
        reached = []
        with pytest.raises(Terminated), sigterm_interrupts(), lock.folder_lock(str(out)):
            reached.append(True)
        assert reached == ([] if when == "taking" else [True])
        assert os.listdir(out) == [] and lock._HELD == {}

    def test_a_killed_owner_never_leaves_the_folder_stuck(self, tmp_path):
        out = tmp_path / "out"
        out.mkdir()
        holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pcdof.batch.lock import folder_lock\n"
                                   f"with folder_lock({str(out)!r}):\n print('held', flush=True); time.sleep(60)"],
                                  stdout=subprocess.PIPE, text=True)
        assert holder.stdout.readline().strip() == "held"
        from pcdof.batch.lock import folder_lock

        with pytest.raises(OutputInUseError, match=f"pid {holder.pid}"), folder_lock(str(out)):
            pass
        holder.kill()
        holder.wait()
        with folder_lock(str(out)):  # the kernel released the dead owner's lock; its file is reused
            pass

    def test_two_concurrent_batches_never_mix_settings(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 6)
        refs = {}
        for n in (1.4, 8.0):  # each setting's frames, rendered alone
            ref = tmp_path / f"ref{n}"
            assert run_pcdof(batch_args(seq, ref, n)).returncode == 0
            refs[n] = [(ref / f"frame_{i:06d}.png").read_bytes() for i in range(6)]
        assert refs[1.4] != refs[8.0]
        out = tmp_path / "out"
        env = {**os.environ, "PYTHONWARNINGS": ""}
        procs = {n: subprocess.Popen(pcdof_command() + [str(a) for a in batch_args(seq, out, n)], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for n in (1.4, 8.0)}
        results = {n: (p.wait(timeout=300), p.stderr.read()) for n, p in procs.items()}
        for code, err in results.values():
            assert code in (0, WRITE) and "Traceback" not in err, err
            if code == WRITE:
                assert "in use by another pcdof batch" in err
        report = json.loads((out / "report.json").read_text())
        for rec in report["frames"]:
            n = rec["f_number"]
            assert (out / rec["output"]).read_bytes() == refs[n][rec["index"]], "a frame of the other run's settings"
        assert len({rec["f_number"] for rec in report["frames"]}) == 1


# --------------------------------------------------------------------------- resume keys on content
class TestResumeKeysOnContent:
    def test_a_changed_frame_alone_is_rendered_again(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 4)
        out = tmp_path / "out"
        assert run_pcdof(batch_args(seq, out, 2.0)).returncode == 0
        before = {i: (out / f"frame_{i:06d}.png").read_bytes() for i in range(4)}
        stale = out / ".frame_000003.png.k1ll3d.tmp"  # what a kill -9 during a write leaves
        stale.write_bytes(b"")
        changed = depth_mm(2)
        changed[:, : W // 2] += 700  # same size, same path, new content
        time.sleep(0.01)
        cv2.imwrite(str(seq / "depth" / "0002.png"), changed)
        proc = run_pcdof(batch_args(seq, out, 2.0, "--resume"))
        assert proc.returncode == 0, proc.stderr
        report = json.loads((out / "report.json").read_text())
        assert [r["status"] for r in report["frames"]] == ["skipped", "skipped", "ok", "skipped"]
        assert not stale.exists()
        fresh = tmp_path / "fresh"
        assert run_pcdof(batch_args(seq, fresh, 2.0)).returncode == 0
        assert (out / "frame_000002.png").read_bytes() == (fresh / "frame_000002.png").read_bytes()
        assert (out / "frame_000002.png").read_bytes() != before[2]
        for i in (0, 1, 3):
            assert (out / f"frame_{i:06d}.png").read_bytes() == before[i]

    def test_a_frame_whose_lens_changed_is_rendered_again(self, tmp_path):
        from pcdof.batch.resume import unchanged

        rec = {"source": {"color": [1, 2], "depth": [3, 4]}, "focus_distance_m": 1.0, "f_number": 2.0,
               "focal_length_mm": 50.0}
        assert unchanged(dict(rec), rec)
        assert not unchanged({**rec, "f_number": 2.8}, rec)
        assert not unchanged({**rec, "source": {"color": [1, 2], "depth": [3, 5]}}, rec)
        assert not unchanged({k: v for k, v in rec.items() if k != "source"}, rec)  # an older report


# --------------------------------------------------------------------------- not a regular file
def make_special(kind: str, where: Path) -> Path:
    if kind == "fifo":
        path = where / "pipe.png"
        os.mkfifo(path)
        return path
    if kind == "folder":
        path = where / "folder.png"
        path.mkdir()
        return path
    if kind == "socket":
        path = where / "s.png"
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        return path
    return Path("/dev/zero")


class TestOnlyRegularFiles:
    @HYPO
    @given(kind=st.sampled_from(["fifo", "folder", "socket", "/dev/zero"]),
           reader=st.sampled_from(["color", "depth", "calibration", "list", "list entry"]))
    def test_every_reader_refuses_before_reading(self, tmp_path_factory, kind, reader):
        from pcdof.batch import discover
        from pcdof.io import read_calibration, read_color, read_depth

        if kind == "folder" and reader == "list":
            return  # a folder is a sequence's input
        where = tmp_path_factory.mktemp("special")
        special = make_special(kind, where)
        with pytest.raises(ImageReadError) as info:
            if reader == "color":
                read_color(special)
            elif reader == "depth":
                read_depth(special, 0.001)
            elif reader == "calibration":
                read_calibration(special)
            elif reader == "list":
                discover(special)
            else:
                listing = where / "frames.txt"
                listing.write_text(f"{special} {special}\n")
                read_color(discover(listing).pairs[0].color)
        assert "\n" not in str(info.value)

    def test_a_fifo_colour_file_does_not_hang_render(self, frame):
        os.mkfifo(frame / "fifo.png")
        proc = run_pcdof(["render", frame / "fifo.png", frame / "depth.png", "--calib", frame / "calib.json",
                        "-o", frame / "out.png"], timeout=120)
        one_error_line(proc, READ, "FIFO")


# --------------------------------------------------------------------------- calibrations through one reader
class TestGuardedCalibration:
    @pytest.mark.parametrize("text,word", [("%YAML:1.0\n---\na: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested"),
                                           ("%YAML:1.0\n---\ncameraMatrix1: !!opencv-matrix\n   rows: 3\n   data: [ 1.,",
                                            "calib.yml")])
    def test_tum_batch_with_hostile_yaml(self, tmp_path, text, word):
        seq = tmp_path / "tum"
        (seq / "rgb").mkdir(parents=True)
        (seq / "depth").mkdir()
        cv2.imwrite(str(seq / "rgb" / "1.png"), color8(0))
        cv2.imwrite(str(seq / "depth" / "1.png"), depth_mm(0))
        (seq / "rgb.txt").write_text("1.0 rgb/1.png\n")
        (seq / "depth.txt").write_text("1.0 depth/1.png\n")
        (seq / "calib.yml").write_text(text)
        proc = run_pcdof(["batch", seq, "--calib", seq / "calib.yml", "-o", tmp_path / "out", "--no-progress"])
        one_error_line(proc, CALIB, word)

    def test_load_rig_reads_the_file_once_through_read_calibration(self, tmp_path, monkeypatch):
        import pcdof.io
        from pcdof.sources import discovery as inputs

        calls = []
        real = pcdof.io.read_calibration
        monkeypatch.setattr(pcdof.io, "read_calibration", lambda *a, **k: calls.append(a) or real(*a, **k))
        monkeypatch.setattr(cv2, "FileStorage", None)  # nothing may parse the file but the guarded reader
        seq = inputs.Sequence((), "tum", str(tmp_path), inputs.TUM_DEPTH_SCALE)
        path = tmp_path / "calib.json"
        cal = rig().to_dict()
        del cal["depth_scale"]
        path.write_text(json.dumps(cal))
        assert inputs.load_rig(seq, str(path)).depth_scale == inputs.TUM_DEPTH_SCALE
        path.write_text(json.dumps({**cal, "depth_scale": 0.001}))
        assert inputs.load_rig(seq, str(path)).depth_scale == 0.001  # the file's own scale wins over the layout's
        assert len(calls) == 2


# --------------------------------------------------------------------------- names and bytes
class TestNamesAndBytes:
    @pytest.mark.parametrize("writer", ["write_image", "write_depth", "write_json"])
    def test_nul_in_an_output_path_is_an_input_error(self, tmp_path, writer):
        from pcdof import io

        with pytest.raises(InputError, match="NUL"):
            getattr(io, writer)(str(tmp_path / "a\x00b.png"), np.zeros((2, 2), np.uint16))

    def test_nul_in_a_list_file(self, tmp_path):
        from pcdof.batch import discover

        listing = tmp_path / "frames.txt"
        listing.write_bytes(b"a.png b\x00.png\n")
        with pytest.raises(ImageReadError, match="NUL"):
            discover(listing)

    def test_file_names_that_are_not_utf8(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 2)
        for sub in ("color", "depth"):
            os.rename(os.path.join(os.fsencode(seq), sub.encode(), b"0001.png"),
                      os.path.join(os.fsencode(seq), sub.encode(), b"0001\xff.png"))
        out = tmp_path / "out"
        proc = run_pcdof(batch_args(seq, out, 2.0))
        assert proc.returncode == 0, proc.stderr
        report = json.loads((out / "report.json").read_text(encoding="utf-8"))
        assert report["frames"][1]["color"] == os.path.join("color", os.fsdecode(b"0001\xff.png"))

    @pytest.mark.parametrize("name", ["new\nline.png", "tab\there.png", "bad\udcffname.png"])
    def test_odd_path_characters_keep_the_error_on_one_line(self, frame, name):
        proc = run_pcdof(["render", os.fsencode(str(frame)) + b"/" + os.fsencode(name), frame / "depth.png",
                        "--calib", frame / "calib.json", "-o", frame / "out.png"])
        one_error_line(proc, READ, "not found")

    @given(st.text(max_size=40))
    def test_one_line_is_one_printable_line(self, text):
        out = one_line(text)
        assert out.isprintable() and ("\n" in text) <= ("\\n" in out)
        if text.isprintable():
            assert out == text


# --------------------------------------------------------------------------- lens values
class TestLensValues:
    @HYPO
    @given(blades=st.sampled_from([0, 3, 5, 6, 8, 64]),
           rotation=st.one_of(st.floats(-1e300, 1e300, allow_nan=False), st.sampled_from([1e19, -1e19, 359.9999])))
    def test_aperture_rotation_reduced_to_its_symmetry(self, blades, rotation):
        from pcdof.lens import ThinLens

        lens = ThinLens(50, 1.8, 1.0, blades, rotation)
        period = 360.0 / blades if blades else 360.0
        assert 0.0 <= lens.aperture_rotation_deg < period
        if blades:  # the same polygon: its vertices, from the angle reduced modulo 360 alone, coincide
            def vertices(deg):
                return np.exp(1j * np.radians(deg + period * np.arange(blades)))

            a, b = vertices(math.fmod(rotation, 360.0)), vertices(lens.aperture_rotation_deg)
            assert np.abs(a[:, None] - b[None, :]).min(axis=1).max() < 1e-9

    def test_huge_rotation_renders(self):
        from pcdof import pipeline
        from pcdof.camera import RGBDFrame
        from pcdof.lens import ThinLens

        frame = RGBDFrame(color8(0), depth_mm(0) / 1000.0, rig())
        a = pipeline.run(frame, ThinLens(50, 0.5, 0.8, 6, 1e19)).image
        b = pipeline.run(frame, ThinLens(50, 0.5, 0.8, 6, math.fmod(1e19, 60.0))).image
        assert np.array_equal(a, b)

    @pytest.mark.parametrize("value", [1e300, 1e39, 1e-300, 1e-39])
    def test_focus_distance_beyond_float32_depths(self, value):
        from pcdof.lens import PaperLens, ThinLens

        for make in (lambda: ThinLens(50, 1.8, value), lambda: PaperLens(value)):
            with pytest.raises(LensError, match="focus_distance_m must be a finite number of metres within"):
                make()

    def test_focus_keyframe_out_of_range_names_the_keyframe(self):
        from pcdof.batch import build_schedule, parse_keyframes
        from pcdof.lens import ThinLens

        with pytest.raises(LensError, match="focus keyframe 2:1e-300"):
            build_schedule(ThinLens(50, 1.8, 1.0), 5, focus_keyframes=parse_keyframes("0:1,2:1e-300"))
        tiny = build_schedule(ThinLens(50, 1.8, 1.0), 5, focus_keyframes=parse_keyframes("0:1,2:1e-30"))
        assert tiny.focus_distance_m[2] == 1e-30  # exactly the keyframe's value at its frame

    def test_view_style_refusal_on_the_command_line(self, frame):
        proc = run_pcdof(["render", frame / "color.png", frame / "depth.png", "--calib", frame / "calib.json", "-o",
                        frame / "out.png", "--focus-distance", "1e300"])
        one_error_line(proc, EXIT_CODES[LensError], "focus")


# --------------------------------------------------------------------------- numbers out of range
class TestOutOfRangeNumbers:
    def test_float64_depth_file_beyond_float32(self, tmp_path):
        from pcdof.io import read_depth

        depth = np.full((4, 5), 2.0)
        depth[1, 1] = 1e300
        np.save(tmp_path / "d.npy", depth)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(ImageReadError, match="beyond float32"):
                read_depth(tmp_path / "d.npy")

    @pytest.mark.parametrize("value", [1e300, 1e4, 1e-300])
    def test_depth_scale_out_of_range(self, frame, value):
        from pcdof.io import load_frame, read_calibration

        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InputError, match="depth_scale"):
                load_frame(frame / "color.png", frame / "depth.png", frame / "calib.json", depth_scale=value)
            cal = json.loads((frame / "calib.json").read_text())
            (frame / "c2.json").write_text(json.dumps({**cal, "depth_scale": value}))
            with pytest.raises(CalibrationError, match="depth_scale"):
                read_calibration(frame / "c2.json")

    @pytest.mark.parametrize("key,value", [("fx", 1e-300), ("fy", 1e-4), ("fx", 1e12), ("cx", 1e300)])
    def test_intrinsics_out_of_range(self, frame, key, value):
        from pcdof.io import read_calibration

        cal = json.loads((frame / "calib.json").read_text())
        cal["depth"][key] = value
        (frame / "c2.json").write_text(json.dumps(cal))
        with pytest.raises(CalibrationError, match=f"depth.*{key}"):
            read_calibration(frame / "c2.json")

    def test_cloud_of_depth_near_float32_max(self):
        from pcdof.cloud import colored_points

        depth = np.full((H, W), 3e38, np.float32)
        wide = Intrinsics(W, H, 1e-3, 1e-3, (W - 1) / 2, (H - 1) / 2)  # rays 1e4 wide: x beyond float32
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InputError, match="float32"):
                colored_points(color8(0), depth, wide)
            points, _ = colored_points(color8(0), depth, rig().color)  # within range: fine
        assert np.all(np.isfinite(points))

    @pytest.mark.parametrize("flag,value", [("--focus-min-cutoff", "1e308"), ("--fps", "1e308"),
                                            ("--focus-beta", "1e308"), ("--fps", "1e-300")])
    def test_smoothing_flags_out_of_range(self, tmp_path, flag, value):
        seq = write_sequence(tmp_path / "seq", 2)
        proc = run_pcdof(["batch", seq, "-o", tmp_path / "out", "--no-progress", flag, value])
        one_error_line(proc, INPUT, flag)

    def test_focus_window_is_bounded_by_the_sequence(self):
        from pcdof.batch import running_median

        values = np.array([1.0, np.nan, 3.0, 2.0, 5.0])
        assert np.array_equal(running_median(values, 10**12), running_median(values, len(values)), equal_nan=True)


# --------------------------------------------------------------------------- library chatter and memory
def png_with(chunks: list[tuple[bytes, bytes]]) -> bytes:
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ok, buf = cv2.imencode(".png", color8(0))
    raw = buf.tobytes()
    ihdr_end = 8 + 25
    return raw[:ihdr_end] + b"".join(chunk(k, d) for k, d in chunks) + raw[ihdr_end:]


class TestLibraryMessages:
    @pytest.mark.parametrize("chunks", [[(b"iCCP", b"bad\x00\x00" + zlib.compress(b"not an ICC profile"))],
                                        [(b"gAMA", b"\x00\x00")],
                                        [(b"tRNS", b"\x00" * 40)],
                                        [(b"zTXt", b"k\x00\x00" + b"\x78\x9c garbage")]])
    def test_png_side_chunk_warnings_never_reach_stderr(self, tmp_path, capfd, chunks):
        """The pcdof command captures what C libraries print while decoding (its process is tuned for it)."""
        from pcdof.io import capture, read_color

        path = tmp_path / "side.png"
        path.write_bytes(png_with(chunks))
        capture.enable(True)
        try:
            img = read_color(path)
        finally:
            capture.enable(False)
        assert img.shape == (H, W, 3)
        assert capfd.readouterr().err == ""

    def test_a_library_caller_keeps_its_stderr(self, tmp_path, capfd):
        """Imported as a library, pcdof does not redirect the process's stderr: libpng's warning reaches it."""
        from pcdof.io import capture, read_color

        assert not capture.enabled()
        path = tmp_path / "side.png"
        path.write_bytes(png_with([(b"iCCP", b"bad\x00\x00" + zlib.compress(b"not an ICC profile"))]))
        assert read_color(path).shape == (H, W, 3)
        assert "libpng warning" in capfd.readouterr().err

    def test_opencv_out_of_memory_is_out_of_memory(self):
        try:
            cv2.GaussianBlur(np.zeros((4, 4), np.float32), (1 << 31 | 1, 1 << 31 | 1), 0)
        except cv2.error as err:
            assert err.code == -4 or not is_out_of_memory(err)
        fake = cv2.error("Insufficient memory")
        fake.code = -4
        assert is_out_of_memory(fake) and is_out_of_memory(MemoryError())
        assert not is_out_of_memory(ValueError("x"))


class TestPaperBlurKernel:
    @HYPO
    @given(sigma=st.floats(0.01, 1e300), h=st.integers(1, 40), w=st.integers(1, 40))
    def test_kernel_is_bounded_by_the_image(self, sigma, h, w):
        from pcdof.lens import PAPER_SIGMA_SIDES, PaperLens

        (kx, ky), sx, sy = PaperLens(1.0, blur_sigma_px=sigma).blur_kernel(h, w)
        assert kx % 2 == 1 and ky % 2 == 1
        assert sx == min(sigma, PAPER_SIGMA_SIDES * w) and sy == min(sigma, PAPER_SIGMA_SIDES * h)
        assert kx <= 6 * PAPER_SIGMA_SIDES * w + 3 and ky <= 6 * PAPER_SIGMA_SIDES * h + 3

    def test_limited_blur_is_the_unlimited_one(self):
        from pcdof.lens import PaperLens

        rng = np.random.default_rng(3)
        img = rng.random((30, 40, 3)).astype(np.float32)
        (kx, ky), sx, sy = PaperLens(1.0, blur_sigma_px=1e9).blur_kernel(30, 40)
        limited = cv2.GaussianBlur(img, (kx, ky), sigmaX=sx, sigmaY=sy, borderType=cv2.BORDER_REFLECT)
        far = cv2.GaussianBlur(img, (2 * 2400 + 1, 2 * 1800 + 1), sigmaX=800, sigmaY=600, borderType=cv2.BORDER_REFLECT)
        assert float(np.abs(limited - far).max()) < 2e-5 * float(img.max() - img.min())

    def test_huge_sigma_renders(self):
        from pcdof.stages.render import render_paper
        from pcdof.lens import PaperLens

        out, _ = render_paper(color8(0), depth_mm(0) / 1000.0, PaperLens(0.5, blur_sigma_px=1e9))
        assert out.shape == (H, W, 3)


# --------------------------------------------------------------------------- processes and signals
def descendants(pid: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", "rb") as f:
                    ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    out, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False


def start_batch(seq: Path, out: Path, *extra) -> subprocess.Popen:
    env = {**os.environ, "PYTHONWARNINGS": ""}
    return subprocess.Popen(pcdof_command() + [str(a) for a in ["batch", seq, "-o", out, *extra]], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def wait_for(predicate, seconds: float = 120.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
class TestProcesses:
    def test_workers_die_with_their_parent(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 60)
        out = tmp_path / "out"
        proc = start_batch(seq, out, "--workers", "2", "--no-progress", "--focus-distance", "1")
        assert wait_for(lambda: len(list(out.glob("frame_*.png"))) >= 2), "the batch did not start rendering"
        family = descendants(proc.pid)
        assert family, "no worker processes"
        proc.kill()
        proc.wait()
        assert wait_for(lambda: not any(alive(p) for p in family), 30), "workers outlived their parent"
        assert not list(out.glob(".*.tmp"))

    @pytest.mark.parametrize("delay", [0.0, 0.05, 0.15, 0.3, 0.5, 0.8])
    def test_ctrl_c_on_two_workers_is_clean(self, tmp_path, delay):
        # long enough that the run is still going after the largest delay (warm kernels render the
        # tiny frames at about 60 per second)
        seq = write_sequence(tmp_path / "seq", 400)
        out = tmp_path / "out"
        proc = start_batch(seq, out, "--workers", "2", "--no-progress", "--focus-distance", "1")
        assert wait_for(lambda: any(out.glob("frame_*.png")))
        time.sleep(delay)
        assert proc.poll() is None, "the batch ended before the interrupt: lengthen the sequence"
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        assert "Traceback" not in err and "leaked" not in err, err
        assert err.splitlines()[-1] == "pcdof: interrupted", err
        assert not list(out.rglob(".*.tmp"))
        assert json.loads((out / "report.json").read_text())["status"] == "interrupted"

    def test_sigterm_in_the_focus_pass(self, tmp_path):
        seq = write_sequence(tmp_path / "seq", 400)
        out = tmp_path / "out"
        proc = start_batch(seq, out, "--workers", "1", "--progress", "--focus-at", "5,5")
        assert wait_for(lambda: (out / ".pcdof-batch.lock").exists()), "the batch did not start"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 143, err
        assert "Traceback" not in err and err.splitlines()[-1] == "pcdof: terminated (SIGTERM)", err
        report = json.loads((out / "report.json").read_text())
        assert report["status"] == "interrupted"
        assert not (out / ".pcdof-batch.lock").exists()
