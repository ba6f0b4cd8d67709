"""`pcdof bench`: time against error on the ray-traced ground truth, plus the speed and peer benchmarks."""

from __future__ import annotations

import csv
import io as _io
import json
import os

import click

from ..errors import InputError
from ..versions import library_versions
from ._common import check_output_file, check_output_folder, handle_errors, make_output_folder

#: every part; "wide-tune" (choosing the highlight default on the tuning seeds), "tiers" (the quality tiers'
#: thresholds from the error-vs-blur curve, on the tuning seeds), "hidden" (what the hidden background
#: costs), "depth-errors" (what each class of depth error costs the render) and "fill-rigs" (the fill on rigs of real
#: devices, inside and outside the depth view) run only when named
PARTS = ("dof", "wide", "speed", "registration", "fill", "wide-tune", "tiers", "hidden", "depth-errors", "fill-rigs")
DEFAULT_PARTS = ("dof", "wide", "speed", "registration", "fill")
#: the order the parts run in (the report's sections follow it)
RUN_ORDER = ("dof", "wide", "wide-tune", "tiers", "hidden", "depth-errors", "speed", "registration", "fill",
             "fill-rigs")
#: the stages each side of the speed table sums
PCDOF_STAGES, PAPER_STAGES = ("register", "fill", "coc", "highlights", "render"), ("register", "fill", "render")


def _write_text(path: str, text: str) -> None:
    """Write UTF-8 *text* atomically (ImageWriteError on failure, no temporary file left behind)."""
    from ..io._files import atomic_write_bytes

    atomic_write_bytes(path, text.encode("utf-8"))


def _write_csv(path: str, rows: list[dict]) -> None:
    if not rows:
        return
    keys = list(dict.fromkeys(k for r in rows for k in r if not isinstance(r[k], (dict, list))))
    buf = _io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    _write_text(path, buf.getvalue())


def _split(text: str) -> list[str]:
    return [p.strip() for p in text.split(",") if p.strip()]


def _choices(value, choices, flag):
    """A comma-separated list of names from *choices*, or a usage error (exit 2) that lists them."""
    if value is None:
        return None
    names = _split(value)
    bad = [n for n in names if n not in choices]
    if bad or not names:
        what = f"unknown {', '.join(map(repr, bad))}" if bad else "selects nothing"
        raise click.BadParameter(f"{what}; choose from {', '.join(choices)}", param_hint=flag)
    return names


def _parts(ctx, param, value):
    return _choices(value, PARTS, "--only")


def _scene_list(ctx, param, value):
    from ..synth import SCENES

    return _choices(value, list(SCENES), "--scenes")


def _output_files(parts) -> list[str]:
    """The files a run of *parts* writes into its output folder."""
    files = ["report.json", "report.md"]
    if "dof" in parts:
        files += ["dof.csv", "pareto.png"]
    if "wide" in parts:
        files += ["wide.csv", "budget.png", "wide_tiers.png"]
    if "hidden" in parts:
        files += ["hidden.csv"]
    if "depth-errors" in parts:
        files += ["depth_errors.csv"]
    if "speed" in parts:
        files += ["cost.png"]
    return files


@click.command("bench")
@click.option("-o", "--output", default="out/bench", show_default=True, type=click.Path(readable=False))
@click.option("--quick", is_flag=True, help="Tiny scenes, few repeats: a smoke run for tests.")
@click.option("--only", default=",".join(DEFAULT_PARTS), show_default=True, callback=_parts,
              help=f"Comma-separated parts to run, from {', '.join(PARTS)}.")
@click.option("--size", default="320x240", show_default=True, help="Colour size of the ground-truth scenes.")
@click.option("--depth-size", default="256x212", show_default=True, help="Depth camera size of the scenes.")
@click.option("--repeats", type=int, default=5, show_default=True, help="Timed repeats per measurement (>= 1).")
@click.option("--samples", type=int, default=None,
              help="Aperture samples for the ground truth, >= 1 (default: adaptive).")
@click.option("--scenes", default=None, callback=_scene_list,
              help="Comma-separated scene names of the dof part (default: all).")
