"""The wide benchmark: procedural scenes, large blur, three focus positions, clipped 8-bit input.

Every frame of :data:`pcdof.synth.wide.WIDE_SCENES` (one per scene type and seed) is shot at each
focus position of :data:`~pcdof.synth.wide.FOCUS_POSITIONS` and each largest blur of *blurs*
(the aperture is chosen to give that blur, :func:`~pcdof.synth.wide.lens_for_blur`). The blurs are
given at a frame :data:`REFERENCE_WIDTH_PX` wide (16 and 64 px: 2.5 % and 10 % of the width) and
scale with the run's width, so a small run shoots the same pictures as a large one (absolute
pixels on request). The methods get what a Kinect-like rig gives: 8-bit sRGB colour whose emitters
and glints clip (radiance drawn log-uniform over 2-200 x diffuse white) and noisy sensor depth with
holes from a separate camera. The ground truth is ray traced from the unclipped linear radiance
(:mod:`pcdof.synth.emitters`).

Scores: PSNR of the sRGB-encoded result (clipped at 1, as shown), overall and in the depth-edge
band, per case; pooled per blur-size bucket (each pixel by its own true CoC) and per focus
position. The error budget renders the same frames with pcdof ``exact`` from (a) the measured
input, (b) the true depth, (c) the true depth and unclipped linear colour, and with highlight
reconstruction on (a) and (b), so each stage's cost in dB shows. The quality tiers' error-vs-blur
curve (:func:`tier_curve`) compares ``high``, ``balanced`` and ``fast`` with ``exact`` per bucket.

Seeds: highlight settings are chosen on :data:`TUNING_SEEDS` only; reports use :data:`REPORT_SEEDS`.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
from dataclasses import dataclass, replace

import numpy as np

from ..color import decode_to_linear, linear_to_srgb, to_float
from ..errors import InputError
from ..metrics import depth_edge_band
from . import plot_to
from .dof import PEERS, peers_in

#: frame width (px) at which :data:`BLURS_PX` are given; a run at another width scales them with it
REFERENCE_WIDTH_PX = 640
#: largest blur of each lens setting, px at a frame :data:`REFERENCE_WIDTH_PX` wide (2.5 % and 10 % of the width)
BLURS_PX = (16, 64)
#: blur-size buckets (each pixel by its true CoC diameter, px at the run's size): (lower, upper, label)
BUCKETS = ((0, 2, "<2"), (2, 4, "2-4"), (4, 8, "4-8"), (8, 16, "8-16"), (16, 32, "16-32"), (32, np.inf, "32+"))
#: seeds that choose highlight settings, and seeds that are reported (never the same)
TUNING_SEEDS = (0, 1, 2, 3, 4)
REPORT_SEEDS = tuple(range(100, 110))
#: the highlight setting of the "+hl" rows (a ``RenderOptions.highlights`` value)
HIGHLIGHTS = "auto"


@dataclass(frozen=True)
class Variant:
    """One way pcdof renders a wide case.

    true_depth : the exact depth registered to the colour camera instead of the sensor's
    colour : "8bit" (the clipped sRGB input) or "linear" (the unclipped linear radiance)
    highlights : a ``RenderOptions.highlights`` value, or a dict of
        :func:`pcdof.stages.highlights.reconstruct_highlights` options (any method and gain, for tuning)
    quality : a key of :data:`pcdof.plans.QUALITIES`
    """

    true_depth: bool = False
    colour: str = "8bit"
    highlights: object = "off"
    quality: str = "balanced"


#: pcdof rows of the main table (measured input); the peers (:data:`pcdof.bench.dof.PEERS`) come from :mod:`pcdof.bench.dof`
PCDOF_METHODS = {f"pcdof-{q}": Variant(quality=q) for q in ("exact", "high", "balanced", "fast")}
PCDOF_METHODS["pcdof-balanced+hl"] = Variant(highlights=HIGHLIGHTS)
#: methods of the main table
WIDE_METHODS = (*PCDOF_METHODS, *PEERS)
#: error-budget variants (pcdof exact); "+hl": with highlight reconstruction (run_wide's *highlights*)
BUDGET = {"measured": Variant(quality="exact"), "measured+hl": Variant(highlights=HIGHLIGHTS, quality="exact"),
          "true depth": Variant(True, quality="exact"),
          "true depth+hl": Variant(True, highlights=HIGHLIGHTS, quality="exact"),
          "true depth+linear": Variant(True, "linear", quality="exact")}


def scaled_blurs(blurs, width_px: int, *, reference_width_px=REFERENCE_WIDTH_PX) -> tuple[float, ...]:
    """Largest blurs *blurs* (px at *reference_width_px*) in pixels of a frame *width_px* wide.

    *reference_width_px* None: *blurs* are absolute pixels, returned as they are.

    >>> scaled_blurs((16, 64), 256)
    (6.4, 25.6)
    """
    blurs = tuple(float(b) for b in blurs)
    if reference_width_px is None:
        return blurs
    if isinstance(reference_width_px, bool) or not isinstance(reference_width_px, (int, float)) \
            or not reference_width_px > 0 or not np.isfinite(reference_width_px):
        raise InputError(f"reference_width_px must be a number > 0 or None; got {reference_width_px!r}")
    return tuple(round(b * int(width_px) / reference_width_px, 3) for b in blurs)


def encode_srgb8(image) -> np.ndarray:
    """A method's output as float sRGB in [0, 1] (uint8 decoded, linear float encoded with clipping)."""
    if image.dtype.kind == "f":
        return linear_to_srgb(np.clip(image, 0.0, 1.0))
    return to_float(image)


