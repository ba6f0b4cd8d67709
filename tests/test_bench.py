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
    for part in ("dof", "wide", "wide_budget", "speed", "threads", "startup", "cost", "refocus", "refocus_threads",
                 "memory", "machine_threads", "registration", "fill"):
        assert report.get(part), f"{part} missing from report.json"
    md = (out / "report.md").read_text()
    for heading in ("Depth of field against the ray-traced ground truth", "Speed",
                    "Registration against OpenCV and Open3D", "Hole filling against cv2.inpaint"):
        assert heading in md
    assert "Wide benchmark" in md and "Error budget" in md and "tuning seeds" in md
    for plot in ("pareto.png", "cost.png", "budget.png"):
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


def test_refocus_rows_alternate_the_paper_method_at_each_blur(quick_report):
    from pcdof.bench.refocus import BLURS_PX

    out, report = quick_report
    rows = report["refocus"]
    assert [r["background_blur_px"] for r in rows] == list(BLURS_PX)
    for r in rows:
        assert r["refocus_ms"] > 0 and r["paper_ms"] > 0 and r["ratio"] > 0
        lo, hi = r["refocus_ms_quartiles"]
        assert lo <= hi
    assert rows[0]["relative_to_smallest_blur"] == 1.0
    assert [r["threads"] for r in report["refocus_threads"]][0] == 1
    (memory,) = report["memory"]
    assert memory["color_size"] == "160x120" and memory["peak_mb"] >= memory["baseline_mb"] > 0
    assert memory["marginal_bytes_per_pixel"] is None  # one size: no growth to measure
    assert report["machine_threads"][0]["threads"] == 1 and report["machine_threads"][0]["stream_speedup"] == 1.0
    assert "What this machine's threads can give" in (out / "report.md").read_text()


def test_peak_memory_separates_the_cost_per_pixel_from_fixed_costs(monkeypatch):
    """Children whose peak is a fixed 80 MB plus 50 bytes per pixel: 50 bytes per added pixel, whatever the
    fixed part adds to the bytes per pixel of each size."""
    import json
    import subprocess
    import types

    import numpy as np

    from pcdof.bench import refocus

    def fake_child(cmd, **kwargs):
        color = np.load(cmd[-1] + "/color.npy", mmap_mode="r")
        pixels = color.shape[0] * color.shape[1]
        out = {"baseline": 100_000_000, "peak": 100_000_000 + 80_000_000 + 50 * pixels, "peak_reset": True}
        return types.SimpleNamespace(returncode=0, stdout=json.dumps(out) + "\n", stderr="")

    monkeypatch.setattr(subprocess, "run", fake_child)
    rows = refocus.peak_memory(sizes=((160, 120), (320, 240), (320, 240)), progress=False)
    assert rows[0]["marginal_bytes_per_pixel"] is None and rows[2]["marginal_bytes_per_pixel"] is None
    assert rows[1]["marginal_bytes_per_pixel"] == 50.0
    assert rows[0]["bytes_per_pixel"] > 4000  # the fixed 80 MB over 19200 pixels


def test_lens_for_background_blur_blurs_the_background_by_the_pixels_asked():
    import numpy as np

    from pcdof.bench.refocus import BACKGROUND_PERCENTILE, lens_for_background_blur
    from pcdof.errors import InputError

    rng = np.random.default_rng(1)
    depth = rng.uniform(0.8, 4.0, (60, 80)).astype(np.float32)
    depth[0, :5] = 0  # unknown depth is left out
    z_b = np.percentile(depth[depth > 0], BACKGROUND_PERCENTILE)
    for blur in (4.0, 64.0):
        lens = lens_for_background_blur(depth, 500.0, 1.5, blur)
        assert lens.focus_distance_m == 1.5
        assert float(lens.coc_px(np.float32([z_b]), 500.0)[0]) == pytest.approx(blur, rel=1e-4)
    with pytest.raises(InputError, match="blur_px"):
        lens_for_background_blur(depth, 500.0, 1.5, 0.0)
    with pytest.raises(InputError, match="depth_m"):
        lens_for_background_blur(np.zeros((4, 4)), 500.0, 1.5, 4.0)


