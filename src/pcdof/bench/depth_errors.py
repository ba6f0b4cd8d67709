"""What each class of depth error costs the render: the filled depth against the exact one, one class put right at a
time (a counterfactual on the wide benchmark's cases and ground truths).

pcdof renders each case from its own registered and filled depth (``filled``) and from the scene's exact depth in the
colour camera (``exact``), and between them from the filled depth with one class of its errors replaced by the exact
depth (:func:`error_classes`):

* ``nearer surface given a farther depth``: pixels whose exact depth is nearer than the filled one by more than
  :data:`WRONG_RATIO` (relative): a thin pole's edge columns measured as the wall behind it, a hole inside a
  foreground filled from the background;
* ``farther surface given a nearer depth``: the opposite (the foreground fattened over the background);
* ``small errors``: every other pixel whose depth differs (noise, a slanted surface's steps).

The three classes cover every pixel whose depth differs, so putting all of them right gives the ``exact`` row.
``class minus filled`` is what that class costs; the three costs need not add up to ``exact minus filled`` (a pixel's
error shows through its neighbours' blur). Each render is the pipeline's from the depth on (CoC, highlights, render:
:func:`pcdof.pipeline.render_from_depth`) with the default options; the scores are those of the wide part (PSNR of the
8-bit sRGB result against the ray-traced ground truth, overall and in the depth-edge band).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..validate import positive_number

#: a pixel has another surface's depth when the larger of its filled and exact depths exceeds the smaller by this
#: share (the scale of a depth edge in the wide scenes: 0.45-0.85 m foregrounds over 1.1-4.4 m rooms)
WRONG_RATIO = 0.15
#: the variants rendered per case, in order
VARIANTS = ("filled", "nearer surface given a farther depth", "farther surface given a nearer depth", "small errors",
            "exact")


def error_classes(filled_m, exact_m, *, ratio: float = WRONG_RATIO) -> dict:
    """The pixels of each class of depth error (see the module docstring).

    Parameters
    ----------
    filled_m, exact_m : (H, W) float arrays, metres; the exact depth > 0 where something is seen (elsewhere, 0: no
        class)
    ratio : float > 0, relative depth difference beyond which a pixel has another surface's depth

    Returns
    -------
    dict, class name (:data:`VARIANTS` [1:4]) -> (H, W) bool: disjoint, and together every seen pixel whose depth
    differs
    """
    filled, exact = np.asarray(filled_m, np.float64), np.asarray(exact_m, np.float64)
    if filled.ndim != 2 or filled.shape != exact.shape:
        raise InputError(f"filled_m and exact_m must be (H, W) arrays of one shape; got {filled.shape} and "
                         f"{exact.shape}")
    ratio = positive_number("ratio", ratio)
    seen = exact > 0
    differs = seen & (filled != exact)
    other = differs & (np.maximum(filled, exact) > (1.0 + ratio) * np.minimum(filled, exact))
    return {VARIANTS[1]: other & (exact < filled), VARIANTS[2]: other & (exact > filled), VARIANTS[3]: differs & ~other}


def run_depth_errors(*, kinds=None, seeds=None, blurs=None, reference_width_px=640, size=(256, 192),
                     depth_size=(256, 212), ratio: float = WRONG_RATIO, cache_dir=None,
                     progress: bool = True) -> list[dict]:
    """Render every wide-benchmark case from each variant of its depth (:data:`VARIANTS`) and score it.

    Parameters
    ----------
    kinds, seeds, blurs, reference_width_px, size, depth_size, cache_dir : as :func:`pcdof.bench.wide.run_wide` (the
        same cases and cached ground truths; default kinds: every scene type, seeds: the reported seeds)
    ratio : float > 0, :func:`error_classes`' ratio

    Returns
    -------
    list of dict, one per case and variant: scene, seed, focus, blur_px, variant, psnr, psnr_edge (dB), pixels (of
    the variant's class; the pixels whose depth differs for ``filled``, 0 for ``exact``) and holes (of them, those the
    registered depth left unknown)
    """
    from tqdm.auto import tqdm

    from ..pipeline import prepare_depth, render_from_depth
    from ..synth.wide import generate_wide, lens_for_blur
    from .wide import BLURS_PX, REPORT_SEEDS, case_truth, checked_cases, encode_srgb8, psnr_of_sse

    seeds = REPORT_SEEDS if seeds is None else seeds
    blurs = BLURS_PX if blurs is None else blurs
    kinds, seeds, blurs = checked_cases(kinds, seeds, blurs, size[0], reference_width_px)
    ratio = positive_number("ratio", ratio)  # before any work
    rows = []
    bar = tqdm(total=len(kinds) * len(seeds), desc="depth errors", unit="frame", disable=not progress)
    for kind in kinds:
        for seed in seeds:
            sf, spec = generate_wide(kind, seed=seed, color_size=size, depth_size=depth_size)
            exact = np.asarray(sf.depth_color_m, np.float32)
            registered, filled, _ = prepare_depth(sf.frame, sf.default_lens)
            classes = error_classes(filled, exact, ratio=ratio)
            differs = np.logical_or.reduce(list(classes.values()))
            depths = {VARIANTS[0]: (filled, differs), VARIANTS[4]: (exact, np.zeros_like(differs))}
            depths.update({name: (np.where(mask, exact, filled).astype(np.float32), mask)
                           for name, mask in classes.items()})
            for focus in spec.focus_m:
                for blur in blurs:
                    lens = lens_for_blur(exact, sf.rig.color.fx, spec.focus_m[focus], blur)
                    gt, band = case_truth(sf, lens, (kind, seed, focus, blur), size, depth_size, cache_dir)
                    for name in VARIANTS:
                        depth, mask = depths[name]
                        image = render_from_depth(sf.color, depth, lens, sf.rig.color.fx)[0]
                        err = np.mean((encode_srgb8(image) - gt) ** 2, axis=2)
                        rows.append({"scene": kind, "seed": seed, "focus": focus, "blur_px": blur, "variant": name,
                                     "psnr": psnr_of_sse(float(err.sum()), err.size),
                                     "psnr_edge": psnr_of_sse(float(err[band].sum()), int(band.sum())),
                                     "pixels": int(mask.sum()), "holes": int((mask & ~(registered > 0)).sum())})
            bar.update()
    bar.close()
    return rows


def cost_table(rows: list[dict]) -> str:
    """Markdown: per scene type and focus position, each variant's mean PSNR overall / edge band (dB) and its gain
    over ``filled``; with the mean pixels per frame of each class and the share of them that were holes."""
    if not rows:
        return "(no cases)"
    groups = {}
    for r in rows:
        for key in ((r["scene"], r["focus"]), (r["scene"], "all"), ("all", "all")):
            groups.setdefault(key, {}).setdefault(r["variant"], []).append(r)
    head = ("| scene | focus | cases | " + " | ".join(VARIANTS) + " |\n|---|---|---|"
            + "---|" * len(VARIANTS))
    lines = [head]
    for (scene, focus), by in sorted(groups.items(), key=lambda kv: (kv[0][0] == "all", kv[0])):
        base = np.mean([r["psnr"] for r in by[VARIANTS[0]]])
        cells = []
        for name in VARIANTS:
            overall, edge = (np.mean([r[k] for r in by[name]]) for k in ("psnr", "psnr_edge"))
            gain = "" if name == VARIANTS[0] else f" ({overall - base:+.2f})"
            cells.append(f"{overall:.2f} / {edge:.2f}{gain}")
        lines.append(f"| {scene} | {focus} | {len(by[VARIANTS[0]])} | " + " | ".join(cells) + " |")
    frames = {}
    for r in rows:
        frames.setdefault((r["scene"], r["seed"], r["variant"]), (r["pixels"], r["holes"]))
    lines += ["", "| class | pixels per frame | of them holes in the registered depth |", "|---|---|---|"]
    for name in VARIANTS[1:4]:
        counts = [v for (_, _, variant), v in frames.items() if variant == name]
        pixels, holes = sum(c[0] for c in counts), sum(c[1] for c in counts)
        lines.append(f"| {name} | {pixels / max(len(counts), 1):.0f} | {100.0 * holes / max(pixels, 1):.0f} % |")
    return "\n".join(lines)
