"""Viewable previews of depth and circle-of-confusion maps: a colour map with a labelled scale bar.

Raw maps (16-bit millimetre PNGs, float ``.npy``) keep the numbers but look black in an image
viewer. These pure functions turn a map into an 8-bit RGB picture with a vertical scale bar
beside it, for ``--save-maps`` and for reports.

Layout of every preview: the map, ``W`` columns, then the bar, :func:`bar_width_px` ``(H)``
columns: a colour strip and, where the text fits, tick marks with labels (black on white).
Both bars grow brighter upward: the colour maps (viridis, inferno) have a monotone lightness,
so the picture reads the same in grey print and to colour-blind readers.
"""

from __future__ import annotations

import math
from functools import lru_cache
from numbers import Real

import cv2
import numpy as np

from .errors import InputError

#: RGB colour of pixels whose value is unknown; no entry of the viridis or inferno maps is within
#: 60 levels of it in any channel.
UNKNOWN_RGB = (128, 128, 128)
#: Background of the bar's label area, and the ink of its text and tick marks.
BAR_BACKGROUND_RGB = (255, 255, 255)
BAR_INK_RGB = (0, 0, 0)
#: Percentiles of the known depths that set the depth range when near_m / far_m are not given
#: (a few outliers, e.g. flying pixels at edges, then do not squash the map).
DEPTH_PERCENTILES = (2.0, 98.0)
# Smallest label height in pixels that is still legible; smaller labels are left out.
_MIN_TEXT_PX = 6
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_TEMPLATE = "00.00 px"  # the label width the bar makes room for


def depth_preview(depth_m, *, near_m: float | None = None, far_m: float | None = None) -> np.ndarray:
    """Colour-mapped depth with a scale bar in metres.

    Viridis on inverse depth (``1/z``): equal colour steps are equal steps of defocus blur,
    which is linear in ``1/z`` (thin lens, CoC = A f (1/d_f - 1/z)), and of a stereo or
    structured-light sensor's disparity; near objects, where the blur changes fastest, get most
    of the colours. Near is bright (top of the bar), far is dark (bottom). Depths outside the
    range take the colour of its end.

    Parameters
    ----------
    depth_m : (H, W) real ndarray, metres; 0, negative, NaN and infinite values are unknown
        (drawn in :data:`UNKNOWN_RGB`)
    near_m, far_m : float, optional, metres, finite > 0, near_m < far_m
        Range of the map; each end not given is the 2nd / 98th percentile of the known depths.
        A range of zero width (constant depth) is widened by 10 % each way.

    Returns
    -------
    (H, W + bar_width_px(H), 3) uint8 RGB ndarray

    Raises
    ------
    InputError
        *depth_m* is not a non-empty 2-D array of real numbers, or *near_m* / *far_m* is not a
        finite number > 0, or near_m >= far_m.
    """
    depth = _as_map(depth_m, "depth_m")
    known = np.isfinite(depth) & (depth > 0)
    rng = _depth_range(depth[known], *_check_range(near_m, far_m))
    if rng is None:  # nothing known and no range given: a grey map and an unlabelled bar
        return _compose(depth, known, lambda v: v * 0.0, lambda u: 1.0 - u, [], "m", "viridis")
    near, far = rng
    inv_near, inv_far = 1.0 / near, 1.0 / far

    def to_unit(z):  # 0 = far (bottom of the bar), 1 = near (top)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.clip((1.0 / z - inv_far) / (inv_near - inv_far), 0.0, 1.0)

    def from_unit(u):
        return 1.0 / (inv_far + u * (inv_near - inv_far))

    return _compose(depth, known, to_unit, from_unit, _depth_ticks(near, far), "m", "viridis")


def depth_range_m(depth_m, *, near_m: float | None = None, far_m: float | None = None):
    """The (near, far) range in metres that :func:`depth_preview` maps, or None when nothing sets one.

    Pass it to several previews (e.g. registered and filled depth) so they share one colour scale.

    Parameters
    ----------
    depth_m, near_m, far_m : see :func:`depth_preview`

    Returns
    -------
    (near, far) : tuple of float, metres, 0 < near < far; or None when *depth_m* has no known
        value and neither end is given
    """
    depth = _as_map(depth_m, "depth_m")
    known = np.isfinite(depth) & (depth > 0)
    return _depth_range(depth[known], *_check_range(near_m, far_m))


