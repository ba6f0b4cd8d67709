"""`pcdof register`, `pcdof cloud` and pcdof.cloud on the bundled TUM and NYU frames.

Independent references: Pillow / numpy / Open3D / trimesh to read the outputs, the pinhole formula
and cv2.undistortPoints / cv2.projectPoints for the geometry.
"""

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image

from conftest import invoke

from pcdof.camera import Intrinsics
from pcdof.cloud import colored_points, write_ply
from pcdof.errors import EXIT_CODES, CalibrationError, ImageReadError, InputError, LensError
from pcdof.io import exr_available, read_calibration, read_depth

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TUM = os.path.join(ROOT, "data", "real", "tum_rgbd_open3d")
NYU = os.path.join(ROOT, "data", "real", "nyu_v2_raw_open3d")


def frame_args(folder):
    return [f"{folder}/color.png", f"{folder}/depth.png", "--calib", f"{folder}/calib.json"]


def assert_clean_failure(result, error_class, out_dir):
    assert result.exit_code == EXIT_CODES[error_class], result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), result.stderr
    assert "Traceback" not in result.output
    assert os.listdir(out_dir) == []


# ---------------------------------------------------------------------------------------------------------
class TestRegisterCommand:
    def test_tum_png_millimetres(self, tmp_path):
        out = tmp_path / "reg.png"
        result = invoke("register", *frame_args(TUM), "-o", out)
        assert result.exit_code == 0, result.output
        png = np.asarray(Image.open(out))
        assert png.dtype == np.uint16 and png.shape == (480, 640)
        # TUM is registered (identity rig): the output is the input, 1/5000 m units -> mm
        raw = np.asarray(Image.open(f"{TUM}/depth.png")).astype(np.int64)
        np.testing.assert_array_equal(png, np.rint(raw * 0.2).astype(np.uint16))
        assert os.listdir(tmp_path) == ["reg.png"]

    def test_nyu_npy_against_opencv_projection(self, tmp_path):
        out = tmp_path / "reg.npy"
        result = invoke("register", *frame_args(NYU), "-o", out)
        assert result.exit_code == 0, result.output
        reg = np.load(out)
        assert reg.dtype == np.float32 and reg.shape == (480, 640)
        assert 0.6 < (reg > 0).mean() < 0.95
        # independent forward projection of a grid of depth pixels with OpenCV
        rig = read_calibration(f"{NYU}/calib.json")
        depth = read_depth(f"{NYU}/depth.png", rig.depth_scale)
        vv, uu = np.mgrid[4:480:8, 4:640:8]
        z = depth[vv, uu].ravel().astype(np.float64)
        keep = z > 0
        uv = np.stack([uu.ravel(), vv.ravel()], axis=1)[keep].astype(np.float64)
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), rig.depth.K, rig.depth.dist_coeffs).reshape(-1, 2)
        p = np.column_stack([xy * z[keep, None], z[keep]])
        T = rig.T_color_from_depth
        pc = p @ T[:3, :3].T + T[:3, 3]
        proj, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), rig.color.K, rig.color.dist_coeffs)
        u, v = np.rint(proj.reshape(-1, 2)).astype(int).T
        inside = (u >= 0) & (u < 640) & (v >= 0) & (v < 480)
        got = reg[v[inside], u[inside]]
        ref = pc[inside, 2]
        seen = got > 0
        assert seen.mean() > 0.9
        rel = np.abs(got[seen] - ref[seen]) / ref[seen]
        assert np.median(rel) < 0.003 and np.quantile(rel, 0.9) < 0.02

    @pytest.mark.parametrize("ext", [".tiff", pytest.param(".exr", marks=pytest.mark.skipif(
        not exr_available(), reason="no EXR backend"))])
    def test_float_outputs(self, tmp_path, ext):
        out = tmp_path / f"reg{ext}"
        assert invoke("register", *frame_args(TUM), "-o", out).exit_code == 0
        back = read_depth(out)
        np.testing.assert_allclose(back, read_depth(f"{TUM}/depth.png", 0.0002), rtol=1e-6)

    def test_fill_leaves_no_holes(self, tmp_path):
        out = tmp_path / "filled.npy"
        result = invoke("register", *frame_args(NYU), "-o", out, "--fill", "--fill-method", "nearest-background")
        assert result.exit_code == 0, result.output
        filled = np.load(out)
        assert (filled > 0).all()

    def test_filled_depth_is_the_pipelines(self, tmp_path):
        """`register --fill` writes the depth the pipeline renders from: depth edges aligned, then filled."""
        from pcdof import io, pipeline
        from pcdof.lens import ThinLens

        out = tmp_path / "filled.npy"
        result = invoke("register", *frame_args(TUM), "-o", out, "--fill")
        assert result.exit_code == 0, result.output
        frame = io.load_frame(f"{TUM}/color.png", f"{TUM}/depth.png", f"{TUM}/calib.json")
        _, filled, _ = pipeline.prepare_depth(frame, ThinLens(focal_length_mm=50.0, f_number=2.0,
                                                               focus_distance_m=1.0))
        np.testing.assert_array_equal(np.load(out), filled)

    def test_depth_scale_option(self, tmp_path):
        out = tmp_path / "reg.npy"
        assert invoke("register", *frame_args(TUM), "-o", out, "--depth-scale", 0.001).exit_code == 0
        np.testing.assert_allclose(np.load(out), read_depth(f"{TUM}/depth.png", 0.001), rtol=1e-6)

    def test_bad_extension_fails_before_work(self, tmp_path):
        result = invoke("register", tmp_path / "missing.png", f"{TUM}/depth.png", "--calib", f"{TUM}/calib.json",
                        "-o", tmp_path / "reg.jpg")
        assert_clean_failure(result, InputError, tmp_path)  # not the missing colour file: checked first
        assert "must end in one of" in result.stderr

    def test_missing_input(self, tmp_path):
        out_dir = tmp_path / "out"
        out_dir.mkdir()
        result = invoke("register", tmp_path / "nope.png", f"{TUM}/depth.png", "--calib", f"{TUM}/calib.json",
                        "-o", out_dir / "reg.png")
        assert_clean_failure(result, ImageReadError, out_dir)
        assert "nope.png" in result.stderr

    def test_bad_calibration(self, tmp_path):
        calib = json.load(open(f"{TUM}/calib.json"))
        calib["color"]["fx"] = -1
        (tmp_path / "calib.json").write_text(json.dumps(calib))
        out_dir = tmp_path / "out"
        out_dir.mkdir()
        result = invoke("register", f"{TUM}/color.png", f"{TUM}/depth.png", "--calib", tmp_path / "calib.json",
                        "-o", out_dir / "reg.png")
        assert_clean_failure(result, CalibrationError, out_dir)
        assert "color.fx" in result.stderr

    def test_size_mismatch(self, tmp_path):
        Image.open(f"{TUM}/color.png").resize((320, 240)).save(tmp_path / "small.png")
        out_dir = tmp_path / "out"
        out_dir.mkdir()
        result = invoke("register", tmp_path / "small.png", f"{TUM}/depth.png", "--calib", f"{TUM}/calib.json",
                        "-o", out_dir / "reg.png")
        assert_clean_failure(result, InputError, out_dir)
        assert "320x240" in result.stderr and "640x480" in result.stderr

    def test_bad_depth_scale(self, tmp_path):
        result = invoke("register", *frame_args(TUM), "-o", tmp_path / "reg.png", "--depth-scale", -1)
        assert_clean_failure(result, InputError, tmp_path)

    def test_real_process_one_line_no_traceback(self, tmp_path):
        proc = subprocess.run(
            [sys.executable, "-c", "from pcdof.cli import main; main()", "register", f"{TUM}/depth.png",
             f"{TUM}/color.png", "--calib", f"{TUM}/calib.json", "-o", str(tmp_path / "reg.png")],
            capture_output=True, text=True, timeout=120)
        assert proc.returncode == EXIT_CODES[ImageReadError]
        assert proc.stderr.count("\n") == 1 and "single-channel" in proc.stderr and "Traceback" not in proc.stderr
        assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------------------
