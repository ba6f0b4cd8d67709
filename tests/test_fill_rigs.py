"""The fill benchmark on rigs of real devices (pcdof.synth.rigs, pcdof.bench.fill_rigs) and the rule outside
the depth camera's view it chose."""

import math

import numpy as np
import pytest

from pcdof.bench import fill_rigs
from pcdof.camera import Intrinsics, Rig
from pcdof.errors import InputError
from pcdof.synth.rigs import RIG_KINDS, SCENE_KINDS, rig_case, sensor_rig


def fov_deg(intr):
    """(horizontal, vertical) field of view of pinhole intrinsics, degrees (principal point centred)."""
    return (2 * math.degrees(math.atan(intr.width / 2 / intr.fx)),
            2 * math.degrees(math.atan(intr.height / 2 / intr.fy)))


@pytest.mark.parametrize("kind", list(RIG_KINDS))
def test_rigs_have_their_devices_fields_of_view(kind):
    rig, model = sensor_rig(kind, 320, np.random.default_rng(3))
    color_fov, depth_fov = RIG_KINDS[kind][:2]
    for intr, want in ((rig.color, color_fov), (rig.depth, depth_fov)):
        np.testing.assert_allclose(fov_deg(intr), want, atol=1.0)  # the height is rounded to whole pixels
    assert 0.45 <= model.dropout_threshold <= 0.65
    assert np.sign(model.projector_offset_m[0]) == np.sign(rig.T_color_from_depth[0, 3])  # same side


def test_kinect_v2_colour_is_wider_and_lower_than_depth():
    rig, _ = sensor_rig("kinect-v2", 256, np.random.default_rng(0))
    (ch, cv), (dh, dv) = fov_deg(rig.color), fov_deg(rig.depth)
    assert ch > dh + 10 and cv < dv - 4


@pytest.mark.parametrize("bad", [("phone", 256), ("d435", 16), ("d435", 256.0), ("d435", True)])
def test_sensor_rig_rejects_bad_arguments(bad):
    with pytest.raises(InputError, match="kind|color_width"):
        sensor_rig(*bad, np.random.default_rng(0))


def test_outside_view_is_the_strip_beyond_the_depth_cameras_field():
    """Cameras at one place, colour 90 deg wide, depth 60 deg: the strips are |x - cx| > fx tan(30 deg)."""
    color = Intrinsics(200, 100, 100.0, 100.0, 99.5, 49.5)
    depth = Intrinsics(100, 100, 50 / math.tan(math.radians(30)), 100.0, 49.5, 49.5)

    class Case:  # what outside_view reads of a synthetic frame
        rig = Rig(color, depth, np.eye(4))
        depth_color_m = np.full((100, 200), 2.0, np.float32)

    got = fill_rigs.outside_view(Case)
    # the depth image spans [-0.5, 99.5] px: |x_c - cx_c| / fx_c <= 50 / fx_d
    half = 100.0 * 50.0 / depth.fx
    x = np.arange(200) - 99.5
    np.testing.assert_array_equal(got, np.broadcast_to(np.abs(x) > half, got.shape))
    assert 0.2 < got.mean() < 0.5


def test_score_splits_inside_and_outside_and_counts_near_and_far():
    truth = np.full((2, 4), 2.0)
    filled = np.array([[2.1, 2.0, 1.9, 2.0], [2.0, 2.02, 2.0, 2.0]], np.float32)
    holes = np.array([[1, 1, 1, 0], [0, 1, 0, 0]], bool)
    outside = np.array([[1, 1, 0, 0], [0, 0, 0, 0]], bool)
    s = fill_rigs.score(filled, truth, holes, outside)
    assert s["mae_mm"] == pytest.approx((100 + 0 + 100 + 20) / 4, rel=1e-4)
    assert s["mae_outside_mm"] == pytest.approx(50, rel=1e-4)
    assert s["mae_inside_mm"] == pytest.approx(60, rel=1e-4)
    assert s["too_far_pct"] == pytest.approx(25) and s["too_near_pct"] == pytest.approx(25)


def test_cases_cycle_through_every_scene_and_rig():
    pairs = {(SCENE_KINDS[s % len(SCENE_KINDS)], tuple(RIG_KINDS)[s % len(RIG_KINDS)]) for s in fill_rigs.REPORT_SEEDS}
    assert len(pairs) == len(SCENE_KINDS) * len(RIG_KINDS)
    assert not set(fill_rigs.TUNING_SEEDS) & set(fill_rigs.REPORT_SEEDS)


def test_small_run_scores_every_method_and_the_default_beats_holding_the_depth():
    """Four report seeds, 128 px wide: the wide rigs leave strips outside the view, and there the default rule
    is nearer the truth than holding the depth just inside (the rule it replaced)."""
    rows = fill_rigs.run_fill_rigs(seeds=fill_rigs.REPORT_SEEDS[:4], color_width=128, render=False)
    methods = list(fill_rigs.default_methods())
    assert [r["method"] for r in rows[:len(methods)]] == methods
    by = {(r["seed"], r["method"]): r for r in rows}
    wide = [s for s in fill_rigs.REPORT_SEEDS[:4] if by[(s, "pcdof")]["outside_pct"] > 5]
    assert wide, "no case has holes outside the depth view"
    mean = {m: np.mean([by[(s, m)]["mae_outside_mm"] for s in wide]) for m in ("pcdof", "pcdof border=hold", "telea")}
    assert mean["pcdof"] < mean["pcdof border=hold"] < mean["telea"], mean
    table = fill_rigs.markdown_table(rows, "rig")
    assert "outside-view MAE" in table and "kinect-v2" in table


def test_rig_case_is_reproducible():
    a, b = rig_case(5, color_width=64), rig_case(5, color_width=64)
    assert a.metadata["rig"] == tuple(RIG_KINDS)[5 % 4] and a.metadata["scene_kind"] == SCENE_KINDS[5]
    np.testing.assert_array_equal(a.depth_m, b.depth_m)
    np.testing.assert_array_equal(a.color, b.color)


def test_cli_part_writes_its_section(tmp_path):
    from click.testing import CliRunner

    from pcdof.cli import main

    result = CliRunner().invoke(main, ["bench", "-o", str(tmp_path), "--only", "fill-rigs", "--quick"])
    assert result.exit_code == 0, result.output
    md = (tmp_path / "report.md").read_text()
    assert "## Hole filling on rigs of real devices" in md and "### Per rig" in md
    assert "outside-view MAE" in md and "Report seeds 1000-1003" in md


def test_fill_trace_says_what_the_border_rule_assumes():
    from pcdof.stages.fill import BORDER_ASSUMPTIONS, DEFAULT_BORDER, plan_fill

    text = plan_fill(np.array([[1.0, 0.0]], np.float32)).describe()
    assert f"border {DEFAULT_BORDER}: {BORDER_ASSUMPTIONS[DEFAULT_BORDER]}" in text
    assert "without preferring the farthest" in text
