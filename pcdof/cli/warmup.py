"""`pcdof warmup`: compile every stage's kernels now (numba caches them), with progress."""

from __future__ import annotations

import click

from ..kernels import STAGES
from ._common import handle_errors


@click.command("warmup")
@click.option("--stages", default=",".join(STAGES), show_default=True,
              help="Comma-separated stages to compile.")
@handle_errors
def command(stages):
    """Compile (or load from numba's cache) the kernels of every stage, so the first render starts at once.

    The first run after an install or upgrade compiles them (about half a minute); later runs
    only load them from the cache and report how long that took.
    """
    from ..kernels import check_stages, cold_stages, warmup

    names = check_stages(s.strip() for s in stages.split(",") if s.strip())
    cold = set(cold_stages())
    click.echo("compiling kernels, once after install" if cold & set(names) else "kernels already compiled; loading",
               err=True)
    seconds = warmup(names, progress=lambda line: click.echo(line, err=True), processes=True)
    click.echo(f"ready: {', '.join(f'{k} {v:.1f} s' for k, v in seconds.items())}")
