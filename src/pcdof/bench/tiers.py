"""Calibrating the quality tiers: the reduced-resolution error against ``exact``, per threshold.

A quality tier is one number, ``RenderPlan.reduce_min_coc_px`` = m: a blur layer runs on the 1/s
grid (s = 2, 4, ...) when its CoC in cells of that grid, lo / s, is at least m (so every reduced
layer has between m and 2m cells of blur). This part renders the wide benchmark's cases
(:mod:`pcdof.bench.wide`) once at full resolution and once per threshold of :data:`LADDER` from the
same registered and filled depth, and measures what each threshold costs against the ray-traced
ground truth:

* per case, the PSNR change from ``exact`` (whole frame and depth-edge band);
* the error-vs-CoC curve per reduction factor: the pixels of each layer run at 1/s, grouped by their
  CoC in cells (c / s), their squared error pooled over all cases, against ``exact``'s on the same pixels.

:func:`choose_thresholds` then picks each tier's threshold by the rule stated there. Tune on
:data:`pcdof.bench.wide.TUNING_SEEDS`, report on :data:`pcdof.bench.wide.REPORT_SEEDS`.

The wide part's rows give the tiers' error-vs-blur curve against ``exact`` too (:func:`tier_curve`, its table
and plot), with the loss each tier may have (:data:`TIER_TOLERANCE_DB`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import InputError
from . import plot_to
from .wide import BUCKETS, by_case, pooled_psnr, compare, psnr_of_sse

#: thresholds measured (CoC in cells of the reduced grid), half-octave steps
LADDER = (2.0, 2.83, 4.0, 5.66, 8.0, 11.3, 16.0, 22.6)
#: largest PSNR loss to exact (dB) a tier may have on any case (the issue: balanced 0.1, fast 0.5)
TOLERANCE_DB = {"high": 0.05, "balanced": 0.1, "fast": 0.5}
#: share of the tolerance the worst tuning case may use
MARGIN = 1.0
#: CoC-in-cells buckets of the curve (lower edges; the last is open)
CELL_BUCKETS = (1.0, 1.41, 2.0, 2.83, 4.0, 5.66, 8.0, 11.3, 16.0, 22.6)


def _psnr(sse: float, n: int) -> float:
    return float("nan") if n == 0 else (float("inf") if sse == 0 else float(-10 * np.log10(sse / n)))


def _layer_scale(signed_coc: np.ndarray, m: float) -> np.ndarray:
    """Resolution divisor of each pixel's layer (1 in focus and at full resolution) under threshold *m*, the layers
    cut at the frame's edges as the renderer cuts them (:func:`pcdof.stages.render.classify.frame_edges`)."""
    from ..plans import RenderPlan
    from ..stages.render.classify import frame_edges
    from ..stages.render.reference import layer_keys

    plan = RenderPlan(threads=1, reduce_min_coc_px=m)
    edges = frame_edges(signed_coc)
    keys = layer_keys(signed_coc, edges)  # +-k: edges[k-1] <= |c| < edges[k] of its side
    below = np.maximum(np.abs(keys) - 1, 0)  # the index of the layer's lower edge
    lo = np.where(keys < 0, edges[0][below], np.where(keys > 0, edges[1][below], 0.0))
    scales = {float(v): plan.scale(float(v)) for v in np.unique(lo)}
    return np.vectorize(lambda v: scales[float(v)], otypes=[np.int64])(lo) if scales else np.ones(lo.shape, np.int64)


def _case_curve(err_t, err_x, signed_coc, m) -> dict:
    """{(s, cell bucket): (sse tier, sse exact, pixels)} of the reduced pixels of one case."""
    s = _layer_scale(signed_coc, m)
    coc_abs = np.abs(signed_coc)
    out = {}
    cells = coc_abs / s
    for sv in np.unique(s[s > 1]):
        for i, lo in enumerate(CELL_BUCKETS):
            hi = CELL_BUCKETS[i + 1] if i + 1 < len(CELL_BUCKETS) else np.inf
            sel = (s == sv) & (cells >= lo) & (cells < hi)
            if sel.any():
                out[(int(sv), lo)] = (float(err_t[sel].sum()), float(err_x[sel].sum()), int(sel.sum()))
    return out


