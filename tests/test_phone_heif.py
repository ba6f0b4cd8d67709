"""HEIF/HEIC depth photos: every depth representation type, EXIF orientation, the real iPhone photo, hostile files.

pillow-heif (1.8) reads depth images but cannot write them, so the representation types are tested on the
conversion the reader applies to what pillow-heif returns (values + ``info["metadata"]``), against the
formulas of H.265's depth representation information written out here; the whole reader runs on the real
iPhone file and on HEIC files pillow-heif writes (without depth).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from pcdof.cli import main
from pcdof.errors import ImageReadError
from pcdof.sources import open_source, source_format
from pcdof.sources.heif_depth import depth_from_heif
from pcdof.sources.phone import check_aspect, orient, phone_rig, intrinsics_from_35mm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PUG = os.path.join(ROOT, "data", "real", "iphone_heic_depth", "pug.heic")


def stored(z: np.ndarray, kind: int, lo: float, hi: float, dtype=np.uint8) -> np.ndarray:
    """Metric depth -> stored samples of representation *kind* (0 inverse Z, 1 disparity = 1/z, 2 Z)."""
    top = np.iinfo(dtype).max
    if kind == 2:
        v = (z - lo) / (hi - lo)
    elif kind == 0:  # linear in 1/z, 1 at z_near
        v = (1 / z - 1 / hi) / (1 / lo - 1 / hi)
    else:  # linear in disparity 1/z between d_min and d_max
        v = (1 / z - lo) / (hi - lo)
    return np.rint(np.clip(v, 0, 1) * top).astype(dtype)


class TestRepresentations:
    @pytest.mark.parametrize("kind,keys,lo,hi", [(0, ("z_near", "z_far"), 0.4, 6.0),
                                                 (1, ("d_min", "d_max"), 1 / 6.0, 1 / 0.4),
                                                 (2, ("z_near", "z_far"), 0.4, 6.0)])
    @pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
    def test_round_trip_within_quantisation(self, kind, keys, lo, hi, dtype):
        z = np.random.default_rng(kind).uniform(0.45, 5.9, (30, 40))
        values = stored(z, kind, lo, hi, dtype)
        depth, info = depth_from_heif(values, {"representation_type": kind, keys[0]: lo, keys[1]: hi})
        top = np.iinfo(dtype).max
        assert depth.dtype == np.float32 and depth.shape == z.shape
        if kind == 2:  # half a step in z
            assert np.all(np.abs(depth - z) <= 0.5 * (hi - lo) / top * 1.0001 + 1e-6)
        else:  # half a step in 1/z
            span = (1 / 0.4 - 1 / 6.0)
            assert np.all(np.abs(1 / depth.astype(np.float64) - 1 / z) <= 0.5 * span / top * 1.0001 + 1e-6)
        assert info["near_m"] == pytest.approx(0.4) and info["far_m"] == pytest.approx(6.0)

    def test_ends_map_to_near_and_far(self):
        v = np.array([[0, 255]], np.uint8)
        for kind, meta in ((0, {"z_near": 1.0, "z_far": 4.0}), (1, {"d_min": 0.25, "d_max": 1.0}),
                           (2, {"z_near": 1.0, "z_far": 4.0})):
            depth, _ = depth_from_heif(v, {"representation_type": kind, **meta})
            near_end = depth[0, 1] if kind in (0, 1) else depth[0, 0]  # inverse and disparity grow towards near
            assert near_end == pytest.approx(1.0) and depth.max() == pytest.approx(4.0)

    @pytest.mark.parametrize("meta", [{"representation_type": 3, "d_min": 1, "d_max": 2},
                                      {"representation_type": 7, "d_min": 1, "d_max": 2},
                                      {"representation_type": 1},
                                      {"representation_type": 1, "d_min": 2.0, "d_max": 1.0},
                                      {"representation_type": 2, "z_near": float("nan"), "z_far": 3.0}])
    def test_refused(self, meta):
        with pytest.raises(ImageReadError):
            depth_from_heif(np.zeros((2, 2), np.uint8), meta)


class TestOrientation:
    @pytest.mark.parametrize("code", range(1, 9))
    def test_matches_pillow(self, code):
        """orient() against Pillow's own EXIF transpose, for all eight codes."""
        img = np.arange(3 * 5 * 3, dtype=np.uint8).reshape(3, 5, 3)
        pil = Image.fromarray(img)
        exif = pil.getexif()
        exif[0x0112] = code
        pil.info["exif"] = exif.tobytes()
        from PIL import ImageOps

        expect = np.asarray(ImageOps.exif_transpose(pil))
        assert np.array_equal(orient(img, code), expect)
        assert np.array_equal(orient(img[..., 0], code), expect[..., 0])