@click.option("--seeds", type=click.IntRange(min=1), default=2, show_default=True,
              help="Seeds per scene type of the wide and hidden parts (reported seeds 100, 101, ...; tuning seeds "
                   "0, 1, ...).")
@click.option("--wide-size", default="256x192", show_default=True,
              help="Colour size of the wide and hidden parts (their depth camera: --depth-size).")
@click.option("--wide-blurs", default="16,64", show_default=True, callback=lambda ctx, param, v: _blurs(v),
              help="Largest blurs of the wide part's lens settings, px at a 640 px wide frame (scaled to "
                   "--wide-size's width), comma-separated.")
@click.option("--absolute-blurs", is_flag=True, help="--wide-blurs are pixels at --wide-size, not scaled.")
@click.option("--wide-highlights", default="auto", show_default=True, callback=lambda ctx, param, v: _highlights(v),
              help="--highlights setting of the wide part's '+hl' rows (off, auto, gain, rim or a gain).")
@handle_errors
def command(output, quick, only, size, depth_size, repeats, samples, scenes, seeds, wide_size, wide_blurs,
            absolute_blurs, wide_highlights):
    """Run the benchmarks and write JSON, CSV, Markdown tables and plots into the folder named by -o.

    Every option is checked before any work (--scenes applies to the dof part; --quick overrides
    --size, --depth-size and --repeats, which are checked all the same).
    """
    run = _settings(output, only, quick, size, depth_size, repeats, samples, scenes, seeds, wide_size, wide_blurs,
                    absolute_blurs)
    make_output_folder(output, "output")
    report = {"versions": library_versions(), "quick": quick}
    md = [f"# pcdof benchmark\n\nversions: {json.dumps(report['versions'])}\n"]
    steps = {"dof": lambda: _dof_part(report, md, run),
             "wide": lambda: _wide_part(report, md, output, run["seeds"], run["wide_kw"], wide_highlights),
             "wide-tune": lambda: _wide_tune_part(report, md, output, run["seeds"], run["wide_kw"]),
             "tiers": lambda: _tiers_part(report, md, output, run["seeds"], run["wide_kw"]),
             "hidden": lambda: _hidden_part(report, md, output, run["seeds"], run["wide_kw"]),
             "depth-errors": lambda: _depth_errors_part(report, md, output, run["seeds"], run["wide_kw"]),
             "speed": lambda: _speed_part(report, md, run), "registration": lambda: _registration_part(report, md, run),
             "fill": lambda: _fill_part(report, md, run),
             "fill-rigs": lambda: _fill_rigs_part(report, md, seeds, run["quick"])}
    for part in (p for p in RUN_ORDER if p in only):
        steps[part]()
        _save(output, report, md)  # after every part, so a long run that stops keeps what it measured
    _save(output, report, md)
    click.echo(f"wrote {output}/report.md and report.json", err=True)


def _save(output: str, report: dict, md: list[str]) -> None:
    _write_text(os.path.join(output, "report.json"), json.dumps(report, indent=1, default=float))
    _write_text(os.path.join(output, "report.md"), "\n".join(md))


def _settings(output, parts, quick, size, depth_size, repeats, samples, scenes, seeds, wide_size, wide_blurs,
              absolute_blurs) -> dict:
    """The checked options of a run as a dict (``--quick`` applied), or an error before any work."""
    from ..bench import check_repeats, check_scenes, wide
    from ..synth.rig import parse_size

    size, depth_size = parse_size(size, "--size"), parse_size(depth_size, "--depth-size")
    wide_size = parse_size(wide_size, "--wide-size")
    check_repeats(repeats, "--repeats")
    if samples is not None and samples < 1:
        raise InputError(f"--samples must be an integer >= 1; got {samples}")
    scene_list = check_scenes(scenes, "--scenes") if scenes is not None else None
    check_output_folder(output, "output")
    for name in _output_files(parts):
        check_output_file(os.path.join(output, name), "output")
    if any(p in parts for p in ("dof", "wide", "wide-tune", "tiers", "hidden", "depth-errors")):
        check_output_folder(os.path.join(output, "cache"), "output")
    wide_kw = {"kinds": None, "blurs": wide_blurs, "size": wide_size, "depth_size": depth_size,
               "reference_width_px": None if absolute_blurs else wide.REFERENCE_WIDTH_PX}
    if quick:
        size, depth_size, repeats, seeds = (96, 72), (80, 66), 1, 1
        scene_list = scene_list or ["portrait", "slanted_plane"]
        samples = samples or 64
        wide_kw = {"kinds": ["room"], "blurs": (120.0,), "size": (64, 48), "depth_size": (64, 53),
                   "reference_width_px": wide.REFERENCE_WIDTH_PX}
    return {"output": output, "quick": quick, "size": size, "depth_size": depth_size, "repeats": repeats,
            "samples": samples, "scenes": scene_list, "seeds": seeds, "wide_kw": wide_kw}