def _renders(sf, lens, ladder):
    """(filled depth's exact render, {m: render}, signed CoC of the filled depth) of one case, measured input."""
    from ..camera import RGBDFrame
    from ..pipeline import run
    from ..plans import plan_render
    from ..stages.render import render_image

    depth = run(RGBDFrame(sf.color, sf.depth_m, sf.rig), lens, quality="exact").depth_filled_m
    fx, exact = sf.rig.color.fx, plan_render(quality="exact")
    out = {}
    for m in (math.inf, *ladder):
        out[m] = render_image(sf.color, depth, lens, fx=fx, max_range_m=sf.rig.max_range_m, quality="exact",
                              plan=replace(exact, reduce_min_coc_px=m))[0]
    return out.pop(math.inf), out, lens.signed_coc_px(depth, fx)


def run_tiers(*, kinds=None, seeds=(0, 1, 2, 3, 4), blurs=(16, 64), reference_width_px=640, size=(256, 192),
              depth_size=(256, 212), ladder=LADDER, cache_dir=None, progress: bool = True) -> dict:
    """Render every wide case at ``exact`` and at each threshold of *ladder*; see the module docstring.

    Parameters are those of :func:`pcdof.bench.wide.run_wide` (*ladder*: thresholds, CoC in cells > 0).

    Returns
    -------
    dict: "cases" (list of {scene, seed, focus, blur_px, psnr_exact, psnr_edge_exact, "delta" {m: dB},
    "delta_edge" {m: dB}}), "curve" (list of {threshold, scale, cells, pixels, delta_db}: the PSNR change
    of the reduced pixels from exact's on the same pixels, pooled over the cases)
    """
    from tqdm.auto import tqdm

    from ..synth.wide import generate_wide, lens_for_blur
    from .wide import case_truth, checked_cases, encode_srgb8, wide_cases

    ladder = tuple(float(m) for m in ladder)
    if not ladder or any(not (math.isfinite(m) and m > 0) for m in ladder):
        raise InputError(f"ladder must be numbers > 0; got {ladder!r}")
    kinds, seeds, blurs = checked_cases(kinds, seeds, blurs, size[0], reference_width_px)
    cases, curve = [], {}
    todo = wide_cases(kinds, seeds, blurs)
    frames = {}
    for kind, seed, focus, blur in tqdm(todo, desc="tiers bench", unit="case", disable=not progress):
        if (kind, seed) not in frames:
            frames = {(kind, seed): generate_wide(kind, seed=seed, color_size=size, depth_size=depth_size)}
        sf, spec = frames[(kind, seed)]
        lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m[focus], blur)
        gt, band = case_truth(sf, lens, (kind, seed, focus, blur), size, depth_size, cache_dir)
        exact, reduced, signed_coc = _renders(sf, lens, ladder)
        err_x = np.mean((encode_srgb8(exact) - gt) ** 2, axis=2)
        row = {"scene": kind, "seed": seed, "focus": focus, "blur_px": blur,
               "psnr_exact": _psnr(float(err_x.sum()), err_x.size),
               "psnr_edge_exact": _psnr(float(err_x[band].sum()), int(band.sum())), "delta": {}, "delta_edge": {}}
        for m, img in reduced.items():
            err_t = np.mean((encode_srgb8(img) - gt) ** 2, axis=2)
            row["delta"][m] = _psnr(float(err_t.sum()), err_t.size) - row["psnr_exact"]
            row["delta_edge"][m] = _psnr(float(err_t[band].sum()), int(band.sum())) - row["psnr_edge_exact"]
            for key, (st, sx, n) in _case_curve(err_t, err_x, signed_coc, m).items():
                acc = curve.setdefault((m, *key), [0.0, 0.0, 0])
                acc[0] += st
                acc[1] += sx
                acc[2] += n
        cases.append(row)
    points = [{"threshold": m, "scale": s, "cells": c, "pixels": n, "delta_db": _psnr(st, n) - _psnr(sx, n)}
              for (m, s, c), (st, sx, n) in sorted(curve.items())]
    return {"cases": cases, "curve": points, "ladder": list(ladder)}


def worst_loss(result: dict) -> dict:
    """{threshold: (worst whole-frame change, worst edge-band change, cases losing more than 0.1 dB)}, dB."""
    out = {}
    for m in result["ladder"]:
        d = [c["delta"][m] for c in result["cases"]]
        e = [c["delta_edge"][m] for c in result["cases"]]
        out[m] = (float(min(d)), float(min(e)), int(sum(x < -0.1 for x in d)))
    return out