def ground_truth(sf, lens, *, cache_dir, key):
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


def case_truth(sf, lens, case, size, depth_size, cache_dir):
    """What a wide case is scored against: (sRGB ground truth (H, W, 3) float in [0, 1], the ray-traced linear light
    clipped at white and cached under the case's key; depth-edge band (H, W) bool, as far as the case's blur reaches).
    *case* is (kind, seed, focus, blur_px), *size* and *depth_size* the frame's, as :func:`wide_cases` and
    :func:`run_wide` give them."""
    kind, seed, focus, blur = case
    gt_lin = ground_truth(sf, lens, cache_dir=cache_dir,
                          key=["wide", kind, seed, focus, blur, list(size), list(depth_size), 2])
    return linear_to_srgb(np.clip(gt_lin, 0, 1)), depth_edge_band(sf.depth_color_m, max(3, int(round(blur / 2))))


def _true_frame(sf, color):
    from ..camera import RGBDFrame, Rig

    return RGBDFrame(color, sf.depth_color_m, Rig.registered(sf.rig.color, max_range_m=sf.rig.max_range_m))


def render_method(name: str, sf, lens, *, highlights=HIGHLIGHTS) -> np.ndarray:
    """One method of :data:`WIDE_METHODS` on the measured 8-bit frame (image, uint8 or linear float).

    *highlights* replaces the setting of the "+hl" method.
    """
    from .dof import METHODS

    if name in PCDOF_METHODS:
        v = PCDOF_METHODS[name]
        return render_variant(replace(v, highlights=highlights) if v.highlights != "off" else v, sf, lens)
    return METHODS[name].run(sf, lens)[0]


def render_variant(variant, sf, lens) -> np.ndarray:
    """pcdof's render of one :class:`Variant` (or the name of a :data:`BUDGET` variant) of a case.

    Highlights given as a pipeline value run through the pipeline's highlights stage (the render
    comes back in the input's dtype); a dict of reconstruction options is applied here, between the
    pipeline's stages (the circle of confusion of the filled depth as the pipeline computes it), and
    the linear result rendered (a linear float image).
    """
    from ..camera import RGBDFrame
    from ..pipeline import run

    v = BUDGET[variant] if isinstance(variant, str) else variant
    color, linear, hl = sf.color, False, v.highlights
    if v.colour == "linear":
        color, linear, hl = sf.color_linear, True, "off"
    frame = _true_frame(sf, color) if v.true_depth else RGBDFrame(color, sf.depth_m, sf.rig)
    if isinstance(hl, dict):
        return _render_reconstructed(frame, lens, hl, quality=v.quality)
    return run(frame, lens, quality=v.quality, linear=linear, highlights=hl).image


