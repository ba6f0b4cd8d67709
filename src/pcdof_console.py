"""The ``pcdof`` console script, outside the package so that Ctrl-C is pcdof's from its first line.

Importing anything of ``pcdof`` runs the package's ``__init__`` (numba's settings, a cache folder
check); this module installs a handler first (one ``pcdof: interrupted`` line, exit status 130), then
hands over to :func:`pcdof.interrupts.console`, whose handler replaces it.
"""

import os
import sys

import _signal  # the C module behind ``signal``, built into the interpreter: ``signal`` itself imports enum


def _interrupted(signum, frame) -> None:
    try:
        sys.stderr.write("pcdof: interrupted\n")
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass
    os._exit(130)


def main() -> None:
    """Run the ``pcdof`` command line."""
    _signal.signal(_signal.SIGINT, _interrupted)
    from pcdof.interrupts import console

    console()


if __name__ == "__main__":
    main()
