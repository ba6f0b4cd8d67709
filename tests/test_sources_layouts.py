"""Image-file inputs as frame sources: a pair, the folder layouts, TUM RGB-D, list files; a toy source.

Every frame read through a source is compared with what :func:`pcdof.io.load_frame` and the batch
reader (:func:`pcdof.sources.discovery.discover`, :func:`~pcdof.sources.discovery.load_rig`,
:func:`pcdof.batch.runner.read_frame`) give for the same files: bit-identical arrays, the same rig.
The layouts are built in a temporary folder from the bundled frames (``data/sample``, ``data/real``),
each frame shifted differently so that a frame read at the wrong index is caught.
"""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pcdof import io
from pcdof.sources.discovery import discover, load_rig
from pcdof.batch.runner import read_frame
from pcdof.camera import Intrinsics, Rig
from pcdof.cli.info import command as info_command
from pcdof.errors import ImageReadError, InputError, PcdofError
from pcdof.lens import ThinLens
from pcdof.pipeline import run
from pcdof.sources import (SOURCES, FrameSource, SourceFrame, SourceKind, is_recording, open_source, pair_source,
                           register_source, source_format)

DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data")
REAL = os.path.join(DATA, "real")
#: (colour, depth, calibration) of every bundled colour/depth pair
BUNDLED = {
    "sample": ("sample/color.png", "sample/depth.png", "sample/calib.json"),
    "tum": ("real/tum_rgbd_open3d/color.png", "real/tum_rgbd_open3d/depth.png", "real/tum_rgbd_open3d/calib.json"),
    "nyu": ("real/nyu_v2_raw_open3d/color.png", "real/nyu_v2_raw_open3d/depth.png",
            "real/nyu_v2_raw_open3d/calib.json"),
    "motorcycle": ("real/middlebury2014_evalQ/Motorcycle/im1.png", "real/middlebury2014_evalQ/Motorcycle/depth0.png",
                   "real/middlebury2014_evalQ/Motorcycle/calib.json"),
    "motorcycle-im0": ("real/middlebury2014_evalQ/Motorcycle/im0.png",
                       "real/middlebury2014_evalQ/Motorcycle/depth0.png",
                       "real/middlebury2014_evalQ/Motorcycle/calib_im0.json"),
    "adirondack": ("real/middlebury2014_evalQ/Adirondack/im1.png", "real/middlebury2014_evalQ/Adirondack/depth0.png",
                   "real/middlebury2014_evalQ/Adirondack/calib.json"),
}
T0 = 1305031102.175304  # a TUM-like clock, seconds


def _bundled(name):
    return tuple(os.path.join(DATA, p) for p in BUNDLED[name])


def assert_same_frame(got, want) -> None:
    """*got* (a SourceFrame) and *want* (an RGBDFrame) hold bit-identical arrays and equal rigs."""
    assert got.color.dtype == want.color.dtype and got.depth_m.dtype == want.depth_m.dtype == np.float32
    assert got.color.shape == want.color.shape and got.depth_m.shape == want.depth_m.shape
    assert got.color.tobytes() == want.color.tobytes()
    assert got.depth_m.tobytes() == want.depth_m.tobytes()  # bit-exact, zeros and all
    assert got.rig.to_dict() == want.rig.to_dict()
    assert got.rig.T_color_from_depth.tobytes() == want.rig.T_color_from_depth.tobytes()
    assert got.n_invalid_depth == want.n_invalid_depth
    rgbd = got.rgbd()
    assert rgbd.color.tobytes() == want.color.tobytes() and rgbd.depth_m.tobytes() == want.depth_m.tobytes()


def shifted_frames(name, n, out_dir):
    """*n* frames made from the bundled pair *name*, frame k shifted 7k pixels right: [(colour BGR, raw depth)]."""
    color, depth, _ = _bundled(name)
    c, d = cv2.imread(color, cv2.IMREAD_UNCHANGED), cv2.imread(depth, cv2.IMREAD_UNCHANGED)
    os.makedirs(out_dir, exist_ok=True)
    return [(np.roll(c, 7 * k, axis=1), np.roll(d, 7 * k, axis=1)) for k in range(n)]


def write_pairs(frames, color_paths, depth_paths) -> None:
    for (c, d), cp, dp in zip(frames, color_paths, depth_paths):
        os.makedirs(os.path.dirname(cp), exist_ok=True)
        os.makedirs(os.path.dirname(dp), exist_ok=True)
        assert cv2.imwrite(cp, c) and cv2.imwrite(dp, d)


