"""Ctrl-C and SIGTERM in a batch: SIGTERM raises like Ctrl-C, and both are held while workers start or stop."""

from __future__ import annotations

import contextlib
import os
import signal
import threading

from ..interrupts import must_not_raise

#: seconds after which a signal that came inside the import machinery or numba's compiler is sent again
REDELIVER_S = 0.05


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived while a batch ran (raised in the main thread; the CLI exits 143)."""


# SIGINT / SIGTERM held while worker processes start or stop (see signals_held); Python runs signal handlers
# in the main thread.
_SIGNALS = {"held": 0, "pending": None}


def _on_signal(signum, frame) -> None:
    error = Terminated("SIGTERM") if signum == signal.SIGTERM else KeyboardInterrupt()
    if _SIGNALS["held"]:
        _SIGNALS["pending"] = _SIGNALS["pending"] or error
    elif must_not_raise(frame):
        # raised here, the exception would be swallowed by numba's compiler (its callbacks from LLVM), break
        # an import halfway or leave stderr redirected: the signal comes again a moment later, until it lands
        # in pcdof's code
        timer = threading.Timer(REDELIVER_S, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
    else:
        raise error


@contextlib.contextmanager
def sigterm_interrupts():
    """Within the block, SIGTERM raises :class:`Terminated` like Ctrl-C raises KeyboardInterrupt (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        _SIGNALS["pending"] = None


@contextlib.contextmanager
def signals_held():
    """Ctrl-C or SIGTERM within the block raises at its end: a worker being started or stopped is never left
    unknown to its pool, and a second Ctrl-C cannot cut the shutdown short (leaving workers and semaphores)."""
    _SIGNALS["held"] += 1
    try:
        yield
    finally:
        _SIGNALS["held"] -= 1
        pending = _SIGNALS["pending"]
        if not _SIGNALS["held"] and pending is not None:
            _SIGNALS["pending"] = None
            raise pending


_sigterm_held = signals_held  # the name older callers use


@contextlib.contextmanager
def starting_processes():
    """Within the block, new processes (forkserver, resource tracker, workers) start with SIGINT blocked.

    Ctrl-C goes to every process of the terminal's group; a Python process that gets it while it is
    still importing prints "Fatal Python error" and a traceback. Blocked, it stays pending here (and
    raises once the block ends, through :func:`signals_held`) and never reaches the children, which
    inherit the mask: the batch alone decides, and stops its workers with SIGTERM.
    """
    block = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    with signals_held():
        if block:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            if block:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def interrupted_by(err: BaseException) -> str:
    """How a KeyboardInterrupt *err* arrived, for the report: "SIGTERM" or "Ctrl-C (SIGINT)"."""
    return "SIGTERM" if isinstance(err, Terminated) else "Ctrl-C (SIGINT)"
