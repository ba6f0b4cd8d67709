"""pcdof.io: readers on the bundled real data, calibration formats, depth round trips, bad inputs, atomic writes.

Independent references: the JSON files parsed with the json module, Pillow and numpy for image
content, cv2.FileStorage / cv2.stereoCalibrate / Open3D for the calibration formats, the OpenEXR
package for EXR, and the Middlebury disparity-to-depth formula for PFM.
"""

import json
import os
import struct
import warnings
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image

from pcdof.camera import MAX_IMAGE_SIDE, Intrinsics, Rig
from pcdof.errors import CalibrationError, ImageReadError, ImageWriteError, InputError
from pcdof.io import (
    exr_available,
    load_frame,
    read_calibration,
    read_color,
    read_depth,
    write_depth,
    write_image,
    write_json,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REAL = os.path.join(ROOT, "data", "real")
EXAMPLES = os.path.join(ROOT, "data", "calib_examples")
TUM = os.path.join(REAL, "tum_rgbd_open3d")
NYU = os.path.join(REAL, "nyu_v2_raw_open3d")
MOTO = os.path.join(REAL, "middlebury2014_evalQ", "Motorcycle")
ADIR = os.path.join(REAL, "middlebury2014_evalQ", "Adirondack")

# (colour, depth, calibration) of every bundled frame
FRAMES = {
    "tum": (f"{TUM}/color.png", f"{TUM}/depth.png", f"{TUM}/calib.json"),
    "nyu": (f"{NYU}/color.png", f"{NYU}/depth.png", f"{NYU}/calib.json"),
    "motorcycle_im1": (f"{MOTO}/im1.png", f"{MOTO}/depth0.png", f"{MOTO}/calib.json"),
    "motorcycle_im0": (f"{MOTO}/im0.png", f"{MOTO}/depth0.png", f"{MOTO}/calib_im0.json"),
    "adirondack_im1": (f"{ADIR}/im1.png", f"{ADIR}/depth0.png", f"{ADIR}/calib.json"),
    "adirondack_im0": (f"{ADIR}/im0.png", f"{ADIR}/depth0.png", f"{ADIR}/calib_im0.json"),
}

needs_exr = pytest.mark.skipif(not exr_available(), reason="no EXR backend (pip install openexr)")


def assert_intrinsics_equal(intr: Intrinsics, d: dict):
    assert (intr.width, intr.height) == (d["width"], d["height"])
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == (d["fx"], d["fy"], d["cx"], d["cy"])
    assert intr.distortion == tuple(d.get("distortion") or (0.0,) * 5)


def assert_rigs_equal(a: Rig, b: Rig, atol=0.0):
    for name in ("color", "depth"):
        ia, ib = getattr(a, name), getattr(b, name)
        assert ia.shape == ib.shape
        np.testing.assert_allclose([ia.fx, ia.fy, ia.cx, ia.cy], [ib.fx, ib.fy, ib.cx, ib.cy], rtol=0, atol=atol)
        np.testing.assert_allclose(ia.dist_coeffs, ib.dist_coeffs, rtol=0, atol=atol)
    np.testing.assert_allclose(a.T_color_from_depth, b.T_color_from_depth, rtol=0, atol=atol)
    assert a.depth_scale == pytest.approx(b.depth_scale, rel=1e-12)


def write_calib(tmp_path, obj, name="calib.json"):
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return str(path)


def tum_calib() -> dict:
    with open(f"{TUM}/calib.json") as f:
        return json.load(f)


def png_bytes(array) -> bytes:
    ok, buf = cv2.imencode(".png", array)
    assert ok
    return buf.tobytes()


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_from_rows(width, height, idat: bytes, *, bit_depth=8, colour_type=2, interlace=0, before_idat=b"") -> bytes:
    """A PNG with valid chunk CRCs around the given IDAT payload (which need not be valid)."""
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, interlace)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + before_idat + png_chunk(b"IDAT", idat)
            + png_chunk(b"IEND", b""))


def adam7_png(image: np.ndarray) -> bytes:
    """An interlaced (Adam7) 8-bit RGB or 16-bit grey PNG of *image*, every row with filter type 0."""
    rows = []
    for x0, y0, dx, dy in ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
                           (0, 1, 1, 2)):
        sub = image[y0::dy, x0::dx]
        if sub.size:
            rows += [b"\0" + row.astype(">u2" if image.dtype == np.uint16 else np.uint8).tobytes() for row in sub]
    grey16 = image.dtype == np.uint16
    return png_from_rows(image.shape[1], image.shape[0], zlib.compress(b"".join(rows)),
                         bit_depth=16 if grey16 else 8, colour_type=0 if grey16 else 2, interlace=1)


