"""Ctrl-C for the ``pcdof`` command: one line, exit status 130, nothing left behind, whenever it comes.

This module imports nothing but the standard library's ``os``, ``signal`` and ``sys``, so that the
console script installs its handler (:func:`install`) before click, NumPy or any of pcdof's modules
load. The handler has two behaviours:

* inside a command's body (:func:`raising`), Ctrl-C raises :class:`KeyboardInterrupt` so that the
  command's ``finally`` blocks remove what it had started to write; the CLI then says
  ``pcdof: interrupted`` and exits 130;
* anywhere else (starting up, importing a module, parsing arguments, shutting down), or while a module
  is being imported or a kernel compiled inside a command (an exception raised halfway through a C
  extension's import can crash the process later; one raised in numba's compiler is swallowed by its
  callbacks), or while the process's stderr is redirected (:class:`deferring`: a decode whose library
  warnings are captured), it ends the process at once: the cleanups registered with :func:`on_interrupt`
  and :class:`cleanup_on_interrupt` (temporary files of the writes in progress, a command's rollback,
  stderr put back), the line, then ``os._exit(130)``.

Once a command has ended (done, failed or interrupted), Ctrl-C is ignored and the process exits
normally but within :data:`EXIT_GRACE_S` seconds (:func:`ending`): the exit status is the command's,
and no thread still running (a worker stuck on a lock, a library's thread) can hold the process.
"""

from __future__ import annotations

import os
import signal
import sys

#: exit status of an interrupted command (128 + SIGINT)
EXIT_INTERRUPTED = 130

_STATE = {"installed": False, "raising": 0, "said": False, "deferring": 0}
_CLEANUPS: list = []


def on_interrupt(cleanup) -> None:
    """Run ``cleanup()`` (no arguments, quick, never raising) when Ctrl-C ends the process at once."""
    if cleanup not in _CLEANUPS:
        _CLEANUPS.append(cleanup)


def say_interrupted() -> None:
    """Print ``pcdof: interrupted`` on stderr, once per process."""
    if _STATE["said"]:
        return
    _STATE["said"] = True
    try:
        sys.stderr.write("pcdof: interrupted\n")
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):  # stderr closed or gone: the exit status still says it
        pass


def exit_now(code: int = EXIT_INTERRUPTED) -> None:
    """Run the registered cleanups and end the process with *code* at once (saying ``pcdof: interrupted``
    when *code* is :data:`EXIT_INTERRUPTED`: after the cleanups, one of which may give stderr back)."""
    for cleanup in list(_CLEANUPS):
        try:
            cleanup()
        except Exception:  # noqa: BLE001 - a cleanup's failure must not stop the exit
            pass
    if code == EXIT_INTERRUPTED:
        say_interrupted()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(code)


class cleanup_on_interrupt:
    """Within the block, ``cleanup()`` also runs when Ctrl-C ends the process at once (a command's rollback)."""

    def __init__(self, cleanup):
        self.cleanup = cleanup

    def __enter__(self):
        _CLEANUPS.append(self.cleanup)
        return self

    def __exit__(self, *exc) -> None:
        if self.cleanup in _CLEANUPS:
            _CLEANUPS.remove(self.cleanup)


#: Code that an exception must not interrupt: the import machinery (an exception halfway through a C
#: extension's import can crash the process later) and numba's compiler, whose callbacks from LLVM
#: swallow an exception (the interrupt would be lost and the command would go on).
_MACHINERY = ("<frozen importlib", os.sep + "numba" + os.sep, os.sep + "llvmlite" + os.sep)


#: Seconds an interrupted command's normal exit (exit handlers, worker threads joined) may take
#: before the process is ended regardless.
EXIT_GRACE_S = 3.0


def exit_soon(code: int = EXIT_INTERRUPTED, grace_s: float = EXIT_GRACE_S) -> None:
    """Let the interpreter exit normally (its exit handlers release semaphores, temporary folders), but at
    most *grace_s* seconds: a thread still running (a worker stuck on a lock) cannot hold the process.

    Call it as the process is about to exit with status *code* (non-zero: a failed or interrupted command).
    """
    import threading

    def watchdog() -> None:
        import time

        time.sleep(grace_s)
        exit_now(code)

    threading.Thread(target=watchdog, name="pcdof-exit-watchdog", daemon=True).start()


def ending(code: int = 0, grace_s: float = EXIT_GRACE_S) -> None:
    """The command is over and the process is about to exit with status *code*: Ctrl-C is ignored from here
    on and the exit takes at most *grace_s* seconds (:func:`exit_soon`).

    Ignoring is what keeps the status: as the interpreter shuts down it gives SIGINT back its default
    action (unless it is ignored), and a Ctrl-C in that last moment would end the process by the signal,
    after the command's work was done and reported. The watchdog keeps the exit from hanging instead.
    """
    if _STATE["installed"]:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_soon(code, grace_s)


class deferring:
    """Within the block, a signal handler of pcdof's must not raise (:func:`must_not_raise`).

    For code that an exception would leave half done at any line, such as a redirection of the process's
    stderr (:func:`pcdof.io.capture.captured_stderr`): raised between the redirection and its ``try``, or
    in the ``finally`` before stderr is put back, the exception would leave every later message, the
    command's last line included, in a deleted file. Keep such blocks short: Ctrl-C inside one ends the
    process at once, and the batch's SIGTERM comes again a moment later.
    """

    def __enter__(self):
        _STATE["deferring"] += 1
        return self

    def __exit__(self, *exc) -> None:
        _STATE["deferring"] -= 1


def must_not_raise(frame) -> bool:
    """Whether a signal handler must not raise now: a :class:`deferring` block runs, or *frame* or one of
    its callers runs the import machinery or numba's compiler (:func:`in_machinery`)."""
    return _STATE["deferring"] > 0 or in_machinery(frame)


def in_machinery(frame) -> bool:
    """Whether *frame* or one of its callers runs the import machinery or numba's compiler."""
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith(_MACHINERY[0]) or any(part in name for part in _MACHINERY[1:]):
            return True
        frame = frame.f_back
    return False


def _on_sigint(signum, frame) -> None:
    if _STATE["raising"] and not must_not_raise(frame):
        raise KeyboardInterrupt
    exit_now()


def install() -> None:
    """Make Ctrl-C behave as the module documentation says (main thread only; idempotent)."""
    if _STATE["installed"]:
        return
    try:
        signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:  # not the main thread: leave the interpreter's own handling
        return
    _STATE["installed"] = True


def installed() -> bool:
    """Whether :func:`install` put the handler in place in this process."""
    return _STATE["installed"]


class raising:
    """Within the block, Ctrl-C raises KeyboardInterrupt (a command's body: its ``finally`` blocks clean up)."""

    def __enter__(self):
        _STATE["raising"] += 1
        return self

    def __exit__(self, *exc) -> None:
        _STATE["raising"] -= 1