def _dof_part(report, md, run) -> None:
    from ..bench import dof

    output = run["output"]
    rows = dof.run_dof_bench(scenes=run["scenes"], size=run["size"], depth_size=run["depth_size"],
                             repeats=run["repeats"], samples=run["samples"], cache_dir=os.path.join(output, "cache"))
    report["dof"] = rows
    report["dof_summary"] = dof.summarize(rows)
    _write_csv(os.path.join(output, "dof.csv"), rows)
    dof.pareto_plot(rows, os.path.join(output, "pareto.png"))
    from ..bench.blender import peer_note

    md += ["## Depth of field against the ray-traced ground truth\n", peer_note(), "", dof.summary_table(rows), "",
           dof.compact_table(rows), "", "All methods and quality levels:\n", dof.markdown_table(rows), ""]
    click.echo(dof.summary_table(rows))
    click.echo(dof.compact_table(rows))


def _speed_part(report, md, run) -> None:
    from ..bench import machine, speed, table_lines

    quick, repeats = run["quick"], run["repeats"]
    sizes = ((160, 120),) if quick else ((640, 480), (1920, 1080))
    dsize = (128, 106) if quick else (512, 424)
    rows = speed.pipeline_vs_paper(sizes=sizes, depth_size=dsize, repeats=repeats)
    scaling = speed.thread_scaling(size=sizes[0], depth_size=dsize, repeats=repeats)
    start = speed.startup(size=sizes[0], depth_size=dsize, repeats=min(repeats, 5), cold=not quick)
    cost = speed.cost_follows_work(size=sizes[0], depth_size=dsize, repeats=repeats)
    speed.cost_plot(cost, os.path.join(run["output"], "cost.png"))
    report["speed"], report["threads"], report["startup"], report["cost"] = rows, scaling, start, cost
    refocus_rows, refocus_scaling, memory = _refocus_measures(quick, repeats, dsize)
    report["refocus"], report["refocus_threads"], report["memory"] = refocus_rows, refocus_scaling, memory
    megabytes = 40.0 if quick else 400.0
    bounds = machine.thread_bounds(megabytes=megabytes, steps=20_000 if quick else machine.ARITHMETIC_STEPS,
                                   repeats=min(repeats, 3))
    report["machine_threads"] = bounds
    lines = _speed_lines(rows, scaling, start) + [""] + _refocus_lines(refocus_rows, refocus_scaling, memory)
    lines += ["", *_machine_lines(bounds, megabytes)]
    lines += ["", *table_lines(("out of focus", "f-number", "render ms", "relative to 100 %"), (
        (f"{100 * r['share']:.0f} %", f"{r['f_number']:.2f}", f"{r['render_ms']:.2f}", f"{r['relative_to_full']:.3f}")
        for r in cost))]
    md += ["## Speed\n", *lines, ""]
    click.echo("\n".join(lines))


def _machine_lines(bounds, megabytes: float) -> list[str]:
    """The table of :func:`pcdof.bench.machine.thread_bounds`' rows, with the line that says what it shows."""
    from ..bench import table_lines

    return [f"What this machine's threads can give (pcdof.bench.machine): a loop of arithmetic, and a loop that "
            f"streams {megabytes:g} MB as the render's passes stream the frame:", "",
            *table_lines(("threads", "arithmetic loop ms", "speed-up", "streaming loop ms", "speed-up"), (
                (str(r["threads"]), f"{r['arithmetic_ms']:.1f}", f"{r['arithmetic_speedup']:.2f}",
                 f"{r['stream_ms']:.1f}", f"{r['stream_speedup']:.2f}") for r in bounds))]


