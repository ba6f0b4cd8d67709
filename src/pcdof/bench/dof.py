"""Time against error on the ray-traced thin-lens ground truth.

For every scene of :data:`pcdof.synth.SCENES` and every lens setting, each method renders the
sensor's RGB-D frame (noisy depth from the separate depth camera, registered and filled by the
method itself) and is scored against the ray-traced thin-lens image:

* PSNR and SSIM of the sRGB-encoded result, overall, in the band around depth edges (pixels within
  max(3, c_max/2) px of a ground-truth depth discontinuity) and in the interior (the rest);
* median wall time per stage over repeated runs (first run, with JIT compilation, excluded).
"""

from __future__ import annotations

import dataclasses

import hashlib
import io
import json
import os
import statistics
import time
from dataclasses import dataclass

import numpy as np

from ..color import linear_to_srgb, to_float
from ..lens import PaperLens, ThinLens
from ..metrics import depth_edge_band, psnr, ssim_map
from . import blender, check_repeats, check_scenes, plot_to

#: f-number multipliers of the scene's own lens: the benchmark's lens settings
SETTINGS = {"wide": 1.0, "stopped-down": 2.5}


@dataclass
class Method:
    name: str
    run: callable  # (synthetic frame, ThinLens) -> (image uint8, {stage: seconds})


def _physical(quality):
    def method(sf, lens):
        from ..pipeline import run

        res = run(sf.frame, lens, quality=quality)
        return res.image, {t.name: t.seconds for t in res.trace}

    return method