def choose_thresholds(results, tolerance_db=None, margin: float = MARGIN) -> dict:
    """Each tier's threshold: the smallest of the ladder whose worst case, on the whole frame and in the
    depth-edge band, in every one of *results* (a :func:`run_tiers` result, or a list of them: frame sizes),
    loses at most *margin* x the tier's tolerance to exact (inf when none does).

    The smallest threshold is the fastest (a layer's cost falls with the cube of its reduction); a
    threshold a run does not measure (missing from its ladder) does not qualify in it."""
    tolerance_db = TOLERANCE_DB if tolerance_db is None else tolerance_db
    results = [results] if isinstance(results, dict) else list(results)
    worst = [worst_loss(r) for r in results]
    ladder = sorted(set().union(*worst))
    out = {}
    for tier, tol in tolerance_db.items():
        ok = [m for m in ladder if all(m in w and min(w[m][0], w[m][1]) >= -margin * tol for w in worst)]
        out[tier] = ok[0] if ok else math.inf
    return out


def loss_table(result: dict) -> str:
    """Markdown: per threshold, the worst case's change from exact (whole / edge band) and the mean."""
    worst = worst_loss(result)
    lines = ["| threshold (CoC in cells) | worst case dB | worst edge band dB | mean dB | cases losing > 0.1 dB |",
             "|---|---|---|---|---|"]
    for m, (w, e, n) in worst.items():
        mean = float(np.mean([c["delta"][m] for c in result["cases"]]))
        lines.append(f"| {m:g} | {w:+.3f} | {e:+.3f} | {mean:+.3f} | {n} of {len(result['cases'])} |")
    return "\n".join(lines)