# ---------------------------------------------------------------------------------------------------------
class TestReadCalibrationRealData:
    @pytest.mark.parametrize("name", list(FRAMES))
    def test_numbers_equal_the_json(self, name):
        path = FRAMES[name][2]
        with open(path) as f:
            ref = json.load(f)
        rig = read_calibration(path)
        assert_intrinsics_equal(rig.color, ref["color"])
        assert_intrinsics_equal(rig.depth, ref["depth"])
        np.testing.assert_array_equal(rig.T_color_from_depth, np.array(ref["T_color_from_depth"]))
        assert rig.depth_scale == ref["depth_scale"]

    @pytest.mark.parametrize("folder", [MOTO, ADIR])
    def test_middlebury_matches_calib_txt(self, folder):
        # calib.txt: cam0 = [f 0 cx0; 0 f cy; 0 0 1], cam1 = [f 0 cx1; ...], baseline in mm
        txt = dict(map(str.strip, line.split("=", 1)) for line in open(f"{folder}/calib.txt") if "=" in line)
        cam0, cam1 = (np.array(txt[c].strip("[] ").replace(";", " ").split(), float).reshape(3, 3)
                      for c in ("cam0", "cam1"))
        rig = read_calibration(f"{folder}/calib.json")
        np.testing.assert_allclose(rig.depth.K, cam0, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rig.color.K, cam1, rtol=0, atol=1e-9)
        # cam1 sits +baseline along x: p_cam1 = p_cam0 - (B, 0, 0)
        np.testing.assert_allclose(rig.T_color_from_depth[:3, 3], [-float(txt["baseline"]) / 1000, 0, 0], atol=1e-12)
        assert (rig.color.width, rig.color.height) == (int(txt["width"]), int(txt["height"]))
        assert read_calibration(f"{folder}/calib_im0.json").is_registered

    def test_registered_flags(self):
        assert read_calibration(f"{TUM}/calib.json").is_registered
        assert not read_calibration(f"{NYU}/calib.json").is_registered

    def test_opencv_yaml_example_equals_nyu(self):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            yml = read_calibration(f"{EXAMPLES}/stereo_opencv.yml")
        assert_rigs_equal(yml, read_calibration(f"{NYU}/calib.json"))

    def test_open3d_example_equals_tum(self):
        import open3d as o3d

        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rig = read_calibration(f"{EXAMPLES}/tum_open3d_intrinsic.json")
        assert_rigs_equal(rig, read_calibration(f"{TUM}/calib.json"))
        assert rig.is_registered
        # Open3D itself reads the same matrix from the file (it ignores the added depth_scale key)
        o3d_K = o3d.io.read_pinhole_camera_intrinsic(f"{EXAMPLES}/tum_open3d_intrinsic.json").intrinsic_matrix
        np.testing.assert_array_equal(o3d_K, rig.color.K)

    def test_depth_scale_argument_overrides(self):
        rig = read_calibration(f"{TUM}/calib.json", depth_scale=0.001)
        assert rig.depth_scale == 0.001

    @pytest.mark.parametrize("bad", [0, -1.0, float("nan"), "0.001", True])
    def test_bad_depth_scale_argument(self, bad):
        with pytest.raises(InputError, match="depth_scale"):
            read_calibration(f"{TUM}/calib.json", depth_scale=bad)