def paper_lens_matching(sf, lens: ThinLens) -> PaperLens:
    """The paper method's blur chosen as the paper says: the blur expected for the farthest points
    (a Gaussian of sigma c_max/4, which has the variance of a disc of diameter c_max)."""
    cmax = float(lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
    return PaperLens(focus_distance_m=lens.focus_distance_m, blur_sigma_px=max(cmax / 4, 0.3))


def _paper(sf, lens):
    from ..pipeline import run

    res = run(sf.frame, paper_lens_matching(sf, lens), method="paper")
    return res.image, {t.name: t.seconds for t in res.trace}


def _baseline(sf, lens):
    from .baseline import render_baseline

    return render_baseline(sf.frame, lens)


def _blender(sf, lens):
    from .blender import render_blender

    return render_blender(sf, lens)


#: the peers every table compares pcdof with: the seed paper's method, the gather baseline and, when an
#: interpreter with Blender is at hand (:func:`pcdof.bench.blender.available`), Blender's Defocus node
PEERS = ("paper", "baseline", *((blender.NAME,) if blender.available() else ()))

METHODS = {
    **{f"pcdof-{q}": Method(f"pcdof-{q}", _physical(q)) for q in ("exact", "high", "balanced", "fast")},
    "paper": Method("paper", _paper),
    "baseline": Method("baseline", _baseline),
    **({blender.NAME: Method(blender.NAME, _blender)} if blender.NAME in PEERS else {}),
}


def _gt_cache_path(cache_dir, name, size, depth_size, seed, lens, samples):
    key = json.dumps([name, size, depth_size, seed, lens.focal_length_mm, lens.f_number, lens.focus_distance_m,
                      lens.aperture_blades, samples])
    return os.path.join(cache_dir, f"gt_{name}_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npy")


def ground_truth(sf, lens, *, samples, seed, cache_dir=None, name="", size=None, depth_size=None):
    """Ray-traced linear ground truth, cached on disk when *cache_dir* is given."""
    from ..synth import render_thin_lens

    path = _gt_cache_path(cache_dir, name, size, depth_size, seed, lens, samples) if cache_dir else None
    if path and os.path.exists(path):
        return np.load(path)
    gt = render_thin_lens(sf, lens, samples=samples, seed=seed + 1)
    if path:  # atomic: a temporary file, then a rename (missing folders are created)
        from ..io._files import atomic_write_bytes

        buf = io.BytesIO()
        np.save(buf, gt, allow_pickle=False)
        atomic_write_bytes(path, buf.getvalue())
    return gt


def score(image, gt_srgb, band) -> dict:
    img = to_float(image)
    smap = ssim_map(img, gt_srgb)
    interior = ~band
    return {
        "psnr": psnr(img, gt_srgb), "psnr_edge": psnr(img, gt_srgb, mask=band),
        "psnr_interior": psnr(img, gt_srgb, mask=interior),
        "ssim": float(smap.mean()), "ssim_edge": float(smap[band].mean()) if band.any() else float("nan"),
        "ssim_interior": float(smap[interior].mean()),
    }


def run_dof_bench(*, scenes=None, size=(320, 240), depth_size=(256, 212), settings=None, methods=None,
                  repeats: int = 5, samples=None, seed: int = 0, cache_dir=None, progress: bool = True) -> list[dict]:
    """Score every method on every scene and lens setting. Returns one row per (scene, setting, method).

    *scenes* are names of :data:`pcdof.synth.SCENES` (None = all), *repeats* the timed runs per
    measurement (>= 1); both are checked before any work (InputError).
    """
    from tqdm.auto import tqdm

    from ..synth import SCENES, generate_scene

    repeats = check_repeats(repeats)
    scenes = check_scenes(scenes) or list(SCENES)
    settings = dict(settings or SETTINGS)
    methods = [METHODS[m] for m in (methods or METHODS)]
    rows = []
    bar = tqdm(total=len(scenes) * len(settings) * len(methods), desc="dof bench", disable=not progress,
               unit="run")
    for name in scenes:
        sf = generate_scene(name, color_size=tuple(size), depth_size=tuple(depth_size), seed=seed)
        base = sf.default_lens
        for setting, mult in settings.items():
            lens = dataclasses.replace(base, f_number=base.f_number * mult)
            bar.set_postfix_str(f"{name}/{setting}: ground truth")
            gt_lin = ground_truth(sf, lens, samples=samples, seed=seed, cache_dir=cache_dir, name=name, size=size,
                                  depth_size=depth_size)
            gt = linear_to_srgb(np.clip(gt_lin, 0, 1))
            cmax = float(lens.coc_px(sf.depth_color_m, sf.rig.color.fx).max())
            band = depth_edge_band(sf.depth_color_m, max(3, int(round(cmax / 2))))
            for m in methods:
                bar.set_postfix_str(f"{name}/{setting}: {m.name}")
                m.run(sf, lens)  # warm-up (JIT compilation, caches), not timed
                times = []
                image = None
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    image, stages = m.run(sf, lens)
                    times.append((time.perf_counter() - t0, stages))
                med = statistics.median(t for t, _ in times)
                stage_names = sorted({k for _, s in times for k in s})
                row = {"scene": name, "setting": setting, "f_number": lens.f_number,
                       "focus_distance_m": lens.focus_distance_m, "max_coc_px": cmax, "method": m.name,
                       "ms": med * 1e3,
                       **{f"ms_{k}": statistics.median(s.get(k, 0.0) for _, s in times) * 1e3 for k in stage_names},
                       **score(image, gt, band)}
                rows.append(row)
                bar.update()
    bar.close()
    return rows


def _mean_finite(values) -> float:
    """Mean of the non-NaN values (NaN when there are none, without numpy's all-NaN warning)."""
    v = [x for x in values if not np.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


def summarize(rows: list[dict]) -> list[dict]:
    """Per method: mean PSNR overall / edge band, mean SSIM, median time, and wins over the others."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == m]
        out.append({"method": m, "psnr": float(np.mean([r["psnr"] for r in mine])),
                    "psnr_edge": _mean_finite([r["psnr_edge"] for r in mine]),
                    "ssim": float(np.mean([r["ssim"] for r in mine])),
                    "ms": float(np.median([r["ms"] for r in mine]))})
    return out


def markdown_table(rows: list[dict]) -> str:
    head = "| scene | setting | max CoC px | method | PSNR dB | PSNR edge | PSNR interior | SSIM | SSIM edge | ms |"
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['setting']} (f/{r['f_number']:g}) | {r['max_coc_px']:.1f} | {r['method']} | "
                     f"{r['psnr']:.2f} | {r['psnr_edge']:.2f} | {r['psnr_interior']:.2f} | {r['ssim']:.4f} | "
                     f"{r['ssim_edge']:.4f} | {r['ms']:.1f} |")
    return "\n".join(lines)


def compact_table(rows: list[dict], ours: str = "pcdof-balanced", others=None) -> str:
    """One line per scene and lens setting: PSNR overall / edge band and time of *ours* and *others* (default:
    the :data:`PEERS` in *rows*), and the margin of *ours* over the best of the others (dB, overall / edge band)."""
    others = peers_in(rows) if others is None else others
    head = f"| scene | setting | max CoC px | {ours} dB (edge) ms | " + " | ".join(
        f"{o} dB (edge) ms" for o in others) + " | margin dB (edge) |"
    lines = [head, "|" + "---|" * (5 + len(others))]
    cases = list(dict.fromkeys((r["scene"], r["setting"]) for r in rows))
    for scene, setting in cases:
        by = {r["method"]: r for r in rows if r["scene"] == scene and r["setting"] == setting}
        if ours not in by:
            continue

        def cell(r):
            edge = "-" if np.isnan(r["psnr_edge"]) else f"{r['psnr_edge']:.1f}"
            return f"{r['psnr']:.1f} ({edge}) {r['ms']:.0f}"

        best = max(by[o]["psnr"] for o in others if o in by)
        edges = [by[o]["psnr_edge"] for o in others if o in by and not np.isnan(by[o]["psnr_edge"])]
        best_edge = max(edges) if edges else np.nan  # (np.nanmax of all-NaN warns)
        mine = by[ours]
        margin_edge = "-" if np.isnan(best_edge) else f"{mine['psnr_edge'] - best_edge:+.1f}"
        lines.append(f"| {scene} | {setting} (f/{mine['f_number']:g}) | {mine['max_coc_px']:.1f} | {cell(mine)} | "
                     + " | ".join(cell(by[o]) if o in by else "-" for o in others)
                     + f" | {mine['psnr'] - best:+.1f} ({margin_edge}) |")
    return "\n".join(lines)


def peers_in(rows: list[dict]) -> tuple[str, ...]:
    """The peers of :data:`PEERS` (and Blender's, whatever this machine has) that *rows* hold, in that order."""
    there = {r["method"] for r in rows}
    return tuple(p for p in ("paper", "baseline", blender.NAME) if p in there)


def summary_table(rows: list[dict]) -> str:
    """Per method over all scenes and settings: mean PSNR, mean edge-band PSNR, mean SSIM, median ms."""
    lines = ["| method | mean PSNR dB | mean PSNR edge band dB | mean SSIM | median ms |", "|---|---|---|---|---|"]
    for s in summarize(rows):
        lines.append(f"| {s['method']} | {s['psnr']:.2f} | {s['psnr_edge']:.2f} | {s['ssim']:.4f} | {s['ms']:.1f} |")
    return "\n".join(lines)


#: one colour and marker per method (colour-blind-safe palette), reused by the other bench plots
STYLE = {"pcdof-exact": ("#4477aa", "o"), "pcdof-high": ("#66ccee", "s"), "pcdof-balanced": ("#228833", "D"),
         "pcdof-fast": ("#ccbb44", "^"), "pcdof-balanced+hl": ("#aa3377", "P"), "paper": ("#ee6677", "v"),
         "baseline": ("#555555", "X"), blender.NAME: ("#ee7733", "h")}


def method_style(name: str, index: int) -> tuple[str, str]:
    """(colour, marker) of a method: fixed for the known ones, distinct for the rest."""
    if name in STYLE:
        return STYLE[name]
    extra = ("#bbbbbb", "#882255", "#117733", "#999933")
    return extra[index % len(extra)], "ph*8"[index % 4]


def pareto_plot(rows: list[dict], path: str) -> None:
    """Median time against mean PSNR per method (filled: whole frame, hollow: edge band), as a PNG.

    Each method has its own colour and marker; the names are in a legend outside the axes, so no
    label covers a point or another label.
    """
    from matplotlib.lines import Line2D

    summary = summarize(rows)
    handles = []
    with plot_to(path, figsize=(8, 4.2)) as (_, ax):
        for i, s in enumerate(summary):
            colour, marker = method_style(s["method"], i)
            ax.scatter(s["ms"], s["psnr"], s=60, color=colour, marker=marker, zorder=3)
            if not np.isnan(s["psnr_edge"]):
                ax.scatter(s["ms"], s["psnr_edge"], s=60, facecolors="none", edgecolors=colour, marker=marker,
                           zorder=3)
                ax.plot([s["ms"]] * 2, [s["psnr"], s["psnr_edge"]], color=colour, lw=0.8, alpha=0.6, zorder=2)
            handles.append(Line2D([], [], color=colour, marker=marker, ls="", label=s["method"]))
        handles += [Line2D([], [], color="k", marker="o", ls="", label="filled: whole frame"),
                    Line2D([], [], color="k", marker="o", ls="", markerfacecolor="none",
                           label="hollow: depth-edge band")]
        ax.set_xscale("log")
        ax.set_xlabel("median time per frame, ms (log)")
        ax.set_ylabel("mean PSNR vs ray-traced ground truth, dB")
        ax.set_title("time against error (higher and further left is better)")
        ax.grid(True, alpha=0.3)
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
