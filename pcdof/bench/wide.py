"""The wide benchmark: procedural scenes, blur up to 64 px, three focus positions, clipped 8-bit input.

Every frame of :data:`pcdof.synth.wide.WIDE_SCENES` (one per scene type and seed) is shot at each
focus position of :data:`~pcdof.synth.wide.FOCUS_POSITIONS` and each largest blur of *blurs*
(the aperture is chosen to give that blur, :func:`~pcdof.synth.wide.lens_for_blur`). The methods
get what a Kinect-like rig gives: 8-bit sRGB colour whose emitters and glints clip (radiance drawn
log-uniform over 2-200 x diffuse white) and noisy sensor depth with holes from a separate camera.
The ground truth is ray traced from the unclipped linear radiance (:mod:`pcdof.synth.emitters`).

Scores: PSNR of the sRGB-encoded result (clipped at 1, as shown), overall and in the depth-edge
band, per case; pooled per blur-size bucket (each pixel by its own true CoC) and per focus
position. The error budget renders the same frames with pcdof ``exact`` from (a) the measured
input, (b) the true depth, (c) the true depth and unclipped linear colour, and with highlight
reconstruction on (a) and (b), so each stage's cost in dB shows.

Seeds: highlight settings are chosen on :data:`TUNING_SEEDS` only; reports use :data:`REPORT_SEEDS`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os

import numpy as np

from ..color import decode_to_linear, linear_to_srgb, to_float
from ..errors import InputError
from ..metrics import depth_edge_band

#: largest blur of each lens setting, pixels
BLURS_PX = (16, 64)
#: blur-size buckets (each pixel by its true CoC diameter, px): lower edges
BUCKETS = ((0, 4, "<4"), (4, 12, "4-12"), (12, 32, "12-32"), (32, np.inf, "32+"))
#: seeds that choose highlight settings, and seeds that are reported (never the same)
TUNING_SEEDS = (0, 1, 2, 3, 4)
REPORT_SEEDS = tuple(range(100, 110))
#: methods of the main table
WIDE_METHODS = ("pcdof-exact", "pcdof-balanced", "pcdof-fast", "pcdof-balanced+hl", "paper", "baseline")
#: error-budget variants (pcdof exact): name -> (true depth, colour: "8bit" | "8bit+hl" | "linear")
BUDGET = {"measured": (False, "8bit"), "measured+hl": (False, "8bit+hl"), "true depth": (True, "8bit"),
          "true depth+hl": (True, "8bit+hl"), "true depth+linear": (True, "linear")}


def _encode(image) -> np.ndarray:
    """A method's output as float sRGB in [0, 1] (uint8 decoded, linear float encoded with clipping)."""
    if image.dtype.kind == "f":
        return linear_to_srgb(np.clip(image, 0.0, 1.0))
    return to_float(image)


def _ground_truth(sf, lens, *, cache_dir, key):
    from ..synth.emitters import render_thin_lens_split

    path = None
    if cache_dir:
        digest = hashlib.sha1(json.dumps(key).encode()).hexdigest()[:12]
        path = os.path.join(cache_dir, f"wide_gt_{digest}.npy")
        if os.path.exists(path):
            return np.load(path)
    gt = render_thin_lens_split(sf, lens, seed=1)
    if path:
        from ..io._files import atomic_write_bytes

        buf = io.BytesIO()
        np.save(buf, gt, allow_pickle=False)
        atomic_write_bytes(path, buf.getvalue())
    return gt


def _true_frame(sf, color):
    from ..camera import RGBDFrame, Rig

    return RGBDFrame(color, sf.depth_color_m, Rig.registered(sf.rig.color, max_range_m=sf.rig.max_range_m))


def render_method(name: str, sf, lens, *, highlights: dict) -> np.ndarray:
    """One method of :data:`WIDE_METHODS` on the measured 8-bit frame (image, uint8 or linear float)."""
    from ..pipeline import run
    from .dof import METHODS

    if name == "pcdof-balanced+hl":
        return render_variant("measured+hl", sf, lens, highlights=highlights, quality="balanced")
    return METHODS[name].run(sf, lens)[0]