# ---------------------------------------------------------------------------------------------------------
def _rotation(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


K1 = np.array([[580.0, 0, 314.0], [0, 581.0, 240.5], [0, 0, 1]])  # depth camera (camera 1 by default)
D1 = np.array([[-0.1, 0.39, 0.0019, -0.0019, -0.51]])
K2 = np.array([[520.0, 0, 325.5], [0, 519.0, 253.7], [0, 0, 1]])  # colour camera (camera 2 by default)
D2 = np.array([[0.2, -0.58, 0.0007, 0.001, 0.49]])
R12 = _rotation([0.01, -0.02, 0.005])
T12 = np.array([[-0.025], [0.0003], [-0.0007]])


def write_storage(path, entries: dict):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        if isinstance(value, tuple):  # a sequence, as C++ writes cv::Size
            fs.startWriteStruct(key, cv2.FileNode_SEQ)
            for v in value:
                fs.write("", v)
            fs.endWriteStruct()
        else:
            fs.write(key, value)
    fs.release()
    return str(path)


def stereo_entries(**extra) -> dict:
    entries = {"cameraMatrix1": K1, "distCoeffs1": D1, "cameraMatrix2": K2, "distCoeffs2": D2, "R": R12,
               "T": T12, "imageSize1": (640, 480), "imageSize2": (1280, 960), "depth_scale": 0.001}
    entries.update(extra)
    return {k: v for k, v in entries.items() if v is not None}


class TestOpenCVFileStorage:
    @pytest.mark.parametrize("ext", ["yml", "xml", "json"])
    def test_round_trip_known_matrices(self, tmp_path, ext):
        path = write_storage(tmp_path / f"stereo.{ext}", stereo_entries())
        rig = read_calibration(path)
        np.testing.assert_array_equal(rig.depth.K, K1)
        np.testing.assert_array_equal(rig.color.K, K2)
        np.testing.assert_array_equal(rig.depth.dist_coeffs, D1.ravel())
        np.testing.assert_array_equal(rig.color.dist_coeffs, D2.ravel())
        assert rig.depth.shape == (480, 640) and rig.color.shape == (960, 1280)
        np.testing.assert_allclose(rig.T_color_from_depth[:3, :3], R12, atol=1e-15)
        np.testing.assert_allclose(rig.T_color_from_depth[:3, 3], T12.ravel(), atol=1e-15)
        assert rig.depth_scale == 0.001

    def test_stereo_calibrate_output_convention(self, tmp_path):
        """cv2.stereoCalibrate's (R, T) from camera 1 = depth to camera 2 = colour is T_color_from_depth."""
        grid = np.zeros((6 * 9, 3), np.float32)
        grid[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.04
        obj, img1, img2 = [], [], []
        rng = np.random.default_rng(1)
        for _ in range(8):
            rvec = rng.normal(0, 0.25, 3)
            tvec = np.array([-0.15, -0.1, 1.0]) + rng.normal(0, 0.05, 3)
            p1, _ = cv2.projectPoints(grid, rvec, tvec, K1, D1)
            r2, _ = cv2.Rodrigues(R12 @ _rotation(rvec))
            p2, _ = cv2.projectPoints(grid, r2, R12 @ tvec + T12.ravel(), K2, D2)
            obj.append(grid)
            img1.append(p1.astype(np.float32))
            img2.append(p2.astype(np.float32))
        rms, _, _, _, _, R, T, E, F = cv2.stereoCalibrate(obj, img1, img2, K1, D1, K2, D2, (640, 480),
                                                          flags=cv2.CALIB_FIX_INTRINSIC)
        assert rms < 1e-3
        path = write_storage(tmp_path / "stereo.yml", stereo_entries(R=R, T=T, E=E, F=F, rms=rms))
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # E, F and rms are known stereoCalibrate outputs: no warning
            rig = read_calibration(path)
        # a point seen by the depth camera lands where the colour camera's ground truth puts it
        p_depth = np.array([0.3, -0.2, 2.0])
        p_color = rig.T_color_from_depth[:3, :3] @ p_depth + rig.T_color_from_depth[:3, 3]
        np.testing.assert_allclose(p_color, R12 @ p_depth + T12.ravel(), atol=1e-6)

    def test_color_camera_1_inverts(self, tmp_path):
        path = write_storage(tmp_path / "s.yml", stereo_entries(color_camera=1))
        rig = read_calibration(path)
        np.testing.assert_array_equal(rig.color.K, K1)
        np.testing.assert_array_equal(rig.depth.K, K2)
        p_color = np.array([0.1, 0.2, 1.5])  # camera 1 = colour now
        p_depth = R12 @ p_color + T12.ravel()
        back = rig.T_color_from_depth[:3, :3] @ p_depth + rig.T_color_from_depth[:3, 3]
        np.testing.assert_allclose(back, p_color, atol=1e-12)

    @pytest.mark.parametrize("extra", [{"units": "mm"}, {"translation_scale": 0.001}])
    def test_translation_in_millimetres(self, tmp_path, extra):
        path = write_storage(tmp_path / "s.yml", stereo_entries(T=T12 * 1000, **extra))
        rig = read_calibration(path)
        np.testing.assert_allclose(rig.T_color_from_depth[:3, 3], T12.ravel(), atol=1e-15)

    def test_millimetres_without_units_warns(self, tmp_path):
        path = write_storage(tmp_path / "s.yml", stereo_entries(T=np.array([[-25.0], [0.3], [-0.7]])))
        with pytest.warns(UserWarning, match="millimetres"):
            read_calibration(path)

    @pytest.mark.parametrize("sizes", [
        {"imageSize": (640, 480)},
        {"image_width": 640, "image_height": 480},
        {"imageSize": np.array([[640, 480]], dtype=np.float64)},
    ])
    def test_shared_image_size_forms(self, tmp_path, sizes):
        path = write_storage(tmp_path / "s.yml", stereo_entries(imageSize1=None, imageSize2=None, **sizes))
        rig = read_calibration(path)
        assert rig.color.shape == rig.depth.shape == (480, 640)

    def test_aliases_and_rodrigues(self, tmp_path):
        entries = {"K_color": K2, "D_color": D2, "K_depth": K1, "D_depth": D1, "R": cv2.Rodrigues(R12)[0],
                   "T": T12, "imageSize": (640, 480), "depth_scale": 0.002}
        rig = read_calibration(write_storage(tmp_path / "s.yml", entries))
        np.testing.assert_array_equal(rig.color.K, K2)
        np.testing.assert_array_equal(rig.depth.K, K1)
        np.testing.assert_allclose(rig.T_color_from_depth[:3, :3], R12, atol=1e-12)
        assert rig.depth_scale == 0.002

    def test_4x4_transform_key(self, tmp_path):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R12, T12.ravel()
        path = write_storage(tmp_path / "s.yml", stereo_entries(R=None, T=None, T_color_from_depth=M))
        np.testing.assert_allclose(read_calibration(path).T_color_from_depth, M, atol=1e-15)

    def test_distortion_optional(self, tmp_path):
        path = write_storage(tmp_path / "s.yml", stereo_entries(distCoeffs1=None, distCoeffs2=None))
        rig = read_calibration(path)
        assert not rig.color.has_distortion and not rig.depth.has_distortion

    def test_depth_scale_from_argument(self, tmp_path):
        path = write_storage(tmp_path / "s.yml", stereo_entries(depth_scale=None))
        with pytest.raises(CalibrationError, match="depth_scale"):
            read_calibration(path)
        assert read_calibration(path, depth_scale=0.0002).depth_scale == 0.0002

    @pytest.mark.parametrize("ext", ["yml", "xml"])
    @pytest.mark.parametrize("drop", ["cameraMatrix2", "cameraMatrix1", "R", "T", "imageSize2"])
    def test_missing_key(self, tmp_path, ext, drop):
        path = write_storage(tmp_path / f"s.{ext}", stereo_entries(**{drop: None}))
        with pytest.raises(CalibrationError, match=drop) as info:
            read_calibration(path)
        assert path in str(info.value)

    @pytest.mark.parametrize("change, message", [
        ({"cameraMatrix2": np.array([[520.0, 0, np.nan], [0, 519, 253], [0, 0, 1]])}, "cameraMatrix2.*finite"),
        ({"cameraMatrix1": np.array([[-580.0, 0, 314], [0, 581, 240], [0, 0, 1]])}, "cameraMatrix1 fx"),
        ({"cameraMatrix1": np.array([[580.0, 2.0, 314], [0, 581, 240], [0, 0, 1]])}, "skew"),
        ({"cameraMatrix1": np.eye(4)}, "cameraMatrix1 must be a 3x3"),
        ({"R": 1.5 * R12}, "not rigid"),
        ({"R": -np.eye(3)}, "reflection"),
        ({"T": np.array([[1.0], [2.0]])}, "T must be a 3-vector"),
        ({"color_camera": 3}, "color_camera"),
        ({"units": "inch"}, "units"),
        ({"depth_scale": -0.001}, "depth_scale"),
        ({"depth_scale": "mm"}, "depth_scale must be a number"),
        ({"imageSize2": (640,)}, r"imageSize2 must be \[width, height\]"),
        ({"imageSize2": (640.5, 480)}, "whole number"),
        ({"imageSize2": (MAX_IMAGE_SIDE + 1, 480)}, "imageSize2 width"),
        ({"K_color": K2}, "both cameraMatrix2 and K_color"),
    ])
    def test_bad_values(self, tmp_path, change, message):
        path = write_storage(tmp_path / "s.yml", stereo_entries(**change))
        with pytest.raises(CalibrationError, match=message) as info:
            read_calibration(path)
        assert path in str(info.value)

    def test_unknown_key_warns(self, tmp_path):
        path = write_storage(tmp_path / "s.yml", stereo_entries(distCoefs2=D2))
        with pytest.warns(UserWarning, match="distCoefs2"):
            read_calibration(path)

    def test_parse_error(self, tmp_path):
        path = tmp_path / "s.yml"
        path.write_text("%YAML:1.0\ncameraMatrix1: [1, 2\n")
        with pytest.raises(CalibrationError, match="cv2.FileStorage") as info:
            read_calibration(str(path))
        assert str(path) in str(info.value)


# ---------------------------------------------------------------------------------------------------------
class TestOpen3DIntrinsic:
    def test_written_by_open3d(self, tmp_path):
        import open3d as o3d

        path = str(tmp_path / "intr.json")
        o3d.io.write_pinhole_camera_intrinsic(path, o3d.camera.PinholeCameraIntrinsic(800, 600, 610.5, 612.25,
                                                                                      401.0, 299.5))
        rig = read_calibration(path, depth_scale=0.001)
        assert rig.is_registered
        assert rig.color.shape == (600, 800)
        assert (rig.color.fx, rig.color.fy, rig.color.cx, rig.color.cy) == (610.5, 612.25, 401.0, 299.5)
        np.testing.assert_array_equal(rig.color.K, o3d.io.read_pinhole_camera_intrinsic(path).intrinsic_matrix)

    def test_needs_depth_scale(self, tmp_path):
        path = write_calib(tmp_path, {"width": 640, "height": 480,
                                      "intrinsic_matrix": [525.0, 0, 0, 0, 525.0, 0, 319.5, 239.5, 1]})
        with pytest.raises(CalibrationError, match="depth_scale"):
            read_calibration(path)

    def test_row_major_by_mistake(self, tmp_path):
        path = write_calib(tmp_path, {"width": 640, "height": 480, "depth_scale": 0.001,
                                      "intrinsic_matrix": [525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1]})
        with pytest.raises(CalibrationError, match="column-major"):
            read_calibration(path)

    @pytest.mark.parametrize("matrix, message", [
        ([525.0, 0, 0, 0, 525.0, 0, 319.5, 239.5], "9 numbers"),
        ([0.0, 0, 0, 0, 525.0, 0, 319.5, 239.5, 1], "fx"),
        ([525.0, 0, 0, 0, "525", 0, 319.5, 239.5, 1], "numbers only"),
    ])
    def test_bad_matrix(self, tmp_path, matrix, message):
        path = write_calib(tmp_path, {"width": 640, "height": 480, "depth_scale": 0.001, "intrinsic_matrix": matrix})
        with pytest.raises(CalibrationError, match=message):
            read_calibration(path)


# ---------------------------------------------------------------------------------------------------------
class TestCalibJsonErrors:
    @pytest.mark.parametrize("where, key", [
        (None, "color"), (None, "depth"), (None, "depth_scale"), (None, "T_color_from_depth"),
        ("color", "fx"), ("color", "cy"), ("depth", "width"), ("depth", "height"),
    ])
    def test_missing_key(self, tmp_path, where, key):
        obj = tum_calib()
        del (obj[where] if where else obj)[key]
        path = write_calib(tmp_path, obj)
        name = f"{where}.{key}" if where else key
        with pytest.raises(CalibrationError, match=f"missing key {name}") as info:
            read_calibration(path)
        assert path in str(info.value)

    @pytest.mark.parametrize("where, key, value, message", [
        ("color", "fx", float("nan"), "color.fx must be finite"),
        ("color", "fx", float("inf"), "color.fx must be finite"),
        ("color", "fx", "525", "color.fx must be a number"),
        ("color", "fx", 0.0, r"color.fx must be > 0"),
        ("depth", "fy", -525.0, r"depth.fy must be > 0"),
        ("color", "width", 640.5, "color.width must be a whole number"),
        ("color", "width", True, "color.width must be a number"),
        ("color", "height", 0, "color.height"),
        ("depth", "distortion", ["a", 0, 0, 0, 0], "depth.distortion must hold numbers"),
        ("depth", "distortion", [0.1, 0.0, 0.0], "depth: .*distortion must have"),
        (None, "depth_scale", 0, "depth_scale must be > 0"),
        (None, "depth_scale", None, "depth_scale must be a number"),
        (None, "T_color_from_depth", "identity", "T_color_from_depth must be a list"),
        (None, "T_color_from_depth", [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "T_color_from_depth must be 4x4"),
        (None, "T_color_from_depth", [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not rigid"),
        (None, "T_color_from_depth", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "reflection"),
        (None, "T_color_from_depth", [[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "finite"),
        (None, "T_color_from_depth", [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "rectangular"),
        (None, "max_range_m", -1, "max_range_m must be > 0"),
        (None, "color", [525.0], "color must be an object"),
    ])
    def test_bad_value(self, tmp_path, where, key, value, message):
        obj = tum_calib()
        (obj[where] if where else obj)[key] = value
        path = write_calib(tmp_path, obj)
        with pytest.raises(CalibrationError, match=message) as info:
            read_calibration(path)
        assert path in str(info.value)

    def test_unknown_key_warns(self, tmp_path):
        obj = tum_calib()
        obj["depth_scal"] = 0.001
        obj["_comment"] = "ignored"
        with pytest.warns(UserWarning, match="depth_scal") as record:
            read_calibration(write_calib(tmp_path, obj))
        assert "_comment" not in str(record[0].message)

    def test_baseline_in_millimetres_warns(self, tmp_path):
        obj = tum_calib()
        obj["T_color_from_depth"][0][3] = -25.0
        with pytest.warns(UserWarning, match="millimetres"):
            read_calibration(write_calib(tmp_path, obj))

    def test_max_range(self, tmp_path):
        obj = tum_calib()
        obj["max_range_m"] = 4.5
        assert read_calibration(write_calib(tmp_path, obj)).max_range_m == 4.5

    def test_invalid_json(self, tmp_path):
        path = tmp_path / "calib.json"
        path.write_text('{"color": {"width": 640,, }')
        with pytest.raises(CalibrationError, match="not valid JSON") as info:
            read_calibration(str(path))
        assert str(path) in str(info.value)

    def test_unrecognised_json(self, tmp_path):
        with pytest.raises(CalibrationError, match="unrecognised.*got keys"):
            read_calibration(write_calib(tmp_path, {"focal": 500}))

    def test_missing_file_and_folder(self, tmp_path):
        with pytest.raises(ImageReadError, match="not found.*nope.json"):
            read_calibration(tmp_path / "nope.json")
        with pytest.raises(ImageReadError, match="folder"):
            read_calibration(tmp_path)

    def test_rig_written_by_write_json_reads_back(self, tmp_path):
        rig = read_calibration(f"{NYU}/calib.json")
        path = str(tmp_path / "copy.json")
        write_json(path, rig)
        assert_rigs_equal(read_calibration(path), rig)


# ---------------------------------------------------------------------------------------------------------
class TestReadColor:
    @pytest.mark.parametrize("name", list(FRAMES))
    def test_real_png_equals_pillow(self, name):
        path = FRAMES[name][0]
        img = read_color(path)
        assert img.dtype == np.uint8 and img.flags.c_contiguous
        np.testing.assert_array_equal(img, np.asarray(Image.open(path).convert("RGB")))

    def test_channel_order_grey_alpha_16bit(self, tmp_path):
        rgba = np.zeros((4, 5, 4), np.uint8)
        rgba[..., 0], rgba[..., 3] = 200, 17  # pure red, translucent
        Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
        np.testing.assert_array_equal(read_color(tmp_path / "rgba.png")[0, 0], [200, 0, 0])
        grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
        Image.fromarray(grey, "L").save(tmp_path / "grey.png")
        g = read_color(tmp_path / "grey.png")
        assert g.shape == (4, 5, 3)
        np.testing.assert_array_equal(g[..., 1], grey)
        rgb16 = np.random.default_rng(0).integers(0, 65535, (4, 5, 3), dtype=np.uint16)
        cv2.imwrite(str(tmp_path / "c16.png"), rgb16[..., ::-1])
        np.testing.assert_array_equal(read_color(tmp_path / "c16.png"), rgb16)

    def test_float_tiff_npy(self, tmp_path):
        rgb = np.random.default_rng(1).random((6, 7, 3)).astype(np.float32)
        np.save(tmp_path / "c.npy", rgb)
        np.testing.assert_array_equal(read_color(tmp_path / "c.npy"), rgb)
        write_image(tmp_path / "c.tiff", rgb)
        np.testing.assert_array_equal(read_color(tmp_path / "c.tiff"), rgb)

    @needs_exr
    def test_exr(self, tmp_path):
        rgb = np.random.default_rng(2).random((6, 7, 3)).astype(np.float32)
        write_image(tmp_path / "c.exr", rgb)
        np.testing.assert_array_equal(read_color(tmp_path / "c.exr"), rgb)

    def test_nan_in_float_colour(self, tmp_path):
        rgb = np.zeros((3, 3, 3), np.float32)
        rgb[1, 1, 1] = np.nan
        np.save(tmp_path / "c.npy", rgb)
        with pytest.raises(ImageReadError, match="1 NaN"):
            read_color(tmp_path / "c.npy")

    def test_missing_empty_garbage(self, tmp_path):
        with pytest.raises(ImageReadError, match="not found.*nope.png"):
            read_color(tmp_path / "nope.png")
        (tmp_path / "empty.png").write_bytes(b"")
        with pytest.raises(ImageReadError, match="empty"):
            read_color(tmp_path / "empty.png")
        (tmp_path / "junk.png").write_bytes(b"this is not an image" * 10)
        with pytest.raises(ImageReadError, match="junk.png"):
            read_color(tmp_path / "junk.png")

    def test_truncated_png_and_jpeg(self, tmp_path, capfd):
        data = open(FRAMES["tum"][0], "rb").read()
        (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
        with pytest.raises(ImageReadError, match="truncated"):
            read_color(tmp_path / "t.png")
        assert capfd.readouterr().err == ""  # no libpng chatter on stderr
        ok, jpg = cv2.imencode(".jpg", np.asarray(Image.open(FRAMES["tum"][0])))
        (tmp_path / "t.jpg").write_bytes(jpg.tobytes()[: len(jpg) // 2])
        with pytest.raises(ImageReadError, match="t.jpg"):
            read_color(tmp_path / "t.jpg")

    @pytest.mark.parametrize("mode", ["1", "P", "L", "LA", "RGBA", "I;16"])
    def test_png_kinds_equal_pillow(self, tmp_path, mode):
        rgb = np.random.default_rng(3).integers(0, 256, (13, 17, 3), dtype=np.uint8)
        im = Image.fromarray(rgb).convert("I").convert(mode) if mode == "I;16" else Image.fromarray(rgb).convert(mode)
        im.save(tmp_path / "k.png")
        expected = np.asarray(Image.open(tmp_path / "k.png").convert("RGB"))
        if mode == "I;16":
            expected = np.repeat(np.asarray(Image.open(tmp_path / "k.png"))[:, :, None], 3, axis=2)
        np.testing.assert_array_equal(read_color(tmp_path / "k.png"), expected)

    @pytest.mark.parametrize("size", [(1, 1), (5, 3), (9, 9), (13, 17)])
    def test_interlaced_png(self, tmp_path, size):
        rng = np.random.default_rng(4)
        rgb = rng.integers(0, 256, (*size, 3), dtype=np.uint8)
        (tmp_path / "i.png").write_bytes(adam7_png(rgb))
        np.testing.assert_array_equal(read_color(tmp_path / "i.png"), rgb)
        raw = rng.integers(1, 65536, size, dtype=np.uint16)
        (tmp_path / "d.png").write_bytes(adam7_png(raw))
        np.testing.assert_allclose(read_depth(tmp_path / "d.png", 0.001), raw * np.float32(0.001), rtol=1e-6)

    @pytest.mark.parametrize("name, data, match", [
        ("bad_crc", png_bytes(np.zeros((6, 8, 3), np.uint8))[:29] + b"\0\0\0\0"
         + png_bytes(np.zeros((6, 8, 3), np.uint8))[33:], "IHDR chunk .* CRC"),
        ("not_zlib", png_from_rows(8, 6, b"\0" * 40), "compressed pixel data"),
        ("too_little", png_from_rows(8, 6, zlib.compress(b"\0" * 10)), "holds 10 of the 150 bytes"),
        ("too_much", png_from_rows(8, 6, zlib.compress(b"\0" * 500)), "longer than its 8x6 header"),
        ("extra_data", png_from_rows(8, 6, zlib.compress(b"\0" * 150) + b"xyz"), "after the end"),
        ("no_stream_end", png_from_rows(8, 6, zlib.compressobj().compress(b"\0" * 150)), "truncated or corrupt"),
        ("bad_filter", png_from_rows(8, 6, zlib.compress(bytes([9] + [0] * 24) * 6)), "filter type"),
        ("bad_bit_depth", png_from_rows(8, 6, zlib.compress(b"\0" * 150), bit_depth=3), "bit depth 3"),
        ("no_palette", png_from_rows(8, 6, zlib.compress(b"\0" * 54), colour_type=3), "PLTE"),
        ("critical_chunk", png_from_rows(8, 6, zlib.compress(b"\0" * 150), before_idat=png_chunk(b"CgBI", b"")),
         "critical"),
    ])
    def test_corrupt_png_refused_without_libpng_chatter(self, tmp_path, capfd, name, data, match):
        (tmp_path / f"{name}.png").write_bytes(data)
        with pytest.raises(ImageReadError, match=f"{name}.png .*{match}"):
            read_color(tmp_path / f"{name}.png")
        assert capfd.readouterr().err == ""

    def test_absurd_size_refused_from_header(self, tmp_path):
        data = bytearray(png_bytes(np.zeros((2, 2, 3), np.uint8)))
        data[16:24] = struct.pack(">II", 100_000, 100_000)  # IHDR width, height; the pixels are never decoded
        (tmp_path / "bomb.png").write_bytes(bytes(data))
        with pytest.raises(ImageReadError, match="100000x100000.*limit"):
            read_color(tmp_path / "bomb.png")

    def test_too_many_pixels_npy_header(self, tmp_path):
        header = {"descr": "<f4", "fortran_order": False, "shape": (16000, 16000)}  # 256 Mpixel
        with open(tmp_path / "big.npy", "wb") as f:
            np.lib.format.write_array_header_1_0(f, header)
        with pytest.raises(ImageReadError, match="Mpixel"):
            read_depth(tmp_path / "big.npy")


# ---------------------------------------------------------------------------------------------------------
class TestReadDepth:
    def test_tum_png_scaled(self):
        raw = np.asarray(Image.open(FRAMES["tum"][1]))
        assert raw.dtype == np.uint16
        depth = read_depth(FRAMES["tum"][1], 0.0002)
        assert depth.dtype == np.float32 and depth.shape == raw.shape
        np.testing.assert_allclose(depth, raw * 0.0002, rtol=1e-6)
        assert depth.max() == pytest.approx(9.331, abs=1e-3)  # the README's range

    def test_pfm_matches_middlebury_depth(self):
        # depth0.png was made from disp0GT.pfm with Z = B f / (d + doffs), rounded to mm (README)
        with pytest.warns(UserWarning, match="NaN, inf or negative"):  # inf = unknown disparity
            disp = read_depth(f"{MOTO}/disp0GT.pfm")
        depth = read_depth(f"{MOTO}/depth0.png", 0.001)
        known = disp > 0
        np.testing.assert_array_equal(known, depth > 0)
        z = 193.001 * 999.421 / (disp[known].astype(np.float64) + 32.778) / 1000
        assert np.abs(z - depth[known]).max() <= 0.0005 + 1e-6

    @pytest.mark.parametrize("ext", [".npy", ".tiff", ".tif", pytest.param(".exr", marks=needs_exr)])
    def test_float_round_trip_exact(self, tmp_path, ext):
        depth = np.random.default_rng(3).uniform(0.3, 80.0, (37, 53)).astype(np.float32)
        depth[5, :] = 0.0
        path = tmp_path / f"d{ext}"
        write_depth(path, depth)
        back = read_depth(path)
        assert back.dtype == np.float32
        np.testing.assert_array_equal(back, depth)

    def test_float_files_independently_readable(self, tmp_path):
        depth = np.random.default_rng(4).uniform(0.3, 8.0, (9, 11)).astype(np.float32)
        write_depth(tmp_path / "d.npy", depth)
        np.testing.assert_array_equal(np.load(tmp_path / "d.npy"), depth)
        write_depth(tmp_path / "d.tiff", depth)
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "d.tiff")), depth)

    @needs_exr
    def test_exr_written_independently(self, tmp_path):
        import OpenEXR

        depth = np.random.default_rng(5).uniform(0.3, 8.0, (9, 11)).astype(np.float32)
        write_depth(tmp_path / "d.exr", depth)
        with OpenEXR.File(str(tmp_path / "d.exr"), separate_channels=True) as f:
            np.testing.assert_array_equal(f.channels()["Z"].pixels, depth)
        half = depth.astype(np.float16)  # a half-float depth written by another program
        with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": half}) as f:
            f.write(str(tmp_path / "half.exr"))
        np.testing.assert_array_equal(read_depth(tmp_path / "half.exr"), half.astype(np.float32))

    def test_png_millimetres(self, tmp_path):
        depth = np.array([[0.0, 1.2344, 1.2346, np.nan], [np.inf, -1.0, 0.0002, 70.0]], np.float32)
        with pytest.warns(UserWarning, match="1 depth values beyond 65.535 m"):
            write_depth(tmp_path / "d.png", depth)
        raw = np.asarray(Image.open(tmp_path / "d.png"))
        assert raw.dtype == np.uint16
        # unknown -> 0; rounded to mm; a tiny known depth stays known (1 mm); clipped at 65535
        np.testing.assert_array_equal(raw, [[0, 1234, 1235, 0], [0, 0, 1, 65535]])
        np.testing.assert_allclose(read_depth(tmp_path / "d.png", 0.001), raw * 0.001, rtol=1e-6)

    @pytest.mark.parametrize("ext", [".png", ".tiff"])
    def test_pgm_and_tiff_16bit(self, tmp_path, ext):
        raw = np.random.default_rng(6).integers(0, 65535, (7, 8), dtype=np.uint16)
        path = tmp_path / f"d{ext}"
        cv2.imwrite(str(path), raw)
        np.testing.assert_allclose(read_depth(path, 0.001), raw * 0.001, rtol=1e-6)
        pgm = tmp_path / "d.pgm"
        cv2.imwrite(str(pgm), raw)
        np.testing.assert_allclose(read_depth(pgm, 0.001), raw * 0.001, rtol=1e-6)

    def test_invalid_values_zeroed_and_counted(self, tmp_path):
        depth = np.ones((4, 4), np.float32)
        depth[0, 0], depth[1, 1], depth[2, 2] = np.nan, -np.inf, -2.0
        np.save(tmp_path / "d.npy", depth)
        with pytest.warns(UserWarning, match="3 depth values"):
            out = read_depth(tmp_path / "d.npy")
        assert out[0, 0] == out[1, 1] == out[2, 2] == 0 and (out > 0).sum() == 13

    def test_8bit_depth_refused(self, tmp_path):
        cv2.imwrite(str(tmp_path / "d8.png"), np.full((4, 4), 100, np.uint8))
        with pytest.raises(ImageReadError, match="d8.png is 8-bit; expected 16-bit"):
            read_depth(tmp_path / "d8.png", 0.001)

    def test_colour_image_as_depth_refused(self):
        with pytest.raises(ImageReadError, match="single-channel.*3 channels"):
            read_depth(FRAMES["tum"][0], 0.001)

    def test_integer_file_needs_depth_scale(self):
        with pytest.raises(InputError, match="depth_scale"):
            read_depth(FRAMES["tum"][1])

    def test_truncated_and_missing(self, tmp_path):
        data = open(FRAMES["tum"][1], "rb").read()
        (tmp_path / "t.png").write_bytes(data[:1000])
        with pytest.raises(ImageReadError, match="t.png is truncated"):
            read_depth(tmp_path / "t.png", 0.001)
        npy = tmp_path / "t.npy"
        np.save(npy, np.ones((50, 50), np.float32))
        npy.write_bytes(npy.read_bytes()[:-100])
        with pytest.raises(ImageReadError, match="t.npy is truncated"):
            read_depth(npy)
        with pytest.raises(ImageReadError, match="depth file not found"):
            read_depth(tmp_path / "nope.png", 0.001)

    def test_bad_path_type(self):
        with pytest.raises(InputError, match="depth path"):
            read_depth(42, 0.001)


# ---------------------------------------------------------------------------------------------------------
class TestLoadFrame:
    @pytest.mark.parametrize("name", list(FRAMES))
    def test_all_frames_load(self, name):
        color, depth, calib = FRAMES[name]
        frame = load_frame(color, depth, calib)
        rig = read_calibration(calib)
        assert frame.color.shape == (*rig.color.shape, 3) and frame.color.dtype == np.uint8
        assert frame.depth_m.shape == rig.depth.shape and frame.depth_m.dtype == np.float32
        raw = np.asarray(Image.open(depth))
        np.testing.assert_allclose(frame.depth_m, raw * rig.depth_scale, rtol=1e-6)
        assert frame.n_invalid_depth == 0

    def test_depth_scale_override(self):
        frame = load_frame(*FRAMES["tum"], depth_scale=0.001)
        assert frame.rig.depth_scale == 0.001
        np.testing.assert_allclose(frame.depth_m, read_depth(FRAMES["tum"][1], 0.0002) * 5, rtol=1e-6)

    def test_size_mismatch(self, tmp_path):
        small = tmp_path / "small.png"
        Image.open(FRAMES["tum"][0]).resize((320, 240)).save(small)
        with pytest.raises(InputError, match=r"colour image .*small.png is 320x240 .* expects 640x480"):
            load_frame(small, FRAMES["tum"][1], FRAMES["tum"][2])
        with pytest.raises(InputError, match="depth image .* expects 718x496"):
            load_frame(FRAMES["adirondack_im0"][0], FRAMES["motorcycle_im0"][1], FRAMES["adirondack_im0"][2])

    def test_swapped_arguments(self):
        color, depth, calib = FRAMES["tum"]
        with pytest.raises(ImageReadError, match="single-channel"):
            load_frame(depth, color, calib)


# ---------------------------------------------------------------------------------------------------------
class TestWriters:
    @pytest.mark.parametrize("ext", [".png", ".tif", ".tiff"])
    def test_image_lossless_round_trip_with_pillow(self, tmp_path, ext):
        rgb = np.random.default_rng(7).integers(0, 256, (9, 10, 3), dtype=np.uint8)
        rgb[0, 0] = (255, 0, 0)
        write_image(tmp_path / f"i{ext}", rgb)
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / f"i{ext}").convert("RGB")), rgb)

    def test_jpeg_and_16bit_png(self, tmp_path):
        rgb = np.zeros((16, 16, 3), np.uint8)
        rgb[..., 0] = 250  # red survives JPEG in the right channel
        write_image(tmp_path / "i.jpg", rgb)
        back = np.asarray(Image.open(tmp_path / "i.jpg").convert("RGB")).astype(int)
        assert np.abs(back - rgb).max() <= 3
        rgb16 = np.random.default_rng(8).integers(0, 65536, (5, 6, 3), dtype=np.uint16)
        write_image(tmp_path / "i16.png", rgb16)
        np.testing.assert_array_equal(cv2.imread(str(tmp_path / "i16.png"), cv2.IMREAD_UNCHANGED)[..., ::-1], rgb16)
        grey = np.arange(30, dtype=np.uint8).reshape(5, 6)
        write_image(tmp_path / "g.png", grey)
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "g.png")), grey)

    @pytest.mark.parametrize("name, array, message", [
        ("i.png", np.zeros((4, 4, 3), np.float32), "float32"),
        ("i.jpg", np.zeros((4, 4, 3), np.uint16), "uint16"),
        ("i.gif", np.zeros((4, 4, 3), np.uint8), "must end in one of"),
        ("i.png", np.zeros((4, 4, 2), np.uint8), "shape"),
        ("i.tiff", np.full((4, 4, 3), np.nan, np.float32), "finite"),
    ])
    def test_bad_image_input_writes_nothing(self, tmp_path, name, array, message):
        with pytest.raises(InputError, match=message):
            write_image(tmp_path / name, array)
        assert os.listdir(tmp_path) == []

    @pytest.mark.parametrize("name, array, message", [
        ("d.jpg", np.ones((4, 4)), "must end in one of"),
        ("d.png", np.ones((4, 4, 3)), r"\(H, W\)"),
        ("d.npy", np.ones((4, 4), dtype=object), "numeric"),
    ])
    def test_bad_depth_input_writes_nothing(self, tmp_path, name, array, message):
        with pytest.raises(InputError, match=message):
            write_depth(tmp_path / name, array)
        assert os.listdir(tmp_path) == []

    def test_encoder_failure_leaves_nothing(self, tmp_path, monkeypatch):
        monkeypatch.setattr(cv2, "imencode", lambda *a, **k: (False, None))
        with pytest.raises(ImageWriteError, match="encode"):
            write_image(tmp_path / "i.png", np.zeros((4, 4, 3), np.uint8))
        with pytest.raises(ImageWriteError, match="encode"):
            write_depth(tmp_path / "d.png", np.ones((4, 4)))
        assert os.listdir(tmp_path) == []

    def test_failed_rename_leaves_old_file_and_no_temp(self, tmp_path, monkeypatch):
        target = tmp_path / "d.npy"
        target.write_bytes(b"old")

        def fail(src, dst):
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(os, "replace", fail)
        with pytest.raises(ImageWriteError, match="No space left"):
            write_depth(target, np.ones((4, 4)))
        assert os.listdir(tmp_path) == ["d.npy"] and target.read_bytes() == b"old"

    def test_interrupted_write_removes_temp(self, tmp_path, monkeypatch):
        def interrupt(fd):
            raise KeyboardInterrupt

        monkeypatch.setattr(os, "fsync", interrupt)
        with pytest.raises(KeyboardInterrupt):
            write_json(tmp_path / "x.json", {"a": 1})
        assert os.listdir(tmp_path) == []

    def test_permissions_and_parent_folders(self, tmp_path):
        path = tmp_path / "new" / "deeper" / "x.json"
        write_json(path, {"a": np.float32(1.5), "b": np.arange(3), "p": tmp_path})
        assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2], "p": str(tmp_path)}
        umask = os.umask(0)
        os.umask(umask)
        assert path.stat().st_mode & 0o777 == 0o666 & ~umask

    def test_json_nan_refused(self, tmp_path):
        with pytest.raises(InputError, match="NaN"):
            write_json(tmp_path / "x.json", {"a": float("nan")})
        with pytest.raises(InputError, match="not JSON serialisable"):
            write_json(tmp_path / "x.json", {"a": object()})
        assert os.listdir(tmp_path) == []

    def test_folder_as_target(self, tmp_path):
        (tmp_path / "sub.png").mkdir()
        with pytest.raises(ImageWriteError, match="folder"):
            write_depth(tmp_path / "sub.png", np.ones((2, 2)))
