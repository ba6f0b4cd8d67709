"""``python -m pcdof``: the ``pcdof`` command without its console script."""

from pcdof.cli import console_main

if __name__ == "__main__":
    console_main()
