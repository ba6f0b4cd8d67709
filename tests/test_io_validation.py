"""Readers refuse damaged files and writers refuse values they cannot store.

Each test was written against a defect: a corrupt JPEG read as an image, ``jpeg_quality`` clamped by
OpenCV, plain ``ValueError``/``OverflowError`` (or a crash) from a calibration file, float writers
that stored inf after the float32 cast, integer PLY colours clipped as if in [0, 1], and a PFM file
with a NaN scale read as big-endian garbage. Written files are read back with other libraries, and a
refused write must leave nothing behind.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from pcdof.cloud import write_ply
from pcdof.errors import EXIT_CODES, CalibrationError, ImageReadError, InputError
from pcdof.io import read_calibration, read_color, read_depth, write_depth, write_image
from pcdof.io._jpeg import decode_jpeg

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sample"


def sample_bgr() -> np.ndarray:
    return cv2.imread(str(SAMPLE / "color.png"), cv2.IMREAD_UNCHANGED)


def jpeg(img: np.ndarray, *params: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", img, list(params))
    assert ok
    return buf.tobytes()


def segments(data: bytes) -> list[tuple[int, int, int]]:
    """(marker, start, end) of the marker segments before the first scan's data."""
    out, pos = [], 2
    while True:
        marker, length = data[pos + 1], struct.unpack_from(">H", data, pos + 2)[0]
        out.append((marker, pos, pos + 2 + length))
        if marker == 0xDA:
            return out
        pos += 2 + length


def scan_start(data: bytes) -> int:
    return segments(data)[-1][2]


def without_dht(data: bytes) -> bytes:
    """*data* without its Huffman tables, like a Motion-JPEG frame."""
    return data[:2] + b"".join(data[s:e] for m, s, e in segments(data) if m != 0xC4) + data[scan_start(data):]


# ------------------------------------------------------------------------------------------------ JPEG
@pytest.fixture
def library_messages_captured():
    """What the ``pcdof`` command turns on (:func:`pcdof.runtime.process.tune_process`): libjpeg's complaints on
    file descriptor 2 captured and turned into errors; restored afterwards (a library user's process, which pcdof
    leaves alone, does not capture). Set here, not inherited from whichever test ran the command before."""
    from pcdof.io import capture

    before = capture.enabled()
    capture.enable(True)
    try:
        yield
    finally:
        capture.enable(before)