def _refocus_measures(quick: bool, repeats: int, dsize) -> tuple[list, list, list]:
    """The refocus rows (sizes x background blurs, the paper's whole frame alternated), the refocus per thread
    count, and the pipeline's peak memory per pixel (:mod:`pcdof.bench.refocus`)."""
    from ..bench import refocus

    if quick:
        sizes, memory_sizes, scaling_size = ((160, 120),), ((160, 120),), (160, 120)
    else:
        sizes = ((640, 480), (1920, 1080), (3840, 2160))
        memory_sizes = ((640, 480), (1920, 1080), (3840, 2160), (8064, 6048))
        scaling_size = (1920, 1080)
    rows = refocus.refocus_vs_paper(sizes=sizes, depth_size=dsize, repeats=repeats)
    scaling = refocus.refocus_threads(size=scaling_size, depth_size=dsize, repeats=repeats)
    memory = refocus.peak_memory(sizes=memory_sizes, depth_size=dsize)
    return rows, scaling, memory


def _refocus_lines(rows, scaling, memory) -> list[str]:
    """The refocus tables: per size and background blur against the paper's whole frame, per thread count, and
    the pipeline's peak memory per pixel."""
    from ..bench import table_lines

    def q(pair, fmt="{:.1f}"):
        return "-".join(fmt.format(v) for v in pair)

    lines = table_lines(
        ("colour", "background blur px", "refocus ms (coc + highlights + render)", "quartiles",
         "paper whole frame ms (cv2.registerDepth + blur/weight/blend)", "ratio (per repeat)",
         "refocus cost over the smallest blur's"),
        ((r["color_size"], f"{r['background_blur_px']:.0f}", f"{r['refocus_ms']:.1f}", q(r["refocus_ms_quartiles"]),
          f"{r['paper_ms']:.1f}", f"{r['ratio']:.2f} ({q(r['ratio_quartiles'], '{:.2f}')})",
          f"{r['relative_to_smallest_blur']:.2f}") for r in rows))
    lines += ["", *table_lines(("threads", "colour", "background blur px", "refocus ms", "quartiles",
                                "speed-up over 1 thread"), (
        (str(r["threads"]), r["color_size"], f"{r['background_blur_px']:.0f}", f"{r['ms']:.1f}",
         q(r["ms_quartiles"]), f"{r['speedup']:.2f}") for r in scaling))]
    lines += ["", *table_lines(("colour", "megapixels", "baseline MB", "peak MB", "bytes per pixel above baseline",
                                "bytes per added pixel (from the size above)"), (
        (r["color_size"], f"{r['megapixels']:.2f}", f"{r['baseline_mb']:.0f}", f"{r['peak_mb']:.0f}",
         f"{r['bytes_per_pixel']:.0f}",
         "-" if r.get("marginal_bytes_per_pixel") is None else f"{r['marginal_bytes_per_pixel']:.0f}") for r in memory))]
    return lines


