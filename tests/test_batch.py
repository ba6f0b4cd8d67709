"""Batch rendering of sequences: discovery, TUM association, lens schedules, execution backends, resilience.

The sequences are generated here: a textured plane at 3 m and a textured box at 1 m moving to the
right, 64x48 pixels, depth as TUM-style 16-bit PNGs (5000 units per metre) with rgb.txt / depth.txt.
"""

from __future__ import annotations

import contextlib
import json
import math
import os

import cv2
import numpy as np
import pytest

from pcdof.batch import (
    EXIT_ALL_FAILED,
    EXIT_OK,
    EXIT_PARTIAL,
    associate,
    build_schedule,
    discover,
    interpolate_keyframes,
    load_rig,
    one_euro,
    parse_keyframes,
    read_tum_list,
    render_sequence,
    running_median,
    smooth_focus_track,
)
from pcdof.batch.runner import frame_name
from pcdof.errors import EXIT_CODES, ImageReadError, InputError, LensError
from pcdof.lens import PaperLens, ThinLens

W, H = 64, 48
FX = 60.0
PLANE_M, BOX_M = 3.0, 1.0
BOX = 14  # box side, pixels
T0 = 1305031102.175304


# ------------------------------------------------------------------------------------ test data
def calib_dict(*, depth_scale=None) -> dict:
    intr = {"width": W, "height": H, "fx": FX, "fy": FX, "cx": (W - 1) / 2, "cy": (H - 1) / 2,
            "distortion": [0, 0, 0, 0, 0]}
    d = {"color": intr, "depth": intr, "T_color_from_depth": np.eye(4).tolist()}
    if depth_scale is not None:
        d["depth_scale"] = depth_scale
    return d


def box_x0(i: int, moving: bool) -> int:
    return 6 + 6 * i if moving else 25