def _render_reconstructed(frame, lens, options: dict, *, quality: str) -> np.ndarray:
    """*frame* registered and filled as :func:`pcdof.pipeline.run` does, its colour reconstructed with
    :func:`pcdof.stages.highlights.reconstruct_highlights` (*options*), rendered as linear light as the
    pipeline's render stage renders it (the estimated light above white not continued beyond the frame)."""
    from ..stages.highlights import reconstruct_highlights
    from ..stages.render import render_image
    from ..pipeline import prepare_depth

    _registered, filled, _trace = prepare_depth(frame, lens)
    fx = frame.rig.color.fx
    lin = reconstruct_highlights(decode_to_linear(frame.color), coc_px=lens.coc_px(filled, fx), **options)
    return render_image(lin, filled, lens, fx=fx, max_range_m=frame.rig.max_range_m, linear=True, quality=quality,
                        border_most=1.0)[0]


def bucket_sums(err, coc, band) -> dict:
    """Squared-error sums and pixel counts per bucket, overall and in the edge band."""
    out = {}
    for lo, hi, label in BUCKETS:
        sel = (coc >= lo) & (coc < hi)
        for part, m in (("all", sel), ("edge", sel & band)):
            out[f"{label}|{part}"] = (float(err[m].sum()), int(np.count_nonzero(m)))
    return out


def psnr_of_sse(sse: float, n: int) -> float:
    if n == 0:
        return float("nan")
    mse = sse / n
    return float("inf") if mse == 0 else float(-10 * np.log10(mse))


def wide_cases(kinds, seeds, blurs) -> list[tuple]:
    """(scene type, seed, focus position, largest blur px) of every case, in run order."""
    from ..synth.wide import FOCUS_POSITIONS

    return [(k, s, f, b) for k in kinds for s in seeds for f in FOCUS_POSITIONS for b in blurs]


def checked_cases(kinds, seeds, blurs, width_px: int, reference_width_px=REFERENCE_WIDTH_PX):
    """*kinds*, *seeds* and *blurs* checked (:func:`check_cases`), the blurs in pixels of a frame *width_px* wide
    (:func:`scaled_blurs`; *reference_width_px* None: already pixels): (kinds, seeds, blurs_px) as lists."""
    px = scaled_blurs(check_cases(kinds, seeds, blurs)[2], width_px, reference_width_px=reference_width_px)
    return check_cases(kinds, seeds, px)


def check_cases(kinds, seeds, blurs):
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


def _renderers(methods, budget, highlights, variants) -> dict:
    """Row name -> function(sf, lens) -> image, for the methods, budget variants and extra variants."""
    for name, pool in (("methods", WIDE_METHODS), ("budget", BUDGET)):
        chosen = methods if name == "methods" else budget
        bad = [m for m in chosen if m not in pool]
        if bad:
            raise InputError(f"{name} must be names of {', '.join(pool)}; got {bad!r}")
    out = {m: (lambda sf, lens, m=m: render_method(m, sf, lens, highlights=highlights)) for m in methods}
    for b in budget:
        v = BUDGET[b]
        v = replace(v, highlights=highlights) if v.highlights != "off" else v
        out[f"budget:{b}"] = lambda sf, lens, v=v: render_variant(v, sf, lens)
    for name, v in (variants or {}).items():
        out[name] = lambda sf, lens, v=v: render_variant(v, sf, lens)
    return out