def _speed_lines(rows, scaling, start) -> list[str]:
    """The speed tables: pipeline against the paper method (medians, quartiles, per-repeat ratio), the pipeline
    per thread count, and start-up in fresh processes."""
    from ..bench import table_lines

    def q(pair, fmt="{:.1f}"):
        return "-".join(fmt.format(v) for v in pair)

    lines = table_lines(
        ("colour", "depth", "pcdof ms (register + fill + coc + highlights + render)", "quartiles",
         "paper method ms (register + fill + blur/weight/blend)", "quartiles", "ratio (per repeat: median, quartiles)",
         "paper blur/weight/blend alone ms"),
        ((r["color_size"], r["depth_size"], f"{r['pcdof_ms']:.1f} ({_stage_sum(r['pcdof_stages_ms'], PCDOF_STAGES)})",
          q(r["pcdof_ms_quartiles"]), f"{r['paper_ms']:.1f} ({_stage_sum(r['paper_stages_ms'], PAPER_STAGES)})",
          q(r["paper_ms_quartiles"]), f"{r['ratio_paired']:.2f} ({q(r['ratio_quartiles'], '{:.2f}')})",
          f"{r['paper_stages_ms'].get('render', 0):.1f}") for r in rows))
    lines += ["", *table_lines(
        ("colour", "pcdof ms", "paper method on cv2.registerDepth depth, no fill, ms", "quartiles",
         "ratio (per repeat: median, quartiles)"),
        ((r["color_size"], f"{r['pcdof_ms']:.1f}", f"{r['paper_cv2_ms']:.1f}", q(r["paper_cv2_ms_quartiles"]),
          f"{r['ratio_cv2_paired']:.2f} ({q(r['ratio_cv2_quartiles'], '{:.2f}')})") for r in rows))]
    lines += ["", *table_lines(("threads", "colour", "pipeline ms", "quartiles", "speed-up over 1 thread"), (
        (str(r["threads"]), r["color_size"], f"{r['ms']:.1f}", q(r["ms_quartiles"]), f"{r['speedup']:.2f}")
        for r in scaling))]
    cold = "not measured" if start["cold_render_s"] is None else f"{start['cold_render_s']:.1f}"
    load = "" if start["load_average"] is None else f" (load average {start['load_average']:.1f})"
    lines += ["", *table_lines(("fresh process", "seconds (median)", "quartiles"), (
        ("python -c 'import pcdof'", f"{start['import_s']:.3f}", q(start["import_s_quartiles"], "{:.3f}")),
        (f"pcdof render, {start['color_size']}, kernels cached", f"{start['warm_render_s']:.2f}",
         q(start["warm_render_s_quartiles"], "{:.2f}")),
        (f"pcdof render, {start['color_size']}, empty kernel cache (first run after an install)", cold, "one run")))]
    lines.append(f"Start-up: {start['repeats']} run{'s' if start['repeats'] != 1 else ''} of each{load}.")
    return lines


def _stage_sum(stages_ms: dict, names) -> str:
    """The times of the stages *names* (ms, 0 where missing) as "a + b + ..."."""
    return " + ".join(f"{stages_ms.get(k, 0):.1f}" for k in names)


def _registration_part(report, md, run) -> None:
    from ..bench import registration

    report["registration"] = rows = registration.run_registration_bench(quick=run["quick"], repeats=run["repeats"])
    _table_section(md, "## Registration against OpenCV and Open3D\n", registration.format_registration_table(rows))


def _fill_part(report, md, run) -> None:
    from ..bench import fill

    report["fill"] = rows = fill.run_fill_bench(quick=run["quick"])
    _table_section(md, "## Hole filling against cv2.inpaint\n", fill.markdown_table(rows))


def _fill_rigs_part(report, md, seeds, quick) -> None:
    from ..bench import fill_rigs

    # --seeds counts scenes per type elsewhere; here each of 28 consecutive seeds is one (scene, rig) pairing
    seed_list = fill_rigs.REPORT_SEEDS[:4] if quick else fill_rigs.REPORT_SEEDS[:min(28, 14 * seeds)]
    width = 96 if quick else 256
    rows = fill_rigs.run_fill_rigs(seeds=seed_list, color_width=width, render=not quick)
    report["fill_rigs"] = rows
    note = (f"Report seeds {seed_list[0]}-{seed_list[-1]} (the border rule was chosen on seeds "
            f"{fill_rigs.TUNING_SEEDS[0]}-{fill_rigs.TUNING_SEEDS[-1]}), colour {width} px wide; errors at the holes "
            f"of the registered sensor depth, mm; too near / far: off by more than {fill_rigs.OFF_M * 100:g} cm; "
            "render dB: pcdof's render from the filled depth against its render from the exact depth.")
    tables = [fill_rigs.markdown_table(rows), "", "### Per scene\n", fill_rigs.markdown_table(rows, "scene"), "",
              "### Per rig\n", fill_rigs.markdown_table(rows, "rig"), ""]
    md += ["## Hole filling on rigs of real devices\n", note, "", *tables]
    click.echo(note)
    click.echo("\n".join(tables))


def _table_section(md: list, title: str, table: str) -> None:
    md += [title, table, ""]
    click.echo(table)


