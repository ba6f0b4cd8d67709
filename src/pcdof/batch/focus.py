"""The lens of every frame of a batch: fixed, keyframed, or following the depth at a pixel (the focus pass)."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ..camera import Rig
from ..errors import InputError, PcdofError
from ..lens import check_radius_px, focus_depth_at, parse_focus_pixel, pixel_inside
from .frames import read_depth_m
from ..sources.discovery import Sequence
from .report import progress_bar
from .schedule import LensSchedule, build_schedule, parse_keyframes, smooth_focus_track

log = logging.getLogger("pcdof.batch")

#: Default focus-tracking smoothing (see :func:`pcdof.batch.schedule.smooth_focus_track`).
DEFAULT_SMOOTHING = {"median_window": 5, "min_cutoff_hz": 0.5, "beta": 1.0, "d_cutoff_hz": 1.0}
#: how :func:`measure_focus_track` words a frame that was read but has no depth near the point
NO_DEPTH_PREFIX = "InputError: no known depth"


def measure_focus_track(sequence: Sequence, rig: Rig, xy, *, n_frames: int | None = None, radius_px: int = 7,
                        progress: bool = False) -> tuple[np.ndarray, dict[int, str]]:
    """Depth at colour pixel *xy* in every frame (registered depth, robust window median).

    Parameters
    ----------
    sequence : Sequence
    rig : Rig
    xy : (x, y) colour pixel
    n_frames : int or None, measure the first n frames (None = all)
    radius_px : int, half-size of the window passed to :func:`pcdof.lens.focus_depth_at`
    progress : bool, show a progress bar on stderr

    Returns
    -------
    raw_m : (n,) float64 ndarray, metres, NaN where the frame has no depth near *xy* or cannot be read
    problems : {frame index: reason} for the NaN entries
    """
    from ..stages.register import needs_registration, reproject_depth

    x, y = check_xy(xy, rig)
    check_radius_px(radius_px)  # once, not once per frame
    n = len(sequence) if n_frames is None else min(int(n_frames), len(sequence))
    registered = not needs_registration(rig)[0]
    raw = np.full(n, np.nan)
    problems: dict[int, str] = {}
    for i in progress_bar(range(n), progress, desc="focus", unit="frame"):
        try:
            depth = read_depth_m(sequence.pairs[i], rig)
            color_depth = depth if registered else reproject_depth(depth, rig)
            raw[i] = focus_depth_at(color_depth, x, y, radius_px=radius_px)
        except PcdofError as err:
            problems[i] = f"{type(err).__name__}: {err}"
    return raw, problems


def check_xy(xy, rig: Rig) -> tuple[float, float]:
    x, y = parse_focus_pixel(xy)
    w, h = rig.color.width, rig.color.height
    if not pixel_inside(x, y, w, h):
        raise InputError(f"focus_at ({x:g}, {y:g}) is outside the colour image of size {w}x{h}")
    return x, y


def parse_lens_keyframes(focus_keyframes, f_number_keyframes) -> tuple:
    """The focus and f-number keyframes as sequences of (frame, value); "FRAME:VALUE,..." strings parsed."""
    if isinstance(focus_keyframes, str):
        focus_keyframes = parse_keyframes(focus_keyframes, name="focus keyframes")
    if isinstance(f_number_keyframes, str):
        f_number_keyframes = parse_keyframes(f_number_keyframes, name="f-number keyframes")
    return focus_keyframes, f_number_keyframes


def _smoothing_params(smoothing: dict | None) -> dict:
    params = {**DEFAULT_SMOOTHING, **(smoothing or {})}
    unknown = set(params) - set(DEFAULT_SMOOTHING)
    if unknown:
        raise InputError(f"smoothing keys must be among {sorted(DEFAULT_SMOOTHING)}; got {sorted(unknown)}")
    return params


def _unfocusable(raw: np.ndarray, problems: dict[int, str], no_depth: dict[int, str], where: str,
                 xy: tuple[float, float]) -> dict[int, str]:
    """{frame: reason} failing every frame when the focus point has depth in none of them."""
    why = (f"no frame of the {len(raw)} has depth at {where} ({xy[0]:g}, {xy[1]:g}), so none can be focused; "
           f"give --focus-distance or another --focus-at")
    if no_depth:
        log.warning("%s", why)
    return {i: problems[i] if i in problems and i not in no_depth
            else f"InputError: {why} (this frame: {problems.get(i, 'no depth near the point')})"
            for i in range(len(raw))}


def _follow_focus(sequence: Sequence, rig: Rig, template, *, n_frames: int, focus_at, f_number_keyframes,
                  easing: str, rate_hz: float, params: dict, progress: bool) -> LensSchedule:
    """The schedule whose focus follows the smoothed depth at *focus_at* (a pixel or "center")."""
    centre = isinstance(focus_at, str)
    if centre:
        focus_at = ((rig.color.width - 1) / 2, (rig.color.height - 1) / 2)
    raw, problems = measure_focus_track(sequence, rig, focus_at, n_frames=n_frames, progress=progress)
    x, y = check_xy(focus_at, rig)
    source = f"focus-at {x:g},{y:g}"
    # a frame whose files cannot be read fails with that reason when it renders; only a missing
    # measurement at a readable frame is the focus point's doing
    no_depth = {i: why for i, why in problems.items() if why.startswith(NO_DEPTH_PREFIX)}
    where = "the image centre" if centre else "the focus point"
    if not np.any(np.isfinite(raw) & (raw > 0)):  # nothing to follow: no frame can be focused
        schedule = build_schedule(template, n_frames, f_number_keyframes=f_number_keyframes, easing=easing,
                                  source=source, raw_focus_m=raw)
        return replace(schedule, failures=_unfocusable(raw, problems, no_depth, where, (x, y)))
    for i, why in sorted(no_depth.items())[:5]:
        log.log(logging.INFO if centre else logging.WARNING,
                "%s: frame %d has no depth there (%s); its focus follows the neighbouring frames", where, i, why)
    track = smooth_focus_track(raw, rate_hz=rate_hz, **params)
    return build_schedule(template, n_frames, focus_track_m=track, f_number_keyframes=f_number_keyframes,
                          easing=easing, source=source, raw_focus_m=raw)


def plan_lens(sequence: Sequence, rig: Rig, template, *, n_frames: int, focus_at=None, focus_keyframes=None,
              f_number_keyframes=None, easing: str = "linear", rate_hz: float = 30.0, smoothing: dict | None = None,
              progress: bool = False) -> LensSchedule:
    """Decide the lens of frames 0..n_frames-1 (runs the focus pass when *focus_at* is given).

    Parameters
    ----------
    sequence, rig : the input
    template : ThinLens or PaperLens, fixed settings (and the focus / f-number where nothing else decides)
    n_frames : int
    focus_at : (x, y) colour pixel, "center" (the image centre) or None: focus follows the smoothed depth there
    focus_keyframes, f_number_keyframes : "FRAME:VALUE,..." strings or sequences of (frame, value), or None
    easing : "linear" or "smoothstep" (between keyframes)
    rate_hz : float, frames per second (the focus smoother's time base)
    smoothing : dict or None, overrides of :data:`DEFAULT_SMOOTHING`

    Returns
    -------
    LensSchedule; when *focus_at* has no depth in any frame, every frame is in its ``failures``
    (the batch records them as failed, exit 11) instead of an error that stops the batch
    """
    focus_keyframes, f_number_keyframes = parse_lens_keyframes(focus_keyframes, f_number_keyframes)
    if focus_at is None:
        return build_schedule(template, n_frames, focus_keyframes=focus_keyframes,
                              f_number_keyframes=f_number_keyframes, easing=easing)
    if focus_keyframes is not None:
        raise InputError("focus_at and focus keyframes exclude each other; give one")
    if isinstance(focus_at, str) and focus_at not in ("center", "centre"):
        raise InputError(f"focus_at must be (x, y), 'center' or None; got {focus_at!r}")
    params = _smoothing_params(smoothing)
    return _follow_focus(sequence, rig, template, n_frames=n_frames, focus_at=focus_at,
                         f_number_keyframes=f_number_keyframes, easing=easing, rate_hz=rate_hz, params=params,
                         progress=progress)
