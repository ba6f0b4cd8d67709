"""pcdof.sources: the registry, pairing, calibration conversion of Azure Kinect factory calibrations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcdof.camera import Intrinsics, Rig
from pcdof.errors import CalibrationError, ImageReadError, InputError
from pcdof.sources import SOURCES, open_source, pair_by_time, source_format
from pcdof.sources.azure_kinect import COLOR_MODES, DEPTH_MODES, k4a_rig
from pcdof.sources.k4a_writer import k4a_calibration_json


def _camera(location, params, size, R=np.eye(3), t=(0.0, 0.0, 0.0), model="BrownConrady"):
    return {"Location": f"CALIBRATION_CameraLocation{location}", "SensorWidth": size[0], "SensorHeight": size[1],
            "MetricRadius": 1.7, "Rt": {"Rotation": np.asarray(R).ravel().tolist(), "Translation": list(t)},
            "Intrinsics": {"ModelType": f"CALIBRATION_LensDistortionModel{model}", "ModelParameterCount": 14,
                           "ModelParameters": list(params)}}


def _calibration(depth_cam, color_cam):
    return {"CalibrationInformation": {"Cameras": [depth_cam, color_cam]}}


# cx, cy, fx, fy, k1..k6, codx, cody, p2, p1
PARAMS = [0.5, 0.5, 0.5, 0.5, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.0, 0.0, 0.01, 0.02]


class TestK4aRig:
    def test_mode_specific_intrinsics_by_hand(self):
        # NFOV_UNBINNED: x 1024, crop (192, 180), -0.5 px to OpenCV's pixel centres; 720P: x (1280, 960), crop (0, 120)
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024)), _camera("PV0", PARAMS, (4096, 3072)))
        rig = k4a_rig(json.dumps(cal), depth_mode="NFOV_UNBINNED", color_mode="MJPG_720P")
        d, c = rig.depth, rig.color
        assert (d.width, d.height, d.fx, d.fy, d.cx, d.cy) == (640, 576, 512.0, 512.0, 319.5, 331.5)
        assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == (1280, 720, 640.0, 480.0, 639.5, 359.5)
        # all 8 rational coefficients, in OpenCV order (k1, k2, p1, p2, k3, k4, k5, k6); p1 is the last parameter
        assert d.distortion == (0.1, 0.2, 0.02, 0.01, 0.3, 0.4, 0.5, 0.6)
        assert rig.depth_scale == 0.001 and rig.max_range_m == DEPTH_MODES["NFOV_UNBINNED"].max_range_m

    def test_binned_mode_halves_the_focal_length(self):
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024)), _camera("PV0", PARAMS, (4096, 3072)))
        a = k4a_rig(cal, depth_mode="NFOV_UNBINNED", color_mode="MJPG_1080P").depth
        b = k4a_rig(cal, depth_mode="NFOV_2X2BINNED", color_mode="MJPG_1080P").depth
        assert b.fx == a.fx / 2 and (b.cx + 0.5) == (a.cx + 0.5) / 2

    def test_extrinsics_in_metres_and_composed(self):
        rng = np.random.default_rng(3)
        Rd, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        Rd *= np.sign(np.linalg.det(Rd))
        Rc = np.eye(3)
        td, tc = np.array([0.001, -0.002, 0.0005]), np.array([-0.032, -0.0021, 0.0039])  # metres, as the SDK stores
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024), Rd, td), _camera("PV0", PARAMS, (4096, 3072), Rc, tc))
        rig = k4a_rig(cal, depth_mode="WFOV_2X2BINNED", color_mode="BGRA_3072P")
        p_world = rng.normal(size=3)
        p_depth, p_color = Rd @ p_world + td, Rc @ p_world + tc
        np.testing.assert_allclose(rig.T_color_from_depth[:3, :3] @ p_depth + rig.T_color_from_depth[:3, 3], p_color,
                                   atol=1e-12)

    def test_depth_reference_gives_translation_as_stored(self):
        t = (-0.0320, -0.0021, 0.0039)
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024)), _camera("PV0", PARAMS, (4096, 3072), t=t))
        rig = k4a_rig(cal, depth_mode="NFOV_UNBINNED", color_mode="MJPG_720P")
        np.testing.assert_allclose(rig.T_color_from_depth[:3, 3], t)
        assert 0.03 < rig.baseline_m < 0.04  # metres, not millimetres

    def test_legacy_16_9_colour_calibration(self):
        # SDK: a 4096x2304 calibration is re-normalised to 4096x3072 (y offset 384 px) before the mode's crop
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024)), _camera("PV0", PARAMS, (4096, 2304)))
        c = k4a_rig(cal, depth_mode="NFOV_UNBINNED", color_mode="MJPG_720P").color
        cy43, fy43 = (0.5 * 2304 + 384) / 3072, 0.5 * 2304 / 3072
        assert c.cy == pytest.approx(cy43 * 960 - 120 - 0.5) and c.fy == pytest.approx(fy43 * 960)

    @pytest.mark.parametrize("depth_mode", list(DEPTH_MODES))
    @pytest.mark.parametrize("resolution", list(COLOR_MODES))
    def test_round_trip_through_the_writer(self, depth_mode, resolution):
        rng = np.random.default_rng(hash((depth_mode, resolution)) % 2**32)
        dm, cm = DEPTH_MODES[depth_mode], COLOR_MODES[resolution]

        def intr(mode):
            f = rng.uniform(0.4, 0.6) * mode.width
            return Intrinsics(mode.width, mode.height, f, f * rng.uniform(0.99, 1.01), mode.width / 2 + rng.normal(),
                              mode.height / 2 + rng.normal(), tuple(rng.normal(scale=0.1, size=8)))

        T = np.eye(4)
        T[:3, 3] = rng.normal(scale=0.02, size=3)
        rig = Rig(intr(cm), intr(dm), T)
        back = k4a_rig(k4a_calibration_json(rig, depth_mode=depth_mode, color_mode="MJPG_" + resolution),
                       depth_mode=depth_mode, color_mode="MJPG_" + resolution)
        for a, b in ((rig.color, back.color), (rig.depth, back.depth)):
            np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=0, atol=1e-9)
            np.testing.assert_allclose(a.distortion, b.distortion, rtol=0, atol=1e-15)
        np.testing.assert_allclose(back.T_color_from_depth, T, atol=1e-15)

    @pytest.mark.parametrize("change, message", [
        (lambda c: c["CalibrationInformation"]["Cameras"].pop(1), "no camera CALIBRATION_CameraLocationPV0"),
        (lambda c: c["CalibrationInformation"]["Cameras"][0]["Intrinsics"].update(
            ModelType="CALIBRATION_LensDistortionModelTheta"), "lens model"),
        (lambda c: c["CalibrationInformation"]["Cameras"][0]["Intrinsics"]["ModelParameters"].__setitem__(10, 0.1),
         "centre of distortion"),
        (lambda c: c["CalibrationInformation"]["Cameras"][0].pop("Rt"), "Rt"),
        (lambda c: c.pop("CalibrationInformation"), "not an Azure Kinect calibration"),
    ])
    def test_bad_calibrations(self, change, message):
        cal = _calibration(_camera("D0", list(PARAMS), (1024, 1024)), _camera("PV0", list(PARAMS), (4096, 3072)))
        change(cal)
        with pytest.raises(CalibrationError, match=message):
            k4a_rig(cal, depth_mode="NFOV_UNBINNED", color_mode="MJPG_720P", where="x.mkv: calibration.json")

    def test_unknown_modes(self):
        cal = _calibration(_camera("D0", PARAMS, (1024, 1024)), _camera("PV0", PARAMS, (4096, 3072)))
        with pytest.raises(CalibrationError, match="PASSIVE_IR"):
            k4a_rig(cal, depth_mode="PASSIVE_IR", color_mode="MJPG_720P")
        with pytest.raises(CalibrationError, match="colour mode"):
            k4a_rig(cal, depth_mode="NFOV_UNBINNED", color_mode="MJPG_999P")
        with pytest.raises(CalibrationError, match="not valid JSON"):
            k4a_rig(b"{", depth_mode="NFOV_UNBINNED", color_mode="MJPG_720P")


class TestPairByTime:
    def test_default_tolerance_is_the_slower_period(self):
        color = np.arange(10) / 15.0  # 15 fps
        depth = np.arange(20) / 30.0 + 0.02  # 30 fps, 20 ms late
        pairs, tol = pair_by_time(color, depth)
        assert tol == pytest.approx(1 / 15)
        assert len(pairs) == 10
        assert np.all(np.abs(color[pairs[:, 0]] - depth[pairs[:, 1]]) < 1 / 30)  # the nearest one was taken

    def test_explicit_tolerance_and_each_frame_once(self):
        pairs, _ = pair_by_time([0.0, 0.01], [0.005], max_difference_s=0.02)
        assert pairs.tolist() == [[0, 0]]
        assert len(pair_by_time([0.0], [0.5], max_difference_s=0.1)[0]) == 0

    def test_single_frames_pair(self):
        assert pair_by_time([3.0], [7.0])[0].tolist() == [[0, 0]]

    @pytest.mark.parametrize("bad", [0, -1, float("nan"), float("inf"), "0.1", True])
    def test_bad_tolerance(self, bad):
        with pytest.raises(InputError, match="max_difference_s"):
            pair_by_time([0.0], [0.0], max_difference_s=bad)


class TestRegistry:
    def test_sniffs_by_magic_then_suffix(self, tmp_path):
        mkv, bag, other = tmp_path / "a.dat", tmp_path / "b.dat", tmp_path / "c.png"
        mkv.write_bytes(b"\x1a\x45\xdf\xa3\x9f\x42\x86\x81\x01\x42\x82\x88matroska")
        bag.write_bytes(b"#ROSBAG V2.0\n")
        other.write_bytes(b"\x89PNG\r\n\x1a\n")
        assert source_format(mkv) == "azure-kinect" and source_format(bag) == "realsense-bag"
        assert source_format(other) is None and source_format(tmp_path) is None
        assert source_format(tmp_path / "missing.mkv") == "azure-kinect"
        assert set(SOURCES) == {"azure-kinect", "realsense-bag", "heif-depth", "depth-jpeg", "tum", "folder",
                                "list"}

    def test_open_errors(self, tmp_path):
        with pytest.raises(ImageReadError, match="does not exist"):
            open_source(tmp_path / "none.bag")
        with pytest.raises(InputError, match="is a folder"):
            open_source(tmp_path)
        (tmp_path / "c.png").write_bytes(b"\x89PNG\r\n\x1a\n")
        with pytest.raises(InputError, match="not a recording"):
            open_source(tmp_path / "c.png")
        (tmp_path / "x.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 10)
        with pytest.raises(ImageReadError, match="x.bag"):
            open_source(tmp_path / "x.bag")
