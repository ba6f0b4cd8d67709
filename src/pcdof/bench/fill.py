"""Hole filling against cv2.inpaint (Telea) on the ray-traced ground truth.

For each synthetic scene the sensor's noisy depth is registered into the colour camera
(:func:`pcdof.stages.register.register_depth`); its holes are what every method fills, and the error is
measured at those pixels against the exact colour-camera depth (``depth_color_m``). Holes are
split into *disocclusions* (still missing when the exact, noise-free depth is registered: the
colour camera sees what the depth camera does not, or outside its view) and *sensor* holes (the
rest: projector shadows, dark glossy dropouts, range limits). Times are medians of interleaved
runs in one process, JIT warm-up excluded.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from ..stages.fill import FILL_METHODS, warmup
from . import table_lines

#: A filled pixel more than this far off (relative) took the wrong surface.
WRONG_SURFACE_RATIO = 0.05


def _case(name: str, size, depth_size, seed: int):
    from ..camera import RGBDFrame
    from ..stages.register import register_depth
    from ..synth import generate_scene

    kwargs = {} if depth_size is None else {"depth_size": tuple(depth_size)}
    sf = generate_scene(name, color_size=tuple(size), seed=seed, **kwargs)
    registered = register_depth(sf.frame)
    registered_clean = register_depth(RGBDFrame(sf.color, sf.depth_clean_m, sf.rig))
    return sf, registered, registered_clean


def score(filled: np.ndarray, truth: np.ndarray, holes: np.ndarray, disoccluded: np.ndarray) -> dict:
    """Errors (mm) of a filled depth map at the holes, overall and per kind of hole."""
    err = np.abs(filled.astype(np.float64) - truth)
    rel = err / np.maximum(truth, 1e-9)

    def mae(mask):
        return float(err[mask].mean() * 1e3) if mask.any() else float("nan")

    return {
        "mae_mm": mae(holes), "p95_mm": float(np.percentile(err[holes], 95) * 1e3),
        "mae_disocclusion_mm": mae(holes & disoccluded), "mae_sensor_mm": mae(holes & ~disoccluded),
        "wrong_surface_pct": float(100.0 * (rel[holes] > WRONG_SURFACE_RATIO).mean()),
    }


def run_fill_bench(*, scenes=None, size=(640, 480), depth_size=None, seed: int = 0, methods=None,
                   repeats: int = 5, quick: bool = False, progress: bool = False) -> list[dict]:
    """Fill the registered sensor depth of each scene with each method; one row per (scene, method).

    Parameters
    ----------
    scenes : sequence of :data:`pcdof.synth.SCENES` names, or None for all (two when ``quick``)
    size : (W, H), colour size of the scenes (``quick``: 160x120)
    depth_size : (w, h) of the depth camera, or None for the synthetic rig's default
    seed : int, scene and sensor-noise seed
    methods : sequence of :data:`pcdof.stages.fill.FILL_METHODS` names, or None for all
    repeats : int, timed runs per method (median reported; ``quick``: 1)
    quick : bool, a smoke run
    progress : bool, show a progress bar

    Returns
    -------
    list of dict rows: scene, color_size, holes_pct, disocclusion_pct (of the holes), method,
    mae_mm, p95_mm, mae_disocclusion_mm, mae_sensor_mm, wrong_surface_pct, time_ms,
    mae_vs_telea (this method's MAE / Telea's; present when Telea ran). Scenes without holes
    give no rows.
    """
    from tqdm.auto import tqdm

    from ..synth import SCENES

    if quick:
        size, depth_size, repeats = (160, 120), (128, 106), 1
    names = list(SCENES) if scenes is None else list(scenes)
    if quick and scenes is None:
        names = names[:2]
    methods = list(FILL_METHODS) if methods is None else list(methods)
    unknown = [m for m in methods if m not in FILL_METHODS]
    if unknown:
        from ..errors import InputError

        raise InputError(f"methods must be among {sorted(FILL_METHODS)}; got {unknown}")
    warmup()
    rows = []
    for name in tqdm(names, desc="fill", disable=not progress):
        sf, registered, registered_clean = _case(name, size, depth_size, seed)
        holes = registered == 0
        if not holes.any():
            continue
        disoccluded = registered_clean == 0
        color = sf.color
        times = {m: [] for m in methods}
        outs = {}
        for _ in range(max(1, int(repeats))):
            for m in methods:  # interleaved, so load changes hit every method alike
                t0 = time.perf_counter()
                outs[m] = FILL_METHODS[m](registered, color)
                times[m].append(time.perf_counter() - t0)
        group = []
        for m in methods:
            group.append({
                "scene": name, "color_size": f"{size[0]}x{size[1]}",
                "holes_pct": float(100.0 * holes.mean()),
                "disocclusion_pct": float(100.0 * (holes & disoccluded).sum() / holes.sum()),
                "method": m, **score(outs[m], sf.depth_color_m, holes, disoccluded),
                "time_ms": statistics.median(times[m]) * 1e3,
            })
        telea = next((r for r in group if r["method"] == "telea"), None)
        if telea is not None:
            for r in group:
                r["mae_vs_telea"] = r["mae_mm"] / telea["mae_mm"] if telea["mae_mm"] > 0 else float("nan")
        rows += group
    return rows


def markdown_table(rows: list[dict]) -> str:
    """The rows of :func:`run_fill_bench` as a markdown table."""
    columns = ("scene", "size", "holes %", "method", "MAE mm", "disocclusion MAE", "sensor-hole MAE", "p95 mm",
               "wrong surface %", "vs Telea", "ms")
    return "\n".join(table_lines(columns, (
        (r["scene"], r["color_size"], f"{r['holes_pct']:.1f}", r["method"], f"{r['mae_mm']:.1f}",
         f"{r['mae_disocclusion_mm']:.1f}", f"{r['mae_sensor_mm']:.1f}", f"{r['p95_mm']:.0f}",
         f"{r['wrong_surface_pct']:.2f}", f"{r['mae_vs_telea']:.3f}" if "mae_vs_telea" in r else "-",
         f"{r['time_ms']:.1f}") for r in rows)))
