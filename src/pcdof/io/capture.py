"""Capture what C libraries (libpng, libjpeg, libtiff) print on the process's stderr while decoding.

Capturing redirects file descriptor 2 of the whole process for the duration of a decode, so it is off unless
the process asked for it (:func:`enable`, which :func:`pcdof.runtime.process.tune_process` calls for the
``pcdof`` command): a program that imports pcdof keeps its stderr, and the libraries' warnings reach it as
they are printed. With it on, a libjpeg warning about damaged data becomes pcdof's one-line error.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading

from .. import interrupts

# The redirection is process-wide: one block at a time holds it.
_stderr_lock = threading.Lock()
#: whether :func:`captured_stderr` redirects (set by :func:`enable`)
_enabled = False


def enable(on: bool = True) -> None:
    """Turn capturing on (or off) for this process; see the module docstring."""
    global _enabled
    if not isinstance(on, bool):
        from ..errors import InputError

        raise InputError(f"on must be True or False; got {on!r}")
    _enabled = on


def enabled() -> bool:
    """Whether :func:`captured_stderr` redirects in this process."""
    return _enabled
#: Bytes of captured output kept (a damaged file can make a library print a line per row).
_MAX_CAPTURED = 1 << 20


@contextlib.contextmanager
def captured_stderr():
    """Redirect the process's C-level stderr (fd 2) into a temporary file within the block.

    Yields a list that receives the captured lines when the block ends. Libraries such as libpng,
    libjpeg and libtiff print their warnings there, where no caller can catch them. One block at a
    time holds the redirection (it is process-wide). When capturing is off (:func:`enable`), the block runs
    as it is and the list stays empty.
    """
    lines: list[str] = []
    if not _enabled:
        yield lines
        return
    # Ctrl-C or the batch's SIGTERM must not raise between the redirection and its try, nor in the finally
    # before stderr is back (every later message would go to the deleted file); one that ends the process
    # at once puts stderr back first (a cleanup).
    with _stderr_lock, tempfile.TemporaryFile() as captured, interrupts.deferring():
        sys.stderr.flush()
        saved = os.dup(2)

        def give_back() -> None:
            os.dup2(saved, 2)

        with interrupts.cleanup_on_interrupt(give_back):
            os.dup2(captured.fileno(), 2)
            try:
                yield lines
            finally:
                give_back()
                os.close(saved)
        captured.seek(0)
        text = captured.read(_MAX_CAPTURED).decode("utf-8", "replace")
        lines.extend(line.strip() for line in text.splitlines() if line.strip())


def pass_on(lines) -> None:
    """Write *lines* (captured, but not a library's message about the file) to the real stderr."""
    if lines:
        os.write(2, "".join(line + "\n" for line in lines).encode("utf-8", "replace"))
