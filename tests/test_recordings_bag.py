"""The bundled RealSense D435 recording (.bag, ROS bag v2 written by the RealSense SDK)."""

from __future__ import annotations

import dataclasses
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("rosbags")

from pcdof.camera import Rig  # noqa: E402
from pcdof.cli.export import command as export_command  # noqa: E402
from pcdof.cli.info import command as info_command  # noqa: E402
from pcdof.errors import ImageReadError, InputError  # noqa: E402
from pcdof.io import load_frame  # noqa: E402
from pcdof.stages.register import register_depth  # noqa: E402
from pcdof.sources import open_source  # noqa: E402

BAG = os.path.join(os.path.dirname(__file__), "..", "data", "real", "realsense_d435_bag",
                   "single_depth_color_640x480.bag")


@pytest.fixture(scope="module")
def frame():
    with open_source(BAG) as src:
        yield src.frame(0)


def test_reads_one_pair(frame):
    with open_source(BAG) as src:
        assert len(src) == 1  # 1 colour frame; the second depth frame (0.27 s later) has no colour partner
        info = src.info()
    assert info["streams"]["Depth"]["frames"] == 2 and info["streams"]["Color"]["frames"] == 1
    assert frame.color.shape == (480, 640, 3) and frame.depth_m.shape == (480, 640)
    assert frame.depth_time_s - frame.color_time_s == pytest.approx(0.101566, abs=1e-6)
    known = frame.depth_m[frame.depth_m > 0]
    assert 0.9 < known.size / frame.depth_m.size and 0.3 < np.median(known) < 3.0  # metres, not millimetres


def test_documented_calibration(frame):
    rig = frame.rig
    # the README's numbers, from the bag's camera_info messages
    assert (rig.depth.fx, rig.depth.fy, rig.depth.cx, rig.depth.cy) == pytest.approx((390.43, 390.43, 331.39, 242.19),
                                                                                    abs=0.01)
    assert (rig.color.fx, rig.color.fy, rig.color.cx, rig.color.cy) == pytest.approx((613.20, 613.42, 319.94, 239.18),
                                                                                    abs=0.01)
    assert rig.depth_scale == 0.001
    assert rig.baseline_m * 1000 == pytest.approx(14.34, abs=0.05)


def test_extrinsic_as_the_sdk_reads_it(frame):
    # pyrealsense2 2.59.1 playback of this file: depth_profile.get_extrinsics_to(color_profile) gives
    # rotation (column-major) and translation (metres) as below; measured once, the SDK is not a dependency
    rot = [0.99986332654953, 0.01030866801738739, -0.01292696874588728, -0.010310042649507523, 0.9999468326568604,
           -3.9757887861924246e-05, 0.012925871647894382, 0.00017303005733992904, 0.9999164342880249]
    t = [0.014311314560472965, 0.000602306448854506, 0.000610804243478924]
    T = frame.rig.T_color_from_depth
    np.testing.assert_allclose(T[:3, :3], np.reshape(rot, (3, 3)).T, atol=1e-6)
    np.testing.assert_allclose(T[:3, 3], t, atol=1e-6)


def _edge_distance(frame, T) -> float:
    """Mean distance (px) from the registered depth's discontinuities to the nearest colour edge."""
    reg = register_depth(dataclasses.replace(frame, rig=Rig(frame.rig.color, frame.rig.depth, T)).rgbd())
    grey = cv2.GaussianBlur(cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY), (5, 5), 0)
    dist = cv2.distanceTransform((cv2.Canny(grey, 30, 90) == 0).astype(np.uint8), cv2.DIST_L2, 5)
    edges = np.zeros(reg.shape, bool)
    for axis in (0, 1):  # a jump of more than 5 % between the pixels two either side
        a, b = np.roll(reg, 2, axis), np.roll(reg, -2, axis)
        edges |= (a > 0) & (b > 0) & (reg > 0) & (np.abs(a - b) > 0.05 * reg)
    edges[:3] = edges[-3:] = False
    edges[:, :3] = edges[:, -3:] = False
    assert edges.sum() > 100
    return float(dist[edges].mean())


def test_registered_depth_aligns_with_colour_edges(frame):
    T = frame.rig.T_color_from_depth
    wrong = {"identity": np.eye(4), "translation negated": T * [[1, 1, 1, -1]],
             "translation read as millimetres": T * [[1, 1, 1, 1e-3]], "translation doubled": T * [[1, 1, 1, 2]]}
    for M in wrong.values():
        M[3] = [0, 0, 0, 1]
    good = _edge_distance(frame, T)
    for name, M in wrong.items():
        assert good < 0.75 * _edge_distance(frame, M), name


def test_cli_info_and_export(tmp_path, frame):
    result = CliRunner().invoke(info_command, [BAG])
    assert result.exit_code == 0, result.output
    assert "realsense-bag, 1 colour+depth frames" in result.output and "baseline 14.34 mm" in result.output
    result = CliRunner().invoke(export_command, [BAG, "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    out = tmp_path / "out"
    back = load_frame(out / "color/000000.png", out / "depth/000000.png", out / "calib.json")
    np.testing.assert_array_equal(back.depth_m, frame.depth_m)
    np.testing.assert_array_equal(back.color, frame.color)
    np.testing.assert_allclose(back.rig.T_color_from_depth, frame.rig.T_color_from_depth, atol=1e-12)


def test_bad_bags(tmp_path):
    data = open(BAG, "rb").read()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageReadError, match=r"cut\.bag"):
        with open_source(cut) as src:
            src.frame(0)
    with open_source(BAG) as src:
        with pytest.raises(InputError, match=r"single_depth_color_640x480\.bag: frame index 1 is out of range"):
            src.frame(1)