def test_speed_frame_upscales_big_frames_with_their_intrinsics(monkeypatch):
    from pcdof.bench import refocus

    small = refocus.speed_frame("slanted_plane", (96, 72), (80, 66))
    assert small.frame.color.shape == (72, 96, 3)
    monkeypatch.setattr(refocus, "MAX_GENERATED_SIDE", 96)
    up = refocus.speed_frame("slanted_plane", (192, 144), (80, 66))
    assert up.frame.color.shape == (144, 192, 3)
    c, c0 = up.rig.color, small.rig.color
    assert (c.width, c.height) == (192, 144) and c.fx == pytest.approx(2 * c0.fx)
    assert c.cx == pytest.approx(2 * c0.cx + 0.5) and up.rig.depth == small.rig.depth


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


def test_refocus_bounds_script(capsys):
    """scripts/refocus_bounds.py times the refocus with passes made free, and gives every pass back afterwards."""
    import importlib.util
    import os

    import pcdof.stages.render.composite as composite
    import pcdof.stages.render.scatter as scatter

    passes = (scatter.scatter_packed, composite.composite_under)
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "refocus_bounds.py")
    spec = importlib.util.spec_from_file_location("refocus_bounds", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--size", "160x120", "--blur", "8", "--repeats", "1"]) == 0
    assert (scatter.scatter_packed, composite.composite_under) == passes
    rows = {line[:30].strip(): line[30:].split() for line in capsys.readouterr().out.splitlines()[2:]}
    assert set(rows) == {"refocus", "no scatter", "no scatter, no compositing", "highlights off", "paper whole frame"}
    assert rows["paper whole frame"][1] == "1.00"
    assert all(0 < float(ms) < 60_000 and float(ratio) > 0 for ms, ratio in rows.values())
    with pytest.raises(SystemExit):
        script.main(["--repeats", "0"])


@pytest.mark.parametrize("args, flag", [
    (["--only", "speed", "--repeats", "0"], "--repeats"),
    (["--only", "speed", "--repeats", "-3"], "--repeats"),
    (["--only", "dof", "--size", "0x0"], "--size"),
    (["--only", "dof", "--depth-size", "64"], "--depth-size"),
    (["--only", "dof", "--samples", "0"], "--samples"),
])
def test_bad_options_fail_before_any_work(tmp_path, monkeypatch, args, flag):
    from pcdof.bench import dof, fill, refocus, registration, speed

    def no_work(*a, **k):
        raise AssertionError("benchmark work started before the options were checked")

    for module, name in ((dof, "run_dof_bench"), (speed, "pipeline_vs_paper"), (speed, "cost_follows_work"),
                         (speed, "thread_scaling"), (speed, "startup"), (refocus, "refocus_vs_paper"),
                         (refocus, "refocus_threads"), (refocus, "peak_memory"),
                         (registration, "run_registration_bench"), (fill, "run_fill_bench")):
        monkeypatch.setattr(module, name, no_work)
    out = tmp_path / "b"
    result = CliRunner().invoke(main, ["bench", "-o", str(out), *args])
    assert result.exit_code == 6, result.output
    assert result.output.startswith("pcdof: error: ") and result.output.count("\n") == 1 and flag in result.output
    assert not out.exists()


@pytest.mark.parametrize("args, flag, valid", [
    (["--quick", "--only", "dof", "--scenes", "slanted_plane,nosuch"], "--scenes", "portrait"),
    (["--only", "dof", "--scenes", ","], "--scenes", "portrait"),
    (["--only", " , "], "--only", "wide"),
    (["--only", "dof,bogus"], "--only", "wide"),
    (["--only", "foo"], "--only", "registration"),
    (["--seeds", "0"], "--seeds", None),
    (["--only", "wide", "--wide-blurs", "16,-1"], "--wide-blurs", None),
    (["--only", "wide", "--wide-blurs", "a"], "--wide-blurs", None),
    (["--only", "wide", "--wide-highlights", "0.5"], "--wide-highlights", None),
])
def test_invalid_choices_are_usage_errors_listing_the_choices(tmp_path, args, flag, valid):
    out = tmp_path / "b"
    result = CliRunner().invoke(main, ["bench", "-o", str(out), *args])
    assert result.exit_code == 2, result.output
    assert flag in result.output and (valid is None or valid in result.output)
    assert not out.exists()


def test_report_path_that_is_a_folder_fails_first_and_cleanly(tmp_path, monkeypatch):
    from pcdof.bench import fill

    monkeypatch.setattr(fill, "run_fill_bench", lambda *a, **k: pytest.fail("work started"))
    (tmp_path / "report.json").mkdir()
    result = CliRunner().invoke(main, ["bench", "-o", str(tmp_path), "--only", "fill", "--quick"])
    assert result.exit_code == 7, result.output
    assert "report.json" in result.output and result.output.startswith("pcdof: error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_report_writes_are_atomic(tmp_path):
    from pcdof.cli.bench import _write_text
    from pcdof.errors import ImageWriteError

    (tmp_path / "report.json").mkdir()
    with pytest.raises(ImageWriteError, match="report.json"):
        _write_text(str(tmp_path / "report.json"), "{}")
    _write_text(str(tmp_path / "report.md"), "# ok\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json", "report.md"]  # no temporary left
    assert (tmp_path / "report.md").read_text() == "# ok\n"


def test_bench_functions_check_their_arguments():
    from pcdof.bench import dof, speed
    from pcdof.errors import InputError

    with pytest.raises(InputError, match="repeats"):
        speed.pipeline_vs_paper(sizes=((32, 24),), repeats=0, progress=False)
    with pytest.raises(InputError, match="repeats"):
        speed.cost_follows_work(size=(32, 24), repeats=-1, progress=False)
    with pytest.raises(InputError, match="repeats"):
        speed.thread_scaling(size=(32, 24), repeats=0, progress=False)
    with pytest.raises(InputError, match="repeats"):
        speed.startup(size=(32, 24), repeats=True, progress=False)
    with pytest.raises(InputError, match="scene"):
        speed.startup(size=(32, 24), scene="nosuch", progress=False)
    with pytest.raises(InputError, match="scenes"):
        dof.run_dof_bench(scenes=["slanted_plane", "nosuch"], progress=False)
    with pytest.raises(InputError, match="repeats"):
        dof.run_dof_bench(scenes=["slanted_plane"], repeats=0, progress=False)


def test_quick_bench_prints_no_numpy_warning(quick_report, recwarn):
    from pcdof.bench import dof

    rows = [{"scene": "s", "setting": "wide", "f_number": 2.0, "max_coc_px": 3.0, "method": m, "psnr": 30.0,
             "psnr_edge": float("nan"), "ssim": 0.9, "ms": 1.0} for m in ("pcdof-balanced", "paper", "baseline")]
    dof.compact_table(rows)
    dof.summarize(rows)
    assert not [w for w in recwarn if "NaN" in str(w.message)]


def test_wide_rows_cover_every_focus_and_the_budget(quick_report):
    _, report = quick_report
    rows = report["wide"]
    assert {r["focus"] for r in rows} == {"near", "mid", "far"}
    methods = {r["method"] for r in rows}
    assert {"pcdof-exact", "pcdof-balanced", "pcdof-fast", "paper", "baseline"} <= methods
    assert {"budget:measured", "budget:true depth", "budget:true depth+linear"} <= methods
    for r in rows:
        assert 10 < r["psnr"] < 80
        assert all(seed >= 100 for seed in [r["seed"]])  # reported seeds never overlap the tuning seeds
    pixels = sum(n for k, (_, n) in rows[0]["sse"].items() if k.endswith("|all"))
    assert pixels == 64 * 48  # every pixel falls in exactly one blur bucket
    assert {r["blur_px"] for r in rows} == {12.0}  # --quick: 120 px at 640 px wide, scaled to 64 px
    tiers = {(c["tier"], c["bucket"]) for c in report["wide_tiers"]}
    assert {("pcdof-balanced", "all"), ("pcdof-fast", "all")} <= tiers


def test_wide_blurs_scale_with_the_width():
    from pcdof.bench.wide import BLURS_PX, REFERENCE_WIDTH_PX, scaled_blurs
    from pcdof.errors import InputError

    assert scaled_blurs(BLURS_PX, REFERENCE_WIDTH_PX) == (16.0, 64.0)
    assert scaled_blurs((16, 64), 256) == (6.4, 25.6)  # 2.5 % and 10 % of the width
    assert scaled_blurs((16, 64), 1280) == (32.0, 128.0)
    assert scaled_blurs((16, 64), 256, reference_width_px=None) == (16.0, 64.0)  # absolute pixels
    with pytest.raises(InputError, match="reference_width_px"):
        scaled_blurs((16,), 256, reference_width_px=0)


def _fake_rows(method_psnr: dict, cases=(("room", 100, "far", 8.0), ("thin", 100, "near", 8.0))):
    """Rows of made-up errors: per case, every method's squared-error sums in two buckets."""
    from pcdof.bench.wide import BUCKETS

    rows = []
    for i, case in enumerate(cases):
        for m, db in method_psnr.items():
            mse = 10 ** (-(db + i) / 10)
            rows.append({"scene": case[0], "seed": case[1], "focus": case[2], "blur_px": case[3], "blur_share": 0.1,
                         "method": m, "psnr": db + i, "psnr_edge": db + i - 1,
                         "sse": {**{f"{b}|{p}": (0.0, 0) for _, _, b in BUCKETS
                                    for p in ("all", "edge")},
                                 "<2|all": (mse * 1000, 1000), "8-16|all": (mse * 500, 500)}})
    return rows


def test_tier_curve_and_compare_measure_the_change_from_exact():
    from pcdof.bench import tiers, wide

    rows = _fake_rows({"pcdof-exact": 30.0, "pcdof-balanced": 29.95, "pcdof-fast": 29.0})
    curve = {(c["tier"], c["bucket"]): c for c in tiers.tier_curve(rows, tiers=("pcdof-balanced", "pcdof-fast"))}
    for bucket in ("<2", "8-16", "all"):
        assert curve[("pcdof-balanced", bucket)]["mean_db"] == pytest.approx(-0.05, abs=1e-9)
        assert curve[("pcdof-fast", bucket)]["worst_db"] == pytest.approx(-1.0, abs=1e-9)
    assert ("pcdof-fast", "16-32") not in curve  # no pixels there: no point on the curve
    c = wide.compare(rows, "pcdof-exact", "pcdof-fast", tolerance_db=0.5)
    assert c["cases"] == 2 and len(c["losses"]) == 2 and c["mean_db"] == pytest.approx(-1.0)
    assert wide.compare(rows, "pcdof-exact", "pcdof-balanced", tolerance_db=0.1)["losses"] == []
    table = tiers.tier_table(rows)
    assert "pcdof-fast: 2 of 2 cases lose more than 0.5 dB" in table
    assert "pcdof-balanced: 0 of 2 cases lose more than 0.1 dB" in table


def test_losses_table_lists_exactly_the_cases_lost():
    from pcdof.bench import wide

    rows = _fake_rows({"pcdof-balanced": 30.0, "paper": 29.0, "baseline": 30.5})
    table = wide.losses_table(rows)
    assert table.count("baseline | -0.50 (-0.50) |") == 2 and "2 of 2 cases lose" in table
    assert "0 of 2 cases lose" in wide.losses_table(_fake_rows({"pcdof-balanced": 30.0, "paper": 29.0}))


def test_lens_for_blur_gives_the_requested_largest_blur():
    import numpy as np

    from pcdof.synth.wide import lens_for_blur

    depth = np.random.default_rng(1).uniform(0.5, 4.0, (30, 40)).astype(np.float32)
    for focus in (0.6, 1.5, 3.9):
        for blur in (4.0, 64.0):
            lens = lens_for_blur(depth, 300.0, focus, blur)
            assert float(lens.coc_px(depth, 300.0).max()) == pytest.approx(blur, rel=1e-4)


def test_table_lines_gives_one_markdown_row_per_row_with_as_many_cells_as_columns():
    from pcdof.bench import table_lines

    lines = table_lines(("a", "b", "c"), [(1, "x", ""), (2.5, "y", "z")])
    assert lines == ["| a | b | c |", "|---|---|---|", "| 1 | x |  |", "| 2.5 | y | z |"]
    assert all(line.count("|") == 4 for line in lines)


def test_plot_to_writes_a_png_and_writes_nothing_when_drawing_fails(tmp_path):
    import matplotlib.pyplot as plt

    from pcdof.bench import plot_to

    with plot_to(str(tmp_path / "ok.png"), figsize=(2, 2)) as (fig, ax):
        ax.plot([0, 1], [0, 1])
    assert (tmp_path / "ok.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.fignum_exists(fig.number)
    with pytest.raises(ZeroDivisionError), plot_to(str(tmp_path / "bad.png"), figsize=(2, 2)) as (fig, ax):
        ax.plot([0, 1], [0, 1 / 0])
    assert not (tmp_path / "bad.png").exists() and not plt.fignum_exists(fig.number)


def test_wide_spec_default_lens_is_focused_on_the_subject():
    import numpy as np

    from pcdof.synth import SceneSpec
    from pcdof.synth.wide import WIDE_SCENES

    for kind, build in WIDE_SCENES.items():
        spec = build(np.random.default_rng(3))
        assert isinstance(spec, SceneSpec), kind
        assert spec.default_lens.focus_distance_m == spec.focus_m["mid"]
        assert spec.focus_m["near"] < spec.focus_m["mid"] < spec.focus_m["far"]


def test_wide_fence_scene_puts_its_poles_at_the_near_focus():
    import numpy as np

    from pcdof.synth.wide import WIDE_SCENES

    for seed in (100, 101, 5):
        spec = WIDE_SCENES["fence"](np.random.default_rng([seed, 7]))
        poles = [mesh for mesh, group in zip(spec.scene.meshes, spec.object_groups) if group == "foreground"]
        assert 6 <= len(poles) <= 10  # 5-9 upright poles and a rail
        for mesh in poles:
            assert mesh.bounds[0][2] <= spec.focus_m["near"] + 0.05 and mesh.bounds[1][2] >= spec.focus_m["near"] - 0.05
        widths = sorted(float(m.extents[0]) for m in poles)[:-1]  # the rail spans the view
        assert max(widths) <= 0.031  # thin: at most 30 mm across


def test_speed_part_reports_spread_threads_and_start_up(quick_report):
    out, report = quick_report
    for row in report["speed"]:
        lo, hi = row["ratio_quartiles"]
        assert 0 < lo <= row["ratio_paired"] <= hi
        assert row["pcdof_ms_quartiles"][0] <= row["pcdof_ms"] <= row["pcdof_ms_quartiles"][1]
        # the target's own baseline (cv2.registerDepth, no fill), measured in the same alternation
        lo, hi = row["ratio_cv2_quartiles"]
        assert 0 < lo <= row["ratio_cv2_paired"] <= hi
        assert row["paper_cv2_ms_quartiles"][0] <= row["paper_cv2_ms"] <= row["paper_cv2_ms_quartiles"][1]
    threads = report["threads"]
    assert threads[0]["threads"] == 1 and threads[0]["speedup"] == 1.0
    assert [r["threads"] for r in threads] == sorted({r["threads"] for r in threads})
    start = report["startup"]
    # a fresh render process imports pcdof and more, and renders: it takes longer than the import alone
    assert 0 < start["import_s"] < start["warm_render_s"]
    assert start["cold_render_s"] is None  # --quick leaves out the compile from an empty cache
    md = (out / "report.md").read_text()
    assert "speed-up over 1 thread" in md and "python -c 'import pcdof'" in md
    assert "paper method on cv2.registerDepth depth, no fill" in md


def test_quartiles():
    from pcdof.bench.speed import quartiles

    assert quartiles([5.0]) == [5.0, 5.0]
    assert quartiles([1, 2, 3, 4, 5]) == [2.0, 4.0]
    assert quartiles([4, 1, 3, 2]) == [1.75, 3.25]


def _splat_nearest(depth_m, rig):
    """An independent point splat: every depth pixel back-projected, moved into the colour camera, rounded to the
    nearest pixel; the nearest point wins (no distortion on either camera)."""
    import numpy as np

    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w]
    z = depth_m.astype(np.float64)
    ok = z > 0
    kd, kc = rig.depth.K, rig.color.K
    points = np.stack([(u[ok] - kd[0, 2]) / kd[0, 0] * z[ok], (v[ok] - kd[1, 2]) / kd[1, 1] * z[ok], z[ok]])
    t = np.asarray(rig.T_color_from_depth, np.float64)
    q = t[:3, :3] @ points + t[:3, 3:]
    px = np.floor(kc[0, 0] * q[0] / q[2] + kc[0, 2] + 0.5).astype(np.int64)
    py = np.floor(kc[1, 1] * q[1] / q[2] + kc[1, 2] + 0.5).astype(np.int64)
    W, H = rig.color.width, rig.color.height
    keep = (q[2] > 0) & (px >= 0) & (py >= 0) & (px < W) & (py < H)
    out = np.full((H, W), np.inf)
    np.minimum.at(out, (py[keep], px[keep]), q[2][keep])
    out[np.isinf(out)] = 0.0
    return out.astype(np.float32)


_CV2_SMALL_PLANE = """
import json, sys
import numpy as np
from pcdof.bench.registration import register_cv2
from pcdof.synth import generate_scene
sf = generate_scene("portrait", color_size=(int(sys.argv[1]), int(sys.argv[2])), depth_size=(256, 212), seed=3)
out = register_cv2(sf.frame.depth_m, sf.rig)
np.save(sys.argv[3], out)
"""


@pytest.mark.parametrize("size", [(256, 192), (160, 120), (300, 200)])
def test_cv2_registration_survives_a_colour_camera_smaller_than_the_depth_image(size, tmp_path):
    """cv2.registerDepth corrupts the heap when its output plane is narrower or lower than the depth image
    (opencv_contrib#3761): the wrapper registers onto a plane widened to the depth image's size and crops it, and
    gives what an independent point splat gives. Run in a child process: the bug aborts the process it runs in."""
    import subprocess
    import sys

    import numpy as np

    from pcdof.synth import generate_scene

    path = tmp_path / "registered.npy"
    done = subprocess.run([sys.executable, "-c", _CV2_SMALL_PLANE, str(size[0]), str(size[1]), str(path)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-800:]
    got = np.load(path)
    sf = generate_scene("portrait", color_size=size, depth_size=(256, 212), seed=3)
    expected = _splat_nearest(sf.frame.depth_m, sf.rig)
    assert got.shape == (size[1], size[0]) and got.dtype == np.float32
    assert (expected > 0).mean() > 0.3
    # OpenCV projects in float32: a point within rounding of a pixel's edge may land on the neighbour
    assert np.mean(np.abs(got - expected) > 1e-3) < 0.002


def test_cv2_registration_is_opencv_as_it_is_where_the_plane_is_large_enough():
    """Where the colour camera's image is at least the depth image's size the wrapper is one plain call."""
    import cv2
    import numpy as np

    from pcdof.bench.registration import register_cv2
    from pcdof.synth import generate_scene

    sf = generate_scene("near_object", color_size=(320, 240), depth_size=(256, 212), seed=2)
    rig = sf.rig
    for dilation in (False, True):
        plain = cv2.registerDepth(rig.depth.K, rig.color.K, rig.color.dist_coeffs, np.asarray(rig.T_color_from_depth),
                                  sf.frame.depth_m, (rig.color.width, rig.color.height), depthDilation=dilation)
        got = register_cv2(sf.frame.depth_m, rig, dilation=dilation)
        assert np.array_equal(got, np.maximum(np.nan_to_num(plain, nan=0.0), 0.0))
    assert np.mean(np.abs(register_cv2(sf.frame.depth_m, rig) - _splat_nearest(sf.frame.depth_m, rig)) > 1e-3) < 0.002


def test_paper_on_opencv_depth_is_the_paper_method_on_cv2_registered_depth():
    """The speed target's baseline: the paper renderer fed cv2.registerDepth's depth (holes kept), nothing else."""
    import numpy as np

    from pcdof.bench.registration import register_cv2
    from pcdof.bench.speed import paper_on_opencv_depth
    from pcdof.lens import PaperLens
    from pcdof.stages.render import render_paper
    from pcdof.synth import generate_scene

    sf = generate_scene("portrait", color_size=(96, 72), depth_size=(64, 53), seed=1)
    lens = PaperLens(focus_distance_m=sf.default_lens.focus_distance_m, blur_sigma_px=2.0)
    depth = register_cv2(sf.frame.depth_m, sf.rig)
    assert (depth == 0).any()  # a point splat leaves holes, and the baseline does not fill them
    expected, _ = render_paper(sf.frame.color, depth, lens, fx=sf.rig.color.fx, max_range_m=sf.rig.max_range_m)
    got = paper_on_opencv_depth(sf.frame, lens)
    assert got.dtype == sf.frame.color.dtype and np.array_equal(got, expected)