def render_variant(variant: str, sf, lens, *, highlights: dict, quality: str = "exact") -> np.ndarray:
    """One error-budget variant of :data:`BUDGET` rendered by pcdof at *quality*."""
    from ..camera import RGBDFrame
    from ..highlights import reconstruct_highlights
    from ..pipeline import run

    true_depth, colour = BUDGET[variant]
    if colour == "linear":
        color, linear = sf.color_linear, True
    elif colour == "8bit+hl":
        color, linear = reconstruct_highlights(decode_to_linear(sf.color), **highlights), True
    else:
        color, linear = sf.color, False
    frame = _true_frame(sf, color) if true_depth else RGBDFrame(color, sf.depth_m, sf.rig)
    return run(frame, lens, quality=quality, linear=linear).image


def _bucket_sums(err, coc, band) -> dict:
    """Squared-error sums and pixel counts per bucket, overall and in the edge band."""
    out = {}
    for lo, hi, label in BUCKETS:
        sel = (coc >= lo) & (coc < hi)
        for part, m in (("all", sel), ("edge", sel & band)):
            out[f"{label}|{part}"] = (float(err[m].sum()), int(np.count_nonzero(m)))
    return out


def _psnr(sse: float, n: int) -> float:
    if n == 0:
        return float("nan")
    mse = sse / n
    return float("inf") if mse == 0 else float(-10 * np.log10(mse))


def wide_cases(kinds, seeds, blurs) -> list[tuple]:
    """(scene type, seed, focus position, largest blur px) of every case, in run order."""
    from ..synth.wide import FOCUS_POSITIONS

    return [(k, s, f, b) for k in kinds for s in seeds for f in FOCUS_POSITIONS for b in blurs]


def _check(kinds, seeds, blurs):
    from ..synth.wide import WIDE_SCENES

    kinds = list(kinds or WIDE_SCENES)
    bad = [k for k in kinds if k not in WIDE_SCENES]
    if bad or not kinds:
        raise InputError(f"kinds must be names of {', '.join(WIDE_SCENES)}; got {kinds!r}")
    seeds = [int(s) for s in seeds]
    if not seeds or any(s < 0 for s in seeds):
        raise InputError(f"seeds must be a non-empty list of integers >= 0; got {seeds!r}")
    blurs = [float(b) for b in blurs]
    if not blurs or any(not np.isfinite(b) or b <= 0 for b in blurs):
        raise InputError(f"blurs must be numbers > 0; got {blurs!r}")
    return kinds, seeds, blurs


def run_wide(*, kinds=None, seeds=REPORT_SEEDS, blurs=BLURS_PX, size=(256, 192), depth_size=(256, 212),
             methods=WIDE_METHODS, budget=tuple(BUDGET), highlights=None, cache_dir=None,
             progress: bool = True) -> list[dict]:
    """Score *methods* and the error-budget variants on every wide case. One row per case and method.

    Parameters
    ----------
    kinds : names of :data:`pcdof.synth.wide.WIDE_SCENES` (None = all)
    seeds : scene seeds (report on :data:`REPORT_SEEDS`, tune on :data:`TUNING_SEEDS`)
    blurs : largest blur of each lens setting, px
    size, depth_size : (W, H) of the colour and depth cameras
    methods : names of :data:`WIDE_METHODS`; budget : names of :data:`BUDGET` (method "budget:<name>")
    highlights : keyword options of :func:`pcdof.highlights.reconstruct_highlights` (None = its defaults)
    cache_dir : folder for the ray-traced ground truths (None = no cache)

    Returns
    -------
    list of dict: scene, seed, focus, blur_px, f_number, focus_distance_m, method, psnr, psnr_edge,
    and "sse" {bucket|part: (sum of squared error, pixels)}
    """
    from tqdm.auto import tqdm

    from ..synth.wide import generate_wide, lens_for_blur

    kinds, seeds, blurs = _check(kinds, seeds, blurs)
    highlights = dict(highlights or {})
    names = list(methods) + [f"budget:{b}" for b in budget]
    rows, frames = [], {}
    cases = wide_cases(kinds, seeds, blurs)
    bar = tqdm(total=len(cases) * (len(names) + 1), desc="wide bench", unit="run", disable=not progress)
    for kind, seed, focus, blur in cases:
        if (kind, seed) not in frames:
            frames = {(kind, seed): generate_wide(kind, seed=seed, color_size=size, depth_size=depth_size)}
        sf, spec = frames[(kind, seed)]
        lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m[focus], blur)
        bar.set_postfix_str(f"{kind}/{seed}/{focus}/{blur:g}px: ground truth")
        gt_lin = _ground_truth(sf, lens, cache_dir=cache_dir,
                               key=["wide", kind, seed, focus, blur, list(size), list(depth_size), 2])
        bar.update()
        gt = linear_to_srgb(np.clip(gt_lin, 0, 1))
        coc = lens.coc_px(sf.depth_color_m, sf.rig.color.fx)
        band = depth_edge_band(sf.depth_color_m, max(3, int(round(blur / 2))))
        for name in names:
            bar.set_postfix_str(f"{kind}/{seed}/{focus}/{blur:g}px: {name}")
            if name.startswith("budget:"):
                image = render_variant(name[7:], sf, lens, highlights=highlights)
            else:
                image = render_method(name, sf, lens, highlights=highlights)
            err = np.mean((_encode(image) - gt) ** 2, axis=2)
            sse = _bucket_sums(err, coc, band)
            rows.append({"scene": kind, "seed": seed, "focus": focus, "blur_px": blur, "f_number": lens.f_number,
                         "focus_distance_m": lens.focus_distance_m, "method": name,
                         "psnr": _psnr(float(err.sum()), err.size),
                         "psnr_edge": _psnr(float(err[band].sum()), int(band.sum())), "sse": sse})
            bar.update()
    bar.close()
    return rows


