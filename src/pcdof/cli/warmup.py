"""`pcdof warmup`: compile every stage's kernels now (numba caches them), with progress and the total."""

from __future__ import annotations

import time

import click

from ..runtime.kernels import STAGES
from ._common import handle_errors


@click.command("warmup")
@click.option("--stages", default=",".join(STAGES), show_default=True,
              help="Comma-separated stages to compile.")
@handle_errors
def command(stages):
    """Compile (or load from numba's cache) the kernels of every stage, so the first render starts at once.

    The first run after an install or upgrade compiles them (the stages side by side, one line as
    each is done); later runs only load them from the cache and report how long that took.
    """
    from ..runtime.kernels import check_stages, cold_stages, estimate_seconds, warmup

    names = check_stages(s.strip() for s in stages.split(",") if s.strip())
    cold = cold_stages(names)
    if cold:
        click.echo(f"pcdof: compiling kernels, once after install: {', '.join(cold)} "
                   f"(about {estimate_seconds(cold):.0f} s)", err=True)
    else:
        click.echo("kernels already compiled; loading", err=True)
    t0 = time.perf_counter()
    seconds = warmup(names, progress=lambda line: click.echo(line, err=True), processes=True)
    click.echo(f"ready in {time.perf_counter() - t0:.1f} s: {', '.join(f'{k} {v:.1f} s' for k, v in seconds.items())}")
