"""Shared CLI plumbing: logging set-up, one-line errors with distinct exit codes, common options, output checks.

Path options are plain ``click.Path()`` values: a folder given where a file belongs (or a file where a
folder belongs) is reported by pcdof's readers or by the checks below, as one of pcdof's errors with
its own exit code, not as a click usage error.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
import warnings

import click

from ..errors import ImageWriteError, PcdofError, exit_code_for

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



def check_output_file(path: str, name: str = "output") -> None:
    """ImageWriteError, before any work is done, when *path* cannot be written as a file.

    Refused: *path* is a folder, or the nearest existing one of its parent folders is not a folder.
    """
    if os.path.isdir(path):
        raise ImageWriteError(f"{name} {path} is a folder; expected a file name")
    _check_parents(path, name)


def check_output_folder(path: str, name: str) -> None:
    """ImageWriteError, before any work is done, when *path* cannot be (or become) a folder.

    Refused: *path* exists and is not a folder, or the nearest existing one of its parents is not a folder.
    """
    if os.path.lexists(path) and not os.path.isdir(path):
        raise ImageWriteError(f"{name} {path} is a file; expected a folder")
    _check_parents(path, name)


def make_output_folder(path: str, name: str) -> None:
    """Create the folder *path* (and its parents) if missing; ImageWriteError when it cannot be."""
    check_output_folder(path, name)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create {name} folder {path}: {err.strerror or err}") from None


def _check_parents(path: str, name: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.lexists(folder):  # ends at the root at the latest
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ImageWriteError(f"cannot write {name} {path}: {folder} is not a folder")
