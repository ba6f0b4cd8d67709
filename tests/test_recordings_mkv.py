"""Azure Kinect .mkv recordings, written by the project in the k4arecorder layout from a synthetic scene."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("av")

from pcdof.cli.export import command as export_command  # noqa: E402
from pcdof.cli.info import command as info_command  # noqa: E402
from pcdof.errors import CalibrationError, ImageReadError, InputError  # noqa: E402
from pcdof.io import load_frame, read_calibration, write_depth, write_image, write_json  # noqa: E402
from pcdof.stages.register import register_depth  # noqa: E402
from pcdof.sources import open_source  # noqa: E402
from pcdof.sources.k4a_writer import write_k4a_recording  # noqa: E402
from pcdof.synth import generate_scene  # noqa: E402

N = 3
T_US = [1_000_000, 1_033_333, 1_066_667]


@pytest.fixture(scope="module")
def scene():
    # colour 720P and depth NFOV_2X2BINNED: the smallest modes of the device
    return generate_scene("portrait", color_size=(1280, 720), depth_size=(320, 288), seed=4, pixel_samples=1)


@pytest.fixture(scope="module")
def frames(scene):
    mm = np.rint(scene.depth_m * 1000).astype(np.uint16)
    depths = [np.where(mm > 0, mm + 7 * i, 0).astype(np.uint16) for i in range(N)]  # each frame its own depth
    colors = [np.roll(scene.color, 5 * i, axis=1) for i in range(N)]
    return colors, depths


@pytest.fixture(scope="module")
def recording(tmp_path_factory, scene, frames):
    path = tmp_path_factory.mktemp("k4a") / "rec.mkv"
    write_k4a_recording(path, *frames, scene.rig, timestamps_us=T_US, depth_delay_us=-150)
    return str(path)


def _write(tmp_path, scene, frames, name="rec.mkv", **kwargs):
    path = tmp_path / name
    write_k4a_recording(path, *frames, scene.rig, **kwargs)
    return str(path)


def test_depth_is_bit_exact(recording, frames):
    with open_source(recording) as src:
        assert len(src) == N
        for i, raw in enumerate(frames[1]):
            d = src.frame(i).depth_m
            assert d.dtype == np.float32
            np.testing.assert_array_equal(d, raw.astype(np.float32) * np.float32(0.001))
            np.testing.assert_array_equal(np.rint(d / np.float32(0.001)).astype(np.uint16), raw)


def test_colour_within_jpeg_error(recording, frames):
    with open_source(recording) as src:
        for i, color in enumerate(frames[0]):
            got = src.frame(i).color
            assert got.shape == color.shape and got.dtype == np.uint8
            assert cv2.PSNR(got, color) > 35  # quality 95 JPEG
            assert np.abs(got.astype(int) - color).mean() < 2


def test_timestamps_pairs_and_lookup(recording):
    with open_source(recording) as src:
        f = src.frame(1)
        assert f.timestamp_s == pytest.approx(T_US[1] * 1e-6) and f.depth_time_s == pytest.approx(T_US[1] * 1e-6 - 150e-6)
        assert src.index_at(1.07) == 2 and src.frame_at(0.0).index == 0
        assert [fr.index for fr in src] == list(range(N))
        info = src.info()
        assert info["frames"] == N and info["streams"]["DEPTH"]["codec"] == "b16g"
        assert info["streams"]["COLOR"]["mode"] == "MJPG_720P" and info["streams"]["DEPTH"]["mode"] == "NFOV_2X2BINNED"
        json.dumps(info)


def test_calibration_is_the_rig_written(recording, scene):
    with open_source(recording) as src:
        rig = src.rig
    for a, b in ((rig.color, scene.rig.color), (rig.depth, scene.rig.depth)):
        assert a.shape == b.shape
        np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=0, atol=1e-9)
        assert not a.has_distortion
    np.testing.assert_allclose(rig.T_color_from_depth, scene.rig.T_color_from_depth, atol=1e-12)
    assert rig.depth_scale == 0.001


def test_registration_matches_truth_as_the_png_path(recording, scene, frames, tmp_path):
    with open_source(recording) as src:
        frame = src.frame(0)
        mkv = register_depth(frame.rgbd())
    write_image(tmp_path / "c.png", frames[0][0])
    write_image(tmp_path / "d.png", frames[1][0])
    write_json(tmp_path / "calib.json", scene.rig)
    png = register_depth(load_frame(tmp_path / "c.png", tmp_path / "d.png", tmp_path / "calib.json"))
    truth = scene.depth_color_m
    both = (mkv > 0) & (png > 0) & (truth > 0)
    err_mkv = np.median(np.abs(mkv[both] - truth[both]))
    err_png = np.median(np.abs(png[both] - truth[both]))
    assert err_mkv <= err_png + 1e-6
    assert err_mkv < 0.01  # metres: the sensor noise of the synthetic depth, not a misregistration
    np.testing.assert_allclose(mkv, png, atol=1e-5)


def test_calib_override(recording, scene, tmp_path):
    path = tmp_path / "calib.json"
    write_json(path, scene.rig.to_dict() | {"depth_scale": 0.5})
    with open_source(recording, calib=path) as src:
        assert src.info()["calibration_from"] == str(path)
        assert src.rig.depth_scale == 0.001  # the recording's units convert its integers
    bad = scene.rig.to_dict()
    bad["color"]["width"] = 640
    write_json(path, bad)
    with pytest.raises(CalibrationError, match="colour|color"):
        open_source(recording, calib=path)


class TestBadRecordings:
    def test_truncated(self, recording, tmp_path):
        cut = tmp_path / "cut.mkv"
        data = open(recording, "rb").read()
        cut.write_bytes(data[: len(data) // 2])
        with pytest.raises(ImageReadError, match=r"cut\.mkv is truncated"):
            open_source(cut)

    def test_missing_calibration(self, tmp_path, scene, frames):
        path = _write(tmp_path, scene, frames, calibration=b"")
        with pytest.raises(CalibrationError, match=r"rec\.mkv has no calibration\.json attachment"):
            open_source(path)

    def test_unknown_depth_codec(self, tmp_path, scene, frames):
        path = _write(tmp_path, scene, frames, depth_fourcc=b"Y16 ")
        with pytest.raises(ImageReadError, match=r"rec\.mkv: the DEPTH track's codec .* is unknown.*b16g"):
            open_source(path)

    def test_frame_index_out_of_range(self, recording):
        with open_source(recording) as src:
            for bad in (N, -N - 1):
                with pytest.raises(InputError, match=r"rec\.mkv: frame index .* out of range.*3 frames"):
                    src.frame(bad)
            with pytest.raises(InputError, match="integer"):
                src.frame(1.0)

    def test_one_undecodable_frame(self, tmp_path, scene, frames):
        path = _corrupt_frame(tmp_path, scene, frames, 1)
        with open_source(path) as src:
            assert src.frame(0).index == 0 and src.frame(2).index == 2
            with pytest.raises(ImageReadError, match=r"bad\.mkv: frame 1: its colour image .* cannot be decoded"):
                src.frame(1)
        out = tmp_path / "out"
        result = CliRunner().invoke(export_command, [path, "-o", str(out)])
        assert result.exit_code == 10, result.output
        assert "frame 1" in result.output and "wrote 2 of 3 frames" in result.output
        assert sorted(os.listdir(out / "color")) == ["000000.png", "000002.png"]


def _corrupt_frame(tmp_path, scene, frames, k):
    """A recording whose colour frame *k* has lost the end of its JPEG data (same length, zeros)."""
    path = _write(tmp_path, scene, frames, name="bad.mkv")
    ok, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(frames[0][k][:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    jpeg = jpeg.tobytes()
    data = bytearray(open(path, "rb").read())
    at = data.find(jpeg)
    assert at > 0 and data.find(jpeg, at + 1) < 0
    data[at + len(jpeg) - 2000: at + len(jpeg)] = bytes(2000)
    open(path, "wb").write(bytes(data))
    return path


class TestCli:
    def test_info(self, recording):
        result = CliRunner().invoke(info_command, [recording])
        assert result.exit_code == 0, result.output
        assert "azure-kinect, 3 colour+depth frames" in result.output and "1280x720" in result.output
        result = CliRunner().invoke(info_command, [recording, "--json"])
        assert json.loads(result.output)["frames"] == N

    def test_export_raw_reads_back_as_the_recording(self, recording, frames, scene, tmp_path):
        out = tmp_path / "out"
        result = CliRunner().invoke(export_command, [recording, "-o", str(out), "--frames", "1:3"])
        assert result.exit_code == 0, result.output
        assert sorted(os.listdir(out / "depth")) == ["000001.png", "000002.png"]
        frame = load_frame(out / "color/000001.png", out / "depth/000001.png", out / "calib.json")
        np.testing.assert_array_equal(frame.depth_m, frames[1][1].astype(np.float32) * np.float32(0.001))
        rig = read_calibration(out / "calib.json")
        np.testing.assert_allclose(rig.T_color_from_depth, scene.rig.T_color_from_depth, atol=1e-12)

    def test_export_registered(self, recording, tmp_path):
        out = tmp_path / "reg"
        result = CliRunner().invoke(export_command, [recording, "-o", str(out), "--registered", "--frames", "0"])
        assert result.exit_code == 0, result.output
        frame = load_frame(out / "color/000000.png", out / "depth/000000.png", out / "calib.json")
        assert frame.rig.is_registered and frame.depth_m.shape == (720, 1280)
        with open_source(recording) as src:
            expected = register_depth(src.frame(0).rgbd())
        np.testing.assert_allclose(frame.depth_m, expected, atol=0.0005 + 1e-6)  # millimetre PNG

    def test_export_refuses_bad_frames_and_overwriting_input(self, recording, tmp_path):
        result = CliRunner().invoke(export_command, [recording, "-o", str(tmp_path / "o"), "--frames", "7"])
        assert result.exit_code != 0 and "3 frames" in result.output
        assert not (tmp_path / "o").exists()


def test_export_never_overwrites_the_recording(recording, tmp_path):
    out = tmp_path / "o"
    (out / "color").mkdir(parents=True)
    os.link(recording, out / "color" / "000000.png")
    before = open(recording, "rb").read()
    result = CliRunner().invoke(export_command, [recording, "-o", str(out), "--frames", "0"])
    assert result.exit_code != 0 and "refusing to overwrite the input RECORDING" in result.output
    assert open(recording, "rb").read() == before