def run_wide(*, kinds=None, seeds=REPORT_SEEDS, blurs=BLURS_PX, reference_width_px=REFERENCE_WIDTH_PX,
             size=(256, 192), depth_size=(256, 212), methods=WIDE_METHODS, budget=tuple(BUDGET),
             highlights=HIGHLIGHTS, variants=None, cache_dir=None, progress: bool = True) -> list[dict]:
    """Score *methods* and the error-budget variants on every wide case. One row per case and method.

    Parameters
    ----------
    kinds : names of :data:`pcdof.synth.wide.WIDE_SCENES` (None = all)
    seeds : scene seeds (report on :data:`REPORT_SEEDS`, tune on :data:`TUNING_SEEDS`)
    blurs : largest blur of each lens setting, px at a frame *reference_width_px* wide (scaled to
        *size*'s width, :func:`scaled_blurs`); *reference_width_px* None: absolute pixels
    size, depth_size : (W, H) of the colour and depth cameras
    methods : names of :data:`WIDE_METHODS`; budget : names of :data:`BUDGET` (method "budget:<name>")
    highlights : the ``RenderOptions.highlights`` value of the "+hl" rows
    variants : {row name: :class:`Variant`} rendered as well (the highlight tuning's candidates)
    cache_dir : folder for the ray-traced ground truths (None = no cache)

    Returns
    -------
    list of dict: scene, seed, focus, blur_px (at *size*), blur_share (of the width), f_number,
    focus_distance_m, method, psnr, psnr_edge, and "sse" {bucket|part: (sum of squared error, pixels)}
    """
    from tqdm.auto import tqdm

    from ..stages.highlights import parse_highlights
    from ..synth.wide import generate_wide, lens_for_blur

    parse_highlights(highlights)
    kinds, seeds, blurs = checked_cases(kinds, seeds, blurs, size[0], reference_width_px)
    renderers = _renderers(methods, budget, highlights, variants)
    rows, frames = [], {}
    cases = wide_cases(kinds, seeds, blurs)
    bar = tqdm(total=len(cases) * (len(renderers) + 1), desc="wide bench", unit="run", disable=not progress)
    for kind, seed, focus, blur in cases:
        if (kind, seed) not in frames:
            frames = {(kind, seed): generate_wide(kind, seed=seed, color_size=size, depth_size=depth_size)}
        sf, spec = frames[(kind, seed)]
        lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m[focus], blur)
        bar.set_postfix_str(f"{kind}/{seed}/{focus}/{blur:g}px: ground truth")
        gt, band = case_truth(sf, lens, (kind, seed, focus, blur), size, depth_size, cache_dir)
        bar.update()
        coc = lens.coc_px(sf.depth_color_m, sf.rig.color.fx)
        for name, render in renderers.items():
            bar.set_postfix_str(f"{kind}/{seed}/{focus}/{blur:g}px: {name}")
            err = np.mean((encode_srgb8(render(sf, lens)) - gt) ** 2, axis=2)
            rows.append({"scene": kind, "seed": seed, "focus": focus, "blur_px": blur,
                         "blur_share": blur / size[0], "f_number": lens.f_number,
                         "focus_distance_m": lens.focus_distance_m, "method": name,
                         "psnr": psnr_of_sse(float(err.sum()), err.size),
                         "psnr_edge": psnr_of_sse(float(err[band].sum()), int(band.sum())),
                         "sse": bucket_sums(err, coc, band)})
            bar.update()
    bar.close()
    return rows


def pooled_psnr(rows, method, key) -> float:
    """PSNR (dB) of *method*'s squared errors under *key* (a bucket and region of a row's ``sse``), pooled over *rows*."""
    sse = [r["sse"][key] for r in rows if r["method"] == method]
    return psnr_of_sse(sum(s for s, _ in sse), sum(n for _, n in sse))


def _methods(rows) -> list[str]:
    return list(dict.fromkeys(r["method"] for r in rows))


def _case(r) -> tuple:
    return r["scene"], r["seed"], r["focus"], r["blur_px"]


def by_case(rows) -> dict:
    """{case: {method: row}}."""
    out: dict = {}
    for r in rows:
        out.setdefault(_case(r), {})[r["method"]] = r
    return out


