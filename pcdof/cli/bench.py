"""`pcdof bench`: time against error on the ray-traced ground truth, plus the speed and peer benchmarks."""

from __future__ import annotations

import csv
import io as _io
import json
import os
import platform

import click

from ..errors import InputError
from ._common import check_output_file, check_output_folder, handle_errors, make_output_folder

PARTS = ("dof", "speed", "registration", "fill")


def versions() -> dict:
    import cv2
    import numba
    import numpy
    import open3d

    return {"python": platform.python_version(), "numpy": numpy.__version__, "opencv": cv2.__version__,
            "open3d": open3d.__version__, "numba": numba.__version__, "machine": platform.machine(),
            "cpus": os.cpu_count()}


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


def _output_files(parts) -> list[str]:
    """The files a run of *parts* writes into its output folder."""
    files = ["report.json", "report.md"]
    if "dof" in parts:
        files += ["dof.csv", "pareto.png"]
    if "speed" in parts:
        files += ["cost.png"]
    return files


@click.command("bench")
@click.option("-o", "--output", default="out/bench", show_default=True, type=click.Path(readable=False))
@click.option("--quick", is_flag=True, help="Tiny scenes, few repeats: a smoke run for tests.")
@click.option("--only", default=",".join(PARTS), show_default=True, help="Comma-separated parts to run.")
@click.option("--size", default="320x240", show_default=True, help="Colour size of the ground-truth scenes.")
@click.option("--depth-size", default="256x212", show_default=True, help="Depth camera size of the scenes.")
@click.option("--repeats", type=int, default=5, show_default=True, help="Timed repeats per measurement (>= 1).")
@click.option("--samples", type=int, default=None,
              help="Aperture samples for the ground truth, >= 1 (default: adaptive).")
@click.option("--scenes", default=None, help="Comma-separated scene names (default: all).")
@handle_errors
def command(output, quick, only, size, depth_size, repeats, samples, scenes):
    """Run the benchmarks and write JSON, CSV, Markdown tables and plots into OUTPUT.

    Every option is checked before any work (--scenes applies to the dof part; --quick overrides
    --size, --depth-size and --repeats, which are checked all the same).
    """
    from ..bench import check_repeats, check_scenes
    from ..synth.rig import parse_size

    parts = _split(only)
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise InputError(f"--only: unknown part(s) {', '.join(map(repr, bad))}; choose from {', '.join(PARTS)}")
    if not parts:
        raise InputError(f"--only selects no part; choose from {', '.join(PARTS)}")
    size, depth_size = parse_size(size, "--size"), parse_size(depth_size, "--depth-size")
    check_repeats(repeats, "--repeats")
    if samples is not None and samples < 1:
        raise InputError(f"--samples must be an integer >= 1; got {samples}")
    scene_list = check_scenes(_split(scenes), "--scenes") if scenes is not None else None
    check_output_folder(output, "output")
    for name in _output_files(parts):
        check_output_file(os.path.join(output, name), "output")
    if "dof" in parts:
        check_output_folder(os.path.join(output, "cache"), "output")
    if quick:
        size, depth_size, repeats = (96, 72), (80, 66), 1
        scene_list = scene_list or ["portrait", "slanted_plane"]
    make_output_folder(output, "output")
    report = {"versions": versions(), "quick": quick}
    md = [f"# pcdof benchmark\n\nversions: {json.dumps(report['versions'])}\n"]

    def save():
        _write_text(os.path.join(output, "report.json"), json.dumps(report, indent=1, default=float))
        _write_text(os.path.join(output, "report.md"), "\n".join(md))

    if "dof" in parts:
        from ..bench import dof

        rows = dof.run_dof_bench(scenes=scene_list, size=size, depth_size=depth_size, repeats=repeats,
                                 samples=samples if not quick else (samples or 64),
                                 cache_dir=os.path.join(output, "cache"))
        report["dof"] = rows
        report["dof_summary"] = dof.summarize(rows)
        _write_csv(os.path.join(output, "dof.csv"), rows)
        dof.pareto_plot(rows, os.path.join(output, "pareto.png"))
        md += ["## Depth of field against the ray-traced ground truth\n", dof.summary_table(rows), "",
               dof.compact_table(rows), "", "All methods and quality levels:\n", dof.markdown_table(rows), ""]
        click.echo(dof.summary_table(rows))
        click.echo(dof.compact_table(rows))
        save()
    if "speed" in parts:
        from ..bench import speed

        sizes = ((160, 120),) if quick else ((640, 480), (1920, 1080))
        dsize = (128, 106) if quick else (512, 424)
        rows = speed.pipeline_vs_paper(sizes=sizes, depth_size=dsize, repeats=repeats)
        cost = speed.cost_follows_work(size=sizes[0], depth_size=dsize, repeats=repeats)
        speed.cost_plot(cost, os.path.join(output, "cost.png"))
        report["speed"], report["cost"] = rows, cost
        lines = ["| colour | depth | pcdof ms (register + fill + coc + render) | paper method ms (register + fill + "
                 "blur/weight/blend) | ratio | paper blur/weight/blend alone ms |", "|---|---|---|---|---|---|"]
        for r in rows:
            st, pst = r["pcdof_stages_ms"], r["paper_stages_ms"]
            ours = " + ".join(f"{st.get(k, 0):.1f}" for k in ("register", "fill", "coc", "render"))
            theirs = " + ".join(f"{pst.get(k, 0):.1f}" for k in ("register", "fill", "render"))
            lines.append(f"| {r['color_size']} | {r['depth_size']} | {r['pcdof_ms']:.1f} ({ours}) | "
                         f"{r['paper_ms']:.1f} ({theirs}) | {r['ratio']:.2f} | {pst.get('render', 0):.1f} |")
        lines += ["", "| out of focus | f-number | render ms | relative to 100 % |", "|---|---|---|---|"]
        lines += [f"| {100 * r['share']:.0f} % | {r['f_number']:.2f} | {r['render_ms']:.2f} | "
                  f"{r['relative_to_full']:.3f} |" for r in cost]
        md += ["## Speed\n", *lines, ""]
        click.echo("\n".join(lines))
        save()
    if "registration" in parts:
        from ..bench import registration

        rows = registration.run_registration_bench(quick=quick, repeats=repeats)
        report["registration"] = rows
        table = registration.format_registration_table(rows)
        md += ["## Registration against OpenCV and Open3D\n", table, ""]
        click.echo(table)
        save()
    if "fill" in parts:
        from ..bench import fill

        rows = fill.run_fill_bench(quick=quick)
        report["fill"] = rows
        table = fill.markdown_table(rows)
        md += ["## Hole filling against cv2.inpaint\n", table, ""]
        click.echo(table)
        save()
    save()
    click.echo(f"wrote {output}/report.md and report.json", err=True)
