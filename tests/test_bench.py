"""`pcdof bench --quick`: every part runs end to end and writes its tables, plots and report."""

from __future__ import annotations

import json
import math

import cv2
import pytest
from click.testing import CliRunner

from pcdof.bench.speed import lens_for_share
from pcdof.cli import main


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    result = CliRunner().invoke(main, ["bench", "--quick", "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out, json.loads((out / "report.json").read_text())


def test_every_part_is_reported(quick_report):
    out, report = quick_report
    for part in ("dof", "speed", "cost", "registration", "fill"):
        assert report.get(part), f"{part} missing from report.json"
    md = (out / "report.md").read_text()
    for heading in ("Depth of field against the ray-traced ground truth", "Speed",
                    "Registration against OpenCV and Open3D", "Hole filling against cv2.inpaint"):
        assert heading in md
    for plot in ("pareto.png", "cost.png"):
        image = cv2.imread(str(out / plot))
        assert image is not None and image.std() > 5, f"{plot} is blank"
    assert (out / "dof.csv").read_text().count("\n") == len(report["dof"]) + 1


def test_dof_rows_score_every_method_against_the_ground_truth(quick_report):
    _, report = quick_report
    methods = {r["method"] for r in report["dof"]}
    assert {"paper", "baseline", "pcdof-exact", "pcdof-balanced"} <= methods
    for r in report["dof"]:
        assert 10 < r["psnr"] < 80 and 0 < r["ssim"] <= 1 and r["ms"] > 0


def test_cost_follows_the_blurred_share(quick_report):
    _, report = quick_report
    cost = report["cost"]
    shares = [r["share"] for r in cost]
    assert shares == sorted(shares) and shares[0] == 0 and shares[-1] == pytest.approx(1.0)
    assert cost[0]["render_skipped"]  # nothing out of focus: the renderer does no work at all
    assert not any(r["render_skipped"] for r in cost[1:])


def test_lens_for_share_hits_the_requested_share():
    import numpy as np

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.8, 4.0, (60, 80)).astype(np.float32)
    fx = 500.0
    for share in (0.0, 0.25, 0.5, 1.0):
        lens = lens_for_share(depth, fx, share)
        got = float(np.mean(lens.coc_px(depth, fx) >= 1.0))
        assert got == pytest.approx(share, abs=1.0 / depth.size + 1e-9)
        assert math.isfinite(lens.f_number) and lens.f_number > 0
    assert lens_for_share(depth, fx, 0.0).coc_px(depth, fx).max() < 0.5


def test_registration_profile_script(capsys):
    """scripts/profile_registration.py times the two registration passes on the benchmark's box scene."""
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts",
                        "profile_registration.py")
    spec = importlib.util.spec_from_file_location("profile_registration", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--size", "640x480", "--rounds", "1", "--calls", "1"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| pass") or line.startswith("| reproject")
            or line.startswith("| open3d")]
    assert len(rows) >= 4
    for row in rows:
        ms = float(row.split("|")[2])
        assert 0 < ms < 10_000
    quads = int(out.split(" quads drawn")[0].split()[-1])
    assert 0.9 * 639 * 479 < quads <= 639 * 479  # the box scene fills nearly the whole depth image