def _blur_label(blur_px, share) -> str:
    return f"{100 * share:.3g} % ({blur_px:g} px)"


def bucket_table(rows: list[dict]) -> str:
    """PSNR overall / edge band per blur bucket (pixels pooled by their true CoC), one line per method."""
    used = [b for b in BUCKETS if any(r["sse"][f"{b[2]}|all"][1] for r in rows)]
    lines = ["| method | " + " | ".join(f"CoC {label} px" for _, _, label in used) + " |",
             "|---|" + "---|" * len(used)]
    for m in _methods(rows):
        cells = []
        for _, _, label in used:
            a, e = pooled_psnr(rows, m, f"{label}|all"), pooled_psnr(rows, m, f"{label}|edge")
            cells.append("-" if np.isnan(a) else f"{a:.2f} / {e:.2f}" if not np.isnan(e) else f"{a:.2f} / -")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def focus_table(rows: list[dict]) -> str:
    """Mean PSNR overall / edge band per focus position and largest blur, one line per method."""
    from ..synth.wide import FOCUS_POSITIONS

    groups = list(dict.fromkeys((r["focus"], r["blur_px"], r["blur_share"]) for r in rows))
    groups.sort(key=lambda g: (FOCUS_POSITIONS.index(g[0]), g[1]))
    head = "| method | " + " | ".join(f"{f}, {_blur_label(b, s)}" for f, b, s in groups) + " | all |"
    lines = [head, "|---|" + "---|" * (len(groups) + 1)]
    for m in _methods(rows):
        mine = [r for r in rows if r["method"] == m]
        cells = []
        for g in groups + [None]:
            sel = [r for r in mine if g is None or (r["focus"], r["blur_px"]) == g[:2]]
            cells.append(f"{np.mean([r['psnr'] for r in sel]):.2f} / {np.mean([r['psnr_edge'] for r in sel]):.2f}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def budget_summary(rows: list[dict]) -> list[dict]:
    """Mean PSNR of each error-budget variant over its cases."""
    out = []
    for b in BUDGET:
        sel = [r for r in rows if r["method"] == f"budget:{b}"]
        if sel:
            out.append({"variant": b, "psnr": float(np.mean([r["psnr"] for r in sel])),
                        "psnr_edge": float(np.mean([r["psnr_edge"] for r in sel])), "cases": len(sel)})
    return out


def budget_table(rows: list[dict], highlights=HIGHLIGHTS) -> str:
    """The error budget: what each input error costs pcdof exact, in dB ("+hl": highlights *highlights*)."""
    s = {b["variant"]: b for b in budget_summary(rows)}
    lines = ["| pcdof exact given | mean PSNR dB | edge band dB |", "|---|---|---|"]
    lines += [f"| {v.replace('+hl', f' + highlights {highlights}').replace('+linear', ' + unclipped linear colour')}"
              f" | {b['psnr']:.2f} | {b['psnr_edge']:.2f} |" for v, b in s.items()]

    def step(a, b):
        return f"{s[b]['psnr'] - s[a]['psnr']:+.2f}" if a in s and b in s else "-"

    lines += ["", "| stage | cost dB (negative: what it costs; positive: what it gains) |", "|---|---|",
              f"| depth errors (true depth -> measured) | {step('true depth', 'measured')} |",
              f"| clipping (unclipped linear colour -> 8-bit, true depth) | {step('true depth+linear', 'true depth')} |",
              f"| clipping left after highlights {highlights} (true depth) | "
              f"{step('true depth+linear', 'true depth+hl')} |",
              f"| highlights {highlights} on measured input | {step('measured', 'measured+hl')} |"]
    if "true depth+linear" in s:
        lines.append(f"| renderer's own error (true depth + linear colour) | PSNR {s['true depth+linear']['psnr']:.2f} |")
    return "\n".join(lines)


def losses_table(rows: list[dict], ours: str = "pcdof-balanced", others=None) -> str:
    """Every case where *ours* scores below one of *others* (default: the peers in *rows*, :func:`pcdof.bench.dof.peers_in`),
    overall or in the edge band, with the margin."""
    others = peers_in(rows) if others is None else others
    lines = [f"| scene | seed | focus | blur px | {ours} dB (edge) | best other dB (edge) | margin dB (edge) |",
             "|---|---|---|---|---|---|---|"]
    cases = by_case(rows)
    for case, by in cases.items():
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


def compare(rows: list[dict], a: str, b: str, *, tolerance_db: float = 0.0) -> dict:
    """Per-case PSNR of method *b* minus method *a*: mean, worst, and cases *b* loses by more than *tolerance_db*."""
    d = [(case, by[b]["psnr"] - by[a]["psnr"], by[b]["psnr_edge"] - by[a]["psnr_edge"])
         for case, by in by_case(rows).items() if a in by and b in by]
    if not d:
        return {"cases": 0}
    return {"cases": len(d), "mean_db": float(np.mean([x[1] for x in d])),
            "mean_edge_db": float(np.mean([x[2] for x in d])),
            "worst_db": float(min(x[1] for x in d)), "worst_edge_db": float(min(x[2] for x in d)),
            "wins": sum(x[1] > tolerance_db for x in d),
            "losses": [(c, round(x, 3), round(e, 3)) for c, x, e in d if x < -tolerance_db or e < -tolerance_db]}


def compare_table(rows: list[dict], a: str, b: str, *, tolerance_db: float = 0.0) -> str:
    """:func:`compare` as Markdown: the summary line and every case *b* loses."""
    c = compare(rows, a, b, tolerance_db=tolerance_db)
    if not c["cases"]:
        return f"no case has both {a} and {b}"
    head = (f"{b} - {a} over {c['cases']} cases: mean {c['mean_db']:+.2f} dB (edge {c['mean_edge_db']:+.2f}), "
            f"worst {c['worst_db']:+.2f} (edge {c['worst_edge_db']:+.2f}); {c['wins']} cases gain more than "
            f"{tolerance_db:g} dB, {len(c['losses'])} lose more than {tolerance_db:g} dB (overall or edge band)")
    lines = [head, "", "| scene | seed | focus | blur px | change dB | edge band dB |", "|---|---|---|---|---|---|"]
    lines += [f"| {s} | {sd} | {f} | {bl:g} | {x:+.2f} | {e:+.2f} |" for (s, sd, f, bl), x, e in c["losses"]]
    return "\n".join(lines if c["losses"] else lines[:1])


#: highlight settings compared on the tuning seeds
HIGHLIGHT_CANDIDATES = ({"method": "off"}, *({"method": "gain", "gain": g} for g in (2.0, 3.0, 4.0)), {"method": "rim"},
                        *({"method": "prior", "prior_max": m, "max_channel_ratio": math.inf}
                          for m in (8.0, 12.0, 16.0, 20.0, 24.0, 32.0)),
                        *({"method": "prior", "prior_max": m, "max_channel_ratio": r}
                          for r in (4.0, 8.0) for m in (16.0, 24.0, 32.0)),
                        *({"method": "prior-rim", "prior_max": m, "max_channel_ratio": math.inf} for m in (8.0, 12.0, 16.0)))
#: the rule that picks the default from the tuning table, stated before it is run: the largest mean
#: change from off per case (balanced, measured input) among the settings whose every case loses at
#: most this much to off, overall and in the edge band (dB); off when none does
DEFAULT_RULE_MAX_LOSS_DB = 0.25


def _label(cand: dict) -> str:
    names = {"gain": "", "prior_max": "max ", "max_channel_ratio": "ratio "}
    return cand["method"] + "".join(f" {names.get(k, k + ' ')}{v:g}" for k, v in cand.items() if k != "method")


def tune_highlights(*, kinds=None, seeds=TUNING_SEEDS, blurs=BLURS_PX, reference_width_px=REFERENCE_WIDTH_PX,
                    size=(256, 192), depth_size=(256, 212), candidates=HIGHLIGHT_CANDIDATES, cache_dir=None,
                    progress: bool = True) -> list[dict]:
    """Each highlight setting on the tuning seeds: pcdof exact given the true depth (only the colour
    differs) and pcdof balanced on the measured input (what a user gets), against ``off``.

    Returns
    -------
    list of dict per candidate: highlights, psnr / psnr_edge (true depth, exact), psnr_measured /
    psnr_measured_edge (measured, balanced), and per-case change from off on measured input:
    gain_db (mean), worst_db, losses (cases losing more than 0.1 dB), cases
    """
    variants = {}
    for cand in candidates:
        variants[f"tune:{_label(cand)}|true"] = Variant(True, highlights=dict(cand), quality="exact")
        variants[f"tune:{_label(cand)}|measured"] = Variant(highlights=dict(cand), quality="balanced")
    rows = run_wide(kinds=kinds, seeds=seeds, blurs=blurs, reference_width_px=reference_width_px, size=size,
                    depth_size=depth_size, methods=(), budget=(), variants=variants, cache_dir=cache_dir,
                    progress=progress)
    out = []
    for cand in candidates:
        t, m = (f"tune:{_label(cand)}|{k}" for k in ("true", "measured"))
        mean = {k: float(np.mean([r[k] for r in rows if r["method"] == name]))
                for name, k in ((t, "psnr"), (t, "psnr_edge"))}
        c = compare(rows, f"tune:{_label({'method': 'off'})}|measured", m, tolerance_db=0.1)
        out.append({"highlights": dict(cand), **mean,
                    "psnr_measured": float(np.mean([r["psnr"] for r in rows if r["method"] == m])),
                    "psnr_measured_edge": float(np.mean([r["psnr_edge"] for r in rows if r["method"] == m])),
                    "gain_db": c.get("mean_db", float("nan")), "worst_db": c.get("worst_db", float("nan")),
                    "worst_edge_db": c.get("worst_edge_db", float("nan")),
                    "losses": len(c.get("losses", [])), "cases": c["cases"]})
    return out


def choose_highlights(tuned: list[dict], *, max_loss_db: float = DEFAULT_RULE_MAX_LOSS_DB) -> dict:
    """The setting the default rule picks from :func:`tune_highlights`' rows (:data:`DEFAULT_RULE_MAX_LOSS_DB`)."""
    ok = [t for t in tuned if min(t["worst_db"], t["worst_edge_db"]) >= -max_loss_db]
    best = max(ok, key=lambda t: t["gain_db"], default=None)
    return best["highlights"] if best is not None and best["gain_db"] > 0 else {"method": "off"}


def tuning_table(tuned: list[dict]) -> str:
    lines = ["| highlights | exact, true depth: PSNR / edge dB | balanced, measured: PSNR / edge dB | "
             "change from off per case (measured): mean / worst / worst edge dB | cases losing > 0.1 dB |",
             "|---|---|---|---|---|"]
    for t in tuned:
        lines.append(f"| {_label(t['highlights'])} | {t['psnr']:.2f} / {t['psnr_edge']:.2f} | "
                     f"{t['psnr_measured']:.2f} / {t['psnr_measured_edge']:.2f} | {t['gain_db']:+.2f} / "
                     f"{t['worst_db']:+.2f} / {t['worst_edge_db']:+.2f} | {t['losses']} of {t['cases']} |")
    lines += ["", f"The rule (largest mean change among settings whose every case loses at most "
                  f"{DEFAULT_RULE_MAX_LOSS_DB:g} dB to off, overall and in the edge band) picks: "
                  f"{_label(choose_highlights(tuned))}"]
    return "\n".join(lines)


def budget_plot(rows: list[dict], path: str) -> None:
    """Bar chart of the error budget (mean PSNR per variant), as a PNG."""
    s = budget_summary(rows)
    with plot_to(path, figsize=(7, 3.6)) as (_, ax):
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