def _pooled(rows, method, key) -> float:
    sse = [r["sse"][key] for r in rows if r["method"] == method]
    return _psnr(sum(s for s, _ in sse), sum(n for _, n in sse))


def bucket_table(rows: list[dict]) -> str:
    """PSNR overall / edge band per blur bucket (pixels pooled by their true CoC), one line per method."""
    methods = [m for m in dict.fromkeys(r["method"] for r in rows)]
    head = "| method | " + " | ".join(f"CoC {label} px" for _, _, label in BUCKETS) + " |"
    lines = [head, "|---|" + "---|" * len(BUCKETS)]
    for m in methods:
        cells = []
        for _, _, label in BUCKETS:
            a, e = _pooled(rows, m, f"{label}|all"), _pooled(rows, m, f"{label}|edge")
            cells.append("-" if np.isnan(a) else f"{a:.2f} / {e:.2f}" if not np.isnan(e) else f"{a:.2f} / -")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def focus_table(rows: list[dict]) -> str:
    """Mean PSNR overall / edge band per focus position and largest blur, one line per method."""
    from ..synth.wide import FOCUS_POSITIONS

    groups = list(dict.fromkeys((r["focus"], r["blur_px"]) for r in rows))
    groups.sort(key=lambda g: (FOCUS_POSITIONS.index(g[0]), g[1]))
    head = "| method | " + " | ".join(f"{f}, {b:g} px" for f, b in groups) + " | all |"
    lines = [head, "|---|" + "---|" * (len(groups) + 1)]
    for m in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == m]
        cells = []
        for g in groups + [None]:
            sel = [r for r in mine if g is None or (r["focus"], r["blur_px"]) == g]
            cells.append(f"{np.mean([r['psnr'] for r in sel]):.2f} / {np.mean([r['psnr_edge'] for r in sel]):.2f}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def budget_summary(rows: list[dict]) -> list[dict]:
    """Mean PSNR of each error-budget variant, and the step from the one before it (dB)."""
    out = []
    for b in BUDGET:
        sel = [r for r in rows if r["method"] == f"budget:{b}"]
        if sel:
            out.append({"variant": b, "psnr": float(np.mean([r["psnr"] for r in sel])),
                        "psnr_edge": float(np.mean([r["psnr_edge"] for r in sel])), "cases": len(sel)})
    return out


def budget_table(rows: list[dict]) -> str:
    """The error budget: what each input error costs pcdof exact, in dB."""
    s = {b["variant"]: b for b in budget_summary(rows)}
    lines = ["| pcdof exact given | mean PSNR dB | edge band dB |", "|---|---|---|"]
    lines += [f"| {v} | {b['psnr']:.2f} | {b['psnr_edge']:.2f} |" for v, b in s.items()]

    def step(a, b):
        return f"{s[b]['psnr'] - s[a]['psnr']:+.2f}" if a in s and b in s else "-"

    lines += ["", "| stage | cost dB |", "|---|---|",
              f"| depth errors (measured -> true depth) | {step('measured', 'true depth')} |",
              f"| clipping (true depth -> unclipped linear colour) | {step('true depth', 'true depth+linear')} |",
              f"| clipping left after highlight reconstruction | {step('true depth+hl', 'true depth+linear')} |",
              f"| highlight reconstruction on measured input | {step('measured', 'measured+hl')} |"]
    if "true depth+linear" in s:
        lines.append(f"| renderer's own error (true depth + linear colour) | PSNR {s['true depth+linear']['psnr']:.2f} |")
    return "\n".join(lines)


def losses_table(rows: list[dict], ours: str = "pcdof-balanced", others=("paper", "baseline")) -> str:
    """Every case where *ours* scores below one of *others* (overall or edge band), with the margin."""
    lines = [f"| scene | seed | focus | blur px | {ours} dB (edge) | best other dB (edge) | margin dB (edge) |",
             "|---|---|---|---|---|---|---|"]
    cases = dict.fromkeys((r["scene"], r["seed"], r["focus"], r["blur_px"]) for r in rows)
    for case in cases:
        by = {r["method"]: r for r in rows if (r["scene"], r["seed"], r["focus"], r["blur_px"]) == case}
        if ours not in by or not any(o in by for o in others):
            continue
        best = max((by[o] for o in others if o in by), key=lambda r: r["psnr"])
        best_edge = max(by[o]["psnr_edge"] for o in others if o in by)
        me = by[ours]
        if me["psnr"] < best["psnr"] or me["psnr_edge"] < best_edge:
            lines.append(f"| {case[0]} | {case[1]} | {case[2]} | {case[3]:g} | {me['psnr']:.2f} ({me['psnr_edge']:.2f}) | "
                         f"{best['psnr']:.2f} ({best_edge:.2f}) {best['method']} | {me['psnr'] - best['psnr']:+.2f} "
                         f"({me['psnr_edge'] - best_edge:+.2f}) |")
    return "\n".join(lines) + f"\n\n{len(lines) - 2} of {len(cases)} cases lose to {' or '.join(others)}."


#: highlight settings compared on the tuning seeds
HIGHLIGHT_CANDIDATES = ({"method": "off"}, *({"method": "gain", "gain": g} for g in (2.0, 4.0, 8.0, 16.0, 32.0)),
                        {"method": "rim"}, {"method": "auto"})


def tune_highlights(*, kinds=None, seeds=TUNING_SEEDS, blurs=BLURS_PX, size=(256, 192), depth_size=(256, 212),
                    candidates=HIGHLIGHT_CANDIDATES, cache_dir=None, progress: bool = True) -> list[dict]:
    """Mean PSNR of pcdof exact (true depth, so only the colour differs) for each highlight setting
    on the tuning seeds. Returns one dict per candidate: settings, psnr, psnr_edge."""
    out = []
    for cand in candidates:
        rows = run_wide(kinds=kinds, seeds=seeds, blurs=blurs, size=size, depth_size=depth_size, methods=(),
                        budget=("true depth+hl",), highlights=cand, cache_dir=cache_dir, progress=progress)
        out.append({"highlights": dict(cand), "psnr": float(np.mean([r["psnr"] for r in rows])),
                    "psnr_edge": float(np.mean([r["psnr_edge"] for r in rows]))})
    return out


def tuning_table(tuned: list[dict]) -> str:
    lines = ["| highlights | mean PSNR dB | edge band dB |", "|---|---|---|"]
    for t in tuned:
        h = t["highlights"]
        label = h["method"] + (f" {h['gain']:g}" if "gain" in h else "")
        lines.append(f"| {label} | {t['psnr']:.2f} | {t['psnr_edge']:.2f} |")
    return "\n".join(lines)


def budget_plot(rows: list[dict], path: str) -> None:
    """Bar chart of the error budget (mean PSNR per variant), as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from . import save_figure

    s = budget_summary(rows)
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    y = np.arange(len(s))
    ax.barh(y - 0.2, [b["psnr"] for b in s], 0.4, color="#4477aa", label="whole frame")
    ax.barh(y + 0.2, [b["psnr_edge"] for b in s], 0.4, color="#ee6677", label="depth-edge band")
    for i, b in enumerate(s):
        ax.text(b["psnr"], i - 0.2, f" {b['psnr']:.2f}", va="center", fontsize=8)
        ax.text(b["psnr_edge"], i + 0.2, f" {b['psnr_edge']:.2f}", va="center", fontsize=8)
    ax.set_yticks(y, [f"pcdof exact, {b['variant']}" for b in s])
    lo = min(min(b["psnr"], b["psnr_edge"]) for b in s) if s else 0
    ax.set_xlim(max(0, lo - 3), max(max(b["psnr"], b["psnr_edge"]) for b in s) + 3 if s else 1)
    ax.set_xlabel("mean PSNR vs ray-traced ground truth, dB")
    ax.set_title("error budget on the wide benchmark")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)
