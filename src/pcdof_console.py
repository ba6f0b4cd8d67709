"""The ``pcdof`` console script, outside the package so that Ctrl-C is pcdof's from its first line.

Importing the package and its command line takes a moment; this module installs a handler first (one
``pcdof: interrupted`` line, exit status 130), then hands over to :func:`pcdof.interrupts.install`, whose
handler replaces it, and runs :func:`pcdof.cli.console_main`.
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
    from pcdof.interrupts import install

    install()  # pcdof's handler replaces the one above
    from pcdof.cli import console_main

    console_main()


if __name__ == "__main__":
    main()
