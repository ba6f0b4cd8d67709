"""The one line a command prints at normal verbosity: what it decided, and where the result is.

Every command that renders or writes something calls :func:`report_decision` once, after its output
is written; ``-q`` (before or after the subcommand) silences it. Errors and warnings are not
affected by ``-q``; they always go to stderr.
"""

from __future__ import annotations

import math

import click

from ..errors import InputError


def is_quiet() -> bool:
    """Whether ``-q`` was given (before or after the subcommand) to the running command."""
    ctx = click.get_current_context(silent=True)
    while ctx is not None:
        if isinstance(ctx.obj, dict) and ctx.obj.get("quiet"):
            return True
        ctx = ctx.parent
    return False


def format_decision(command: str, *, output: str | None = None, focus_distance_m: float | None = None,
                    focus_source: str | None = None, max_blur_px: float | None = None,
                    details: str | None = None) -> str:
    """One line: ``pcdof COMMAND: focus D m (SOURCE), max blur B px[, DETAILS] -> OUTPUT``.

    Parameters
    ----------
    command : str, the subcommand's name (``"render"``)
    output : str, the path written, as the user gave it (None: nothing written)
    focus_distance_m : float, metres, the focus distance used (None: no focus, e.g. ``register``)
    focus_source : str, how the focus was chosen (``"--focus-at 160,80"``, ``"depth at the image centre"``)
    max_blur_px : float, the largest circle of confusion in the render, pixels
    details : str, anything else the command decided (lens, method), already formatted

    Returns
    -------
    str, without a trailing newline
    """
    parts = []
    if focus_distance_m is not None:
        if not (isinstance(focus_distance_m, (int, float)) and math.isfinite(focus_distance_m)):
            raise InputError(f"focus_distance_m must be a finite number; got {focus_distance_m!r}")
        parts.append(f"focus {focus_distance_m:.2f} m" + (f" ({focus_source})" if focus_source else ""))
    if max_blur_px is not None:
        if not (isinstance(max_blur_px, (int, float)) and math.isfinite(max_blur_px) and max_blur_px >= 0):
            raise InputError(f"max_blur_px must be a finite number >= 0; got {max_blur_px!r}")
        parts.append(f"max blur {max_blur_px:.1f} px")
    if details:
        parts.append(details)
    line = f"pcdof {command}: " + (", ".join(parts) if parts else "done")
    if output is not None:
        line += f" -> {output}"
    return line.replace("\n", " ")


def report_decision(command: str, **fields) -> None:
    """Print :func:`format_decision` of *fields* on stdout, unless ``-q`` was given."""
    line = format_decision(command, **fields)
    if not is_quiet():
        click.echo(line)
