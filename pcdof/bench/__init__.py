"""Benchmarks: depth of field against a ray-traced ground truth, speed, registration and hole filling.

Shared here: the argument checks of the benchmark functions and an atomic figure writer.
"""

from __future__ import annotations

import io

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


def save_figure(fig, path: str) -> None:
    """Write a matplotlib figure as a PNG atomically (ImageWriteError on failure, no file left behind)."""
    from ..io._files import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