def scene(i: int, *, moving: bool = True, noise_seed: int | None = None):
    """Colour (H, W, 3) uint8 RGB and depth (H, W) float metres of frame *i*."""
    rng = np.random.default_rng(0)
    blocks = rng.integers(40, 216, (H // 4, W // 4, 3)).astype(np.float64)
    color = np.kron(blocks, np.ones((4, 4, 1)))
    depth = np.full((H, W), PLANE_M)
    x0, y0 = box_x0(i, moving), 17
    yy, xx = np.mgrid[0:BOX, 0:BOX]
    checker = np.where(((yy // 2) + (xx // 2)) % 2 == 0, 230.0, 25.0)
    color[y0:y0 + BOX, x0:x0 + BOX] = checker[..., None] * np.array([1.0, 0.8, 0.6])
    depth[y0:y0 + BOX, x0:x0 + BOX] = BOX_M
    if noise_seed is not None:
        nrng = np.random.default_rng(noise_seed)
        color = color + nrng.normal(0, 4.0, color.shape)
        depth = depth + nrng.normal(0, 0.004, depth.shape) * depth**2
    return np.clip(np.rint(color), 0, 255).astype(np.uint8), depth


def write_tum(root, n: int, *, moving=True, noisy=False, extra_color=True, calib=True, depth_offset=0.004):
    """A TUM RGB-D style folder; returns its path. Timestamps of depth lag colour by *depth_offset* s."""
    root = str(root)
    os.makedirs(os.path.join(root, "rgb"), exist_ok=True)
    os.makedirs(os.path.join(root, "depth"), exist_ok=True)
    rgb_lines = ["# color images", "# file: 'synthetic'", "# timestamp filename"]
    depth_lines = ["# depth maps", "# file: 'synthetic'", "# timestamp filename"]
    for i in range(n):
        tc, td = T0 + i / 30, T0 + i / 30 + depth_offset
        color, depth = scene(i, moving=moving, noise_seed=100 + i if noisy else None)
        cv2.imwrite(os.path.join(root, "rgb", f"{tc:.6f}.png"), color[:, :, ::-1])
        cv2.imwrite(os.path.join(root, "depth", f"{td:.6f}.png"), np.rint(depth * 5000).astype(np.uint16))
        rgb_lines.append(f"{tc:.6f} rgb/{tc:.6f}.png")
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
    if extra_color:  # a colour frame 0.5 frame periods after the last one, with no depth near it
        tc = T0 + (n - 0.5) / 30
        color, _ = scene(n - 1, moving=moving)
        cv2.imwrite(os.path.join(root, "rgb", f"{tc:.6f}.png"), color[:, :, ::-1])
        rgb_lines.append(f"{tc:.6f} rgb/{tc:.6f}.png")
    with open(os.path.join(root, "rgb.txt"), "w") as f:
        f.write("\n".join(rgb_lines) + "\n")
    with open(os.path.join(root, "depth.txt"), "w") as f:
        f.write("\n".join(depth_lines) + "\n")
    if calib:
        with open(os.path.join(root, "calib.json"), "w") as f:
            json.dump(calib_dict(), f)
    return root


def write_folders(root, names, *, moving=True):
    """A color/ + depth/ folder (depth in mm, calib.json with depth_scale 0.001); one frame per name."""
    root = str(root)
    for sub in ("color", "depth"):
        os.makedirs(os.path.join(root, sub), exist_ok=True)
    for i, name in enumerate(names):
        color, depth = scene(i, moving=moving)
        cv2.imwrite(os.path.join(root, "color", name), color[:, :, ::-1])
        cv2.imwrite(os.path.join(root, "depth", name), np.rint(depth * 1000).astype(np.uint16))
    with open(os.path.join(root, "calib.json"), "w") as f:
        json.dump(calib_dict(depth_scale=0.001), f)
    return root


def file_bytes(folder):
    """{relative path: bytes} of every file under *folder*."""
    out = {}
    for dirpath, _, names in os.walk(folder):
        for n in names:
            with open(os.path.join(dirpath, n), "rb") as f:
                out[os.path.relpath(os.path.join(dirpath, n), folder)] = f.read()
    return out


def lens(**kw):
    opts = {"focal_length_mm": 200.0, "f_number": 1.4, "focus_distance_m": BOX_M}
    opts.update(kw)
    return ThinLens(**opts)


def read_png(path):
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img[:, :, ::-1] if img.ndim == 3 else img


def sharpness(img, region) -> float:
    """Mean squared Laplacian (grey) inside region = (y0, y1, x0, x1), a standard focus measure."""
    grey = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY).astype(np.float64)
    lap = cv2.Laplacian(grey, cv2.CV_64F)
    y0, y1, x0, x1 = region
    return float(np.mean(lap[y0:y1, x0:x1] ** 2))


def tum_associate_reference(first: dict, second: dict, offset: float, max_difference: float):
    """TUM RGB-D benchmark's associate.py algorithm, transcribed (O(n m))."""
    first_keys = list(first)
    second_keys = list(second)
    potential = [(abs(a - (b + offset)), a, b) for a in first_keys for b in second_keys
                 if abs(a - (b + offset)) < max_difference]
    potential.sort()
    matches = []
    for _, a, b in potential:
        if a in first_keys and b in second_keys:
            first_keys.remove(a)
            second_keys.remove(b)
            matches.append((a, b))
    matches.sort()
    return matches


# ------------------------------------------------------------------------------------ association
class TestAssociate:
    @pytest.mark.parametrize("seed", range(6))
    def test_matches_tum_associate_py(self, seed):
        rng = np.random.default_rng(seed)
        a = np.sort(rng.uniform(0, 3, rng.integers(5, 60)))
        b = np.sort(rng.uniform(0, 3, rng.integers(5, 60)))
        offset = float(rng.uniform(-0.01, 0.01))
        tol = float(rng.choice([0.01, 0.02, 0.05]))
        got = associate(a, b, max_difference=tol, offset=offset)
        ref = tum_associate_reference({float(t): i for i, t in enumerate(a)},
                                      {float(t): j for j, t in enumerate(b)}, offset, tol)
        assert [(float(a[i]), float(b[j])) for i, j in got] == ref

    def test_nearest_within_tolerance_each_depth_once(self):
        color = [0.000, 0.033, 0.066, 0.100]
        depth = [0.005, 0.030, 0.031, 0.300]  # 0.030 and 0.031 compete for colour 0.033
        pairs = associate(color, depth, max_difference=0.02)
        assert pairs.tolist() == [[0, 0], [1, 2]]  # 0.031 is nearer 0.033; 0.030 is > 0.02 from 0.066
        # depth 0.030 is then free but 0.036 from colour 0.066: no partner; colour 0.100 has none either
        pairs = associate(color, depth, max_difference=0.04)
        assert pairs.tolist() == [[0, 0], [1, 2], [2, 1]]

    def test_tolerance_is_strict_and_validated(self):
        assert associate([0.0], [0.02], max_difference=0.0200001).tolist() == [[0, 0]]
        assert associate([0.0], [0.03], max_difference=0.02).shape == (0, 2)
        with pytest.raises(InputError, match="max_difference"):
            associate([0.0], [0.0], max_difference=0)

    def test_tum_folder_pairs_and_counts_unmatched(self, tmp_path):
        root = write_tum(tmp_path / "seq", 5)
        seq = discover(root)
        assert seq.layout == "tum" and len(seq) == 5
        assert seq.unmatched_color == 1 and seq.unmatched_depth == 0
        for i, p in enumerate(seq.pairs):
            assert p.color_time == pytest.approx(T0 + i / 30)
            assert p.depth_time - p.color_time == pytest.approx(0.004, abs=1e-5)  # float64 at 1.3e9 s: ~1e-6 s steps
            assert os.path.isfile(p.color) and os.path.isfile(p.depth)
        assert [p.color for p in discover(os.path.join(root, "rgb.txt")).pairs] == [p.color for p in seq.pairs]
        # a tolerance below the 4 ms lag pairs nothing
        with pytest.raises(InputError, match="no colour/depth pairs"):
            discover(root, max_difference=0.003)

    def test_tum_list_parsing(self, tmp_path):
        f = tmp_path / "rgb.txt"
        f.write_text("# comment\n\n1.5 rgb/a.png\n2.5\trgb/b.png\n")
        assert read_tum_list(str(f)) == [(1.5, str(tmp_path / "rgb" / "a.png")), (2.5, str(tmp_path / "rgb" / "b.png"))]
        f.write_text("abc rgb/a.png\n")
        with pytest.raises(InputError, match=r"rgb.txt:1"):
            read_tum_list(str(f))


# ------------------------------------------------------------------------------------ discovery
def touch_images(folder, names):
    os.makedirs(folder, exist_ok=True)
    for n in names:
        cv2.imwrite(os.path.join(folder, n), np.zeros((4, 4), np.uint8))


class TestDiscover:
    def test_color_and_depth_folders_by_stem_in_natural_order(self, tmp_path):
        touch_images(tmp_path / "color", ["2.png", "10.png", "1.png", "7.png"])
        touch_images(tmp_path / "depth", ["1.png", "2.png", "10.png", "9.png"])
        seq = discover(str(tmp_path))
        assert seq.layout == "folders"
        assert [p.key for p in seq.pairs] == ["1", "2", "10"]
        assert all(os.path.basename(p.color) == os.path.basename(p.depth) for p in seq.pairs)
        assert (seq.unmatched_color, seq.unmatched_depth) == (1, 1)

    def test_folders_by_number_when_stems_differ(self, tmp_path):
        touch_images(tmp_path / "rgb", ["frame-0001.jpg", "frame-0002.jpg"])
        touch_images(tmp_path / "depth", ["depth-1.png", "depth-2.png"])
        seq = discover(str(tmp_path))
        assert [(os.path.basename(p.color), os.path.basename(p.depth)) for p in seq.pairs] == [
            ("frame-0001.jpg", "depth-1.png"), ("frame-0002.jpg", "depth-2.png")]

    def test_suffix_layout(self, tmp_path):
        touch_images(tmp_path, ["a_color.png", "a_depth.png", "b_rgb.png", "b_depth.png", "c_depth.png", "x.png"])
        seq = discover(str(tmp_path))
        assert seq.layout == "suffixes"
        assert [p.key for p in seq.pairs] == ["a", "b"]
        assert seq.unmatched_depth == 1

    def test_list_file_two_and_four_columns(self, tmp_path):
        touch_images(tmp_path / "imgs", ["c 1.png", "d1.png"])
        lst = tmp_path / "frames.txt"
        lst.write_text("# colour depth\n'imgs/c 1.png' imgs/d1.png\n1.0 imgs/c1.png 1.01 imgs/d1.png\n")
        seq = discover(str(lst))
        assert seq.layout == "list" and len(seq) == 2
        assert seq.pairs[0].color == str(tmp_path / "imgs" / "c 1.png")
        assert seq.pairs[1].color_time == 1.0 and seq.pairs[1].depth_time == 1.01
        lst.write_text("only_one_column.png\n")
        with pytest.raises(InputError, match="frames.txt:1"):
            discover(str(lst))

    def test_list_file_quotes_commas_and_hashes_inside_names(self, tmp_path):
        lst = tmp_path / "takes" / "frames.txt"
        lst.parent.mkdir()
        lst.write_text('# colour depth\n'
                       '"../my take/c/f#3.png" "../my take/d/f,3.png"\n'
                       'take#1_c.png take#1_d.png  # a comment after the fields\n'
                       "a.png,b.png\n"
                       "c.png\td.png\n"
                       "  #an indented comment\n")
        seq = discover(str(lst))
        got = [(os.path.relpath(p.color, tmp_path), os.path.relpath(p.depth, tmp_path)) for p in seq.pairs]
        assert got == [(os.path.join("my take", "c", "f#3.png"), os.path.join("my take", "d", "f,3.png")),
                       (os.path.join("takes", "take#1_c.png"), os.path.join("takes", "take#1_d.png")),
                       (os.path.join("takes", "a.png"), os.path.join("takes", "b.png")),
                       (os.path.join("takes", "c.png"), os.path.join("takes", "d.png"))]
        lst.write_text('"unclosed.png d.png\n')
        with pytest.raises(InputError, match=r"frames.txt:1: no closing quotation"):
            discover(str(lst))

    def test_ambiguous_and_missing(self, tmp_path):
        touch_images(tmp_path / "color", ["1.png", "1.jpg"])
        touch_images(tmp_path / "depth", ["1.png"])
        with pytest.raises(InputError, match="both pair"):
            discover(str(tmp_path))
        with pytest.raises(ImageReadError, match="does not exist"):
            discover(str(tmp_path / "nope"))
        os.makedirs(tmp_path / "empty")
        with pytest.raises(InputError, match="no colour/depth pairs"):
            discover(str(tmp_path / "empty"))


class TestLoadRig:
    def test_tum_default_scale_unless_the_calibration_states_one(self, tmp_path):
        root = write_tum(tmp_path / "seq", 2)
        seq = discover(root)
        assert load_rig(seq).depth_scale == pytest.approx(1 / 5000)
        other = tmp_path / "calib_mm.json"
        other.write_text(json.dumps(calib_dict(depth_scale=0.001)))
        assert load_rig(seq, str(other)).depth_scale == pytest.approx(0.001)
        assert load_rig(seq, str(other), depth_scale=0.0005).depth_scale == pytest.approx(0.0005)

    def test_missing_calibration_is_named(self, tmp_path):
        root = write_tum(tmp_path / "seq", 2, calib=False)
        with pytest.raises(InputError, match="--calib"):
            load_rig(discover(root))


# ------------------------------------------------------------------------------------ schedules
class TestKeyframes:
    def test_parse(self):
        assert parse_keyframes("50:3.0, 0:1.2") == ((0, 1.2), (50, 3.0))
        for bad, msg in (("0:1,0:2", "more than once"), ("1.5:2", "integer"), ("0:-1", "> 0"), ("x", "FRAME:VALUE"),
                         ("", "FRAME:VALUE")):
            with pytest.raises(InputError, match=msg):
                parse_keyframes(bad)

    def test_linear_matches_np_interp_and_holds_ends(self):
        keys = [(3, 1.2), (10, 3.0), (14, 2.0)]
        got = interpolate_keyframes(keys, 20)
        np.testing.assert_allclose(got, np.interp(np.arange(20), [3, 10, 14], [1.2, 3.0, 2.0]), rtol=0, atol=1e-12)
        assert got[0] == 1.2 and got[-1] == 2.0

    def test_smoothstep(self):
        got = interpolate_keyframes([(0, 1.0), (10, 3.0)], 11, easing="smoothstep")
        assert got[0] == 1.0 and got[10] == 3.0 and got[5] == pytest.approx(2.0)
        # eased: slower than linear near the keyframes, monotone throughout
        assert got[1] - got[0] < 0.2 * 0.5 and np.all(np.diff(got) > 0)
        with pytest.raises(InputError, match="easing"):
            interpolate_keyframes([(0, 1.0)], 3, easing="cubic")

    def test_schedule_lens_per_frame(self):
        s = build_schedule(lens(), 6, focus_keyframes=[(0, 1.0), (5, 3.0)], f_number_keyframes=[(0, 2.0), (5, 4.0)])
        assert s.lens_at(0) == lens(focus_distance_m=1.0, f_number=2.0)
        assert s.lens_at(5).focus_distance_m == pytest.approx(3.0) and s.lens_at(5).f_number == pytest.approx(4.0)
        with pytest.raises(LensError, match="paper"):
            build_schedule(PaperLens(1.0), 3, f_number_keyframes=[(0, 2.0)])
        with pytest.raises(LensError, match="exclude"):
            build_schedule(lens(), 3, focus_keyframes=[(0, 1.0)], focus_track_m=np.ones(3))


class TestFocusSmoothing:
    def test_running_median_matches_numpy(self):
        rng = np.random.default_rng(3)
        x = rng.normal(size=40)
        x[[4, 5, 17]] = np.nan
        got = running_median(x, 5)
        for i in range(40):
            win = x[max(0, i - 4): i + 1]
            win = win[np.isfinite(win)]
            assert got[i] == pytest.approx(np.median(win))

    def test_one_euro_is_exact_on_constants_and_smooths_noise(self):
        np.testing.assert_array_equal(one_euro(np.full(30, 0.7), rate_hz=30), np.full(30, 0.7))
        rng = np.random.default_rng(0)
        noisy = 1.0 + rng.normal(0, 0.05, 300)
        out = one_euro(noisy, rate_hz=30, min_cutoff_hz=0.5, beta=0.0)
        assert np.std(out[60:]) < 0.25 * np.std(noisy)
        # first-order low-pass with cut-off fc at 30 Hz: alpha = 1 / (1 + 30 / (2 pi fc))
        step = one_euro(np.r_[0.0, np.ones(5)], rate_hz=30, min_cutoff_hz=0.5, beta=0.0)
        a = 1 / (1 + 30 / (2 * math.pi * 0.5))
        np.testing.assert_allclose(step[1:], 1 - (1 - a) ** np.arange(1, 6), rtol=1e-12)

    def test_track_is_causal_flicker_free_and_follows_a_step(self):
        rng = np.random.default_rng(5)
        true = np.r_[np.full(60, 2.0), np.full(60, 1.0)]
        raw = true + rng.normal(0, 0.01, 120) * true**2
        raw[[10, 30, 31]] = [0.4, np.nan, 6.0]  # spikes and a dropout
        track = smooth_focus_track(raw, rate_hz=30)
        # causal: the first k frames are smoothed the same whatever follows (so --limit k agrees with a full run)
        np.testing.assert_array_equal(smooth_focus_track(raw[:45], rate_hz=30), track[:45])
        # still subject: far less frame-to-frame change than the measurements, spikes gone
        assert np.abs(np.diff(track[15:60])).max() < 0.2 * np.nanmax(np.abs(np.diff(raw[15:60])))
        assert np.abs(track[5:60] - 2.0).max() < 0.05
        # moving subject: reaches the new distance within 1 s
        assert abs(track[-1] - 1.0) < 0.02 and abs(track[60 + 30] - 1.0) < 0.05

    def test_all_unknown_is_an_error(self):
        with pytest.raises(InputError, match="no known depth"):
            smooth_focus_track(np.full(4, np.nan))


# ------------------------------------------------------------------------------------ running batches
N = 6


@pytest.fixture(scope="module")
def tum_seq(tmp_path_factory):
    return write_tum(tmp_path_factory.mktemp("tum") / "seq", N)


@pytest.fixture(scope="module")
def serial_run(tum_seq, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("serial"))
    rep = render_sequence(tum_seq, out, lens=lens(), save_depth=True, workers=1)
    return out, rep


def output_bytes(folder, n=N, depth=True):
    out = {}
    for i in range(n):
        names = [frame_name(i)] + ([os.path.join("depth", frame_name(i))] if depth else [])
        for name in names:
            with open(os.path.join(folder, name), "rb") as f:
                out[name] = f.read()
    return out


class TestRunBatch:
    def test_serial_outputs_and_report(self, serial_run, tum_seq):
        out, rep = serial_run
        assert rep["exit_code"] == EXIT_OK and rep["status"] == "ok"
        assert rep["totals"]["ok"] == N and rep["totals"]["failed"] == 0
        assert rep["input"]["unmatched_color"] == 1
        with open(os.path.join(out, "report.json")) as f:
            on_disk = json.load(f)
        assert on_disk["totals"] == rep["totals"] and len(on_disk["frames"]) == N
        rec = on_disk["frames"][2]
        assert rec["output"] == frame_name(2) and rec["color"].startswith("rgb/")
        assert rec["focus_distance_m"] == BOX_M and rec["f_number"] == 1.4 and rec["seconds"] > 0
        assert rec["skipped_stages"]["register"]  # the TUM rig is registered: the pipeline skipped that stage
        assert "numpy" in on_disk["versions"]
        # outputs: a blurred plane, a sharp box; depth = registered, filled depth (16-bit mm)
        img = read_png(os.path.join(out, frame_name(2)))
        src, depth = scene(2)
        x0 = box_x0(2, True)
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        box = (19, 17 + BOX - 2, x0 + 2, x0 + BOX - 2)
        np.testing.assert_allclose(sharpness(img, box), sharpness(src, box), rtol=0.15)
        plane = (2, 14, 2, W - 2)
        assert sharpness(img, plane) < 0.3 * sharpness(src, plane)
        d = read_png(os.path.join(out, "depth", frame_name(2)))
        assert d.dtype == np.uint16
        np.testing.assert_allclose(d / 1000.0, depth, atol=0.002)
        assert not any(name.endswith(".tmp") or ".partial" in name for name in os.listdir(out))

    def test_two_local_processes_identical_to_serial(self, serial_run, tum_seq, tmp_path):
        rep = render_sequence(tum_seq, str(tmp_path), lens=lens(), save_depth=True, workers=2)
        assert rep["exit_code"] == EXIT_OK and rep["backend"]["kind"] == "processes" and rep["backend"]["workers"] == 2
        pids = [int(r["worker"].rsplit(":", 1)[1]) for r in rep["frames"]]
        assert pids[0] == os.getpid() and os.getpid() not in pids[1:]  # frame 0 warms numba here, the rest in workers
        assert output_bytes(str(tmp_path)) == output_bytes(serial_run[0])

    def test_dask_local_cluster_identical_to_serial(self, serial_run, tum_seq, tmp_path):
        distributed = pytest.importorskip("distributed")
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                      dashboard_address=None) as cluster:
            rep = render_sequence(tum_seq, str(tmp_path), lens=lens(), save_depth=True,
                                  scheduler=cluster.scheduler_address)
        assert rep["exit_code"] == EXIT_OK and rep["backend"]["kind"] == "dask"
        assert os.getpid() not in {int(r["worker"].rsplit(":", 1)[1]) for r in rep["frames"]}  # ran in the cluster
        assert output_bytes(str(tmp_path)) == output_bytes(serial_run[0])
        frames = {r["index"]: r for r in rep["frames"]}
        serial = {r["index"]: r for r in serial_run[1]["frames"]}
        for i in range(N):
            for key in ("color", "depth", "output", "focus_distance_m", "f_number", "skipped_stages", "status"):
                assert frames[i][key] == serial[i][key]

    def test_corrupt_frame_is_reported_and_the_rest_written(self, tmp_path):
        root = write_tum(tmp_path / "seq", N)
        seq = discover(root)
        bad = seq.pairs[3].color
        data = open(bad, "rb").read()
        with open(bad, "wb") as f:
            f.write(data[: len(data) // 2])  # truncated PNG
        out = str(tmp_path / "out")
        rep = render_sequence(root, out, lens=lens(), workers=2)
        assert rep["exit_code"] == EXIT_PARTIAL and rep["status"] == "partial"
        rec = rep["frames"][3]
        assert rec["status"] == "failed" and rec["error"].startswith("ImageReadError")
        assert os.path.basename(bad) in rec["error"]
        assert not os.path.exists(os.path.join(out, frame_name(3)))
        for i in set(range(N)) - {3}:
            assert rep["frames"][i]["status"] == "ok" and os.path.isfile(os.path.join(out, frame_name(i)))
        with open(os.path.join(out, "report.json")) as f:
            assert json.load(f)["frames"][3]["error"] == rec["error"]

    def test_nothing_succeeds(self, tmp_path):
        root = write_tum(tmp_path / "seq", 2)
        for p in discover(root).pairs:
            open(p.depth, "wb").close()
        rep = render_sequence(root, str(tmp_path / "out"), lens=lens(), workers=1)
        assert rep["exit_code"] == EXIT_ALL_FAILED and rep["totals"]["ok"] == 0

    def test_exit_codes_are_distinct_from_the_error_codes(self):
        taken = set(EXIT_CODES.values()) | {1, 2}
        assert len({EXIT_OK, EXIT_PARTIAL, EXIT_ALL_FAILED}) == 3
        assert not ({EXIT_PARTIAL, EXIT_ALL_FAILED} & taken) and EXIT_OK == 0

    def test_resume_writes_only_missing_frames(self, tum_seq, tmp_path):
        out = str(tmp_path)
        first = render_sequence(tum_seq, out, lens=lens(), workers=1, limit=3)
        assert first["totals"]["frames"] == 3 and first["exit_code"] == EXIT_OK
        paths = [os.path.join(out, frame_name(i)) for i in range(N)]
        os.utime(paths[0], (1_000_000, 1_000_000))  # an old mtime that a rewrite would change
        os.remove(paths[1])  # as if interrupted before frame 1 was written
        mtimes = {i: os.stat(paths[i]).st_mtime_ns for i in (0, 2)}
        rep = render_sequence(tum_seq, out, lens=lens(), workers=1, resume=True)
        status = [(r["status"], r["skipped"]) for r in rep["frames"]]
        assert status == [("skipped", "resume"), ("ok", None), ("skipped", "resume")] + [("ok", None)] * (N - 3)
        assert {i: os.stat(paths[i]).st_mtime_ns for i in (0, 2)} == mtimes
        assert rep["exit_code"] == EXIT_OK and all(os.path.isfile(p) for p in paths)
        # resuming under different settings would mix two renderings: refused
        with pytest.raises(InputError, match="different settings"):
            render_sequence(tum_seq, out, lens=lens(f_number=2.8), workers=1, resume=True)

    def test_resumed_frames_equal_a_fresh_run(self, tum_seq, serial_run, tmp_path):
        out = str(tmp_path)
        render_sequence(tum_seq, out, lens=lens(), save_depth=True, workers=1, limit=2)
        render_sequence(tum_seq, out, lens=lens(), save_depth=True, workers=2, resume=True)
        assert output_bytes(out) == output_bytes(serial_run[0])

    def test_focus_pull_video(self, tmp_path):
        imageio = pytest.importorskip("imageio.v2")
        n = 6
        root = write_tum(tmp_path / "seq", n, moving=False)
        out = str(tmp_path / "out")
        video = str(tmp_path / "pull.mp4")
        rep = render_sequence(root, out, lens=lens(), focus_keyframes="0:1.0,5:3.0", easing="linear",
                              video=video, fps=10, workers=2)
        assert rep["exit_code"] == EXIT_OK
        with open(os.path.join(out, "report.json")) as f:
            frames = json.load(f)["frames"]
        focus = [r["focus_distance_m"] for r in frames]
        np.testing.assert_allclose(focus, np.interp(np.arange(n), [0, 5], [1.0, 3.0]), rtol=0, atol=1e-12)
        reader = imageio.get_reader(video, "ffmpeg")
        try:
            decoded = [f for f in reader]
            meta = reader.get_meta_data()
        finally:
            reader.close()
        assert len(decoded) == n and decoded[0].shape == (H, W, 3)
        assert meta["fps"] == pytest.approx(10)
        # the video shows the rendered frames (H.264 4:2:0 is lossy: compare loosely)
        first = read_png(os.path.join(out, frame_name(0))).astype(float)
        assert np.abs(decoded[0].astype(float) - first).mean() < 6
        # sharpness moves from the near box to the far plane
        x0 = box_x0(0, False)
        box = (19, 17 + BOX - 2, x0 + 2, x0 + BOX - 2)
        plane = (2, 14, 2, W - 2)
        imgs = [read_png(os.path.join(out, frame_name(i))) for i in range(n)]
        ratio = [sharpness(im, box) / sharpness(im, plane) for im in imgs]
        assert ratio[0] > 4 * ratio[-1]
        assert sharpness(imgs[0], box) > 2 * sharpness(imgs[-1], box)
        assert sharpness(imgs[-1], plane) > 2 * sharpness(imgs[0], plane)

    def test_video_of_odd_sized_frames_is_padded(self, tmp_path):
        imageio = pytest.importorskip("imageio.v2")
        from pcdof.batch import write_video

        frames = [np.full((7, 9, 3), 40 * k, np.uint8) for k in range(4)]
        info = write_video(frames, str(tmp_path / "odd.mp4"), fps=5)
        assert (info["width"], info["height"], info["frames"]) == (10, 8, 4)
        reader = imageio.get_reader(str(tmp_path / "odd.mp4"), "ffmpeg")
        decoded = [f for f in reader]  # (len() of an ffmpeg reader is inf)
        reader.close()
        assert len(decoded) == 4 and decoded[0].shape == (8, 10, 3)
        assert abs(float(decoded[3].mean()) - 120) < 4

    def test_static_scene_is_temporally_stable(self, tmp_path):
        n = 5
        root = write_tum(tmp_path / "seq", n, moving=False, noisy=True)
        out = str(tmp_path / "out")
        rep = render_sequence(root, out, lens=lens(), workers=1)
        assert rep["exit_code"] == EXIT_OK
        seq = discover(root)
        inputs = [read_png(p.color).astype(float) for p in seq.pairs]
        outputs = [read_png(os.path.join(out, frame_name(i))).astype(float) for i in range(n)]
        d_in = [np.abs(b - a).mean() for a, b in zip(inputs, inputs[1:])]
        d_out = [np.abs(b - a).mean() for a, b in zip(outputs, outputs[1:])]
        assert max(d_out) <= max(d_in) and np.mean(d_out) <= np.mean(d_in)
        # the in-focus box and its edges, where depth noise could move the blur boundary from frame to frame
        x0 = box_x0(0, False)
        win = (slice(15, 19 + BOX), slice(x0 - 2, x0 + BOX + 2))
        d_in = [np.abs(b[win] - a[win]).mean() for a, b in zip(inputs, inputs[1:])]
        d_out = [np.abs(b[win] - a[win]).mean() for a, b in zip(outputs, outputs[1:])]
        assert max(d_out) <= max(d_in)

    def test_followed_focus_is_steadier_than_the_measurement(self, tmp_path):
        n = 8
        root = write_tum(tmp_path / "seq", n, moving=False, noisy=True)
        x = box_x0(0, False) + BOX // 2
        rep = render_sequence(root, str(tmp_path / "out"), lens=lens(), focus_at=(x, 17 + BOX // 2), workers=1)
        raw = np.array([r["focus_measured_m"] for r in rep["frames"]])
        used = np.array([r["focus_distance_m"] for r in rep["frames"]])
        np.testing.assert_allclose(raw, BOX_M, atol=0.01)
        np.testing.assert_allclose(used, BOX_M, atol=0.01)
        assert np.abs(np.diff(used)).max() < np.abs(np.diff(raw)).max()
        # the focus of a prefix does not depend on later frames
        rep3 = render_sequence(root, str(tmp_path / "out3"), lens=lens(), focus_at=(x, 17 + BOX // 2), limit=3)
        assert [r["focus_distance_m"] for r in rep3["frames"]] == list(used[:3])

    def test_unregistered_rig_focus_pass_and_registration(self, tmp_path):
        # depth camera at half resolution, 2.5 cm to the side: each frame is registered (not skipped)
        d_intr = {"width": W // 2, "height": H // 2, "fx": FX / 2, "fy": FX / 2, "cx": (W / 2 - 1) / 2,
                  "cy": (H / 2 - 1) / 2, "distortion": [0, 0, 0, 0, 0]}
        calib = calib_dict(depth_scale=0.001)
        calib["depth"] = d_intr
        T = np.eye(4)
        T[0, 3] = -0.025
        calib["T_color_from_depth"] = T.tolist()
        for i in range(3):
            color, _ = scene(i)
            depth = np.full((H // 2, W // 2), 2000, np.uint16)  # a wall at 2 m, seen by the depth camera
            os.makedirs(tmp_path / "color", exist_ok=True)
            os.makedirs(tmp_path / "depth", exist_ok=True)
            cv2.imwrite(str(tmp_path / "color" / f"{i:03d}.png"), color[:, :, ::-1])
            cv2.imwrite(str(tmp_path / "depth" / f"{i:03d}.png"), depth)
        (tmp_path / "calib.json").write_text(json.dumps(calib))
        rep = render_sequence(str(tmp_path), str(tmp_path / "out"), lens=lens(), focus_at=(W / 2, H / 2),
                              save_depth=True, workers=1)
        assert rep["exit_code"] == EXIT_OK and rep["input"]["layout"] == "folders"
        for r in rep["frames"]:
            assert "register" not in r["skipped_stages"] and r["stages"]["register"] > 0
            assert r["focus_measured_m"] == pytest.approx(2.0, abs=0.005)
            assert r["focus_distance_m"] == pytest.approx(2.0, abs=0.005)
        d = read_png(tmp_path / "out" / "depth" / frame_name(1))
        assert d.shape == (H, W) and np.median(d) == 2000

    def test_invalid_arguments(self, tum_seq, tmp_path):
        with pytest.raises(InputError, match="workers"):
            render_sequence(tum_seq, str(tmp_path), lens=lens(), workers=0)
        with pytest.raises(InputError, match="outside the colour image"):
            render_sequence(tum_seq, str(tmp_path), lens=lens(), focus_at=(W + 5, 3))
        with pytest.raises(InputError, match="video"):
            render_sequence(tum_seq, str(tmp_path), lens=lens(), video=str(tmp_path / "x.gif"))
        with pytest.raises(InputError, match="limit"):
            render_sequence(tum_seq, str(tmp_path), lens=lens(), limit=0)

    def test_outputs_that_would_overwrite_inputs_are_refused(self, tmp_path):
        root = write_folders(tmp_path / "seqin", ["frame_000000.png", "frame_000001.png"])
        before = file_bytes(root)
        # -o = the input folder: its depth/ is the input's depth/
        cases = [({"output_dir": root, "save_depth": True}, "depth/frame_000000.png"),
                 ({"output_dir": os.path.join(root, "color")}, "color/frame_000000.png"),
                 ({"output_dir": str(tmp_path / "out"), "video": os.path.join(root, "color", "frame_000001.png")},
                  "color/frame_000001.png")]
        os.symlink(os.path.join(root, "depth"), tmp_path / "link")  # the same folder under another name
        cases.append(({"output_dir": str(tmp_path / "link")}, "depth/frame_000000.png"))
        for kw, named in cases:
            with pytest.raises(InputError, match=f"overwrite the input file .*{named}"):
                render_sequence(root, lens=lens(), workers=1, **kw)
            assert file_bytes(root) == before and not (tmp_path / "out").exists()
        # the input folder itself is fine where no name collides
        rep = render_sequence(root, root, lens=lens(), workers=1)
        assert rep["exit_code"] == EXIT_OK and os.path.isfile(os.path.join(root, frame_name(1)))
        assert {k: v for k, v in file_bytes(root).items() if k in before} == before

    def test_a_failed_frame_leaves_no_output_of_an_earlier_run(self, tmp_path):
        root = write_tum(tmp_path / "seq", 3)
        out = str(tmp_path / "out")
        assert render_sequence(root, out, lens=lens(f_number=1.8), save_depth=True, workers=1)["exit_code"] == EXIT_OK
        depth = discover(root).pairs[1].depth
        good = open(depth, "rb").read()
        with open(depth, "wb") as f:
            f.write(b"not a png")
        rep = render_sequence(root, out, lens=lens(f_number=8.0), save_depth=True, workers=1)
        assert rep["exit_code"] == EXIT_PARTIAL and rep["frames"][1]["status"] == "failed"
        assert not os.path.exists(os.path.join(out, frame_name(1)))  # not the f/1.8 image
        assert not os.path.exists(os.path.join(out, "depth", frame_name(1)))
        # resume renders the failed frame (its input repaired), keeps the others
        with open(depth, "wb") as f:
            f.write(good)
        rep = render_sequence(root, out, lens=lens(f_number=8.0), save_depth=True, workers=1, resume=True)
        assert [(r["status"], r["skipped"]) for r in rep["frames"]] == [
            ("skipped", "resume"), ("ok", None), ("skipped", "resume")]

    def test_resume_refuses_the_frames_of_another_list_file(self, tmp_path):
        for take in ("a", "b"):
            write_folders(tmp_path / take, [f"{i}.png" for i in range(6)], moving=take == "a")
        (tmp_path / "calib.json").write_text(json.dumps(calib_dict(depth_scale=0.001)))
        lines = {take: [f"{take}/color/{i}.png {take}/depth/{i}.png" for i in range(6)] for take in ("a", "b")}
        (tmp_path / "takeA.txt").write_text("\n".join(lines["a"][:4]) + "\n")
        (tmp_path / "takeB.txt").write_text("\n".join(lines["b"]) + "\n")
        (tmp_path / "takeA6.txt").write_text("\n".join(lines["a"]) + "\n")
        out = str(tmp_path / "out")
        assert render_sequence(str(tmp_path / "takeA.txt"), out, lens=lens(), workers=1)["exit_code"] == EXIT_OK
        first = file_bytes(out)
        with pytest.raises(InputError, match=r"--resume: frame 0 .* a/color/0.png .* not b/color/0.png"):
            render_sequence(str(tmp_path / "takeB.txt"), out, lens=lens(), workers=1, resume=True)
        assert file_bytes(out) == first
        # the same takes, longer: the first four frames are kept
        rep = render_sequence(str(tmp_path / "takeA6.txt"), out, lens=lens(), workers=1, resume=True)
        assert [r["status"] for r in rep["frames"]] == ["skipped"] * 4 + ["ok"] * 2

    def test_video_fills_failed_frames_at_the_start(self, tmp_path):
        imageio = pytest.importorskip("imageio.v2")
        root = write_tum(tmp_path / "seq", 6)
        pairs = discover(root).pairs
        for i in (0, 1, 4):
            open(pairs[i].color, "wb").close()
        out, video = str(tmp_path / "out"), str(tmp_path / "v.mp4")
        rep = render_sequence(root, out, lens=lens(), video=video, workers=1)
        assert rep["exit_code"] == EXIT_PARTIAL
        assert rep["video"]["frames"] == 6 and rep["video"]["held_frames"] == [0, 1, 4]
        assert rep["video"]["held_from"] == [[0, 2], [1, 2], [4, 3]]
        reader = imageio.get_reader(video, "ffmpeg")
        decoded = [f.astype(float) for f in reader]
        reader.close()
        assert len(decoded) == 6
        shown = [read_png(os.path.join(out, frame_name(i))).astype(float) for i in (2, 2, 2, 3, 3, 5)]
        for got, want in zip(decoded, shown):
            assert np.abs(got - want).mean() < 6  # H.264 is lossy

    def test_sigterm_stops_the_batch_like_ctrl_c(self, tmp_path, monkeypatch):
        import signal

        from pcdof.batch import runner

        root = write_tum(tmp_path / "seq", 4)
        calls = []
        real_read = runner.read_frame

        def read_then_terminate(pair, rig):
            calls.append(pair)
            if len(calls) == 2:
                os.kill(os.getpid(), signal.SIGTERM)  # as `timeout` or a job scheduler would
            return real_read(pair, rig)

        monkeypatch.setattr(runner, "read_frame", read_then_terminate)
        seen = []

        def mine(signum, frame):
            seen.append(signum)

        previous = signal.signal(signal.SIGTERM, mine)
        try:
            with pytest.raises(KeyboardInterrupt) as info:  # a Terminated, which the CLI turns into exit 143
                render_sequence(root, str(tmp_path / "out"), lens=lens(), workers=1)
            assert type(info.value).__name__ == "Terminated"
            assert not seen and signal.getsignal(signal.SIGTERM) is mine  # the previous handler is back
        finally:
            signal.signal(signal.SIGTERM, previous)
        with open(tmp_path / "out" / "report.json") as f:
            report = json.load(f)
        assert report["status"] == "interrupted" and report["error"] == "interrupted by SIGTERM"
        assert report["totals"]["pending"] >= 2

    def test_no_depth_at_the_focus_point_fails_every_frame_not_the_batch(self, tmp_path):
        import cv2

        root = write_tum(tmp_path / "seq", 3)
        for p in discover(root).pairs:  # readable depth, but nothing measured anywhere
            depth = cv2.imread(p.depth, cv2.IMREAD_UNCHANGED)
            cv2.imwrite(p.depth, np.zeros_like(depth))
        out = tmp_path / "out"
        (out).mkdir()
        (out / frame_name(0)).write_bytes(b"an earlier run's frame")
        for focus_at, where in (("center", "the image centre"), ((5, 5), "the focus point")):
            rep = render_sequence(root, str(out), lens=lens(), focus_at=focus_at, workers=1)
            assert rep["exit_code"] == EXIT_ALL_FAILED and rep["status"] == "failed"
            with open(out / "report.json") as f:
                frames = json.load(f)["frames"]
            for r in frames:
                assert r["status"] == "failed" and f"no frame of the 3 has depth at {where}" in r["error"]
                assert "--focus-distance" in r["error"] and "no known depth" in r["error"]  # and this frame's reason
            assert sorted(os.listdir(out)) == ["report.json"]

    def test_unreadable_files_are_named_first_not_the_focus(self, tmp_path):
        root = write_tum(tmp_path / "seq", 3)
        pairs = discover(root).pairs
        for p in pairs:
            with open(p.depth, "wb") as f:
                f.write(b"not a png")
        for focus_at in ("center", (5, 5), None):
            out = tmp_path / f"out{focus_at}"
            rep = render_sequence(root, str(out), lens=lens(), focus_at=focus_at, workers=1)
            assert rep["exit_code"] == EXIT_ALL_FAILED
            for r, p in zip(rep["frames"], pairs):
                assert r["error"].startswith("ImageReadError: ") and p.depth in r["error"], r["error"]
                assert "focus" not in r["error"]

    def test_unreachable_scheduler_is_named_in_the_report(self, tmp_path, monkeypatch):
        pytest.importorskip("distributed")
        from pcdof.batch import dask as batch_dask

        monkeypatch.setattr(batch_dask, "DASK_CONNECT_TIMEOUT_S", 1)
        root = write_tum(tmp_path / "seq", 2)
        with pytest.raises(InputError, match="Dask scheduler"):
            render_sequence(root, str(tmp_path / "out"), lens=lens(), scheduler="tcp://127.0.0.1:1")
        with open(tmp_path / "out" / "report.json") as f:
            report = json.load(f)
        assert report["status"] == "error"
        assert report["error"].startswith("InputError: cannot connect to the Dask scheduler at 'tcp://127.0.0.1:1'")


class TestCli:
    def test_partial_exit_code_and_summary(self, tmp_path):
        from click.testing import CliRunner

        from pcdof.cli import main

        root = write_tum(tmp_path / "seq", 3)
        bad = discover(root).pairs[1].depth
        with open(bad, "wb") as f:
            f.write(b"\x89PNG\r\n\x1a\n")
        out = tmp_path / "out"
        result = CliRunner().invoke(main, ["batch", root, "-o", str(out), "--focal-length", "200", "--f-number", "1.4",
                                           "--focus-distance", "1.0", "--workers", "1", "--no-progress"])
        assert result.exit_code == EXIT_PARTIAL, result.output
        assert "2 written" in result.output and "frame 1" in result.output
        assert sorted(os.listdir(out)) == [frame_name(0), frame_name(2), "report.json"]

    @pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux /proc to find the workers")
    def test_sigterm_exits_143_and_stops_the_workers(self, tmp_path):
        import shutil
        import signal
        import subprocess
        import sys
        import time

        sample = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "sample")
        root = tmp_path / "seq"
        for sub in ("color", "depth"):
            (root / sub).mkdir(parents=True)
        for i in range(60):  # 320x240 frames: several seconds of work on two workers
            shutil.copy(os.path.join(sample, "color.png"), root / "color" / f"{i}.png")
            shutil.copy(os.path.join(sample, "depth.png"), root / "depth" / f"{i}.png")
        shutil.copy(os.path.join(sample, "calib.json"), root)

        def descendants(pid):
            kids = set()
            for task in os.listdir(f"/proc/{pid}/task") if os.path.isdir(f"/proc/{pid}/task") else []:
                with contextlib.suppress(OSError):
                    kids |= {int(c) for c in open(f"/proc/{pid}/task/{task}/children").read().split()}
            return kids.union(*(descendants(k) for k in kids))

        def pool_processes():
            """Live forkserver / worker processes of this run (their command line holds its working folder)."""
            found = []
            for pid in filter(str.isdigit, os.listdir("/proc")):
                with contextlib.suppress(OSError):
                    cmd = open(f"/proc/{pid}/cmdline", "rb").read().decode(errors="replace")
                    state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
                    if "multiprocessing.forkserver" in cmd and str(tmp_path) in cmd and state != "Z":
                        found.append(int(pid))
            return found

        out, log_path = tmp_path / "out", tmp_path / "log.txt"
        with open(log_path, "wb") as log_file:
            proc = subprocess.Popen([sys.executable, "-c", "from pcdof.cli import main; main()", "batch", str(root),
                                     "-o", str(out), "--focus-distance", "1", "--workers", "2", "--no-progress"],
                                    cwd=tmp_path, stdout=log_file, stderr=subprocess.STDOUT)
            try:
                deadline = time.monotonic() + 60
                while len(descendants(proc.pid)) < 3 and proc.poll() is None and time.monotonic() < deadline:
                    time.sleep(0.02)  # until the pool starts its workers: the most delicate moment
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        deadline = time.monotonic() + 10
        while pool_processes() and time.monotonic() < deadline:
            time.sleep(0.1)
        left = pool_processes()
        for pid in left:  # do not leave them behind when the test fails
            os.kill(pid, signal.SIGKILL)
        output = log_path.read_text()
        assert proc.returncode == 143, output
        assert "terminated (SIGTERM)" in output
        assert not left, "worker processes outlived the batch"
        with open(out / "report.json") as f:
            report = json.load(f)
        assert report["status"] == "interrupted" and report["error"] == "interrupted by SIGTERM"
        assert report["totals"]["pending"] > 0

    def test_conflicting_focus_options(self, tmp_path):
        from click.testing import CliRunner

        from pcdof.cli import main

        root = write_tum(tmp_path / "seq", 2)
        result = CliRunner().invoke(main, ["batch", root, "-o", str(tmp_path / "o"), "--focus-distance", "1",
                                           "--focus-keyframes", "0:1,5:2"])
        assert result.exit_code == EXIT_CODES[InputError]
        assert "exclude each other" in result.output
