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

from ..errors import EXIT_OUT_OF_MEMORY, ImageWriteError, InputError, PcdofError, exit_code_for, is_out_of_memory, \
    one_line

log = logging.getLogger("pcdof")


def configure_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="pcdof: %(message)s", stream=sys.stderr)

    def _showwarning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"pcdof: warning: {one_line(message)}", err=True)

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
            click.echo(f"pcdof: error: {one_line(err)}", err=True)
            sys.exit(exit_code_for(err))
        except KeyboardInterrupt:
            click.echo("pcdof: interrupted", err=True)
            sys.exit(130)
        except Exception as err:  # noqa: BLE001 - the CLI promises no tracebacks
            if is_out_of_memory(err):  # MemoryError, or OpenCV's "Insufficient memory"
                click.echo("pcdof: error: out of memory (try a smaller image)", err=True)
                sys.exit(EXIT_OUT_OF_MEMORY)
            if _debug():
                raise
            click.echo(f"pcdof: internal error: {type(err).__name__}: {one_line(err)} (run with -vv for details)",
                       err=True)
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
        raise ImageWriteError(f"{name} {path!r} is a folder; expected a file name")
    _check_parents(path, name)


def check_output_folder(path: str, name: str) -> None:
    """ImageWriteError, before any work is done, when *path* cannot be (or become) a folder.

    Refused: *path* exists and is not a folder, or the nearest existing one of its parents is not a folder.
    """
    if os.path.lexists(path) and not os.path.isdir(path):
        raise ImageWriteError(f"{name} {path!r} is a file; expected a folder")
    _check_parents(path, name)


def make_output_folder(path: str, name: str) -> None:
    """Create the folder *path* (and its parents) if missing; ImageWriteError when it cannot be."""
    check_output_folder(path, name)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create {name} folder {path!r}: {err.strerror or err}") from None


def _check_parents(path: str, name: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.lexists(folder):  # ends at the root at the latest
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ImageWriteError(f"cannot write {name} {path!r}: {folder!r} is not a folder")
    try:
        limit = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    parts = os.path.relpath(os.path.abspath(path), folder).split(os.sep)
    for part in parts:  # the names still to be created
        if len(os.fsencode(part)) > limit:
            raise ImageWriteError(f"cannot write {name} {path!r}: File name too long ({len(os.fsencode(part))} "
                                  f"bytes; this file system allows {limit})")


def check_output_paths(inputs: dict, outputs: dict, folders: dict | None = None) -> None:
    """InputError, before any work, when an output would replace an input or another output.

    Every path is compared by :func:`pcdof.io._files.same_file`: symbolic links are resolved and
    hard links (same device and inode) are caught, so no spelling of an input's path can be written.

    Parameters
    ----------
    inputs : {label: path or None}, the files read (e.g. ``{"COLOR": ..., "DEPTH": ..., "--calib": ...}``)
    outputs : {label: path or None}, every file the command writes (a folder's files listed one by one)
    folders : {label: path or None}, output folders; no output file and no input may be one of them
    """
    from ..io._files import file_identity, fspath, same_file

    def named(mapping):
        return [(label, fspath(path, name=label)) for label, path in (mapping or {}).items() if path is not None]

    ins = [(label, path, file_identity(path)) for label, path in named(inputs)]
    outs = [(label, path, file_identity(path)) for label, path in named(outputs)]
    dirs = [(label, path, file_identity(path)) for label, path in named(folders)]
    for k, (label, path, ident) in enumerate(outs):
        for in_label, in_path, in_ident in ins:
            if same_file(ident, in_ident):
                raise InputError(f"refusing to overwrite the input {in_label} {in_path!r} with {label} {path!r}; "
                                 "choose another output path")
        for other_label, other_path, other_ident in outs[:k] + dirs:
            if same_file(ident, other_ident):
                raise InputError(f"{label} {path!r} and {other_label} {other_path!r} are the same path; give each "
                                 "output its own")
    for label, path, ident in dirs:
        for in_label, in_path, in_ident in ins:
            if same_file(ident, in_ident):
                raise InputError(f"{label} {path!r} is the input {in_label} {in_path!r}; choose another folder")
