"""``python -m pcdof``: the ``pcdof`` command."""

from pcdof.interrupts import console

console()
