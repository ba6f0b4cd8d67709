"""The fill on rigs that look like real sensors: holes inside the depth view and strips outside it.

Each case (:func:`pcdof.synth.rigs.rig_case`) is a procedural scene shot by a device rig drawn from
the seed: colour wider than depth on one axis (Kinect v2) or both (Kinect v1, wide-both), or colour
inside depth (RealSense D435), with IR-projector shadows, dropouts on dark glossy surfaces, thin
structures and near objects cut by the frame border. The sensor's depth is registered into the
colour camera; each fill fills its holes, scored against the exact colour-camera depth:

* ``mae_mm`` at every hole, ``mae_inside_mm`` at holes whose true surface the depth camera's view
  covers (shadows, dropouts, disocclusions), ``mae_outside_mm`` in the strips it does not cover;
* ``too_near_pct`` / ``too_far_pct``: holes filled more than :data:`OFF_M` nearer / farther than true;
* ``mae_edge_mm`` at the *measured* pixels within :data:`EDGE_PX` of a true depth discontinuity (a relative
  jump over :data:`EDGE_JUMP` between 4-neighbours of the exact depth), ``edge_off_pct`` the share of them
  more than :data:`OFF_M` off: what a rule that moves measured depth at its edges
  (:func:`pcdof.stages.fill.align_depth_edges`) changes, the holes' scores do not see;
* ``render_db``: PSNR (dB) of pcdof's render from the filled depth against its render from the exact
  depth (same colour, same lens: focus on the nearest tenth of the scene, a largest blur of 2.5 % of
  the width), i.e. what the fill's errors cost the picture (higher is better; inf = no cost).

Rules are chosen on :data:`TUNING_SEEDS` and reported on :data:`REPORT_SEEDS` (never the same).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from . import table_lines

#: a hole filled more than this far (metres) from the true depth is counted too near or too far
OFF_M = 0.05
#: measured pixels this near (px) to a true depth discontinuity are scored as ``mae_edge_mm``, ``edge_off_pct``
EDGE_PX = 3
#: relative depth jump between 4-neighbours of the exact depth that makes a discontinuity
EDGE_JUMP = 0.05
#: seeds that chose the border rule, and seeds that are reported (28 consecutive seeds: every scene and rig)
TUNING_SEEDS = tuple(range(0, 28))
REPORT_SEEDS = tuple(range(1000, 1028))
#: largest blur of the render-cost lens, as a share of the colour width
BLUR_SHARE = 0.025


def default_methods() -> dict:
    """Method name -> fill(depth_m, color): pcdof's default as the pipeline's fill stage runs it (depth edges aligned,
    then filled: :func:`pcdof.stages.fill.fill_aligned`), the fill without the alignment, the other border rules,
    and OpenCV's Telea."""
    from ..stages.fill import BORDER_RULES, DEFAULT_BORDER, fill_aligned, fill_joint_bilateral, fill_telea

    out = {"pcdof": lambda d, c: fill_aligned(d, c)[0],
           "pcdof without edge alignment": lambda d, c: fill_joint_bilateral(d, c)}
    for rule in BORDER_RULES:
        if rule != DEFAULT_BORDER:
            out[f"pcdof border={rule}"] = lambda d, c, rule=rule: fill_aligned(d, c, border=rule)[0]
    out["telea"] = lambda d, c: fill_telea(d, c)
    return out