def _blurs(text: str) -> tuple[float, ...]:
    """--wide-blurs as numbers > 0, or a usage error."""
    try:
        blurs = tuple(float(b) for b in _split(text))
    except ValueError:
        blurs = ()
    if not blurs or any(not (b > 0 and b < float("inf")) for b in blurs):
        raise click.BadParameter(f"expected comma-separated numbers > 0; got {text!r}", param_hint="--wide-blurs")
    return blurs


def _highlights(text: str):
    """--wide-highlights as a RenderOptions.highlights value, or a usage error."""
    from ..stages.highlights import parse_highlights

    try:
        how, gain = parse_highlights(text)
    except InputError as e:
        raise click.BadParameter(str(e), param_hint="--wide-highlights") from None
    return text if text == how else gain


def _report_seeds(seeds: int) -> tuple[int, ...]:
    """The first *seeds* reported seeds of the wide benchmark (100, 101, ...)."""
    from ..bench import wide

    return wide.REPORT_SEEDS[:seeds] if seeds <= len(wide.REPORT_SEEDS) else tuple(range(100, 100 + seeds))


def _wide_part(report, md, output, seeds, kw, highlights) -> None:
    from ..bench import tiers, wide

    seed_list = _report_seeds(seeds)
    rows = wide.run_wide(seeds=seed_list, highlights=highlights, cache_dir=os.path.join(output, "cache"), **kw)
    report["wide"] = rows
    report["wide_budget"] = wide.budget_summary(rows)
    report["wide_tiers"] = tiers.tier_curve(rows)
    report["wide_highlights"] = {k: v for k, v in wide.compare(rows, "pcdof-balanced", "pcdof-balanced+hl",
                                                               tolerance_db=0.1).items()}
    _write_csv(os.path.join(output, "wide.csv"), [{k: v for k, v in r.items() if k != "sse"} for r in rows])
    wide.budget_plot(rows, os.path.join(output, "budget.png"))
    tiers.tier_plot(rows, os.path.join(output, "wide_tiers.png"))
    blurs = ", ".join(f"{b:g}" for b in kw["blurs"])
    size = f"{kw['size'][0]}x{kw['size'][1]}"
    scale = (f"largest blurs {blurs} px at a {kw['reference_width_px']:g} px wide frame, scaled to {size}"
             if kw["reference_width_px"] else f"largest blurs {blurs} px at {size}")
    seeds_note = (f"Reported seeds {', '.join(map(str, seed_list))}, {scale} (highlight settings were chosen on the "
                  f"separate tuning seeds {', '.join(map(str, wide.TUNING_SEEDS))}; `--only wide-tune` reruns that).")
    tables = ["### PSNR per blur bucket (overall / depth-edge band, dB; pixels pooled by their true CoC)\n",
              wide.bucket_table(rows), "", "### PSNR per focus position and largest blur (overall / edge band, dB)\n",
              wide.focus_table(rows), "", "### Error budget (pcdof exact)\n", wide.budget_table(rows, highlights), "",
              "### Quality tiers against exact (PSNR change, dB: pixels pooled / worst case)\n",
              tiers.tier_table(rows), "",
              f"### Highlights {highlights} on pcdof-balanced (measured input)\n",
              wide.compare_table(rows, "pcdof-balanced", "pcdof-balanced+hl", tolerance_db=0.1), "",
              "### Cases where pcdof-balanced loses to a peer (the paper method, the gather baseline, Blender's Defocus node "
              "when it ran)\n",
              wide.losses_table(rows), "",
              f"### Cases where pcdof-balanced+hl (highlights {highlights}) loses to a peer\n",
              wide.losses_table(rows, "pcdof-balanced+hl"), ""]
    from ..bench.blender import peer_note

    seeds_note += "\n\n" + peer_note()
    md += ["## Wide benchmark: large blur, focus near / mid / far, clipped 8-bit input\n", seeds_note, "", *tables]
    click.echo(seeds_note)
    click.echo("\n".join(tables))


def _wide_tune_part(report, md, output, seeds, kw) -> None:
    from ..bench import wide

    seed_list = wide.TUNING_SEEDS[:seeds]
    tuned = wide.tune_highlights(seeds=seed_list, cache_dir=os.path.join(output, "cache"), **kw)
    report["wide_tune"] = tuned
    table = wide.tuning_table(tuned)
    md += ["## Highlight settings on the tuning seeds\n",
           f"Tuning seeds {', '.join(map(str, seed_list))}, never reported elsewhere.\n", table, ""]
    click.echo(table)