def assert_matches_batch_and_load_frame(src, path, calib, **rig_options) -> None:
    """Every frame of *src* equals the batch reader's and load_frame's for the same files, in order."""
    sequence = discover(path, **({"max_difference": rig_options.pop("max_difference")}
                                 if "max_difference" in rig_options else {}))
    rig = load_rig(sequence, calib, **rig_options)
    assert len(src) == len(sequence) and src.rig.to_dict() == rig.to_dict()
    for i, pair in enumerate(sequence.pairs):
        got = src.frame(i)
        assert got.index == i
        batch = read_frame(pair, rig)
        assert got.color.tobytes() == batch.color.tobytes() and got.depth_m.tobytes() == batch.depth_m.tobytes()
        assert got.rig.to_dict() == batch.rig.to_dict()
        assert_same_frame(got, io.load_frame(pair.color, pair.depth, calib or src.calib_path,
                                             depth_scale=rig.depth_scale))
    assert [f.index for f in src] == list(range(len(src)))


# ------------------------------------------------------------------------------------------ a pair
class TestPair:
    @pytest.mark.parametrize("name", list(BUNDLED))
    def test_bundled_pairs_read_as_load_frame_reads_them(self, name):
        color, depth, calib = _bundled(name)
        want = io.load_frame(color, depth, calib)
        with pair_source(color, depth, calib) as src:
            assert len(src) == 1 and src.format == "pair" and src.rig.to_dict() == want.rig.to_dict()
            assert_same_frame(src.frame(0), want)
            assert_same_frame(src.frame(-1), want)
        with open_source(color, depth=depth, calib=calib) as src:
            assert_same_frame(src.frame(0), want)

    def test_depth_scale_overrides_the_calibration(self):
        color, depth, calib = _bundled("nyu")
        want = io.load_frame(color, depth, calib, depth_scale=0.002)
        src = open_source(color, depth=depth, calib=calib, depth_scale=0.002)
        assert src.rig.depth_scale == 0.002
        assert_same_frame(src.frame(0), want)

    def test_float_depth_with_invalid_values_counted_as_load_frame_counts(self, tmp_path):
        color, depth, calib = _bundled("sample")
        d = io.read_depth(depth, depth_scale=0.001)
        d[:3, :5] = np.nan
        d[10, 10] = -1.0
        np.save(tmp_path / "depth.npy", d)
        with pytest.warns(UserWarning, match="16 depth values"):
            want = io.load_frame(color, tmp_path / "depth.npy", calib)
        with pytest.warns(UserWarning, match="16 depth values"):
            got = pair_source(color, tmp_path / "depth.npy", calib).frame(0)
        assert got.n_invalid_depth == 16
        assert_same_frame(got, want)

    def test_calibration_found_next_to_the_colour_image(self, tmp_path):
        color, depth, calib = _bundled("sample")
        for p in (color, depth, calib):
            shutil.copy(p, tmp_path)
        got = pair_source(tmp_path / "color.png", tmp_path / "depth.png").frame(0)
        assert_same_frame(got, io.load_frame(color, depth, calib))

    def test_errors_are_load_frames(self, tmp_path):
        color, depth, calib = _bundled("sample")
        for args in ((color, tmp_path / "none.png", calib), (color, _bundled("tum")[1], calib),
                     (color, depth, tmp_path / "missing.json"), (color, depth, _bundled("sample")[0])):
            with pytest.raises(PcdofError) as want:
                io.load_frame(*args)
            with pytest.raises(PcdofError) as got:
                pair_source(*args).frame(0)
            assert type(got.value) is type(want.value) and str(got.value) == str(want.value)
        with pytest.raises(InputError, match=f"no calibration given.*{tmp_path}"):
            pair_source(tmp_path / "c.png", tmp_path / "d.png")
        with pytest.raises(InputError, match="max_difference_s"):
            open_source(color, depth=depth, calib=calib, max_difference_s=0.1)


# ----------------------------------------------------------------------------------- the layouts
@pytest.fixture
def folders(tmp_path):
    """color/ + depth/ with differently named files paired by their numbers; calib.json in the folder."""
    root = str(tmp_path / "folders")
    frames = shifted_frames("sample", 4, root)
    write_pairs(frames, [f"{root}/color/frame-{k:04d}.png" for k in range(4)],
                [f"{root}/depth/depth-{k}.png" for k in range(4)])
    shutil.copy(_bundled("sample")[2], os.path.join(root, "calib.json"))
    return root