def coc_preview(coc_px, *, max_px: float | None = None) -> np.ndarray:
    """Colour-mapped circle of confusion with a scale bar in pixels, 0 at the bottom.

    The map shows the CoC's magnitude ``|coc_px|`` (a signed map, front of the focus plane < 0,
    behind > 0, is shown as its absolute value: the blur is what the picture answers). Inferno,
    linear in pixels: in focus is black, the largest blur is pale yellow.

    Parameters
    ----------
    coc_px : (H, W) real ndarray, CoC diameter in pixels; NaN and infinite values are unknown
        (drawn in :data:`UNKNOWN_RGB`)
    max_px : float, optional, finite > 0
        Top of the bar (larger values take its colour); default the largest known ``|coc_px|``,
        or 1 px when every known value is 0.

    Returns
    -------
    (H, W + bar_width_px(H), 3) uint8 RGB ndarray, the map with the scale bar on its right

    Raises
    ------
    InputError
        *coc_px* is not a non-empty 2-D array of real numbers, or *max_px* is not a finite number > 0.
    """
    coc = np.abs(_as_map(coc_px, "coc_px"))
    max_px = _check_positive(max_px, "max_px")
    known = np.isfinite(coc)
    if max_px is None:
        top = float(coc[known].max()) if known.any() else 0.0
        max_px = top if top > 0 else 1.0

    def to_unit(c):
        return np.clip(c / max_px, 0.0, 1.0)

    return _compose(coc, known, to_unit, lambda u: u * max_px, _nice_ticks(0.0, max_px), "px", "inferno")


def bar_width_px(height: int) -> int:
    """Width in pixels of the scale bar beside a preview *height* pixels tall (>= 1).

    Room for the colour strip and, when a label fits in *height*, for labels like "00.00 px".
    """
    if isinstance(height, bool) or not isinstance(height, (int, np.integer)) or height < 1:
        raise InputError(f"height must be an integer >= 1; got {height!r}")
    pad, strip, scale, thickness = _bar_geometry(int(height))
    if scale is None:
        return pad + strip + pad
    (text_w, _), _ = cv2.getTextSize(_TEMPLATE, _FONT, scale, thickness)
    return pad + strip + 2 * pad + text_w + pad


@lru_cache(maxsize=None)
def _bar_geometry(height: int):
    """(pad, strip width, font scale or None when no label fits, thickness) for a bar *height* tall."""
    pad = max(1, round(height / 80))
    strip = max(2, round(height / 24))
    scale = min(max(height / 720, 0.25), 1.5)
    thickness = max(1, round(scale * 1.5))
    text_h = _text_height(scale, thickness)
    if text_h < _MIN_TEXT_PX or text_h + 2 > height:
        return pad, strip, None, thickness
    return pad, strip, scale, thickness


def _text_height(scale: float, thickness: int) -> int:
    (_, h), baseline = cv2.getTextSize("0.5", _FONT, scale, thickness)
    return h + baseline


@lru_cache(maxsize=None)
def _lut(name: str) -> np.ndarray:
    """(256, 3) uint8 RGB entries of an OpenCV colour map."""
    code = {"viridis": cv2.COLORMAP_VIRIDIS, "inferno": cv2.COLORMAP_INFERNO}[name]
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(-1, 1), code)[:, 0, ::-1]
    return np.ascontiguousarray(lut)


def _colorize(unit: np.ndarray, known: np.ndarray, cmap: str) -> np.ndarray:
    """(H, W, 3) uint8: the colour map at *unit* (0..1) where *known*, UNKNOWN_RGB elsewhere."""
    index = np.zeros(unit.shape, np.intp)
    index[known] = np.rint(unit[known] * 255).astype(np.intp)
    rgb = _lut(cmap)[index]
    rgb[~known] = UNKNOWN_RGB
    return rgb


def _compose(values, known, to_unit, from_unit, ticks, unit_name, cmap) -> np.ndarray:
    """The map of *values* beside its scale bar (see the module docstring for the layout)."""
    h, w = values.shape
    unit = np.zeros(values.shape, np.float64)
    unit[known] = to_unit(values[known].astype(np.float64))
    image = _colorize(unit, known, cmap)
    bar = np.empty((h, bar_width_px(h), 3), np.uint8)
    bar[:] = BAR_BACKGROUND_RGB
    pad, strip, scale, thickness = _bar_geometry(h)
    rows_u = 1.0 - np.arange(h) / max(h - 1, 1) if h > 1 else np.array([0.5])  # row 0 is the top
    bar[:, pad:pad + strip] = _colorize(rows_u[:, None], np.ones((h, 1), bool), cmap)
    if scale is not None and ticks:
        positions = [(1.0 - float(to_unit(np.float64(t)))) * (h - 1) for t in ticks]
        _draw_labels(bar, positions, [f"{_round(t):g} {unit_name}" for t in ticks], pad + strip, scale, thickness)
    return np.concatenate([image, bar], axis=1)


