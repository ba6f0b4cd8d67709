"""Benchmarks: depth of field against a ray-traced ground truth, speed, registration and hole filling.

Shared here: the argument checks of the benchmark functions, the markdown table and the atomic
figure writer that every benchmark's report uses.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterable, Sequence

import numpy as np

from ..errors import InputError


def check_repeats(repeats, name: str = "repeats") -> int:
    """*repeats* as an int >= 1 (timed runs per measurement), or InputError naming *name*."""
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise InputError(f"{name} must be an integer >= 1; got {repeats!r}")
    return int(repeats)


def check_scenes(scenes, name: str = "scenes") -> list[str] | None:
    """*scenes* (names of :data:`pcdof.synth.SCENES`, or None for all) as a non-empty list, or InputError naming *name*."""
    if scenes is None:
        return None
    from ..synth import SCENES

    if isinstance(scenes, str):
        raise InputError(f"{name} must be a sequence of scene names, not a string; got {scenes!r}")
    names = list(scenes)
    if not names:
        raise InputError(f"{name} selects no scene; choose from {', '.join(SCENES)}")
    bad = [s for s in names if not isinstance(s, str) or s not in SCENES]
    if bad:
        raise InputError(f"{name}: unknown scene(s) {', '.join(map(repr, bad))}; choose from {', '.join(SCENES)}")
    return names


def table_lines(columns: Sequence[str], rows: Iterable[Sequence]) -> list[str]:
    """A markdown table as lines: the header of *columns*, the separator, one line per row of cells.

    >>> table_lines(["a", "b"], [(1, "x")])
    ['| a | b |', '|---|---|', '| 1 | x |']
    """
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(map(str, cells)) + " |" for cells in rows]
    return lines


@contextlib.contextmanager
def plot_to(path: str, *, figsize: tuple[float, float], dpi: int = 110):
    """A matplotlib (figure, axes) to draw on; on leaving, laid out and written as a PNG to *path*.

    The figure is closed whatever happens; nothing is written when drawing raised.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=figsize, dpi=dpi)
    try:
        yield fig, ax
        fig.tight_layout()
        save_figure(fig, path)
    finally:
        plt.close(fig)


def save_figure(fig, path: str) -> None:
    """Write a matplotlib figure as a PNG atomically (ImageWriteError on failure, no file left behind)."""
    from ..io._files import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