class TestPug:
    def test_info_and_frame(self):
        assert source_format(PUG) == "heif-depth"
        with open_source(PUG) as src:
            info, frame = src.info(), src.frame(0)
        d = info["phone"]["depth"]
        assert (d["representation"], d["width"], d["height"]) == ("uniform disparity", 768, 576)
        assert d["near_m"] == pytest.approx(1 / 4.3828125) and d["far_m"] == pytest.approx(1 / 1.498046875)
        assert frame.color.shape == (3024, 4032, 3) and frame.depth_m.shape == (576, 768)
        cam, dep = frame.rig.color, frame.rig.depth
        assert cam.fx == pytest.approx(26 * 5040 / np.hypot(36, 24))
        assert dep.fx / cam.fx == pytest.approx(768 / 4032) and np.allclose(frame.rig.T_color_from_depth, np.eye(4))
        # the photo's bottom rows are the bed's rim in front, the top the wall: near below, far above
        assert np.median(frame.depth_m[-20:]) < np.median(frame.depth_m[:100])

    def test_cli_info(self):
        result = CliRunner().invoke(main, ["info", PUG], prog_name="pcdof")
        assert result.exit_code == 0, result.output
        assert "768x576 8-bit depth map" in result.output and "uniform disparity" in result.output
        assert "fx 3028.663" in result.output


class TestHostile:
    def run_info(self, path):
        result = CliRunner().invoke(main, ["info", str(path)], prog_name="pcdof")
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error: ") and "Traceback" not in result.output
        return result.exit_code, lines[0]

    def test_no_depth_image(self, tmp_path):
        import pillow_heif

        path = tmp_path / "plain.heic"
        pillow_heif.from_pillow(Image.fromarray(np.zeros((40, 60, 3), np.uint8))).save(str(path), quality=90)
        with pytest.raises(ImageReadError, match="no depth image"):
            open_source(path)
        assert self.run_info(path)[0] == 3

    @pytest.mark.parametrize("keep", [0.5, 0.02])
    def test_truncated(self, tmp_path, keep):
        data = open(PUG, "rb").read()
        path = tmp_path / "cut.heic"
        path.write_bytes(data[:int(len(data) * keep)])
        with pytest.raises(ImageReadError):
            open_source(path)
        assert self.run_info(path)[0] == 3

    def test_depth_of_another_aspect_ratio(self):
        with pytest.raises(ImageReadError, match="another aspect"):
            check_aspect((3024, 4032), (768, 768))
        cam = intrinsics_from_35mm(4032, 3024, 26.0)
        with pytest.raises(ImageReadError, match="another aspect"):
            phone_rig(cam, (576, 700), max_range_m=5.0)
        rig = phone_rig(cam, (576, 768), max_range_m=5.0)  # the same aspect: accepted
        assert rig.depth.cx == pytest.approx((cam.cx + 0.5) * 768 / 4032 - 0.5)

    def test_options_that_do_not_apply(self, tmp_path):
        result = CliRunner().invoke(main, ["info", PUG, "--calib", str(tmp_path / "c.json")], prog_name="pcdof")
        assert result.exit_code == 6 and result.output.startswith("pcdof: error: calib does not apply")


class TestTurnedDepth:
    """libheif turns the photo upright (irot/imir); a depth image stored without the turn follows the EXIF."""

    @pytest.mark.parametrize("orientation", [6, 8, 5, 7])
    def test_depth_turned_like_the_photo(self, monkeypatch, tmp_path, orientation):
        from pcdof.sources import heif_depth

        color = np.zeros((80, 60, 3), np.uint8)  # the upright (portrait) photo as libheif gives it
        upright = np.zeros((40, 30), np.uint8)  # the depth as it should end up: a far patch top left
        upright[2:10, 2:12] = 200
        inverse = {6: 8, 8: 6, 5: 5, 7: 7}[orientation]  # the EXIF turn that undoes *orientation*
        stored = orient(upright, inverse)  # landscape, as a phone stores it unturned
        assert stored.shape == (30, 40)
        exif = Image.Exif()
        exif[0x0112] = orientation
        exif.get_ifd(0x8769)[0xA405] = 26
        meta = {"representation_type": 2, "z_near": 0.5, "z_far": 5.0}
        monkeypatch.setattr(heif_depth, "decode_heif", lambda path: (color, stored, meta, exif.tobytes()))
        src = heif_depth.HeifDepthSource.open(str(tmp_path / "x.heic"))
        frame = src.frame(0)
        assert frame.depth_m.shape == (40, 30) and src.info()["phone"]["depth"]["turned_by_exif"]
        assert np.array_equal(frame.depth_m > 4.0, upright > 0)  # 0.5 + 200/255 * 4.5 = 4.03 m on the patch