def _draw_labels(bar, rows, labels, x0, scale, thickness) -> None:
    """Tick marks at *rows* and their *labels*, left out where they would overlap or not fit."""
    h, w = bar.shape[:2]
    pad = max(1, round(h / 80))
    widest = max(cv2.getTextSize(s, _FONT, scale, thickness)[0][0] for s in labels)
    room = w - x0 - 3 * pad
    if widest > room:  # a label wider than the template: shrink them all, or leave them out
        scale *= room / widest
        if _text_height(scale, thickness) < _MIN_TEXT_PX:
            return
    text_h = _text_height(scale, thickness)
    last = -math.inf
    for row, label in sorted(zip(rows, labels)):
        (_, glyph_h), baseline = cv2.getTextSize(label, _FONT, scale, thickness)
        top = int(round(min(max(row - glyph_h / 2, 0), h - glyph_h - baseline)))
        if top < last + text_h * 0.4:  # too close to the label above
            continue
        last = top + glyph_h + baseline
        r = int(round(row))
        bar[r, x0:x0 + pad + max(1, pad)] = BAR_INK_RGB
        cv2.putText(bar, label, (x0 + 2 * pad, top + glyph_h), _FONT, scale, BAR_INK_RGB, thickness, cv2.LINE_AA)


def _check_range(near_m, far_m):
    """(near_m, far_m) as floats or None, or InputError when either is not a finite number > 0 or near_m >= far_m."""
    near_m = _check_positive(near_m, "near_m")
    far_m = _check_positive(far_m, "far_m")
    if near_m is not None and far_m is not None and near_m >= far_m:
        raise InputError(f"near_m must be < far_m; got near_m={near_m}, far_m={far_m}")
    return near_m, far_m


def _depth_range(known_depths: np.ndarray, near_m, far_m):
    """(near, far) with near < far, metres, or None when nothing sets it."""
    if known_depths.size:
        lo, hi = (float(v) for v in np.percentile(known_depths, DEPTH_PERCENTILES))
    elif near_m is None and far_m is None:
        return None
    else:
        lo = hi = near_m if near_m is not None else far_m
    near = near_m if near_m is not None else lo
    far = far_m if far_m is not None else hi
    if near < far:
        return near, far
    if near_m is not None and far_m is None:
        return near, near * 1.1
    if far_m is not None and near_m is None:
        return far / 1.1, far
    return near / 1.1, near * 1.1


def _depth_ticks(near: float, far: float) -> list[float]:
    """Ticks in metres: the 1-2-5 series within [near, far] when it has 4 or more, else evenly stepped ones.

    Over a wide range even steps crowd at the far end of an inverse-depth bar; the 1-2-5 series,
    about even in ``log z``, does not. Labels that would still overlap are left out when drawn.
    """
    k0, k1 = math.floor(math.log10(near)), math.ceil(math.log10(far))
    series = [m * 10.0**k for k in range(k0, k1 + 1) for m in (1, 2, 5)]
    ticks = [t for t in series if near <= t <= far]
    return ticks if len(ticks) >= 4 else _nice_ticks(near, far, count=8)


def _nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """About *count* evenly stepped ticks within [lo, hi], the step 1, 2, 2.5 or 5 times a power of ten."""
    raw = (hi - lo) / count
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw)
    first = math.ceil(lo / step - 1e-9)
    return [(first + i) * step for i in range(int(math.floor(hi / step + 1e-9)) - first + 1)]


def _round(value: float) -> float:
    """*value* without float noise (0.30000000000000004 -> 0.3)."""
    return float(f"{value:.6g}")


def _as_map(array, name: str) -> np.ndarray:
    """*array* as a 2-D float64 ndarray, or InputError naming *name*."""
    if not isinstance(array, np.ndarray):
        raise InputError(f"{name} must be a numpy array; got {type(array).__name__}")
    if array.ndim != 2 or array.size == 0:
        raise InputError(f"{name} must be a non-empty (H, W) array; got shape {array.shape}")
    if array.dtype.kind not in "iuf":
        raise InputError(f"{name} must hold real numbers; got dtype {array.dtype}")
    return array.astype(np.float64)


def _check_positive(value, name: str):
    """*value* as a float when it is a finite number > 0; None stays None; anything else is an InputError."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, Real) or not (math.isfinite(value) and value > 0):
        raise InputError(f"{name} must be a finite number > 0; got {value!r}")
    return float(value)
