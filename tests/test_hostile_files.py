"""Hostile files through the command line: every failure is one line, its own exit code, no output left.

Each case runs the installed ``pcdof`` executable in a subprocess (the truest test of "never a
traceback": nothing of the test process can catch or reformat an error) on a small valid frame
with one thing broken: a truncated, corrupt or absurdly large image, random bytes named ``.png``,
an 8-bit depth image, a size mismatch, a broken calibration, a folder where a file belongs, bad
lens values or an output that cannot be written. The contract checked for every case:

* the exit code of the error's class (:data:`pcdof.errors.EXIT_CODES`: 3 read, 4 calibration,
  5 lens, 6 input, 7 write);
* stderr is exactly one line, starting with ``pcdof: error:`` (no traceback, no library chatter);
* the output folder is left empty: no output file, no partial file, no temporary file.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest

from conftest import run_pcdof

from pcdof.camera import Intrinsics, Rig
from pcdof.errors import EXIT_CODES, CalibrationError, ImageReadError, ImageWriteError, InputError, LensError

pytestmark = pytest.mark.subprocess  # most tests here run pcdof in a child process

READ, CALIB, LENS, INPUT, WRITE = (EXIT_CODES[k] for k in (ImageReadError, CalibrationError, LensError, InputError,
                                                           ImageWriteError))
W, H = 8, 6
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------------------- hostile files
def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_claiming(width: int, height: int, *, bit_depth: int = 8, colour_type: int = 2,
                 idat: bytes = zlib.compress(b"\0" * 64)) -> bytes:
    """A PNG with valid chunk CRCs whose header declares width x height; its pixel data is *idat* as given."""
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return PNG_SIGNATURE + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", idat) + png_chunk(b"IEND", b"")


def jpeg_claiming(width: int, height: int) -> bytes:
    sof = struct.pack(">HBHHB", 17, 8, height, width, 3) + bytes([1, 0x11, 0, 2, 0x11, 0, 3, 0x11, 0])
    return b"\xff\xd8\xff\xc0" + sof + b"\xff\xd9"


def tiff_claiming(width: int, height: int) -> bytes:
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
               (273, 4, 1, 8), (277, 3, 1, 1), (278, 4, 1, height), (279, 4, 1, 2**32 - 1)]
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", *e) for e in entries) + b"\0\0\0\0"
    return b"II*\x00" + struct.pack("<I", 8) + ifd


def npy_claiming(shape: tuple[int, ...]) -> bytes:
    header = repr({"descr": "<f4", "fortran_order": False, "shape": shape})
    header += " " * ((-(10 + len(header) + 1)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + b"\0" * 64


def encode(ext: str, array: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, array)
    assert ok
    return buf.tobytes()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A valid 8x6 frame (colour.png, depth.png in mm, calib.json) and every hostile variant, in one folder."""
    d = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(0)
    color = encode(".png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    (d / "color.png").write_bytes(color)
    (d / "depth.png").write_bytes(encode(".png", rng.integers(500, 3000, (H, W), dtype=np.uint16)))
    rig = Rig.registered(Intrinsics(W, H, 10.0, 10.0, (W - 1) / 2, (H - 1) / 2), depth_scale=0.001)
    calib = rig.to_dict()
    (d / "calib.json").write_text(json.dumps(calib))

    # images
    (d / "truncated.png").write_bytes(color[: len(color) // 2])
    idat = color.index(b"IDAT") + 4
    corrupt = bytearray(color)
    corrupt[idat: idat + 12] = bytes(12)  # zlib stream destroyed, chunk CRC now wrong
    (d / "corrupt_idat.png").write_bytes(bytes(corrupt))
    bad_crc = bytearray(color)
    bad_crc[29] ^= 0xFF  # IHDR CRC
    (d / "bad_crc.png").write_bytes(bytes(bad_crc))
    (d / "random.png").write_bytes(rng.bytes(777))
    # valid CRCs around pixel data libpng rejects (or warns about) only while decoding
    (d / "not_zlib.png").write_bytes(png_claiming(W, H, idat=bytes(40)))
    (d / "short_idat.png").write_bytes(png_claiming(W, H, idat=zlib.compress(bytes(10))))
    (d / "long_idat.png").write_bytes(png_claiming(W, H, idat=zlib.compress(bytes(500))))
    (d / "bad_filter.png").write_bytes(png_claiming(W, H, idat=zlib.compress(bytes([9] + [0] * 3 * W) * H)))
    (d / "short_idat16.png").write_bytes(png_claiming(W, H, bit_depth=16, colour_type=0,
                                                      idat=zlib.compress(bytes(10))))
    (d / "empty.png").write_bytes(b"")
    (d / "signature_only.png").write_bytes(PNG_SIGNATURE)
    (d / "bomb.png").write_bytes(png_claiming(100_000, 100_000))
    (d / "bomb16.png").write_bytes(png_claiming(100_000, 100_000, bit_depth=16, colour_type=0))
    (d / "wide.png").write_bytes(png_claiming(20_000, 1))
    (d / "zero_width.png").write_bytes(png_claiming(0, H))
    (d / "bomb.jpg").write_bytes(jpeg_claiming(60_000, 60_000))
    (d / "bomb.tif").write_bytes(tiff_claiming(100_000, 100_000))
    (d / "bomb.npy").write_bytes(npy_claiming((100_000, 100_000)))
    np.save(d / "pickle.npy", np.array([[1, None]], dtype=object), allow_pickle=True)
    (d / "depth8.png").write_bytes(encode(".png", rng.integers(0, 256, (H, W), dtype=np.uint8)))
    (d / "depth_rgb16.png").write_bytes(encode(".png", rng.integers(0, 65535, (H, W, 3), dtype=np.uint16)))
    (d / "depth_small.png").write_bytes(encode(".png", rng.integers(500, 3000, (H - 1, W - 1), dtype=np.uint16)))
    (d / "color_big.png").write_bytes(encode(".png", rng.integers(0, 256, (H + 2, W, 3), dtype=np.uint8)))
    (d / "depth_zero.png").write_bytes(encode(".png", np.zeros((H, W), np.uint16)))
    (d / "folder.png").mkdir()
    (d / "folder.json").mkdir()

    # calibrations
    def calib_file(name, obj=None, text=None):
        (d / name).write_text(text if text is not None else json.dumps(obj))

    missing = dict(calib)
    del missing["depth_scale"]
    calib_file("missing_key.json", missing)
    no_color = {k: v for k, v in calib.items() if k != "color"}
    calib_file("missing_color.json", no_color)
    calib_file("wrong_type.json", {**calib, "color": {**calib["color"], "fx": "ten"}})
    calib_file("wrong_type_T.json", {**calib, "T_color_from_depth": "identity"})
    calib_file("nan.json", {**calib, "depth": {**calib["depth"], "cy": float("nan")}})  # json writes NaN
    calib_file("infinity.json", text=json.dumps(calib).replace('"fx": 10.0', '"fx": 1e999', 1))
    calib_file("zero_fx.json", {**calib, "color": {**calib["color"], "fx": 0}})
    calib_file("reflection.json", {**calib, "T_color_from_depth": np.diag([-1.0, 1, 1, 1]).tolist()})
    calib_file("not_json.json", text="color: fx = 10 (this is not JSON)")
    calib_file("broken.json", text=json.dumps(calib)[:-20])
    calib_file("top_level_list.json", [calib])
    calib_file("deep.json", text='{"color": ' + "[" * 100_000 + "]" * 100_000 + "}")
    (d / "binary.json").write_bytes(rng.bytes(300))
    (d / "empty.json").write_bytes(b"")
    calib_file("broken.yml", text="%YAML:1.0\n---\ncameraMatrix1: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
                                  "   dt: d\n   data: [ 10., 0., 4., 0., 10., 3., 0.\n")
    calib_file("truncated.xml", text='<?xml version="1.0"?>\n<opencv_storage>\n<cameraMatrix1 type_id="opencv-matrix">'
                                     "<rows>3</rows><cols>3")
    (d / "not_a_folder").write_bytes(b"a file where a folder is expected")
    return d


# ----------------------------------------------------------------------------------------- the cases
@dataclass(frozen=True)
class CliCase:
    """One command line. ``argv(inputs, case_dir)`` builds it (and any set-up) with outputs in ``case_dir/out``.

    ``code`` is the expected exit status (0 = success); ``word`` must appear in the error line;
    ``keep`` maps files placed in ``out`` beforehand to their content (None: an empty folder), which must
    survive the failure unchanged;
    ``{inputs}`` in an argument stands for the folder of input files.
    """

    id: str
    argv: Callable[[Path, Path], list[str]]
    code: int
    word: str = ""
    keep: tuple = ()


def frame_command(command="render", color="color.png", depth="depth.png", calib="calib.json", output=None,
                  extra=()):
    output = output or {"render": "out.png", "register": "depth.png", "cloud": "points.ply"}[command]

    def argv(inputs: Path, case_dir: Path) -> list[str]:
        target = output(case_dir) if callable(output) else case_dir / "out" / output
        return [command, str(inputs / color), str(inputs / depth), "--calib", str(inputs / calib), "-o",
                str(target), *extra]

    return argv


def under_a_file(name):
    def target(case_dir: Path) -> Path:
        blocker = case_dir / "blocker"
        blocker.write_bytes(b"not a folder")
        return blocker / name
    return target


CASES = [CliCase("valid render", frame_command(), 0),
         CliCase("valid register", frame_command("register"), 0),
         CliCase("valid cloud", frame_command("cloud"), 0)]
CASES += [CliCase(f"colour {name}", frame_command(color=name), code, word) for name, code, word in [
    ("truncated.png", READ, "truncated"),
    ("corrupt_idat.png", READ, "corrupt_idat.png"),
    ("bad_crc.png", READ, "bad_crc.png"),
    ("random.png", READ, "random.png"),
    ("not_zlib.png", READ, "not_zlib.png"),
    ("short_idat.png", READ, "short_idat.png"),
    ("long_idat.png", READ, "long_idat.png"),
    ("bad_filter.png", READ, "bad_filter.png"),
    ("empty.png", READ, "empty"),
    ("signature_only.png", READ, "signature_only.png"),
    ("missing.png", READ, "not found"),
    ("bomb.png", READ, "100000x100000"),  # header claims 100000x100000: refused before decoding
    ("wide.png", READ, "20000x1"),
    ("zero_width.png", READ, "empty image"),
    ("bomb.jpg", READ, "too large"),
    ("bomb.tif", READ, "too large"),
    ("bomb.npy", READ, "100000x100000"),
    ("pickle.npy", READ, "pickle"),
    ("color_big.png", INPUT, "8x8"),
    ("folder.png", READ, "folder"),
]]
CASES += [CliCase(f"depth {name}", frame_command(depth=name), code, word) for name, code, word in [
    ("truncated.png", READ, "truncated"),
    ("random.png", READ, "random.png"),
    ("short_idat16.png", READ, "short_idat16.png"),
    ("bomb16.png", READ, "100000x100000"),
    ("bomb.npy", READ, "100000x100000"),
    ("depth8.png", READ, "8-bit"),
    ("depth_rgb16.png", READ, "single-channel"),
    ("depth_small.png", INPUT, "7x5"),
    ("depth_zero.png", INPUT, "no known"),
    ("pickle.npy", READ, "pickle"),
    ("folder.png", READ, "folder"),
]]
CASES += [CliCase(f"calib {name}", frame_command(calib=name), code, word) for name, code, word in [
    ("missing_key.json", CALIB, "depth_scale"),
    ("missing_color.json", CALIB, "color"),
    ("wrong_type.json", CALIB, "color.fx"),
    ("wrong_type_T.json", CALIB, "T_color_from_depth"),
    ("nan.json", CALIB, "depth.cy"),
    ("infinity.json", CALIB, "fx"),
    ("zero_fx.json", CALIB, "fx"),
    ("reflection.json", CALIB, "reflection"),
    ("not_json.json", CALIB, "not_json.json"),
    ("broken.json", CALIB, "JSON"),
    ("top_level_list.json", CALIB, "top_level_list.json"),
    ("binary.json", CALIB, "binary.json"),
    ("broken.yml", CALIB, "broken.yml"),
    ("truncated.xml", CALIB, "truncated.xml"),
    ("empty.json", READ, "empty"),
    ("missing.json", READ, "not found"),
    ("deep.json", CALIB, "deep.json"),
    ("folder.json", READ, "folder"),
]]
CASES += [CliCase(f"option {' '.join(extra)}", frame_command(extra=extra), code, word) for extra, code, word in [
    (("--f-number", "0"), LENS, "--f-number"),
    (("--f-number", "-2.8"), LENS, "--f-number"),
    (("--f-number", "nan"), LENS, "--f-number"),
    (("--focus-distance", "0"), LENS, "--focus-distance"),
    (("--focus-distance", "-1"), LENS, "--focus-distance"),
    (("--focal-length", "inf"), LENS, "--focal-length"),
    (("--aperture-blades", "2"), LENS, "aperture_blades"),
    (("--focus-at", "100,100"), INPUT, "outside"),
    (("--depth-scale", "0"), INPUT, "depth_scale"),
]]
CASES += [
    CliCase("existing output unchanged", frame_command(extra=("--f-number", "0")), LENS, "--f-number",
            keep=(("out.png", b"previous result"),)),
    CliCase("output suffix", frame_command(output="out.bmp"), INPUT, "out.bmp"),
    CliCase("output name too long", frame_command(output="x" * 300 + ".png"), WRITE, "xxxx"),
    CliCase("output under a file", frame_command(output=under_a_file("out.png")), WRITE, "blocker"),
    CliCase("output is a folder", frame_command(), WRITE, "out.png", keep=(("out.png", None),)),
    CliCase("save-maps under a file",
            frame_command(extra=("--save-maps", "{inputs}/not_a_folder/maps")), WRITE, "maps"),
    CliCase("save-maps is a file", frame_command(extra=("--save-maps", "{inputs}/not_a_folder")), WRITE,
            "not_a_folder"),
]
for command in ("register", "cloud"):
    name = {"register": "depth.png", "cloud": "points.ply"}[command]
    CASES += [CliCase(f"{command} {label}", frame_command(command, **kw), code) for label, kw, code in [
        ("random depth", {"depth": "random.png"}, READ),
        ("missing key", {"calib": "missing_key.json"}, CALIB),
        ("size mismatch", {"depth": "depth_small.png"}, INPUT),
        ("output suffix", {"output": "out.bmp"}, INPUT),
        ("output under a file", {"output": under_a_file(name)}, WRITE),
        ("deep JSON", {"calib": "deep.json"}, CALIB),
        ("colour folder", {"color": "folder.png"}, READ),
    ]]
    CASES.append(CliCase(f"{command} output is a folder", frame_command(command), WRITE, name, keep=((name, None),)))


@pytest.fixture(scope="module")
def results(inputs, tmp_path_factory) -> dict:
    """Run every case once, a few processes at a time; case id -> (CompletedProcess, case folder)."""
    root = tmp_path_factory.mktemp("cases")

    def one(index_case):
        index, case = index_case
        case_dir = root / f"case{index:03d}"
        (case_dir / "out").mkdir(parents=True)
        for name, content in case.keep:
            if content is None:
                (case_dir / "out" / name).mkdir()
            else:
                (case_dir / "out" / name).write_bytes(content)
        argv = [a.replace("{inputs}", str(inputs)) for a in case.argv(inputs, case_dir)]
        return case.id, (run_pcdof(argv, case_dir), case_dir)

    with ThreadPoolExecutor(max_workers=4) as pool:
        return dict(pool.map(one, enumerate(CASES)))


def assert_clean_failure(proc: subprocess.CompletedProcess, code: int, out_dir: Path, *, word: str = "",
                         keep: tuple = ()) -> None:
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), proc.stderr
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    if word:
        assert word.lower() in lines[0].lower(), lines[0]
    left = sorted(os.listdir(out_dir))  # no output, no partial file, no temporary file
    assert left == sorted(name for name, _ in keep), "left behind: " + ", ".join(left)
    for name, content in keep:
        if content is None:
            assert os.listdir(out_dir / name) == []
        else:
            assert (out_dir / name).read_bytes() == content


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in CASES])
def test_command_line(case, results):
    proc, case_dir = results[case.id]
    out_dir = case_dir / "out"
    if case.code == 0:
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr
        (written,) = os.listdir(out_dir)
        if written.endswith(".png"):
            img = cv2.imread(str(out_dir / written), cv2.IMREAD_UNCHANGED)
            assert img.shape[:2] == (H, W)
        return
    assert_clean_failure(proc, case.code, out_dir, word=case.word, keep=case.keep)