def _tiers_part(report, md, output, seeds, kw) -> None:
    from ..bench import tiers, wide

    seed_list = wide.TUNING_SEEDS[:seeds]
    result = tiers.run_tiers(seeds=seed_list, cache_dir=os.path.join(output, "cache"), **kw)
    chosen = tiers.choose_thresholds(result)
    report["tiers"] = {"result": result, "chosen": chosen}
    tables = ["### Worst case per threshold against exact\n", tiers.loss_table(result), "",
              "### Error-vs-CoC curve (PSNR change of the reduced pixels, dB)\n", tiers.curve_table(result), "",
              "Thresholds by the rule of `pcdof.bench.tiers.choose_thresholds` (CoC in cells): "
              + ", ".join(f"{k} {v:g}" for k, v in chosen.items()), ""]
    md += ["## Quality tiers: thresholds from the measured curve\n",
           f"Tuning seeds {', '.join(map(str, seed_list))}, never reported elsewhere.\n", *tables]
    click.echo("\n".join(tables))


def _depth_errors_part(report, md, output, seeds, kw) -> None:
    from ..bench import depth_errors

    seed_list = _report_seeds(seeds)
    rows = depth_errors.run_depth_errors(seeds=seed_list, cache_dir=os.path.join(output, "cache"), **kw)
    report["depth_errors"] = rows
    _write_csv(os.path.join(output, "depth_errors.csv"), rows)
    size = f"{kw['size'][0]}x{kw['size'][1]}"
    note = (f"Reported seeds {', '.join(map(str, seed_list))} at {size}, the wide part's cases and ground truths. "
            "pcdof (coc + highlights + render, defaults) from its own filled depth, from the exact depth, and from the "
            "filled depth with one class of its errors put right (a surface given another surface's depth: more than "
            f"{depth_errors.WRONG_RATIO:.0%} apart). Mean PSNR overall / depth-edge band, dB (in brackets: the gain "
            "over the filled depth).")
    table = depth_errors.cost_table(rows)
    md += ["## What each class of depth error costs the render\n", note, "", table, ""]
    click.echo(note)
    click.echo(table)


def _hidden_part(report, md, output, seeds, kw) -> None:
    from ..bench import hidden, wide

    seed_list = _report_seeds(seeds)
    rows = hidden.run_hidden(seeds=seed_list, cache_dir=os.path.join(output, "cache"), **kw)
    report["hidden"] = rows
    report["hidden_cost"] = hidden.cost_summary(rows)
    report["hidden_cost_merged"] = hidden.cost_summary(rows, oracle=hidden.ORACLE_MERGED)
    _write_csv(os.path.join(output, "hidden.csv"), [{k: v for k, v in r.items() if k != "sse"} for r in rows])
    size = f"{kw['size'][0]}x{kw['size'][1]}"
    note = (f"Reported seeds {', '.join(map(str, seed_list))} at {size}, the wide part's cases and ground truths. "
            f"'{hidden.PLAIN_BUDGET}' is the error budget's pcdof exact from the true depth and unclipped linear "
            f"colour; '{hidden.PLAIN}' the same with every tile scattered; '{hidden.ORACLE}' the same render given "
            "the true hidden layers (each depth group ray traced with the nearer groups removed, rendered on its "
            f"own and composited front to back with over); '{hidden.ORACLE_MERGED}' merges groups whose blurs "
            "are closer to each other than to sharp first. Oracle minus plain is what the background hidden "
            "behind blurred foregrounds costs.")
    tables = ["### What the hidden background costs (mean PSNR, dB)\n", hidden.cost_table(rows), "",
              "### PSNR per blur bucket (overall / depth-edge band, dB; pixels pooled by their true CoC)\n",
              wide.bucket_table(rows), ""]
    md += ["## Hidden background: pcdof given the true hidden layers\n", note, "", *tables]
    click.echo(note)
    click.echo("\n".join(tables))