def outside_view(sf) -> np.ndarray:
    """(H, W) bool: colour pixels whose true surface point lies outside the depth camera's image."""
    rig = sf.rig
    c, d = rig.color, rig.depth
    z = sf.depth_color_m.astype(np.float64)
    v, u = np.mgrid[0:c.height, 0:c.width].astype(np.float64)
    pts = np.stack([(u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z], axis=-1)
    R, t = rig.T_color_from_depth[:3, :3], rig.T_color_from_depth[:3, 3]
    q = (pts - t) @ R  # R^T (p - t), row vectors
    with np.errstate(divide="ignore", invalid="ignore"):
        ud = d.fx * q[..., 0] / q[..., 2] + d.cx
        vd = d.fy * q[..., 1] / q[..., 2] + d.cy
    inside = (q[..., 2] > 0) & (ud >= -0.5) & (ud <= d.width - 0.5) & (vd >= -0.5) & (vd <= d.height - 0.5)
    return ~inside & (z > 0)


def score(filled, truth, holes, outside, near_edge=None) -> dict:
    """Errors of a filled depth map at the holes, split inside / outside the depth camera's view; with
    *near_edge* ((H, W) bool), also at the measured pixels (not *holes*) it marks."""
    diff = filled.astype(np.float64) - truth
    err = np.abs(diff)
    edge = {}
    if near_edge is not None:
        measured = near_edge & ~holes & (truth > 0)
        m = max(1, int(measured.sum()))
        edge = {"mae_edge_mm": float(err[measured].mean() * 1e3) if measured.any() else float("nan"),
                "edge_off_pct": float(100.0 * np.count_nonzero(measured & (err > OFF_M)) / m)}

    def mae(mask):
        return float(err[mask].mean() * 1e3) if mask.any() else float("nan")

    n = max(1, int(holes.sum()))
    return {"mae_mm": mae(holes), "mae_inside_mm": mae(holes & ~outside), "mae_outside_mm": mae(holes & outside),
            "too_near_pct": float(100.0 * np.count_nonzero(holes & (diff < -OFF_M)) / n),
            "too_far_pct": float(100.0 * np.count_nonzero(holes & (diff > OFF_M)) / n), **edge}


def _render_lens(sf):
    from ..synth.wide import lens_for_blur

    z = sf.depth_color_m[sf.depth_color_m > 0]
    focus = float(np.percentile(z, 10))
    return lens_for_blur(sf.depth_color_m, sf.rig.color.fx, focus, BLUR_SHARE * sf.rig.color.width)


def _render(sf, depth, lens) -> np.ndarray:
    from ..color import to_float
    from ..pipeline import render_from_depth

    image, _ = render_from_depth(sf.color, depth, lens, sf.rig.color.fx, max_range_m=sf.rig.max_range_m,
                                 highlights="off")
    return to_float(image)


def run_fill_rigs(*, seeds=REPORT_SEEDS, color_width: int = 256, methods=None, render: bool = True,
                  progress: bool = False) -> list[dict]:
    """Fill every case's registered sensor depth with each method; one row per (case, method).

    Parameters
    ----------
    seeds : case seeds (:data:`REPORT_SEEDS` to report, :data:`TUNING_SEEDS` to choose rules)
    color_width : int, colour width of the cases in pixels
    methods : {name: fill(depth_m, color)} or None for :func:`default_methods`
    render : bool, also measure ``render_db`` (the render cost)
    progress : bool, show a progress bar

    Returns
    -------
    list of dict: seed, scene, rig, holes_pct, outside_pct (of the holes), method, and the keys of
    :func:`score`, render_db (when *render*)
    """
    from tqdm.auto import tqdm

    from ..metrics import depth_edge_band, psnr
    from ..stages.register import register_depth
    from ..synth.rigs import rig_case

    seeds = [int(s) for s in seeds]
    if not seeds or any(s < 0 for s in seeds):
        raise InputError(f"seeds must be a non-empty list of integers >= 0; got {seeds!r}")
    methods = default_methods() if methods is None else dict(methods)
    if not methods or not all(callable(f) for f in methods.values()):
        raise InputError("methods must be a non-empty {name: fill(depth_m, color)} dict")
    rows = []
    for seed in tqdm(seeds, desc="fill-rigs", disable=not progress):
        sf = rig_case(seed, color_width=color_width)
        registered = register_depth(sf.frame)
        holes = registered == 0
        if not holes.any():
            continue
        outside = outside_view(sf)
        near_edge = depth_edge_band(sf.depth_color_m, EDGE_PX, rel_jump=EDGE_JUMP)
        lens = _render_lens(sf) if render else None
        reference = _render(sf, sf.depth_color_m, lens) if render else None
        for name, fn in methods.items():
            filled = fn(registered, sf.color)
            row = {"seed": seed, "scene": sf.metadata["scene_kind"], "rig": sf.metadata["rig"],
                   "holes_pct": float(100.0 * holes.mean()),
                   "outside_pct": float(100.0 * (holes & outside).sum() / holes.sum()), "method": name,
                   **score(filled, sf.depth_color_m, holes, outside, near_edge)}
            if render:
                row["render_db"] = psnr(_render(sf, filled, lens), reference)
            rows.append(row)
    return rows


def _mean(values) -> float:
    v = [x for x in values if np.isfinite(x)]
    return float(np.mean(v)) if v else float("nan")


def summary(rows: list[dict], by: str | None = None) -> list[dict]:
    """Mean of each score per method (and per value of *by*: "scene" or "rig"), in the rows' order."""
    keys = ("mae_mm", "mae_inside_mm", "mae_outside_mm", "too_near_pct", "too_far_pct", "mae_edge_mm",
            "edge_off_pct", "render_db")
    groups: dict = {}
    for r in rows:
        groups.setdefault((r[by] if by else "all", r["method"]), []).append(r)
    return [{"group": g, "method": m, "cases": len(rs),
             **{k: _mean([r.get(k, float("nan")) for r in rs]) for k in keys}} for (g, m), rs in groups.items()]


def markdown_table(rows: list[dict], by: str | None = None) -> str:
    """:func:`summary` of *rows* as a markdown table."""
    columns = ("group", "method", "cases", "hole MAE mm", "inside-view MAE", "outside-view MAE", "too near %",
               "too far %", "measured at edges MAE", "off at edges %", "render dB")
    return "\n".join(table_lines(columns, (
        (s["group"], s["method"], str(s["cases"]), f"{s['mae_mm']:.1f}", f"{s['mae_inside_mm']:.1f}",
         f"{s['mae_outside_mm']:.1f}", f"{s['too_near_pct']:.2f}", f"{s['too_far_pct']:.2f}",
         f"{s['mae_edge_mm']:.1f}", f"{s['edge_off_pct']:.2f}", f"{s['render_db']:.2f}") for s in summary(rows, by))))