class TestCloudCommand:
    def test_tum_no_fill_stride(self, tmp_path):
        import open3d as o3d

        out = tmp_path / "scene.ply"
        result = invoke("cloud", *frame_args(TUM), "-o", out, "--no-fill", "--stride", 4)
        assert result.exit_code == 0, result.output
        pcd = o3d.io.read_point_cloud(str(out))
        pts, cols = np.asarray(pcd.points), np.asarray(pcd.colors)
        # pinhole back-projection of the known pixels on the stride-4 grid, row-major
        z = np.asarray(Image.open(f"{TUM}/depth.png")).astype(np.float64) * 0.0002
        rgb = np.asarray(Image.open(f"{TUM}/color.png").convert("RGB"))
        vv, uu = np.mgrid[0:480:4, 0:640:4]
        zs = z[vv, uu]
        known = zs > 0
        ref = np.column_stack([(uu[known] - 319.5) * zs[known] / 525.0, (vv[known] - 239.5) * zs[known] / 525.0,
                               zs[known]])
        assert pts.shape == ref.shape
        np.testing.assert_allclose(pts, ref, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(cols, rgb[vv[known], uu[known]] / 255.0, atol=1e-9)
        assert f"wrote {len(ref)} points" in result.stdout

    def test_nyu_filled_every_pixel(self, tmp_path):
        import trimesh

        out = tmp_path / "scene.ply"
        result = invoke("cloud", *frame_args(NYU), "-o", out, "--stride", 2, "--fill-method", "nearest-background")
        assert result.exit_code == 0, result.output
        cloud = trimesh.load(str(out))
        assert cloud.vertices.shape == (240 * 320, 3)
        assert cloud.visual.vertex_colors.shape[0] == 240 * 320
        z = cloud.vertices[:, 2]
        assert z.min() > 0.5 and z.max() < 10.5  # NYU README: 1.5-6.7 m, fill clamps to the known range

    def test_bad_extension(self, tmp_path):
        result = invoke("cloud", *frame_args(TUM), "-o", tmp_path / "scene.obj")
        assert_clean_failure(result, InputError, tmp_path)
        assert ".ply" in result.stderr

    def test_missing_calibration(self, tmp_path):
        result = invoke("cloud", f"{TUM}/color.png", f"{TUM}/depth.png", "--calib", tmp_path / "nope.json",
                        "-o", tmp_path / "scene.ply")
        assert_clean_failure(result, ImageReadError, tmp_path)

    def test_bad_stride_is_usage_error(self, tmp_path):
        result = invoke("cloud", *frame_args(TUM), "-o", tmp_path / "scene.ply", "--stride", 0)
        assert result.exit_code == 2 and os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------------------
class TestColoredPoints:
    def test_points_reproject_to_their_pixels_with_distortion(self):
        intr = Intrinsics(64, 48, 60.0, 61.0, 31.0, 24.5, (0.2, -0.5, 0.001, 0.002, 0.4))
        rng = np.random.default_rng(0)
        depth = rng.uniform(0.5, 3.0, (48, 64)).astype(np.float32)
        depth[rng.random((48, 64)) < 0.2] = 0
        color = rng.integers(0, 65536, (48, 64, 3), dtype=np.uint16)
        pts, cols = colored_points(color, depth, intr)
        vv, uu = np.nonzero(depth > 0)
        assert pts.dtype == np.float32 and cols.dtype == np.float32 and len(pts) == len(vv)
        np.testing.assert_allclose(pts[:, 2], depth[vv, uu])
        proj, _ = cv2.projectPoints(pts.astype(np.float64), np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
        np.testing.assert_allclose(proj.reshape(-1, 2), np.column_stack([uu, vv]), atol=1e-3)
        np.testing.assert_allclose(cols, color[vv, uu] / 65535.0, atol=1e-7)

    def test_stride_grey_and_float_colour(self):
        intr = Intrinsics(5, 4, 2.0, 2.0, 2.0, 1.5)
        depth = np.ones((4, 5), np.float32)
        pts, cols = colored_points(np.full((4, 5), 0.25, np.float32), depth, intr, stride=2)
        assert len(pts) == 2 * 3  # rows 0, 2 x columns 0, 2, 4
        np.testing.assert_allclose(pts[:, :2], [[(u - 2) / 2, (v - 1.5) / 2] for v in (0, 2) for u in (0, 2, 4)])
        np.testing.assert_allclose(cols, 0.25)

    @pytest.mark.parametrize("kwargs, message", [
        ({"stride": 0}, "stride"),
        ({"stride": 1.5}, "stride"),
        ({"depth_m": np.ones((3, 5))}, r"depth_m must be \(H, W\) = \(4, 5\)"),
        ({"color": np.zeros((4, 6, 3), np.uint8)}, "color must be"),
        ({"intrinsics": (2.0, 2.0)}, "intrinsics must be an Intrinsics"),
    ])
    def test_bad_input(self, kwargs, message):
        args = {"color": np.zeros((4, 5, 3), np.uint8), "depth_m": np.ones((4, 5)),
                "intrinsics": Intrinsics(5, 4, 2.0, 2.0, 2.0, 1.5)}
        stride = kwargs.pop("stride", 1)
        args.update(kwargs)
        with pytest.raises(InputError, match=message):
            colored_points(args["color"], args["depth_m"], args["intrinsics"], stride=stride)


class TestWritePly:
    def test_round_trip_with_open3d(self, tmp_path):
        import open3d as o3d

        rng = np.random.default_rng(1)
        pts = rng.normal(size=(100, 3)).astype(np.float32)
        cols = rng.random((100, 3))
        write_ply(tmp_path / "c.ply", pts, cols)
        assert open(tmp_path / "c.ply", "rb").read(40).startswith(b"ply\nformat binary_little_endian 1.0\n")
        pcd = o3d.io.read_point_cloud(str(tmp_path / "c.ply"))
        np.testing.assert_array_equal(np.asarray(pcd.points), pts.astype(np.float64))
        np.testing.assert_allclose(np.asarray(pcd.colors), np.rint(cols * 255) / 255, atol=1e-12)

    def test_no_colours_and_empty(self, tmp_path):
        import trimesh

        write_ply(tmp_path / "a.ply", np.eye(3))
        np.testing.assert_array_equal(trimesh.load(str(tmp_path / "a.ply")).vertices, np.eye(3))
        write_ply(tmp_path / "e.ply", np.zeros((0, 3)), np.zeros((0, 3)))
        assert b"element vertex 0" in (tmp_path / "e.ply").read_bytes()

    @pytest.mark.parametrize("name, pts, cols, message", [
        ("c.obj", np.zeros((2, 3)), None, ".ply"),
        ("c.ply", np.zeros((2, 2)), None, r"\(N, 3\)"),
        ("c.ply", np.array([[0, 0, np.nan]]), None, "finite"),
        ("c.ply", np.zeros((2, 3)), np.zeros((3, 3)), r"\(2, 3\)"),
    ])
    def test_bad_input_writes_nothing(self, tmp_path, name, pts, cols, message):
        with pytest.raises(InputError, match=message):
            write_ply(tmp_path / name, pts, cols)
        assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------------------
class TestRenderPaperOptions:
    SAMPLE = os.path.join(ROOT, "data", "sample")

    def test_eq1_aperture_reaches_the_paper_lens(self, tmp_path):
        """`--weight eq1 --eq1-aperture A` renders what PaperLens(weight="eq1", eq1_aperture=A) renders."""
        from pcdof.io import load_frame
        from pcdof.lens import PaperLens
        from pcdof.pipeline import run

        frame = load_frame(*(os.path.join(self.SAMPLE, n) for n in ("color.png", "depth.png", "calib.json")))
        images = {}
        for a in (0.05, 2.0):
            out = tmp_path / f"eq1_{a}.png"
            result = invoke("render", *frame_args(self.SAMPLE), "-o", out, "--method", "paper", "--weight", "eq1",
                            "--eq1-aperture", a, "--focus-distance", 1.49)
            assert result.exit_code == 0, result.output
            images[a] = np.asarray(Image.open(out).convert("RGB"))
            expected = run(frame, PaperLens(1.49, weight="eq1", eq1_aperture=a), method="paper").image
            np.testing.assert_array_equal(images[a], expected)
        # a larger A gives a larger weight of the blurred copy: further from the sharp input
        sharp = frame.color.astype(np.float64)
        assert np.abs(images[2.0] - sharp).mean() > 2 * np.abs(images[0.05] - sharp).mean()

    def test_bad_eq1_aperture_is_a_lens_error(self, tmp_path):
        result = invoke("render", *frame_args(self.SAMPLE), "-o", tmp_path / "x.png", "--method", "paper",
                        "--weight", "eq1", "--eq1-aperture", -1)
        assert result.exit_code == EXIT_CODES[LensError], result.output
        assert "--eq1-aperture" in result.stderr and not os.path.exists(tmp_path / "x.png")
