"""Every frame command takes a phone depth photo: render, register, cloud, export, batch, view.

A small Dynamic Depth JPEG (written to the specification by ``test_phone_jpeg``'s writer) stands in for a
phone photo in the fast tests; the real 12 MP iPhone photo is rendered whole in the slow one.
"""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof import io
from pcdof.cli import main
from pcdof.sources import open_source
from test_phone_jpeg import dynamic_depth_jpeg, encode

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PUG = os.path.join(ROOT, "data", "real", "iphone_heic_depth", "pug.heic")


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="pcdof")


def ok(result):
    assert result.exit_code == 0, (result.exit_code, result.output)
    return result


def sharpness(img: np.ndarray) -> float:
    """Mean absolute Laplacian of the grey image: detail that a blur removes."""
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(np.abs(cv2.Laplacian(grey, cv2.CV_32F)).mean())


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    """A 240x320 textured photo: a near square (0.8 m) before a far wall (4 m); depth at 1/4 resolution."""
    rng = np.random.default_rng(3)
    color = rng.integers(0, 255, (240, 320, 3), np.uint8)
    color = cv2.GaussianBlur(color, (3, 3), 0)
    z = np.full((60, 80), 4.0)
    z[20:40, 25:55] = 0.8
    path = tmp_path_factory.mktemp("phone") / "photo.jpg"
    path.write_bytes(dynamic_depth_jpeg(color, encode(z, 0.5, 5.0, "RangeInverse"), near=0.5, far=5.0,
                                        fmt="RangeInverse", fx=300.0))
    return str(path)


def test_render_focus_on_the_near_square(photo, tmp_path):
    out = tmp_path / "r.png"
    result = ok(invoke("render", photo, "--focus-at", "160,120", "--blur", "3", "-o", out))
    assert "focus 0.8" in result.output
    img, src = io.read_color(str(out)), open_source(photo).frame(0).color
    square, wall = (slice(100, 140), slice(120, 200)), (slice(0, 50), slice(0, 320))
    assert sharpness(img[square]) > 0.8 * sharpness(src[square])  # the square keeps its detail
    assert sharpness(img[wall]) < 0.35 * sharpness(src[wall])  # the wall behind is blurred


def test_explain_and_trace_say_where_the_intrinsics_come_from(photo, tmp_path):
    result = ok(invoke("render", photo, "--blur", "2", "-o", tmp_path / "r.png", "--explain",
                       "--save-maps", tmp_path / "maps"))
    assert "(intrinsics from Dynamic Depth ImagingModel)" in result.stderr
    trace = json.loads((tmp_path / "maps" / "trace.json").read_text())
    assert trace["source"].endswith("(intrinsics from Dynamic Depth ImagingModel)")
    register = next(t for t in trace["trace"] if t["name"] == "register")
    assert register["detail"]["edges"]["scale"] == pytest.approx(4.0)


def test_register_cloud_export(photo, tmp_path):
    ok(invoke("register", photo, "-o", tmp_path / "d.npy", "--fill"))
    depth = np.load(tmp_path / "d.npy")
    assert depth.shape == (240, 320) and depth.min() > 0
    assert np.median(depth[100:140, 120:200]) == pytest.approx(0.8, rel=0.02)
    ok(invoke("cloud", photo, "-o", tmp_path / "c.ply"))
    assert os.path.getsize(tmp_path / "c.ply") > 1000
    ok(invoke("export", photo, "-o", tmp_path / "x"))
    calib = json.loads((tmp_path / "x" / "calib.json").read_text())
    assert (calib["color"]["width"], calib["depth"]["width"]) == (320, 80)
    with open_source(os.path.join(tmp_path, "x", "color", "000000.png"),
                     depth=os.path.join(tmp_path, "x", "depth", "000000.png"),
                     calib=os.path.join(tmp_path, "x", "calib.json")) as src:
        again = src.frame(0)
    original = open_source(photo).frame(0)
    assert np.abs(again.depth_m - original.depth_m).max() <= 0.5 * calib["depth_scale"] + 1e-6
    assert np.array_equal(again.color, original.color)


def test_batch_and_view(photo, tmp_path):
    ok(invoke("batch", photo, "-o", tmp_path / "b", "--f-number", "1.4"))
    assert any(name.endswith(".png") for name in os.listdir(tmp_path / "b"))
    refused = invoke("batch", photo, "-o", tmp_path / "b2", "--blur", "2")
    assert refused.exit_code == 6 and refused.output.startswith("pcdof: error: --equivalent-f-number and --blur")
    ok(invoke("view", photo, "--html", tmp_path / "v.html", "--equivalent-f-number", "2"))
    assert os.path.getsize(tmp_path / "v.html") > 1000


@pytest.mark.slow
def test_pug_full_size(tmp_path):
    """The 4032x3024 iPhone photo focused on the pug's head at f/4 in 35 mm terms: the wall behind blurred, the
    head kept (at f/1.4 the head, 0.36-0.39 m deep, softens towards its back, as it would)."""
    out = tmp_path / "pug.png"
    result = ok(invoke("render", PUG, "--focus-at", "2300,1700", "--equivalent-f-number", "4", "-o", out))
    assert "focus 0.37 m" in result.output
    img, src = io.read_color(str(out)), open_source(PUG).frame(0).color
    assert img.shape == (3024, 4032, 3)
    head, wall = (slice(1500, 1900), slice(2100, 2500)), (slice(200, 800), slice(1200, 3600))
    assert sharpness(img[head]) > 0.8 * sharpness(src[head])  # measured 0.88
    assert sharpness(img[wall]) < 0.35 * sharpness(src[wall])  # measured 0.22
