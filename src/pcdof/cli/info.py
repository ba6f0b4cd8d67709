"""`pcdof info`: what a recording holds: streams, frame count, resolutions, calibration."""

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
    """Describe RECORDING (an Azure Kinect .mkv or a RealSense .bag)."""
    from ..sources import open_source

    with open_source(recording, calib=calib) as src:
        info = src.info()
    if as_json:
        click.echo(json.dumps(info, indent=2))
        return
    click.echo(format_info(info))


def format_info(info: dict) -> str:
    """The human-readable summary of :meth:`FrameSource.info`."""
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
    for cam in ("color", "depth"):
        c = cal[cam]
        dist = ", ".join(f"{d:.6g}" for d in c["distortion"])
        lines.append(f"  {cam}: {c['width']}x{c['height']} fx {c['fx']:.3f} fy {c['fy']:.3f} cx {c['cx']:.3f} "
                     f"cy {c['cy']:.3f} distortion [{dist}]")
    T = cal["T_color_from_depth"]
    lines.append("  T_color_from_depth (metres): " + "; ".join(" ".join(f"{v:.6f}" for v in row) for row in T[:3]))
    return "\n".join(lines)
