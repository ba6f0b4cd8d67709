"""Public functions refuse bad arguments with the project's own errors, naming the argument.

Never a bare TypeError / ValueError / OverflowError from deep inside, and never a silent
acceptance of nonsense (a str or bool where a number belongs, a list where a name belongs).
"""

import numpy as np
import pytest

from pcdof import fill_depth, focus_depth_at, register_depth, run
from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.errors import InputError, LensError
from pcdof.lens import PaperLens, ThinLens
from pcdof.pipeline import render_from_depth

INTR = Intrinsics(16, 12, 15.0, 15.0, 7.5, 5.5)
COLOR = np.zeros((12, 16, 3), np.uint8)


def short_id(value):
    """Readable test ids for ints beyond the float range."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**300:
        return "-10**400" if value < 0 else "10**400"
    return None


def depth_plane(value=2.0):
    return np.full((12, 16), value, np.float32)


def frame():
    return RGBDFrame(COLOR, depth_plane(), Rig.registered(INTR))


# -------------------------------------------------------------------------------------- lenses


THIN_ARGS = ("focal_length_mm", "f_number", "focus_distance_m", "aperture_blades", "aperture_rotation_deg")
THIN_GOOD = (50, 1.8, 1.0, 6, 10.0)


@pytest.mark.parametrize("index,value", [
    (4, None), (4, "abc"), (4, 10**400), (4, -10**400), (4, float("nan")), (4, True), (4, 1j),
    (0, "50"), (0, True), (0, 10**400), (0, np.bool_(True)), (0, np.array([50.0])),
    (1, "1.8"), (1, False), (1, np.complex128(2)),
    (2, "1.0"), (2, True), (2, b"1"),
    (3, None), (3, "6"), (3, True), (3, 6.0),
], ids=short_id)
def test_thin_lens_refuses_non_numbers(index, value):
    args = list(THIN_GOOD)
    args[index] = value
    with pytest.raises(LensError, match=THIN_ARGS[index]):
        ThinLens(*args)


@pytest.mark.parametrize("name,value", [
    (name, value) for name in ("focus_distance_m", "sigma", "blur_sigma_px", "eq1_aperture", "max_range_m")
    for value in ("1.0", True, 10**400, None) if (name, value) != ("max_range_m", None)  # None: from the rig
], ids=short_id)
def test_paper_lens_refuses_non_numbers(name, value):
    kwargs = dict(focus_distance_m=1.0, sigma=0.3, blur_sigma_px=4.0, eq1_aperture=1.0, max_range_m=10.0)
    with pytest.raises(LensError, match=name):
        PaperLens(**{**kwargs, name: value})


def test_lenses_still_take_numpy_scalars():
    lens = ThinLens(np.float32(50), np.int64(2), np.float64(1.5), np.int32(6), np.float32(10))
    assert (lens.focal_length_mm, lens.f_number, lens.focus_distance_m) == (50.0, 2.0, 1.5)
    assert lens.aperture_blades == 6 and lens.aperture_rotation_deg == 10.0
    assert PaperLens(np.float32(1.0), sigma=np.float64(0.3), max_range_m=np.int16(8)).max_range_m == 8.0


@pytest.mark.parametrize("weight", [["eq2"], {"eq2": 1}, None, 2, "eq3"])
def test_paper_lens_weight_lists_the_choices(weight):
    with pytest.raises(LensError, match=r"weight must be one of \['eq1', 'eq2'\]"):
        PaperLens(1.0, weight=weight)


@pytest.mark.parametrize("depth", [[[1.0], [1.0, 2.0]], np.array([["a"]]), None, np.array([[object()]]),
                                   np.array([[True]]), np.array([[1 + 1j]])])
@pytest.mark.parametrize("method", ["coc_px", "signed_coc_px"])
def test_coc_refuses_non_numeric_depth(depth, method):
    with pytest.raises(InputError, match="depth_m"):
        getattr(ThinLens(50, 1.8, 1.0), method)(depth, 500)


@pytest.mark.parametrize("fx", ["500", True, None, [500], 10**400], ids=short_id)
def test_coc_refuses_bad_fx(fx):
    with pytest.raises(InputError, match="fx"):  # a CalibrationError
        ThinLens(50, 1.8, 1.0).coc_px(depth_plane(), fx)


def test_paper_alpha_refuses_non_numeric_depth():
    with pytest.raises(InputError, match="depth_m"):
        PaperLens(1.0).alpha([[1.0], [1.0, 2.0]], 10.0)


def test_coc_of_valid_depth_is_unchanged():
    lens = ThinLens(50, 2.0, 1.0)
    expected = lens.aperture_m * 500 * abs(1 / 1.0 - 1 / 2.0)
    np.testing.assert_allclose(lens.coc_px([[2.0, 0.0]], 500), [[expected, 0.0]], rtol=1e-6)
    np.testing.assert_allclose(lens.coc_px(np.array([2, 0], np.int32), 500), [expected, 0.0], rtol=1e-6)


# -------------------------------------------------------------------------------- focus_depth_at


@pytest.mark.parametrize("kwargs,name", [
    (dict(x="a"), "x"), (dict(x=None), "x"), (dict(x=True), "x"), (dict(x=10**400), "x"),
    (dict(y="a"), "y"), (dict(y=None), "y"), (dict(y=float("nan")), "y"),
    (dict(radius_px="a"), "radius_px"), (dict(radius_px=None), "radius_px"), (dict(radius_px=-1), "radius_px"),
    (dict(radius_px=2.5), "radius_px"), (dict(radius_px=True), "radius_px"),
    (dict(depth_m=np.array([["a"]])), "depth_m"), (dict(depth_m=np.array([[object()]])), "depth_m"),
    (dict(depth_m="depth.png"), "depth_m"), (dict(depth_m=[[1.0], [1.0, 2.0]]), "depth_m"),
], ids=short_id)
def test_focus_depth_at_refuses_bad_arguments(kwargs, name):
    args = dict(depth_m=depth_plane(), x=1, y=1, **{"radius_px": 7})
    args.update(kwargs)
    depth, x, y = args.pop("depth_m"), args.pop("x"), args.pop("y")
    with pytest.raises(InputError, match=name):
        focus_depth_at(depth, x, y, **args)


@pytest.mark.parametrize("radius_px,searched", [(7, 56), (0, 4), (3, 24), (10**400, 300)], ids=short_id)
def test_focus_depth_at_reports_the_radius_it_searched(radius_px, searched):
    with pytest.raises(InputError, match=rf"no known depth within {searched} px of focus pixel \(0, 0\)"):
        focus_depth_at(np.zeros((300, 300), np.float32), 0, 0, radius_px=radius_px)


def test_focus_depth_at_valid_input_is_unchanged():
    depth = np.zeros((40, 40), np.float32)
    depth[30, 30] = 3.0
    assert focus_depth_at(depth, 20, 20) == 3.0  # found at radius 14
    assert focus_depth_at(depth, np.float32(30), np.int64(30), radius_px=np.int8(0)) == 3.0
    assert focus_depth_at(depth, 30.4, 29.6, radius_px=0.0) == 3.0


# ------------------------------------------------------------------------------ names of choices


@pytest.mark.parametrize("call,name", [
    (lambda: run(frame(), ThinLens(50, 2, 1), method=["physical"]), "method"),
    (lambda: run(frame(), ThinLens(50, 2, 1), method=None), "method"),
    (lambda: run(frame(), ThinLens(50, 2, 1), fill_method=["telea"]), "fill_method"),
    (lambda: render_from_depth(COLOR, depth_plane(), ThinLens(50, 2, 1), 15.0, method=["paper"]), "method"),
    (lambda: fill_depth(np.array([[1.0, 0.0]]), None, method=["telea"]), "method"),
    (lambda: fill_depth(np.array([[1.0, 0.0]]), None, method={"telea"}), "method"),
], ids=["run-list", "run-None", "run-fill-list", "render_from_depth-list", "fill_depth-list", "fill_depth-set"])
def test_unhashable_method_names_list_the_choices(call, name):
    with pytest.raises(InputError, match=rf"{name} must be one of \["):
        call()


@pytest.mark.parametrize("option,value", [
    ("radius_px", "3"), ("radius_px", True), ("radius_px", 10**400), ("radius_px", None),
], ids=short_id)
def test_fill_options_refuse_non_numbers(option, value):
    with pytest.raises(InputError, match=option):
        fill_depth(np.array([[1.0, 0.0, 2.0]]), None, method="telea", **{option: value})


@pytest.mark.parametrize("focus_at", ["ab", (True, 1), (10**400, 1), (1, None), (1, 2, 3), 5], ids=short_id)
def test_run_refuses_bad_focus_at_before_any_stage(focus_at, monkeypatch):
    import pcdof.pipeline as pipeline

    def forbidden(*a, **k):
        raise AssertionError("a stage ran before focus_at was checked")

    monkeypatch.setattr(pipeline, "run_stages", forbidden)
    with pytest.raises(InputError, match="focus_at"):
        run(frame(), ThinLens(50, 2, 1), focus_at=focus_at)


def test_render_from_depth_refuses_ragged_depth():
    with pytest.raises(InputError, match="depth_filled_m"):
        render_from_depth(COLOR, [[1.0], [1.0, 2.0]], ThinLens(50, 2, 1), 15.0)


# ----------------------------------------------------------------------------------- frames, rigs


@pytest.mark.parametrize("n_invalid", ["x", -1, 1.5, None, True, [3]])
def test_frame_refuses_a_bad_invalid_depth_count(n_invalid):
    with pytest.raises(InputError, match="n_invalid_depth"):
        RGBDFrame(COLOR, depth_plane(), Rig.registered(INTR), n_invalid)


def test_frame_invalid_depth_count_still_adds_up():
    depth = depth_plane()
    depth[0, :3] = np.nan
    assert RGBDFrame(COLOR, depth, Rig.registered(INTR), np.int64(4)).n_invalid_depth == 7


@pytest.mark.parametrize("ratio,message", [
    ("a", "max_depth_ratio must be a number"), ("0.1", "max_depth_ratio must be a number"),
    (True, "max_depth_ratio must be a number"), ([0.1, 0.2], "max_depth_ratio must be a number"),
    (-1, "max_depth_ratio must be a finite number > 0"), (0, "max_depth_ratio must be a finite number > 0"),
    (float("nan"), "max_depth_ratio must be a finite number > 0"),
    (10**400, "max_depth_ratio must be a finite number > 0"),
], ids=short_id)
def test_register_depth_checks_the_ratio_for_a_registered_rig(ratio, message):
    with pytest.raises(InputError, match=message):
        register_depth(frame(), max_depth_ratio=ratio)


def test_register_depth_registered_rig_with_a_valid_ratio_is_a_copy():
    f = frame()
    out = register_depth(f, max_depth_ratio=np.float32(0.05))
    np.testing.assert_array_equal(out, f.depth_m)
    assert out is not f.depth_m