class TestFolders:
    def test_subfolders_paired_by_number(self, folders):
        assert source_format(folders) == "folder" and not is_recording(folders)
        with open_source(folders) as src:
            info = json.loads(json.dumps(src.info()))  # plain, JSON-ready
            assert src.format == "folder" and len(src) == 4 and info["layout"] == "folders"
            assert info["streams"]["depth"] == {"width": 256, "height": 212, "frames": 4}
            assert info["calibration_from"] == os.path.join(folders, "calib.json")
            assert_matches_batch_and_load_frame(src, folders, None)
            # the frames differ, so a frame read at the wrong index would not have matched
            assert not np.array_equal(src.frame(0).color, src.frame(1).color)

    def test_tagged_files_side_by_side(self, tmp_path):
        frames = shifted_frames("nyu", 3, tmp_path)
        names = ["a", "b", "c10"]
        write_pairs(frames, [str(tmp_path / f"{n}_rgb.png") for n in names],
                    [str(tmp_path / f"{n}_depth.png") for n in names])
        calib = _bundled("nyu")[2]
        assert source_format(tmp_path) == "folder"
        with open_source(tmp_path, calib=calib, depth_scale=0.001) as src:
            assert src.info()["layout"] == "suffixes"
            assert_matches_batch_and_load_frame(src, str(tmp_path), calib, depth_scale=0.001)

    def test_pcdof_info_describes_the_folder(self, folders):
        result = CliRunner().invoke(info_command, [folders])
        assert result.exit_code == 0, result.output
        first, color = result.output.splitlines()[:2]
        assert first == (f"{folders}: folder, 4 colour+depth frames (folders layout, paired by name; "
                         "unpaired: 0 colour, 0 depth)")
        assert color == "  color: 320x240, 4 frames"

    def test_no_pairs(self, tmp_path):
        for sub, name in (("color", "a.png"), ("depth", "b.png")):
            os.makedirs(tmp_path / sub)
            cv2.imwrite(str(tmp_path / sub / name), np.zeros((4, 4, 3), np.uint8))
        with pytest.raises(InputError, match=f"no colour/depth pairs found in {tmp_path}"):
            open_source(tmp_path, calib=_bundled("sample")[2])

    def test_no_calibration(self, folders):
        os.remove(os.path.join(folders, "calib.json"))
        with pytest.raises(InputError, match=f"no calibration given and none of .* in {folders}"):
            open_source(folders)

    def test_no_timestamps(self, folders):
        with open_source(folders) as src:
            assert src.frame(0).timestamp_s is None
            with pytest.raises(InputError, match=f"{folders}: its frames have no timestamps"):
                src.index_at(0.0)


@pytest.fixture
def tum(tmp_path):
    """A TUM-like folder of the bundled TUM frame: depth 5000 units per metre, a calibration without depth_scale."""
    root = str(tmp_path / "tum")
    frames = shifted_frames("tum", 4, root)
    tc = [T0 + k / 30 for k in range(4)]
    td = [t + 0.004 for t in tc]
    write_pairs(frames, [f"{root}/rgb/{t:.6f}.png" for t in tc], [f"{root}/depth/{t:.6f}.png" for t in td])
    cv2.imwrite(f"{root}/depth/{T0 + 5:.6f}.png", frames[0][1])  # a depth image with no colour partner
    with open(f"{root}/rgb.txt", "w") as f:
        f.write("# color images\n# file: 'x.bag'\n# timestamp filename\n")
        f.writelines(f"{t:.6f} rgb/{t:.6f}.png\n" for t in tc)
    with open(f"{root}/depth.txt", "w") as f:
        f.writelines(f"{t:.6f} depth/{t:.6f}.png\n" for t in (*td, T0 + 5))
    calib = json.load(open(_bundled("tum")[2]))
    del calib["depth_scale"]
    json.dump(calib, open(f"{root}/calib.json", "w"))
    return root


