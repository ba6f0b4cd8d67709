"""`pcdof demo`: the subject rule, the lens rule, and renders that visibly differ from their inputs."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof import io
from pcdof.cli import main
from pcdof.cli.demo import (BACKGROUND_BLUR_PX, DATA, F_NUMBER, FOCAL_LENGTHS_MM, FRAMES, choose_lens, pick_subject,
                            side_by_side)
from pcdof.errors import InputError

REAL = [name for name, spec in FRAMES.items() if spec[0].startswith("real/")]


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    args = ["demo", "-o", str(out)] + [a for name in [*REAL, "sample"] for a in ("--frame", name)]
    result = CliRunner().invoke(main, args, prog_name="pcdof")
    assert result.exit_code == 0, result.output
    return out, result


def gradient_energy(image: np.ndarray, x: int, y: int, r: int = 6) -> float:
    """Sum of squared Sobel gradients of the grey image in the (2r+1)^2 window around (x, y)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float64)
    gx = cv2.Sobel(grey, cv2.CV_64F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_64F, 0, 1, ksize=3)
    win = (slice(y - r, y + r + 1), slice(x - r, x + r + 1))
    return float(np.sum(gx[win] ** 2 + gy[win] ** 2))


class TestDemoRenders:
    @pytest.mark.parametrize("name", REAL)
    def test_render_differs_visibly_from_its_input(self, demo_out, name):
        out, _ = demo_out
        color = io.read_color(os.path.join(DATA, FRAMES[name][0], FRAMES[name][1]))
        render = io.read_color(os.path.join(out, f"{name}_physical.png"))
        assert render.shape == color.shape and render.dtype == np.uint8
        changed = np.abs(render.astype(int) - color.astype(int)).max(axis=2) > 5
        assert changed.mean() >= 0.20, f"{name}: only {changed.mean():.1%} of pixels changed by more than 5 levels"

    @pytest.mark.parametrize("name", [*REAL, "sample"])
    def test_subject_stays_sharp(self, demo_out, name):
        out, _ = demo_out
        entry = json.loads((out / "summary.json").read_text())[name]
        x, y = entry["subject"]["x"], entry["subject"]["y"]
        color = io.read_color(os.path.join(DATA, FRAMES[name][0], FRAMES[name][1]))
        render = io.read_color(os.path.join(out, f"{name}_physical.png"))
        before, after = gradient_energy(color, x, y), gradient_energy(render, x, y)
        assert before > 0
        assert abs(after / before - 1) <= 0.03, f"{name}: gradient energy at the subject {before:.0f} -> {after:.0f}"

    @pytest.mark.parametrize("name", [*REAL, "sample"])
    def test_background_blur_and_summary(self, demo_out, name):
        out, _ = demo_out
        entry = json.loads((out / "summary.json").read_text())[name]
        frame = io.load_frame(*(os.path.join(DATA, FRAMES[name][0], f) for f in FRAMES[name][1:]))
        # the thin-lens CoC at the background depth, recomputed from the reported lens (README's lens model)
        aperture_m = entry["focal_length_mm"] * 1e-3 / entry["f_number"]
        blur = aperture_m * frame.rig.color.fx * abs(1 / entry["focus_distance_m"] - 1 / entry["background_m"])
        assert blur == pytest.approx(entry["background_blur_px"], rel=1e-6)
        assert blur >= BACKGROUND_BLUR_PX * frame.rig.color.width / 640 - 1e-9
        for path in entry["files"].values():
            assert (out / path).is_file()
        picture = io.read_color(os.path.join(out, entry["files"]["side_by_side"]))
        assert picture.shape[1] == 3 * 640  # input | pcdof | paper

    def test_prints_the_decision_and_where_to_look(self, demo_out):
        out, result = demo_out
        for name in [*REAL, "sample"]:
            assert f"{name}_side_by_side.png" in result.stdout
        assert result.stdout.strip().splitlines()[-1].startswith(f"look at {out}")
        assert "PSNR" in result.stdout  # the sample against its ray-traced ground truth

    def test_quiet(self, tmp_path):
        result = CliRunner().invoke(main, ["demo", "-o", str(tmp_path), "--frame", "tum", "-q"])
        assert result.exit_code == 0 and result.stdout == ""
        assert (tmp_path / "tum_side_by_side.png").is_file()


def scene(h=120, w=160):
    """A wall at 4 m, a receding floor in the lower third, a box at 2 m in the centre, a small can at 1 m."""
    z = np.full((h, w), 4.0, np.float32)
    rows = np.arange(h)[:, None]
    floor = rows >= 2 * h // 3
    z[floor[:, 0]] = (1.2 + 2.8 * (h - 1 - rows[floor[:, 0]]) / (h / 3)).repeat(w, axis=1)
    z[40:100, 50:110] = 2.0  # the subject
    z[10:18, 10:18] = 1.0  # near, but small and outside the centre
    return z


