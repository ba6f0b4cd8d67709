"""Android depth JPEGs: Dynamic Depth 1.0 and GDepth, written here to their specifications, and a real GDepth file.

The writers below follow the specifications, not the reader: Dynamic Depth 1.0 (XMP ``Device`` with a
``Container:Directory`` and the items appended after the primary image's end-of-image marker) and GDepth
(``GDepth:*`` in the standard XMP, base64 ``GDepth:Data`` in extended XMP split over APP1 segments, named by
``xmpNote:HasExtendedXMP`` = the MD5 of the extended packet).
"""

from __future__ import annotations

import base64
import hashlib
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from pcdof.cli import main
from pcdof.errors import ImageReadError
from pcdof.sources import open_source, source_format

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REAL_GDEPTH = os.path.join(ROOT, "data", "real", "android_gdepth_jpeg", "motorola_xt912_lens_blur.jpg")
XMP_STD = b"http://ns.adobe.com/xap/1.0/\x00"
XMP_EXT = b"http://ns.adobe.com/xmp/extension/\x00"
DD = "http://ns.google.com/photos/dd/1.0/"


def app1(body: bytes) -> bytes:
    assert len(body) + 2 <= 65535
    return b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body


def xmp_packet(description: str, namespaces: dict) -> bytes:
    ns = " ".join(f'xmlns:{k}="{v}"' for k, v in namespaces.items())
    return (f'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            f'<rdf:Description rdf:about="" {ns} {description}</rdf:Description></rdf:RDF></x:xmpmeta>').encode()


def jpeg_with(color_rgb: np.ndarray, segments: list[bytes], *, orientation: int | None = None) -> bytes:
    """A JPEG of *color_rgb* with APP1 *segments* (and an EXIF orientation) right after SOI."""
    ok, enc = cv2.imencode(".jpg", cv2.cvtColor(color_rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 98])
    assert ok
    enc = enc.tobytes()
    extra = []
    if orientation is not None:
        exif = Image.Exif()
        exif[0x0112] = orientation
        extra.append(app1(exif.tobytes()))
    return enc[:2] + b"".join(extra + segments) + enc[2:]


def depth_png(values: np.ndarray) -> bytes:
    ok, enc = cv2.imencode(".png", values)
    assert ok
    return enc.tobytes()


def encode(z: np.ndarray, near: float, far: float, fmt: str, dtype=np.uint8) -> np.ndarray:
    """Depth -> normalised stored values, by the specifications' formulas."""
    top = np.iinfo(dtype).max
    if fmt == "RangeLinear":
        v = (z - near) / (far - near)
    else:  # RangeInverse: v = far (z - near) / (z (far - near))
        v = far * (z - near) / (z * (far - near))
    return np.rint(np.clip(v, 0, 1) * top).astype(dtype)


def dynamic_depth_jpeg(color, values, *, near, far, fmt, units="Meters", fx=None, orientation=None,
                       model_size=None, xml_extra="") -> bytes:
    """A Dynamic Depth 1.0 JPEG: the photo, a padding item, then the depth PNG, appended in directory order."""
    h, w = color.shape[:2]
    mw, mh = model_size or (w, h)
    fx = fx or 0.9 * mw
    depth = depth_png(values)
    pad_item = b"\x00" * 37
    description = f"""><Device:Container rdf:parseType="Resource"><Container:Directory><rdf:Seq>
<rdf:li rdf:parseType="Resource">
<Container:Item Item:Mime="image/jpeg" Item:Length="0" Item:DataURI="primary"/></rdf:li>
<rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="application/octet-stream" Item:Length="30" Item:Padding="7"
 Item:DataURI="other"/></rdf:li>
<rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="image/png" Item:Length="{len(depth)}"
 Item:DataURI="android/depthmap"/></rdf:li>
</rdf:Seq></Container:Directory></Device:Container>
<Device:Cameras><rdf:Seq><rdf:li rdf:parseType="Resource"><Device:Camera Camera:Trait="Physical">
<Camera:DepthMap DepthMap:ItemSemantic="Depth" DepthMap:Format="{fmt}" DepthMap:Units="{units}"
 DepthMap:Near="{near}" DepthMap:Far="{far}" DepthMap:DepthURI="android/depthmap"
 DepthMap:MeasureType="OpticalAxis"/>
<Camera:ImagingModel ImagingModel:FocalLengthX="{fx}" ImagingModel:FocalLengthY="{fx}"
 ImagingModel:ImageWidth="{mw}" ImagingModel:ImageHeight="{mh}" ImagingModel:PrincipalPointX="{mw / 2 + 3}"
 ImagingModel:PrincipalPointY="{mh / 2 - 2}"/>
</Device:Camera></rdf:li></rdf:Seq></Device:Cameras>{xml_extra}"""
    names = {n: f"{DD}{n.lower()}/" for n in ("Device", "Container", "Item", "Camera", "DepthMap", "ImagingModel")}
    packet = xmp_packet(description, names)
    return jpeg_with(color, [app1(XMP_STD + packet)], orientation=orientation) + pad_item + depth


def gdepth_jpeg(color, values, *, near, far, fmt="RangeInverse", data_b64=None, chunk=30000, orientation=None,
                drop_chunk=False) -> bytes:
    """A GDepth JPEG: the depth PNG base64 in extended XMP, split into APP1 chunks of *chunk* bytes."""
    data = data_b64 if data_b64 is not None else base64.b64encode(depth_png(values)).decode()
    ext = xmp_packet(f'GDepth:Data="{data}">', {"GDepth": "http://ns.google.com/photos/1.0/depthmap/"})
    guid = hashlib.md5(ext).hexdigest().upper()
    std = xmp_packet(f'GDepth:Format="{fmt}" GDepth:Near="{near}" GDepth:Far="{far}" GDepth:Units="m" '
                     f'GDepth:Mime="image/png" xmpNote:HasExtendedXMP="{guid}">',
                     {"GDepth": "http://ns.google.com/photos/1.0/depthmap/", "xmpNote": "http://ns.adobe.com/xmp/note/"})
    segments = [app1(XMP_STD + std)]
    for off in range(0, len(ext), chunk):
        head = XMP_EXT + guid.encode() + len(ext).to_bytes(4, "big") + off.to_bytes(4, "big")
        segments.append(app1(head + ext[off:off + chunk]))
    if drop_chunk:
        segments.pop(-1 if len(segments) > 2 else 1)
    return jpeg_with(color, segments, orientation=orientation)


def within_half_step(decoded, z, near, far, fmt, top) -> bool:
    """Whether *decoded* is *z* to within half a step of the stored value: in z (linear) or in 1/z (inverse)."""
    if fmt == "RangeLinear":
        return bool(np.all(np.abs(decoded - z) <= 0.5 * (far - near) / top * 1.0001 + 1e-6))
    return bool(np.all(np.abs(1 / decoded.astype(np.float64) - 1 / z) <= 0.5 * (1 / near - 1 / far) / top * 1.0001
                       + 1e-6))


def scene(h=60, w=80):
    """A photo with a bright square, and a depth map: 1.2 m on the square, 3 m elsewhere (rows vary 3..4 m)."""
    color = np.full((h, w, 3), 40, np.uint8)
    color[15:35, 20:50] = 230
    z = np.linspace(3.0, 4.0, h, dtype=np.float64)[:, None] * np.ones((1, w))
    z[15:35, 20:50] = 1.2
    return color, z


def write(tmp_path, name, data: bytes) -> str:
    path = tmp_path / name
    path.write_bytes(data)
    return str(path)


class TestDynamicDepth:
    @pytest.mark.parametrize("fmt", ["RangeLinear", "RangeInverse"])
    @pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
    def test_round_trip_within_quantisation(self, tmp_path, fmt, dtype):
        color, z = scene()
        near, far = 0.5, 5.0
        values = encode(z, near, far, fmt, dtype)
        path = write(tmp_path, "dd.jpg", dynamic_depth_jpeg(color, values, near=near, far=far, fmt=fmt))
        assert source_format(path) == "depth-jpeg"
        with open_source(path) as src:
            frame = src.frame(0)
            info = src.info()
        assert within_half_step(frame.depth_m, z, near, far, fmt, np.iinfo(dtype).max)
        assert info["phone"]["depth"]["container"] == "Dynamic Depth 1.0"
        cam = frame.rig.color
        assert (cam.fx, cam.cx, cam.cy) == pytest.approx((0.9 * 80, 43, 28))
        assert frame.rig.depth.shape == (60, 80) and frame.rig.is_registered

    def test_millimetres_and_model_of_another_size(self, tmp_path):
        color, z = scene()
        values = encode(z * 1000.0, 500.0, 5000.0, "RangeLinear")  # the file counts in millimetres
        path = write(tmp_path, "mm.jpg", dynamic_depth_jpeg(color, values, near=500, far=5000, fmt="RangeLinear",
                                                             units="Millimeters", model_size=(160, 120), fx=150))
        with open_source(path) as src:
            frame = src.frame(0)
        assert np.abs(frame.depth_m - z).max() < 0.01
        assert frame.rig.color.fx == pytest.approx(75) and frame.rig.color.cx == pytest.approx((83 + 0.5) / 2 - 0.5)

    @pytest.mark.parametrize("orientation", [3, 6, 8])
    def test_orientation_turns_photo_depth_and_intrinsics_alike(self, tmp_path, orientation):
        color, z = scene()
        path = write(tmp_path, "o.jpg", dynamic_depth_jpeg(color, encode(z, 0.5, 5.0, "RangeLinear"), near=0.5,
                                                           far=5.0, fmt="RangeLinear", orientation=orientation))
        with open_source(path) as src:
            frame = src.frame(0)
        upright = np.asarray(Image.fromarray(color).transpose(
            {3: Image.Transpose.ROTATE_180, 6: Image.Transpose.ROTATE_270, 8: Image.Transpose.ROTATE_90}[orientation]))
        assert frame.color.shape == upright.shape and np.abs(frame.color.astype(int) - upright).mean() < 3
        near_px = frame.depth_m < 2.0  # the square, in the depth map, lies where the bright square is in the photo
        assert np.array_equal(near_px, upright[..., 0] > 128)
        # the principal point (stored at +3, -2 px from the centre) turns with the image
        cam = frame.rig.color
        cx0, cy0 = 43.0, 28.0
        expect = {3: (79 - cx0, 59 - cy0), 6: (59 - cy0, cx0), 8: (cy0, 79 - cx0)}[orientation]
        assert (cam.width, cam.height) == (upright.shape[1], upright.shape[0])
        assert (cam.cx, cam.cy) == pytest.approx(expect)


class TestGDepth:
    def test_round_trip_over_many_segments(self, tmp_path):
        rng = np.random.default_rng(1)
        color = rng.integers(0, 255, (120, 160, 3), np.uint8)  # an incompressible depth PNG: several APP1 chunks
        z = rng.uniform(0.6, 6.0, (120, 160))
        values = encode(z, 0.5, 8.0, "RangeInverse")
        data = gdepth_jpeg(color, values, near=0.5, far=8.0, chunk=20000)
        assert data.count(b"http://ns.adobe.com/xmp/extension/") >= 2
        with open_source(write(tmp_path, "g.jpg", data)) as src:
            frame = src.frame(0)
        assert within_half_step(frame.depth_m, z, 0.5, 8.0, "RangeInverse", 255)
        assert frame.rig.color.fx == pytest.approx(26 * np.hypot(160, 120) / np.hypot(36, 24))

    def test_real_lens_blur_photo(self):
        with open_source(REAL_GDEPTH) as src:
            info, frame = src.info(), src.frame(0)
        d = info["phone"]["depth"]
        assert (d["container"], d["format"], d["metric"]) == ("GDepth", "RangeInverse", False)
        assert frame.color.shape == (2048, 1536, 3) and frame.depth_m.shape == (2048, 1536)
        assert d["near_m"] <= frame.depth_m.min() and frame.depth_m.max() <= d["far_m"]
        assert info["phone"]["camera"]["focal_35mm"] == 34


HOSTILE = {
    "garbage XMP": lambda c, v: jpeg_with(c, [app1(XMP_STD + b'<x:xmpmeta xmlns:GDepth="http://ns.google.com/photos/'
                                                           b'1.0/depthmap/" <<< GDepth:Format= not xml')]),
    "base64 that does not decode": lambda c, v: gdepth_jpeg(c, v, near=1, far=5, data_b64="!!!not base64!!!"),
    "base64 of no image": lambda c, v: gdepth_jpeg(c, v, near=1, far=5, data_b64=base64.b64encode(b"hello").decode()),
    "missing extended XMP": lambda c, v: gdepth_jpeg(c, v, near=1, far=5, drop_chunk=True),
    "near beyond far": lambda c, v: gdepth_jpeg(c, v, near=5, far=1),
    "unknown format": lambda c, v: gdepth_jpeg(c, v, near=1, far=5, fmt="RangeCubic"),
    "truncated": lambda c, v: dynamic_depth_jpeg(c, v, near=1, far=5, fmt="RangeLinear")[:-400],
    "depth of another aspect ratio": lambda c, v: gdepth_jpeg(c, v[:, :40], near=1, far=5),
    "no depth": lambda c, v: jpeg_with(c, [app1(XMP_STD + xmp_packet(
        'GDepth:Mime="image/png">', {"GDepth": "http://ns.google.com/photos/1.0/depthmap/"}))]),
}


class TestHostile:
    @pytest.mark.parametrize("case", list(HOSTILE))
    def test_one_clear_line(self, tmp_path, case):
        color, z = scene()
        path = write(tmp_path, "bad.jpg", HOSTILE[case](color, encode(z, 1, 5, "RangeLinear")))
        with pytest.raises(ImageReadError):
            open_source(path).frame(0)
        result = CliRunner().invoke(main, ["info", path], prog_name="pcdof")
        assert result.exit_code == 3, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcdof: error: ") and "Traceback" not in result.output
