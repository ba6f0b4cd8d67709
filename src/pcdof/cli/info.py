"""`pcdof info`: what a recording or phone depth photo holds: streams, frames, depth encoding, calibration."""

from __future__ import annotations

import json

import click

from ._common import handle_errors


@click.command("info")
@click.argument("recording", type=click.Path(readable=False))
@click.option("--calib", type=click.Path(readable=False), default=None,
              help="Calibration to use instead of the recording's (calib.json, OpenCV .yml/.xml, Open3D JSON).")
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@handle_errors
def command(recording, calib, as_json):
    """Describe RECORDING (an Azure Kinect .mkv, a RealSense .bag, or a phone depth photo .heic / .jpg)."""
    from ..sources import open_source

    with open_source(recording, calib=calib) as src:
        info = src.info()
    if as_json:
        click.echo(json.dumps(info, indent=2))
        return
    click.echo(format_info(info))


def format_info(info: dict) -> str:
    """The human-readable summary of :meth:`FrameSource.info`."""
    if "phone" in info:
        return format_phone_info(info)
    pair = info["pairing"]
    within = (f"paired within {pair['max_difference_s'] * 1000:.1f} ms" if "max_difference_s" in pair
              else f"{info.get('layout', info['format'])} layout, paired by name")
    lines = [f"{info['path']}: {info['format']}, {info['frames']} colour+depth frames "
             f"({within}; unpaired: {pair['unpaired_color']} colour, {pair['unpaired_depth']} depth)"]
    for name, s in info["streams"].items():
        extra = ", ".join(f"{k} {v}" for k, v in s.items() if k not in ("width", "height", "frames"))
        lines.append(f"  {name}: {s['width']}x{s['height']}, {s['frames']} frames" + (f", {extra}" if extra else ""))
    cal = info["calibration"]
    lines.append(f"calibration (from {info['calibration_from']}): depth scale {cal['depth_scale']:g} m/unit, "
                 f"baseline {info['baseline_mm']:.2f} mm, max range {cal['max_range_m']:g} m")
    lines += format_cameras(cal)
    return "\n".join(lines)


def format_cameras(cal: dict) -> list[str]:
    """The calibration's two cameras and their transform, one line each."""
    lines = []
    for cam in ("color", "depth"):
        c = cal[cam]
        dist = ", ".join(f"{d:.6g}" for d in c["distortion"])
        lines.append(f"  {cam}: {c['width']}x{c['height']} fx {c['fx']:.3f} fy {c['fy']:.3f} cx {c['cx']:.3f} "
                     f"cy {c['cy']:.3f} distortion [{dist}]")
    T = cal["T_color_from_depth"]
    lines.append("  T_color_from_depth (metres): " + "; ".join(" ".join(f"{v:.6f}" for v in row) for row in T[:3]))
    return lines


def format_phone_info(info: dict) -> str:
    """The summary of a phone depth photo: the depth map, its representation and range, the intrinsics used."""
    d, cam, cal = info["phone"]["depth"], info["phone"]["camera"], info["calibration"]
    c = cal["color"]
    what = d.get("representation") or f"{d.get('container')} {d.get('format')}"
    lines = [f"{info['path']}: {info['format']}, one photo {c['width']}x{c['height']} with a "
             f"{d['width']}x{d['height']} {d['bits']}-bit depth map"]
    if "representation_type" in d:
        lines.append(f"  depth: {what} (type {d['representation_type']})" + (f", {d['units']}" if "units" in d
                                                                             and d["units"] else ""))
    else:
        lines.append(f"  depth: {what}, near {d['near']:g} far {d['far']:g} {d.get('units') or '(no units)'}")
    metric = d.get("metric", True)
    unit = "m" if metric else "file units (no metric scale: --blur works, physical f-numbers do not)"
    lines.append(f"  depth range: {d['near_m']:.4g} .. {d['far_m']:.4g} {unit}" + (
        f"; in this photo {d['measured_range_m'][0]:.4g} .. {d['measured_range_m'][1]:.4g}"
        if d.get("measured_range_m") else ""))
    exif = ", ".join(f"{k} {cam[k]:g}" for k in ("focal_length_mm", "focal_35mm", "f_number") if cam.get(k))
    lines.append(f"  camera: {cam.get('model') or 'unknown model'}; EXIF {exif or 'without lens data'}; "
                 f"orientation {cam.get('exif_orientation') or 1}")
    lines.append(f"intrinsics (from {info['calibration_from']}); the depth camera is the photo's camera at the "
                 "depth map's resolution:")
    return "\n".join(lines + format_cameras(cal)[:2])