class TestPickSubject:
    def test_box_in_front_of_a_wall(self):
        z = scene()
        s = pick_subject(z)
        assert 50 <= s.x < 110 and 40 <= s.y < 100
        assert s.mode_m == pytest.approx(2.0, rel=0.03)
        # the deepest interior pixel of the box's part of the central window (rows 30-89, columns 40-119)
        assert (s.x, s.y) == (pytest.approx(79.5, abs=1.5), pytest.approx(64.5, abs=5))

    def test_holes_and_nan_are_unknown(self):
        z = scene()
        rng = np.random.default_rng(0)
        z[rng.random(z.shape) < 0.2] = 0
        z[rng.random(z.shape) < 0.05] = np.nan
        s = pick_subject(z)
        assert s.mode_m == pytest.approx(2.0, rel=0.03)

    def test_scale_invariant(self):
        a, b = pick_subject(scene()), pick_subject(scene() * 3)
        assert (a.x, a.y) == (b.x, b.y) and b.mode_m == pytest.approx(3 * a.mode_m, rel=1e-6)

    def test_small_near_mode_is_not_the_subject(self):
        z = np.full((100, 100), 3.0, np.float32)
        z[45:50, 45:50] = 1.0  # 25 px: under 10 % of the 50x50 central window
        assert pick_subject(z).mode_m == pytest.approx(3.0, rel=0.03)

    @pytest.mark.parametrize("bad", [np.zeros((50, 50)), np.zeros(10), np.full((2, 2), 1.0)])
    def test_refuses_unusable_depth(self, bad):
        with pytest.raises(InputError):
            pick_subject(bad)


class TestChooseLens:
    def test_shortest_focal_length_that_blurs_enough(self):
        z = scene()
        fx, focus = 200.0, 2.0
        lens, z_bg, blur = choose_lens(z, fx, focus, target_px=10.0)
        assert z_bg == pytest.approx(np.percentile(z, 90))
        assert blur >= 10.0 and lens.f_number == F_NUMBER
        shorter = [f for f in FOCAL_LENGTHS_MM if f < lens.focal_length_mm]
        if shorter:  # the next shorter one would not have been enough
            assert shorter[-1] * 1e-3 / F_NUMBER * fx * abs(1 / focus - 1 / z_bg) < 10.0

    def test_subject_at_the_back_blurs_the_front(self):
        z = scene()
        lens, z_bg, blur = choose_lens(z, 200.0, 4.0, target_px=10.0)
        assert z_bg < 4.0 and blur >= 10.0

    def test_past_the_longest_lens(self):
        z = np.full((10, 10), 2.0)
        z[0, 0] = 2.01
        lens, _, blur = choose_lens(z, 100.0, 1.99, target_px=15.0)
        assert lens.focal_length_mm > FOCAL_LENGTHS_MM[-1] and lens.focal_length_mm % 10 == 0 and blur >= 15.0

    @pytest.mark.parametrize("kwargs", [{"fx": 0.0}, {"focus_m": -1.0}, {"target_px": float("nan")}])
    def test_bad_arguments(self, kwargs):
        args = {"fx": 100.0, "focus_m": 2.0, "target_px": 15.0, **kwargs}
        with pytest.raises(InputError):
            choose_lens(scene(), args.pop("fx"), args.pop("focus_m"), **args)


def test_side_by_side_layout():
    a = np.zeros((60, 80, 3), np.uint8)
    picture = side_by_side([a, a, a], ["one", "two", "three"], "a caption " * 40, marker=(10, 10), panel_width=160)
    assert picture.shape[1] == 480 and picture.dtype == np.uint8
    assert picture.shape[0] > 120 + 34 + 26  # panels (scaled 2x), titles and a wrapped caption


def test_bundled_sequence_is_small_and_complete():
    root = os.path.join(DATA, "sequence")
    pairs = [line.split() for line in open(os.path.join(root, "frames.txt")) if not line.startswith("#")]
    assert len(pairs) >= 5
    depths = []
    for color, depth in pairs:
        frame = io.load_frame(os.path.join(root, color), os.path.join(root, depth), os.path.join(root, "calib.json"))
        assert frame.color.shape == (240, 320, 3)
        depths.append(frame.depth_m)
    # a new sensor frame each time: noise and dropouts differ, the scene does not
    assert all(np.mean(a != b) > 0.1 for a, b in zip(depths, depths[1:]))
    known = [(d > 0) for d in depths]
    assert abs(np.median(depths[0][known[0]]) - np.median(depths[-1][known[-1]])) < 0.02
    size = sum(os.path.getsize(os.path.join(dirpath, f)) for dirpath, _, files in os.walk(root) for f in files)
    assert size < 600_000
