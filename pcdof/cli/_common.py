"""Shared CLI plumbing: logging set-up, one-line errors with distinct exit codes, common options."""

from __future__ import annotations

import functools
import logging
import sys
import warnings

import click

from ..errors import PcdofError, exit_code_for

log = logging.getLogger("pcdof")


def configure_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="pcdof: %(message)s", stream=sys.stderr)

    def _showwarning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"pcdof: warning: {message}", err=True)

    warnings.showwarning = _showwarning


def handle_errors(func):
    """Turn any exception into one line on stderr and a non-zero exit code (tracebacks with -vv)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except PcdofError as err:
            if _debug():
                raise
            click.echo(f"pcdof: error: {err}", err=True)
            sys.exit(exit_code_for(err))
        except KeyboardInterrupt:
            click.echo("pcdof: interrupted", err=True)
            sys.exit(130)
        except MemoryError:
            click.echo("pcdof: error: out of memory (try a smaller image)", err=True)
            sys.exit(9)
        except Exception as err:  # noqa: BLE001 - the CLI promises no tracebacks
            if _debug():
                raise
            click.echo(f"pcdof: internal error: {type(err).__name__}: {err} (run with -vv for details)", err=True)
            sys.exit(1)

    return wrapper


def _debug() -> bool:
    ctx = click.get_current_context(silent=True)
    while ctx is not None:
        if ctx.obj and ctx.obj.get("verbose", 0) >= 2:
            return True
        ctx = ctx.parent
    return False