class TestTum:
    def test_paired_by_time_with_the_tum_depth_scale(self, tum):
        assert source_format(tum) == "tum" == source_format(os.path.join(tum, "rgb.txt"))
        with open_source(tum) as src:
            assert src.format == "tum" and len(src) == 4 and src.rig.depth_scale == pytest.approx(1 / 5000)
            info = src.info()
            assert info["pairing"] == {"unpaired_color": 0, "unpaired_depth": 1, "max_difference_s": 0.02}
            assert_matches_batch_and_load_frame(src, tum, None)
            f = src.frame(2)
            assert f.color_time_s == pytest.approx(T0 + 2 / 30) and f.depth_time_s == pytest.approx(T0 + 2 / 30 + 0.004)
            assert src.index_at(T0 + 0.07) == 2 and src.frame_at(T0 + 0.07).index == 2

    def test_bundled_calibration_depth_scale_and_rgb_txt_named(self, tum):
        calib = _bundled("tum")[2]
        with open_source(os.path.join(tum, "rgb.txt"), calib=calib) as src:
            assert_matches_batch_and_load_frame(src, tum, calib)

    def test_tolerance(self, tum):
        with pytest.raises(InputError, match=f"no colour/depth pairs found in {tum}"):
            open_source(tum, max_difference_s=0.003)  # tighter than the 4 ms offset
        with open_source(tum, max_difference_s=0.005) as src:
            assert len(src) == 4 and src.info()["pairing"]["max_difference_s"] == 0.005

    def test_missing_depth_list(self, tum):
        os.remove(os.path.join(tum, "depth.txt"))
        with pytest.raises(InputError, match="needs rgb.txt and depth.txt; .* has no depth.txt"):
            open_source(os.path.join(tum, "rgb.txt"))

    @pytest.mark.parametrize("bad", [0, -0.1, float("nan"), "0.02", True])
    def test_bad_tolerance(self, tum, bad):
        with pytest.raises(InputError, match="max_difference_s must be a finite number"):
            open_source(tum, max_difference_s=bad)


class TestListFile:
    def test_two_columns_relative_and_quoted(self, tmp_path):
        frames = shifted_frames("motorcycle", 3, tmp_path)
        colors = [str(tmp_path / "my take" / f"c#{k}.png") for k in range(3)]
        depths = [str(tmp_path / "d" / f"{k}.png") for k in range(3)]
        write_pairs(frames, colors, depths)
        lst = tmp_path / "frames.lst"
        lst.write_text("# colour depth\n" + "".join(f'"my take/c#{k}.png", d/{k}.png  # frame {k}\n'
                                                    for k in (2, 0, 1)))
        calib = _bundled("motorcycle")[2]
        assert source_format(lst) == "list"
        with open_source(lst, calib=calib) as src:
            assert src.format == "list" and len(src) == 3
            assert_matches_batch_and_load_frame(src, str(lst), calib)
            assert src.frame(0).color.tobytes() == io.read_color(colors[2]).tobytes()  # the file's order

    def test_four_columns_have_times(self, tmp_path):
        frames = shifted_frames("adirondack", 2, tmp_path)
        write_pairs(frames, [str(tmp_path / f"c{k}.png") for k in range(2)],
                    [str(tmp_path / f"d{k}.png") for k in range(2)])
        lst = tmp_path / "associated.txt"
        lst.write_text(f"{T0:.6f} c0.png {T0 + 0.01:.6f} d0.png\n{T0 + 1:.6f} c1.png {T0 + 1.01:.6f} d1.png\n")
        calib = _bundled("adirondack")[2]
        with open_source(lst, calib=calib) as src:
            assert_matches_batch_and_load_frame(src, str(lst), calib)
            assert src.frame(1).color_time_s == pytest.approx(T0 + 1) and src.index_at(T0 + 0.8) == 1

    def test_missing_file_is_one_line_naming_the_list_and_the_frame(self, tmp_path):
        frames = shifted_frames("sample", 1, tmp_path)
        write_pairs(frames, [str(tmp_path / "c.png")], [str(tmp_path / "d.png")])
        lst = tmp_path / "list.txt"
        lst.write_text("c.png d.png\nc.png gone.png\n")
        with open_source(lst, calib=_bundled("sample")[2]) as src:
            src.frame(0)
            with pytest.raises(ImageReadError) as err:
                src.frame(1)
            with pytest.raises(InputError, match=f"{lst}: frame index 2 is out of range: it has 2 frames"):
                src.frame(2)
        msg = str(err.value)
        assert msg.startswith(f"{lst}: frame 1 (c.png, gone.png): ") and "gone.png" in msg[len(str(lst)) + 30:]
        assert "\n" not in msg

    def test_bad_line(self, tmp_path):
        lst = tmp_path / "list.txt"
        lst.write_text("a.png b.png c.png\n")
        with pytest.raises(InputError, match=f"{lst}:1: expected 'color_path depth_path'"):
            open_source(lst, calib=_bundled("sample")[2])


