"""Recordings under hostile use: any name, any kind of file, a damaged header, a missing calibration.

* a RealSense bag is recognised by its content whatever its name (``REC.BAG``, no suffix) and read
  as the same recording;
* a dangling link, a socket, a FIFO or a folder named like a recording is refused with one line
  (exit 3), never opened for reading (a FIFO would block ``info``, ``render`` and ``batch`` forever);
* a Matroska file whose EBML header is malformed (unknown size, invalid size) is a read error;
* ``--calib`` replaces a recording's calibration before the recording's own is needed: a recording
  without its calibration opens with one, and reads the frames of the intact recording.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess

import numpy as np
import pytest

from conftest import one_line

from pcdof.errors import EXIT_CODES, CalibrationError, ImageReadError
from pcdof.sources import open_source, source_format

READ, CALIB = EXIT_CODES[ImageReadError], EXIT_CODES[CalibrationError]


def run(console_script, *args, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run(console_script + [os.fspath(a) for a in args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "COLUMNS": "200"})


# --------------------------------------------------------------------------- a bag by content, whatever its name
@pytest.mark.parametrize("name", ["REC.BAG", "recording", "capture.Bag", "take.rosbag"])
def test_a_bag_under_any_name_is_the_same_recording(sample_bag, tmp_path, name):
    renamed = tmp_path / name
    shutil.copy(sample_bag, renamed)
    assert source_format(renamed) == "realsense-bag"
    with open_source(sample_bag) as a, open_source(renamed) as b:
        assert len(a) == len(b)
        fa, fb = a.frame(0), b.frame(0)
        np.testing.assert_array_equal(fa.color, fb.color)
        np.testing.assert_array_equal(fa.depth_m, fb.depth_m)
        np.testing.assert_array_equal(a.rig.T_color_from_depth, b.rig.T_color_from_depth)


def test_info_reads_a_bag_named_in_capitals(sample_bag, tmp_path, console_script):
    renamed = tmp_path / "REC.BAG"
    shutil.copy(sample_bag, renamed)
    proc = run(console_script, "info", renamed, "--json")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert '"format": "realsense-bag"' in proc.stdout


# --------------------------------------------------------------------------- not a regular file
def _special(kind: str, path):
    if kind == "dangling":
        os.symlink(path.parent / "gone", path)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(os.fspath(path))
        sock.close()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "device":
        os.symlink("/dev/zero", path)
    return path


KINDS = ["dangling", "socket", "fifo", "device"]
NAMES = ["rec.bag", "rec.mkv", "REC.BAG", "rec.MKV"]


@pytest.mark.timeout(120)
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", NAMES)
def test_open_source_refuses_what_is_not_a_regular_file(tmp_path, kind, name):
    path = _special(kind, tmp_path / name)
    with pytest.raises(ImageReadError) as info:
        with open_source(path):
            pass
    assert "\n" not in str(info.value) and name in str(info.value)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("kind,name,command", [
    ("fifo", "rec.bag", "info"), ("fifo", "rec.mkv", "render"), ("fifo", "rec.bag", "batch"),
    ("fifo", "rec.mkv", "export"), ("socket", "rec.bag", "info"), ("socket", "rec.mkv", "export"),
    ("dangling", "rec.bag", "render"), ("device", "rec.mkv", "info"),
])
def test_commands_refuse_it_at_once(tmp_path, console_script, kind, name, command):
    path = _special(kind, tmp_path / name)
    out = tmp_path / "out"
    args = {"info": [], "render": ["-o", out / "r.png"], "batch": ["-o", out], "export": ["-o", out]}[command]
    proc = run(console_script, command, path, *args, timeout=240)
    one_line(proc, READ, name)
    assert not out.exists()


# --------------------------------------------------------------------------- damaged Matroska headers
MAGIC = b"\x1a\x45\xdf\xa3"
DOCTYPE = b"\x42\x82\x88matroska"


@pytest.mark.parametrize("header,word", [
    (MAGIC + b"\xff" + DOCTYPE, "unknown size"),                              # 1-byte "unknown"
    (MAGIC + b"\x01\xff\xff\xff\xff\xff\xff\xff" + DOCTYPE, "unknown size"),  # 8-byte "unknown"
    (MAGIC + b"\x00" + DOCTYPE, "invalid EBML size"),                        # no length marker
    (MAGIC, "invalid EBML size"),                                            # nothing after the magic
    (MAGIC + b"\x01\x00\x00\x00\x00\x10\x00\x00" + DOCTYPE, "no Segment"),   # a size past the end
])
def test_malformed_ebml_header(tmp_path, console_script, header, word):
    path = tmp_path / "rec.mkv"
    path.write_bytes(header + b"\0" * 64)
    with pytest.raises(ImageReadError, match=word):
        open_source(path)
    one_line(run(console_script, "info", path), READ, "rec.mkv")


# --------------------------------------------------------------------------- --calib before the recording's own
def _bag_without(source, target, dropped: tuple[str, ...]) -> None:
    """A copy of the bag *source* without the connections whose topic ends with one of *dropped*."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(source) as reader:
        writer = Writer(target)
        writer.open()
        try:
            conns = {}
            for c in reader.connections:
                if c.topic.endswith(dropped) or c.topic in {k[0] for k in conns}:
                    continue
                conns[(c.topic, c.id)] = writer.add_connection(
                    c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest,
                    callerid=c.ext.callerid, latching=c.ext.latching)
            for c, t, raw in reader.messages():
                key = next((k for k in conns if k[0] == c.topic), None)
                if key is not None:
                    writer.write(conns[key], t, raw)
        finally:
            writer.close()


