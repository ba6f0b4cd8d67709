"""When the renderer's kernels run on one thread: below a size where waking the other threads costs more
than it saves.

The thresholds are read through this module (``serial.SERIAL_BELOW_PX``) by every pass that uses them,
so a test can lower them for the whole renderer at once.
"""

from __future__ import annotations

from ...runtime import threads


#: Kernels with less work than this (pixels, or strips of the scatter: about 1 and 8 ns each on one core) run
#: on one thread. Every parallel region wakes the other threads and waits for the slowest: 10-20 us on an idle
#: machine, and about 0.5 ms, a scheduler's slice, while another process keeps the other core busy.
SERIAL_BELOW_PX = 65_536
SERIAL_BELOW_STRIPS = 16_384


def serial_if(small: bool):
    """Run the block's numba kernels on one thread when *small* (:func:`pcdof.runtime.threads.serial_if`)."""
    return threads.serial_if(small)