# ------------------------------------------------------------------------------- sniffing, errors
class TestOpenSource:
    def test_unknown_inputs(self, tmp_path):
        shutil.copy(_bundled("sample")[0], tmp_path / "color.png")
        with pytest.raises(InputError, match="color.png is not a recording or sequence .* give its depth image"):
            open_source(tmp_path / "color.png")
        with pytest.raises(InputError, match="is a folder pcdof cannot read frames from .*; expected: .*TUM"):
            open_source(tmp_path)
        with pytest.raises(ImageReadError, match="does not exist"):
            open_source(tmp_path / "none")

    def test_options_that_do_not_apply(self):
        bag = os.path.join(REAL, "realsense_d435_bag", "single_depth_color_640x480.bag")
        with pytest.raises(InputError, match="depth_scale applies to integer depth files"):
            open_source(bag, depth_scale=0.001)

    def test_a_text_file_named_like_a_recording_is_the_recordings(self, tmp_path):
        (tmp_path / "x.bag").write_text("c.png d.png\n")
        assert source_format(tmp_path / "x.bag") == "realsense-bag"
        with pytest.raises(ImageReadError, match="not a ROS bag"):
            open_source(tmp_path / "x.bag")


# ------------------------------------------------------------------------------- a new input kind
class ToySource(FrameSource):
    """A made-up input kind: a ``.toy`` file names a depth in metres; frames are a textured plane there."""

    format = "toy"

    def __init__(self, path: str, depth_m: float) -> None:
        intr = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
        super().__init__(path, Rig.registered(intr, max_range_m=10.0))
        self.depth_m = depth_m

    @classmethod
    def open(cls, path, *, calib=None, depth_scale=None, max_difference_s=None):
        with open(path) as f:
            return cls(path, float(f.read()))

    def __len__(self) -> int:
        return 3

    def _read(self, i: int) -> SourceFrame:
        y, x = np.mgrid[0:48, 0:64]
        color = np.stack([(x * 4 + i) % 256, (y * 5) % 256, ((x // 8 + y // 8) % 2) * 255], axis=2).astype(np.uint8)
        depth = np.full((48, 64), self.depth_m + 0.5 * i, np.float32)
        depth[:, :16] = 0.8  # a near strip, so the render has something out of focus
        return SourceFrame(i, color, depth, self.rig, 0.1 * i, 0.1 * i)


@pytest.fixture
def toy_registered():
    register_source("toy", SourceKind(lambda path, head: path.endswith(".toy"), ToySource.open, (".toy",),
                                      "toy scene (a depth in a text file)"))
    try:
        yield
    finally:
        del SOURCES["toy"]


class TestNewInputKind:
    def test_a_toy_source_renders_through_the_pipeline(self, tmp_path, toy_registered):
        (tmp_path / "scene.toy").write_text("2.0")
        assert source_format(tmp_path / "scene.toy") == "toy"
        lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=2.0)
        with open_source(tmp_path / "scene.toy") as src:
            assert len(src) == 3 and src.info()["format"] == "toy" and src.frame(2).timestamp_s == pytest.approx(0.2)
            frame = src.frame(1)
            result = run(frame.rgbd(), lens)
        direct = run(ToySource(str(tmp_path / "scene.toy"), 2.0)._read(1).rgbd(), lens)
        assert result.image.shape == (48, 64, 3) and result.image.dtype == np.uint8
        assert result.image.tobytes() == direct.image.tobytes()
        # the in-focus plane (2.5 m is 0.5 m off focus; the 0.8 m strip much further) is blurred less
        diff = np.abs(result.image.astype(int) - frame.color.astype(int)).mean(axis=2)
        assert diff[:, :16].mean() > diff[:, 24:].mean()
        with pytest.raises(InputError, match="scene.toy: frame index 3 is out of range"):
            src.frame(3)

    def test_a_source_with_the_wrong_image_size_is_refused(self, tmp_path, toy_registered):
        class Wrong(ToySource):
            def _read(self, i):
                f = super()._read(i)
                return SourceFrame(i, f.color[:-1], f.depth_m, f.rig, None, None)

        message = "w.toy: frame 0: the colour image is 64x47; the calibration says 64x48"
        with pytest.raises(ImageReadError, match=message):
            Wrong("w.toy", 1.0).frame(0)

    def test_register_source_checks(self, toy_registered):
        kind = SOURCES["toy"]
        with pytest.raises(InputError, match="'toy' is taken"):
            register_source("toy", kind)
        with pytest.raises(InputError, match="kind must be a SourceKind"):
            register_source("toy2", ToySource)
        with pytest.raises(InputError, match="name must be a non-empty string"):
            register_source("", kind)