@pytest.fixture(scope="module")
def exported_calib(tmp_path_factory, sample_bag):
    """calib.json as ``pcdof export`` writes it for the intact sample bag (the round trip a user makes)."""
    from pcdof.camera import Rig
    from pcdof.io import write_json

    path = tmp_path_factory.mktemp("calib") / "calib.json"
    with open_source(sample_bag) as src:
        write_json(path, src.rig)
        assert isinstance(src.rig, Rig)
    return path


@pytest.mark.parametrize("dropped", [("/info/camera_info",), ("/tf/0",), ("/info/camera_info", "/tf/0")])
def test_calib_rescues_a_bag_without_its_calibration(sample_bag, exported_calib, tmp_path, console_script, dropped):
    stripped = tmp_path / "stripped.bag"
    _bag_without(sample_bag, stripped, dropped)
    with pytest.raises(CalibrationError, match="--calib"):
        open_source(stripped)
    with open_source(stripped, calib=exported_calib) as src, open_source(sample_bag) as intact:
        assert src.info()["calibration_from"] == str(exported_calib)
        got, want = src.frame(0), intact.frame(0)
        np.testing.assert_array_equal(got.depth_m, want.depth_m)
        np.testing.assert_array_equal(got.color, want.color)
        np.testing.assert_allclose(src.rig.T_color_from_depth, intact.rig.T_color_from_depth, atol=1e-12)
        assert src.rig.depth_scale == intact.rig.depth_scale
    proc = run(console_script, "info", stripped, "--calib", exported_calib)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def test_calib_of_the_wrong_size_is_still_refused_without_the_recording_s_own(sample_bag, exported_calib, tmp_path):
    import json

    stripped = tmp_path / "stripped.bag"
    _bag_without(sample_bag, stripped, ("/info/camera_info", "/tf/0"))
    bad = json.loads(exported_calib.read_text())
    bad["depth"]["width"] = 320
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps(bad))
    with pytest.raises(CalibrationError, match=r"depth camera is 320x480 but the depth stream .* is 640x480"):
        open_source(stripped, calib=wrong)


@pytest.fixture(scope="module")
def k4a_parts():
    from pcdof.camera import Intrinsics, Rig

    rng = np.random.default_rng(3)
    colors = [rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8) for _ in range(2)]
    depths = [rng.integers(500, 4000, (288, 320), dtype=np.uint16) for _ in range(2)]
    T = np.eye(4)
    T[0, 3] = -0.032
    rig = Rig(Intrinsics(1280, 720, 610.0, 610.0, 639.5, 359.5), Intrinsics(320, 288, 252.0, 252.0, 159.5, 143.5),
              T, depth_scale=0.001, max_range_m=5.46)
    return colors, depths, rig


@pytest.mark.parametrize("calibration", [b"", b"{}", b"not json"])
def test_calib_rescues_an_mkv_without_a_usable_calibration(tmp_path, k4a_parts, console_script, calibration):
    from pcdof.io import write_json
    from pcdof.sources.k4a_writer import write_k4a_recording

    colors, depths, rig = k4a_parts
    path = tmp_path / "rec.mkv"
    write_k4a_recording(path, colors, depths, rig, calibration=calibration)
    with pytest.raises(CalibrationError):
        open_source(path)
    calib = tmp_path / "calib.json"
    write_json(calib, rig)
    with open_source(path, calib=calib) as src:
        assert len(src) == 2 and src.info()["calibration_from"] == str(calib)
        np.testing.assert_array_equal(src.frame(1).depth_m, depths[1].astype(np.float32) * np.float32(0.001))
        np.testing.assert_allclose(src.rig.color.K, rig.color.K)
    proc = run(console_script, "export", path, "--calib", calib, "-o", tmp_path / "out", "--frames", "0")
    assert proc.returncode == 0, proc.stderr
    assert sorted(os.listdir(tmp_path / "out")) == ["calib.json", "color", "depth"]