def curve_table(result: dict) -> str:
    """Markdown: the error-vs-CoC curve, PSNR change of the reduced pixels (dB) per scale and CoC in cells."""
    pts = result["curve"]
    cells = sorted({p["cells"] for p in pts})
    scales = sorted({p["scale"] for p in pts})
    lines = ["| scale | " + " | ".join(f"{c:g}+ cells" for c in cells) + " |", "|---|" + "---|" * len(cells)]
    for s in scales:
        cell = {}
        for p in pts:
            if p["scale"] == s and p["pixels"]:
                # several thresholds may run the same (scale, cells) bucket: pool them
                acc = cell.setdefault(p["cells"], [])
                acc.append(p["delta_db"])
        lines.append(f"| 1/{s} | " + " | ".join(f"{np.mean(cell[c]):+.3f}" if c in cell else "" for c in cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> None:
    """``python -m pcdof.bench.tiers``: run the calibration on the wide cases and print its tables.

    Options: --seeds (comma-separated; default the tuning seeds), --size WxH (default 256x192),
    --cache (the ray-traced ground truths' folder, shared with ``pcdof bench``'s wide part: its
    ``<output>/cache``), --json (write the result there, atomically)."""
    import argparse
    import json

    from .wide import TUNING_SEEDS

    ap = argparse.ArgumentParser(prog="python -m pcdof.bench.tiers", description=main.__doc__.splitlines()[0])
    ap.add_argument("--seeds", default=",".join(map(str, TUNING_SEEDS)))
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--cache", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    try:
        seeds = [int(v) for v in args.seeds.split(",")]
        size = tuple(int(v) for v in args.size.lower().split("x"))
    except ValueError:
        ap.error(f"--seeds must be integers and --size WxH; got {args.seeds!r}, {args.size!r}")
    if len(size) != 2 or min(size) < 16:
        ap.error(f"--size must be WxH, each at least 16; got {args.size!r}")
    res = run_tiers(seeds=seeds, size=size, cache_dir=args.cache)
    print(loss_table(res), "", curve_table(res), "", f"thresholds by the rule: {choose_thresholds(res)}", sep="\n")
    if args.json:
        from ..io._files import atomic_write_bytes

        atomic_write_bytes(args.json, json.dumps(res, default=str, indent=1).encode())


if __name__ == "__main__":
    main()


#: quality tiers against exact, and the loss each may have (issue's done-when: balanced 0.1, fast 0.5 dB)
TIER_TOLERANCE_DB = {"pcdof-high": 0.1, "pcdof-balanced": 0.1, "pcdof-fast": 0.5}
#: fewest pixels of a case in a bucket for its per-case PSNR there to count towards the worst case
MIN_BUCKET_PIXELS = 200


def tier_curve(rows: list[dict], ref: str = "pcdof-exact", tiers=tuple(TIER_TOLERANCE_DB)) -> list[dict]:
    """Error-vs-blur curve of the quality tiers: per tier and blur bucket, the PSNR change from *ref*
    (pixels pooled over all cases: "mean_db"; the worst single case with at least
    :data:`MIN_BUCKET_PIXELS` pixels there: "worst_db"), and over whole frames ("all")."""
    cases = by_case(rows)
    out = []
    for t in tiers:
        pairs = [(by[ref], by[t]) for by in cases.values() if ref in by and t in by]
        if not pairs:
            continue
        for _, _, label in BUCKETS + ((None, None, "all"),):
            if label == "all":
                diffs = [b["psnr"] - a["psnr"] for a, b in pairs]
                mean = float(np.mean(diffs))
            else:
                key = f"{label}|all"
                n = [a["sse"][key][1] for a, _ in pairs]
                if not sum(n):
                    continue
                mean = pooled_psnr([b for _, b in pairs], t, key) - pooled_psnr([a for a, _ in pairs], ref, key)
                diffs = [psnr_of_sse(*b["sse"][key]) - psnr_of_sse(*a["sse"][key]) for (a, b), k in zip(pairs, n)
                         if k >= MIN_BUCKET_PIXELS]
            out.append({"tier": t, "bucket": label, "mean_db": mean,
                        "worst_db": float(min(diffs)) if diffs else float("nan"), "cases": len(diffs)})
    return out


def tier_table(rows: list[dict], ref: str = "pcdof-exact") -> str:
    """:func:`tier_curve` as Markdown (mean / worst case change from *ref*, dB), and each tier's verdict."""
    curve = tier_curve(rows, ref)
    labels = [lab for lab in dict.fromkeys(c["bucket"] for c in curve)]
    lines = [f"| tier - {ref}, dB (pooled / worst case) | " + " | ".join(
        "whole frame" if lab == "all" else f"CoC {lab} px" for lab in labels) + " |", "|---|" + "---|" * len(labels)]
    verdicts = []
    for t in dict.fromkeys(c["tier"] for c in curve):
        mine = {c["bucket"]: c for c in curve if c["tier"] == t}
        lines.append(f"| {t} | " + " | ".join(f"{mine[lab]['mean_db']:+.2f} / {mine[lab]['worst_db']:+.2f}"
                                               if lab in mine else "-" for lab in labels) + " |")
        tol = TIER_TOLERANCE_DB.get(t)
        if tol is not None and "all" in mine:
            c = compare(rows, ref, t, tolerance_db=tol)
            verdicts.append(f"{t}: {len(c['losses'])} of {c['cases']} cases lose more than {tol:g} dB to {ref} "
                            f"(worst {c['worst_db']:+.2f} dB, edge band {c['worst_edge_db']:+.2f} dB)")
    return "\n".join(lines) + "\n\n" + "\n".join(f"* {v}" for v in verdicts)


def tier_plot(rows: list[dict], path: str, ref: str = "pcdof-exact") -> None:
    """The quality tiers' error-vs-blur curve (:func:`tier_curve`: pooled and worst case), as a PNG."""
    curve = [c for c in tier_curve(rows, ref) if c["bucket"] != "all"]
    labels = list(dict.fromkeys(c["bucket"] for c in curve))
    with plot_to(path, figsize=(7, 3.6)) as (_, ax):
        for t, colour in zip(dict.fromkeys(c["tier"] for c in curve), ("#228833", "#4477aa", "#ee6677", "#aa3377")):
            mine = {c["bucket"]: c for c in curve if c["tier"] == t}
            x = [i for i, lab in enumerate(labels) if lab in mine]
            ax.plot(x, [mine[labels[i]]["mean_db"] for i in x], "-o", color=colour, label=f"{t}, pooled")
            ax.plot(x, [mine[labels[i]]["worst_db"] for i in x], "--x", color=colour, label=f"{t}, worst case")
        for tol in sorted(set(TIER_TOLERANCE_DB.values())):
            ax.axhline(-tol, color="grey", lw=0.8, ls=":")
        ax.set_xticks(range(len(labels)), [f"{lab} px" for lab in labels])
        ax.set_xlabel("true CoC diameter of the pixels")
        ax.set_ylabel(f"PSNR change from {ref}, dB")
        ax.set_title("quality tiers against exact, per blur size (wide benchmark)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
