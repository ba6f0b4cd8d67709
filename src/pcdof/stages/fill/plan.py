"""Whether the fill has work (:func:`needs_fill`) and how it runs (:func:`plan_fill`: threads by the number of
holes)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...errors import InputError
from ...runtime.threads import current_threads
from .inputs import checked_depth, count_holes
from .rules import BORDER_ASSUMPTIONS, DEFAULT_BORDER

#: Below this many holes the kernels run on one thread: starting threads costs more than it saves (on two
#: idle cores the crossover lay near 400 holes; 2,000 holes took 1.60 ms on one thread and 1.32 on two,
#: 9,200 holes 8.96 and 5.38 ms). On a busy machine a parallel region waits for its slowest thread, but there
#: the pipeline runs on the threads other processes leave free (pcdof.runtime.threads.threads_for_load): one, so one here.
PARALLEL_MIN_HOLES = 1000


def needs_fill(depth_m) -> tuple[bool, str]:
    """Whether a depth map has unknown pixels to fill, and why (for the pipeline trace).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 (or NaN, inf, negative) = unknown

    Returns
    -------
    needed : bool
    reason : str, one line
    """
    arr, n = count_holes(depth_m)
    if n == 0:
        return False, "depth has no holes"
    if n == arr.size:
        return True, "depth has no known pixels"
    return True, f"{n} holes ({100.0 * n / arr.size:.1f} % of pixels)"



class FillPlan(NamedTuple):
    """How :func:`~pcdof.stages.fill.methods.fill_depth` runs on one input; chosen by :func:`plan_fill`, shown in
    the trace."""

    holes: int  #: unknown pixels
    threads: int  #: numba threads of the kernels (1: serial)
    reason: str  #: one line, why this many threads
    border: str = DEFAULT_BORDER  #: the rule outside the depth camera's view (:data:`BORDER_RULES`)

    def describe(self) -> str:
        """Threads and why, and what the rule outside the depth camera's view assumes (one line)."""
        return (f"{self.threads} thread{'s' if self.threads != 1 else ''}: {self.reason}; "
                f"border {self.border}: {BORDER_ASSUMPTIONS[self.border]}")


def plan_fill(depth_m, *, parallel: bool | None = None) -> FillPlan:
    """Choose how to run the fill on *depth_m* (the one place where that is decided).

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, 0 (or NaN, inf, negative) = unknown
    parallel : None (by the number of holes), True (all numba threads) or False (one thread)

    Returns
    -------
    FillPlan
    """
    if parallel is not None and not isinstance(parallel, (bool, np.bool_)):
        raise InputError(f"parallel must be None, True or False; got {parallel!r}")
    _, holes = count_holes(depth_m)  # validates depth_m
    if parallel is None:
        parallel = holes >= PARALLEL_MIN_HOLES
        reason = f"{holes} holes {'>=' if parallel else '<'} {PARALLEL_MIN_HOLES}"
    else:
        reason = "parallel=" + str(bool(parallel))
    return FillPlan(holes, current_threads() if parallel else 1, reason)


def planned_threads(depth_m, parallel) -> int:
    """``plan_fill(depth_m, parallel=parallel).threads``, with the same checks; the holes are counted only
    where *parallel* is None (they choose)."""
    if parallel is None or not isinstance(parallel, (bool, np.bool_)):
        return plan_fill(depth_m, parallel=parallel).threads
    checked_depth(depth_m)
    return current_threads() if parallel else 1
