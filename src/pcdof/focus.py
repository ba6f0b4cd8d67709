"""The focus rule, resolved in one place for the CLI, batch, the viewers and the API.

A render is focused by one of:

* a distance: the lens's own ``focus_distance_m`` (``RenderOptions.focus_at`` is None);
* a colour pixel ``(x, y)``: the robust depth around it (:func:`pcdof.lens.focus_depth_at`) on the measured
  (registered) depth, or on the filled depth where registration left nothing known;
* the image centre (:data:`CENTRE`, spelled ``"center"`` or ``"centre"``): the same at the colour image's
  centre pixel; the ``pcdof`` commands' default when no focus flag is given;
* following a subject through a sequence: the batch's focus pass (:mod:`pcdof.batch.focus`) measures the
  depth at a pixel (or the centre) in every frame and smooths it; each frame is then rendered at a distance.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import InputError
from .lens import focus_depth_at, parse_focus_pixel

#: the image centre, as ``RenderOptions.focus_at`` spells it
CENTRE = "center"
_CENTRE_NAMES = ("center", "centre")


def parse_focus_at(focus_at, name: str = "focus_at"):
    """*focus_at* checked: None, :data:`CENTRE` (``"center"`` or ``"centre"``) or an (x, y) pair of finite floats
    (colour pixels); else an InputError naming *name*."""
    if isinstance(focus_at, str):
        if focus_at.lower() in _CENTRE_NAMES:
            return CENTRE
        raise InputError(f"{name} must be an (x, y) pixel, 'center' or None; got {focus_at!r}")
    return parse_focus_pixel(focus_at, name)


def centre_pixel(width: int, height: int) -> tuple[float, float]:
    """The centre of a *width* x *height* image, (x, y) in pixels (pixel i spans [i - 0.5, i + 0.5))."""
    return (width - 1) / 2, (height - 1) / 2


def focus_pixel(focus_at, width: int, height: int) -> tuple[float, float] | None:
    """The colour pixel *focus_at* names in a *width* x *height* image: (x, y), or None for "the lens's distance"."""
    focus_at = parse_focus_at(focus_at)
    return centre_pixel(width, height) if focus_at == CENTRE else focus_at


def measured_depth(registered_m, filled_m) -> np.ndarray:
    """The depth a focus pixel is measured on: the registered one (measured), or the filled one when registration
    left nothing known. Both (H, W) metres, 0 = unknown."""
    return registered_m if np.any(np.asarray(registered_m) > 0) else filled_m


def depth_at(registered_m, filled_m, x: float, y: float) -> float:
    """Focus distance (metres) at colour pixel (x, y): :func:`pcdof.lens.focus_depth_at` on :func:`measured_depth`."""
    return focus_depth_at(measured_depth(registered_m, filled_m), x, y)


def resolve_lens(lens, focus_at, registered_m, filled_m):
    """*lens* focused as *focus_at* says (see the module docstring): a copy with ``focus_distance_m`` set to the
    depth at the pixel, or *lens* itself when *focus_at* is None. *registered_m*, *filled_m*: (H, W) metres."""
    height, width = np.shape(filled_m)[:2]
    pixel = focus_pixel(focus_at, width, height)
    if pixel is None:
        return lens
    return dataclasses.replace(lens, focus_distance_m=depth_at(registered_m, filled_m, *pixel))


def describe(focus_at) -> str:
    """How *focus_at* chooses the focus, in words for a report line."""
    focus_at = parse_focus_at(focus_at)
    if focus_at is None:
        return "the lens's focus distance"
    if focus_at == CENTRE:
        return "depth at the image centre"
    return "depth at pixel {:g},{:g}".format(*focus_at)