@pytest.mark.usefixtures("library_messages_captured")
class TestCorruptJpeg:
    def test_missing_end_of_image_marker(self, tmp_path, capfd):
        data = jpeg(sample_bgr())
        assert data.endswith(b"\xff\xd9")
        (tmp_path / "no_eoi.jpg").write_bytes(data[:-2])
        with pytest.raises(ImageReadError, match=r"no_eoi\.jpg: the JPEG is truncated.*without its end-of-image marker"):
            read_color(tmp_path / "no_eoi.jpg")
        assert capfd.readouterr().err == ""

    def test_scrambled_entropy_data(self, tmp_path, capfd):
        data = bytearray(jpeg(sample_bgr()))
        middle = (scan_start(bytes(data)) + len(data)) // 2
        for i in range(middle, middle + 200):  # new bytes, but no new 0xFF (a marker) and none taken away
            if data[i] != 0xFF:
                data[i] = ((data[i] * 7 + 13) & 0xFF) % 0xFF
        (tmp_path / "scrambled.jpg").write_bytes(bytes(data))
        # what OpenCV does with it: an image, and libjpeg's complaint on stderr
        assert cv2.imdecode(np.frombuffer(bytes(data), np.uint8), cv2.IMREAD_UNCHANGED) is not None
        assert "Corrupt JPEG data" in capfd.readouterr().err
        with pytest.raises(ImageReadError, match=r"scrambled\.jpg: the JPEG is corrupt: Corrupt JPEG data"):
            read_color(tmp_path / "scrambled.jpg")
        assert capfd.readouterr().err == ""  # refused before libjpeg could print anything

    def test_premature_end_of_data_segment(self, tmp_path):
        data = jpeg(sample_bgr())
        start = scan_start(data)
        cut = data[:start + (len(data) - start) // 2] + b"\xff\xd9"  # half the data, then a proper end marker
        (tmp_path / "short.jpg").write_bytes(cut)
        with pytest.raises(ImageReadError, match=r"short\.jpg: the JPEG is corrupt"):
            read_color(tmp_path / "short.jpg")

    def test_restart_markers_out_of_sequence(self, tmp_path):
        data = bytearray(jpeg(sample_bgr(), cv2.IMWRITE_JPEG_RST_INTERVAL, 4))
        first = data.index(b"\xff\xd0", scan_start(bytes(data)))
        data[first + 1] = 0xD3
        (tmp_path / "rst.jpg").write_bytes(bytes(data))
        with pytest.raises(ImageReadError, match=r"rst\.jpg: the JPEG is corrupt"):
            read_color(tmp_path / "rst.jpg")

    def test_stray_bytes_between_segments(self, tmp_path):
        data = jpeg(sample_bgr())
        _, _, end = segments(data)[0]
        (tmp_path / "stray.jpg").write_bytes(data[:end] + b"\x00\x01\x02" + data[end:])
        with pytest.raises(ImageReadError, match=r"stray\.jpg: the JPEG is corrupt: Corrupt JPEG data: 3 extraneous bytes"):
            read_color(tmp_path / "stray.jpg")

    def test_progression_with_a_scan_missing(self, tmp_path):
        """A progressive file that stops after a few scans (with its end marker) is valid; one with a scan
        taken out of the middle refines coefficients it never sent: libjpeg's "bogus progression"."""
        data = jpeg(sample_bgr(), cv2.IMWRITE_JPEG_PROGRESSIVE, 1)
        sos = [i for i in range(len(data) - 1) if data[i:i + 2] == b"\xff\xda"]
        assert len(sos) > 3
        (tmp_path / "fewer_scans.jpg").write_bytes(data[:sos[3]] + b"\xff\xd9")
        read_color(tmp_path / "fewer_scans.jpg")  # an incomplete but valid progression
        (tmp_path / "skipped.jpg").write_bytes(data[:sos[1]] + data[sos[2]:])
        with pytest.raises(ImageReadError, match=r"skipped\.jpg.*corrupt"):
            read_color(tmp_path / "skipped.jpg")

    def test_cli_one_line_exit_code(self, tmp_path):
        (tmp_path / "color.jpg").write_bytes(jpeg(sample_bgr())[:-2])  # OpenCV alone decodes this one
        exe = Path(sys.executable).with_name("pcdof")
        cmd = [str(exe)] if exe.exists() else [sys.executable, "-c", "import sys; from pcdof.cli import main; "
                                                                      "sys.exit(main())"]
        out = tmp_path / "out"
        proc = subprocess.run(cmd + ["register", str(tmp_path / "color.jpg"), str(SAMPLE / "depth.png"), "--calib",
                                     str(SAMPLE / "calib.json"), "-o", str(out / "depth.png")],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == EXIT_CODES[ImageReadError], proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error:") and "color.jpg" in lines[0], proc.stderr
        assert not out.exists() or os.listdir(out) == []


@pytest.mark.usefixtures("library_messages_captured")
class TestValidJpegUnchanged:
    """The check refuses nothing OpenCV decodes cleanly, and read_color still returns OpenCV's pixels."""

    @staticmethod
    def encodings() -> list[tuple[str, bytes]]:
        bgr = sample_bgr()
        odd = cv2.resize(bgr, (97, 61), interpolation=cv2.INTER_AREA)
        grey = cv2.cvtColor(odd, cv2.COLOR_BGR2GRAY)
        out = [
            ("baseline", jpeg(bgr)),
            ("quality 100, 4:4:4", jpeg(odd, cv2.IMWRITE_JPEG_QUALITY, 100, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                        cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444)),
            ("4:1:1, optimised", jpeg(odd, cv2.IMWRITE_JPEG_OPTIMIZE, 1, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                      cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411)),
            ("progressive", jpeg(odd, cv2.IMWRITE_JPEG_PROGRESSIVE, 1)),
            ("restart markers", jpeg(odd, cv2.IMWRITE_JPEG_RST_INTERVAL, 1)),
            ("progressive + restart", jpeg(odd, cv2.IMWRITE_JPEG_PROGRESSIVE, 1, cv2.IMWRITE_JPEG_RST_INTERVAL, 3)),
            ("grey", jpeg(grey, cv2.IMWRITE_JPEG_QUALITY, 5)),
            ("trailing data after the end marker", jpeg(odd) + b"appended by some camera"),
        ]
        for mode, kwargs in (("RGB", {"progressive": True, "optimize": True, "subsampling": 2}),
                             ("L", {"progressive": True}), ("CMYK", {"quality": 40}),
                             ("RGB", {"restart_marker_rows": 1, "subsampling": 1})):
            buf = io.BytesIO()
            Image.fromarray(odd[:, :, ::-1]).convert(mode).save(buf, "JPEG", **kwargs)
            out.append((f"Pillow {mode} {kwargs}", buf.getvalue()))
        # a Motion-JPEG frame: no Huffman tables, libjpeg-turbo uses the standard ones
        data = jpeg(odd)
        out.append(("no DHT segments", without_dht(data)))
        return out

    def test_decoded_as_opencv_does(self, tmp_path, capfd):
        for i, (label, data) in enumerate(self.encodings()):
            path = tmp_path / f"{i}.jpg"
            path.write_bytes(data)
            expected = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            assert expected is not None and capfd.readouterr().err == "", label  # libjpeg itself finds nothing wrong
            got = read_color(path)
            expected = np.repeat(expected[:, :, None], 3, axis=2) if expected.ndim == 2 else expected[:, :, 2::-1]
            np.testing.assert_array_equal(got, expected, err_msg=label)

    def test_corrupt_mjpeg_frame(self, tmp_path, capfd):
        """A Motion-JPEG frame (no Huffman tables: libjpeg uses the standard ones) cut short is refused."""
        mjpeg = without_dht(jpeg(sample_bgr()))
        start = scan_start(mjpeg)
        with pytest.raises(ImageReadError, match=r"f\.jpg: the JPEG is corrupt"):
            decode_jpeg(mjpeg[:start + 300] + b"\xff\xd9", "f.jpg", "colour")
        assert capfd.readouterr().err == ""

    def test_other_stderr_output_is_passed_on(self, capfd, monkeypatch):
        """Only libjpeg's damage warnings are taken from stderr; anything else written meanwhile stays."""
        import pcdof.io._jpeg as jpeg_module

        def noisy_decode(buf, flags):
            os.write(2, b"some other library's message\n")
            return np.zeros((2, 2, 3), np.uint8)

        monkeypatch.setattr(jpeg_module.cv2, "imdecode", noisy_decode)
        img = decode_jpeg(jpeg(sample_bgr()), "f.jpg", "colour")
        assert img.shape == (2, 2, 3)
        assert capfd.readouterr().err == "some other library's message\n"


# ------------------------------------------------------------------------------------------------ PNG
def test_truncated_png_refused(tmp_path, capfd):
    """(Already refused before: kept as a guard next to the JPEG cases.)"""
    data = (SAMPLE / "color.png").read_bytes()
    (tmp_path / "no_iend.png").write_bytes(data[:-12])
    with pytest.raises(ImageReadError, match=r"no_iend\.png is truncated"):
        read_color(tmp_path / "no_iend.png")
    assert capfd.readouterr().err == ""


# ------------------------------------------------------------------------------------------------ writers
class TestJpegQuality:
    @pytest.mark.parametrize("quality", [500, 101, -1, "high", float("nan"), 95.0, True, None])
    def test_refused(self, tmp_path, capfd, quality):
        with pytest.raises(InputError, match=r"jpeg_quality must be an integer in 0\.\.100"):
            write_image(tmp_path / "q.jpg", np.zeros((4, 4, 3), np.uint8), jpeg_quality=quality)
        assert os.listdir(tmp_path) == []
        assert capfd.readouterr().err == ""  # no OpenCV warning either

    @pytest.mark.parametrize("quality", [0, 100, np.int64(80)])
    def test_accepted(self, tmp_path, quality):
        rgb = np.full((8, 8, 3), 200, np.uint8)
        write_image(tmp_path / "q.jpg", rgb, jpeg_quality=quality)
        assert np.abs(np.asarray(Image.open(tmp_path / "q.jpg")).astype(int) - 200).max() <= 8


class TestFloatRange:
    """Values finite in float64 but beyond float32 (about 3.4e38) would be stored as inf."""

    @pytest.mark.parametrize("name", ["inf.tif", "inf.npy", "inf.exr"])
    def test_write_image_beyond_float32(self, tmp_path, name):
        if name.endswith(".exr"):
            pytest.importorskip("OpenEXR")
        with pytest.raises(InputError, match="image must be finite.*float32's range"):
            write_image(tmp_path / name, np.full((4, 4, 3), 1e300))
        assert os.listdir(tmp_path) == []

    def test_write_image_float64_in_range(self, tmp_path):
        img = np.random.default_rng(0).random((5, 6, 3)) * 1e30
        write_image(tmp_path / "ok.tif", img)
        back = cv2.imread(str(tmp_path / "ok.tif"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(back[:, :, ::-1], img.astype(np.float32))

    @pytest.mark.parametrize("name", ["d.tif", "d.npy", "d.exr"])
    @pytest.mark.parametrize("value", [1e300, -1e300, np.nan, np.inf])
    def test_write_depth_float_formats(self, tmp_path, name, value):
        if name.endswith(".exr"):
            pytest.importorskip("OpenEXR")
        depth = np.ones((4, 4))
        depth[1, 2] = value
        with pytest.raises(InputError, match="depth_m must be finite"):
            write_depth(tmp_path / name, depth)
        assert os.listdir(tmp_path) == []

    def test_write_depth_png_stays_finite(self, tmp_path):
        with pytest.warns(UserWarning, match="clipped"):
            write_depth(tmp_path / "d.png", np.full((2, 2), 1e300))
        assert np.asarray(Image.open(tmp_path / "d.png")).tolist() == [[65535, 65535], [65535, 65535]]

    def test_write_ply_beyond_float32(self, tmp_path):
        with pytest.raises(InputError, match="points must be finite.*float32's range"):
            write_ply(tmp_path / "a.ply", np.full((1, 3), 1e300))
        assert os.listdir(tmp_path) == []


class TestPlyColours:
    @pytest.mark.parametrize("cols, expected", [
        (np.array([[200, 100, 0]], np.uint8), [200, 100, 0]),
        (np.array([[65535, 32768, 0]], np.uint16), [255, 128, 0]),
        (np.array([[2**31 - 1, -5, 0]], np.int32), [255, 0, 0]),
        (np.array([[1.0, 0.5, -0.2]]), [255, 128, 0]),
    ])
    def test_scaled_by_dtype(self, tmp_path, cols, expected):
        import open3d as o3d

        write_ply(tmp_path / "c.ply", np.array([[0.0, 0.0, 1.0]]), cols)
        pcd = o3d.io.read_point_cloud(str(tmp_path / "c.ply"))
        np.testing.assert_array_equal(np.rint(np.asarray(pcd.colors) * 255), [expected])


# ------------------------------------------------------------------------------------------------ PFM
class TestPfmScale:
    @pytest.mark.parametrize("scale", [b"nan", b"-nan", b"inf", b"-inf", b"0", b"-0.0"])
    def test_non_finite_or_zero_scale(self, tmp_path, scale):
        (tmp_path / "d.pfm").write_bytes(b"Pf\n2 2\n" + scale + b"\n" + np.ones(4, "<f4").tobytes())
        with pytest.raises(ImageReadError, match=r"d\.pfm: malformed PFM header \(scale"):
            read_depth(tmp_path / "d.pfm")

    @pytest.mark.parametrize("scale, order", [(b"-1.0", "<f4"), (b"1.0", ">f4"), (b"-0.003922", "<f4")])
    def test_valid_scale(self, tmp_path, scale, order):
        values = np.array([[1.5, 2.0], [0.5, 3.0]], np.float32)
        (tmp_path / "d.pfm").write_bytes(b"Pf\n2 2\n" + scale + b"\n" + values[::-1].astype(order).tobytes())
        np.testing.assert_array_equal(read_depth(tmp_path / "d.pfm"), values)


# ------------------------------------------------------------------------------------------------ calibration
def calib_dict() -> dict:
    return json.loads((SAMPLE / "calib.json").read_text())


OPEN3D = '{"width": %s, "height": 10, "intrinsic_matrix": [%s, 0, 0, 0, 1, 0, 5, 5, 1], "depth_scale": %s}'


class TestCalibrationNumbers:
    @pytest.mark.parametrize("text, match", [
        (OPEN3D % ("9" * 5000, "1", "0.001"), r"its JSON cannot be read \(Exceeds the limit \(4300 digits\)"),
        (OPEN3D % ("-" + "9" * 5000, "1", "0.001"), "4300 digits"),
        (OPEN3D % ("9" * 400, "1", "0.001"), "width must be finite; got an integer too large for a float"),
        (OPEN3D % ("10", "9" * 400, "0.001"), "intrinsic_matrix must be finite; got an integer too large"),
        (OPEN3D % ("10", "1", "9" * 400), "depth_scale must be finite; got an integer too large"),
    ])
    def test_open3d_json(self, tmp_path, text, match):
        (tmp_path / "calib.json").write_text(text)
        with pytest.raises(CalibrationError, match=r"calib\.json: .*" + match):
            read_calibration(tmp_path / "calib.json")

    @pytest.mark.parametrize("edit", ["T", "distortion", "width", "depth_scale"])
    def test_calib_json(self, tmp_path, edit):
        calib = calib_dict()
        huge = 10 ** 400
        if edit == "T":
            calib["T_color_from_depth"][0][3] = huge
        elif edit == "distortion":
            calib["color"]["distortion"] = [huge, 0, 0, 0, 0]
        elif edit == "width":
            calib["depth"]["width"] = huge
        else:
            calib["depth_scale"] = huge
        (tmp_path / "calib.json").write_text(json.dumps(calib))
        with pytest.raises(CalibrationError, match=r"calib\.json: .*too large for a float"):
            read_calibration(tmp_path / "calib.json")

    def test_huge_depth_scale_argument(self):
        with pytest.raises(InputError, match="depth_scale must be a finite number"):
            read_calibration(SAMPLE / "calib.json", depth_scale=10 ** 400)

    @pytest.mark.parametrize("content", [b'{"color": "\xff\xfe"}', b"{" + bytes(range(256))])
    def test_binary(self, tmp_path, content):
        (tmp_path / "calib.json").write_bytes(content)
        with pytest.raises(CalibrationError, match=r"calib\.json"):
            read_calibration(tmp_path / "calib.json")


DEEP_FILESTORAGE = {
    "flow.yml": "%YAML:1.0\n---\na: " + "[" * 100_000 + "]" * 100_000 + "\n",
    "maps.yml": "%YAML:1.0\n---\na: " + "{b: " * 100_000 + "1" + "}" * 100_000 + "\n",
    "dashes.yml": "%YAML:1.0\n---\na:\n  " + "- " * 100_000 + "1\n",
    "keys.yml": "%YAML:1.0\n---\na: " + "b: " * 100_000 + "1\n",
    "tags.xml": '<?xml version="1.0"?>\n<opencv_storage>' + "<b>" * 100_000 + "1" + "</b>" * 100_000
                + "</opencv_storage>\n",
}


class TestDeepFileStorage:
    """cv2.FileStorage recurses once per nesting level and crashes the process (SIGSEGV) at some 30 000."""

    @pytest.mark.parametrize("name", sorted(DEEP_FILESTORAGE))
    def test_refused_without_crash(self, tmp_path, name):
        (tmp_path / name).write_text(DEEP_FILESTORAGE[name])
        gz = tmp_path / (name + ".gz")
        gz.write_bytes(gzip.compress(DEEP_FILESTORAGE[name].encode()))
        code = ("import sys\nfrom pcdof.errors import CalibrationError\nfrom pcdof.io import read_calibration\n"
                "for path in sys.argv[1:]:\n"
                "    try:\n        read_calibration(path)\n"
                "    except CalibrationError as err:\n        print(err)\n")
        proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / name), str(gz)], capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, f"crashed with {proc.returncode}: {proc.stderr[-500:]}"
        lines = proc.stdout.strip().splitlines()
        assert len(lines) == 2 and all("nested up to" in line for line in lines), proc.stdout
        assert name in lines[0] and name + ".gz" in lines[1]

    def test_opencv_calibration_still_read(self, tmp_path):
        """A FileStorage file as OpenCV writes it (a 1-D array is an ``opencv-nd-matrix``), and gzipped."""
        path = str(tmp_path / "stereo.yml")
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
        K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
        for key, value in (("cameraMatrix1", K), ("distCoeffs1", np.zeros((1, 5))), ("cameraMatrix2", K),
                           ("distCoeffs2", np.array([[-0.1, 0.01, 0, 0, -0.001]])), ("R", np.eye(3)),
                           ("T", np.array([[-0.025], [0.0], [0.0]])),
                           ("imageSize", np.array([640, 480], np.int32)), ("depth_scale", 0.001)):
            fs.write(key, value)
        fs.release()
        rig = read_calibration(path)
        assert rig.color.fx == 500.0 and rig.depth_scale == 0.001
        with open(path, "rb") as f:
            (tmp_path / "stereo.yml.gz").write_bytes(gzip.compress(f.read()))
        assert read_calibration(tmp_path / "stereo.yml.gz").color.width == 640

    def test_bad_gzip(self, tmp_path):
        (tmp_path / "calib.yml.gz").write_bytes(b"not gzip at all")
        with pytest.raises(CalibrationError, match=r"calib\.yml\.gz: is not a valid gzip file"):
            read_calibration(tmp_path / "calib.yml.gz")