# ----------------------------------------------------------------------------------------- in-process guards
def test_exit_codes_are_distinct():
    codes = [EXIT_CODES[k] for k in (ImageReadError, CalibrationError, LensError, InputError, ImageWriteError)]
    assert codes == [3, 4, 5, 6, 7]


def test_bomb_header_refused_without_decoding(inputs, monkeypatch):
    from pcdof.io import _files, read_color

    def no_decoding(*args, **kwargs):
        raise AssertionError("the pixels were decoded")

    monkeypatch.setattr(_files.cv2, "imdecode", no_decoding)
    for name in ("bomb.png", "wide.png", "bomb.npy"):
        with pytest.raises(ImageReadError, match="limit"):
            read_color(inputs / name)


def test_size_mismatch_refused_before_decoding(inputs, monkeypatch, tmp_path):
    from pcdof.io import _files, load_frame

    big = tmp_path / "big.png"
    big.write_bytes(encode(".png", np.zeros((480, 640, 3), np.uint8)))  # the calibration says 8x6

    def no_decoding(*args, **kwargs):
        raise AssertionError("the pixels were decoded")

    monkeypatch.setattr(_files.cv2, "imdecode", no_decoding)
    with pytest.raises(InputError, match="640x480"):
        load_frame(big, inputs / "depth.png", inputs / "calib.json")
